"""Experiment specifications: what one table or figure of the paper needs, read from YAML and checked up front.

A specification (``sb3_emmarl/experiments/specs/<name>.yml``, package data) names the algorithms (zoo algorithms,
optionally with hyperparameter overrides: the variants of an ablation), the environment conditions (the environment's
arguments for training and for evaluation, and an optional fine-tuning stage; the environment is the reserve unless
``env`` names another zoo id, e.g. ``env: ZonePatrol-v0``), the metrics, the reference of the
paired tests, two budgets (``quick``: this 2-core machine in about 30 minutes; ``full``: the paper's 5 seeds and 5000
episodes), the outputs (tables, bar charts, learning curves, trajectory plots) and the paper's claimed numbers.
Every cell of the experiment is one (algorithm, condition, seed). Everything is checked when the file is loaded, so
that a bad specification fails before anything runs, with a message naming the field::

    name: table2_robustness
    title: Robustness to sensor corruption, communication loss and adversarial attacks
    paper: Table 2
    algorithms: {em_ppo: {algo: em_ppo}, ppo: {algo: ppo}}
    conditions: {clean: {}, sensor: {train: {sensor_noise: 0.3}}}
    reference: ppo
    metrics: [team_reward, detection_rate, coverage_efficiency, train_seconds]
    budgets:
      quick: {n_timesteps: 200000, seeds: [0, 1, 2], eval_episodes: 10}
      full: {episodes: 5000, seeds: [0, 1, 2, 3, 4], eval_episodes: 50}
    outputs: [{kind: table}]
    claims: {em_ppo: {sensor: {detection_rate: "85.2 +- 3.1"}}}
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sb3_emmarl.common.env_ids import ENV_ID, check_env_id, check_env_kwargs
from sb3_emmarl.common.trust.safe_config import load_yaml

#: Where the package's specifications live.
SPECS_DIR = Path(__file__).resolve().parent / "specs"
#: The budgets every specification has.
BUDGETS = ("quick", "full")
#: What an experiment can show.
OUTPUT_KINDS = ("table", "bars", "curves", "trajectories")
#: Metrics of an evaluated team (per-episode means over the evaluation episodes): the reserve's episode metrics,
#: ZonePatrol's and, for the EM algorithms, the latent ones.
EPISODE_METRICS = ("team_reward", "coverage_efficiency", "detection_rate", "false_alarms", "poaching_events",
                   "collisions", "energy", "time_to_first_detection", "poachers_entered", "poachers_detected",
                   "signs_found", "episode_length", "detections", "escapes", "intruders", "latent_accuracy",
                   "latent_accuracy_25", "latent_accuracy_50", "latent_accuracy_100", "latent_kl", "latent_nmi")
#: Metrics of the training run itself (the zoo's run_stats.json).
RUN_METRICS = ("train_seconds", "peak_rss_mib", "cpu_percent", "agent_steps_per_second", "n_timesteps")
METRICS = EPISODE_METRICS + RUN_METRICS
#: Tensorboard scalars the learning-curve figures can draw (SB3's names).
CURVE_TAGS = ("rollout/ep_rew_mean", "train/entropy_loss", "train/policy_gradient_loss", "train/actor_loss",
              "train/loss", "train/value_loss")
#: Names an algorithm cannot take: the report's figures sit beside the algorithms' folders of a budget.
RESERVED_NAMES = ("figures",)
#: Agent-steps of one episode in the ``full`` budget's ``episodes`` (the reserve's default ``max_cycles``, 10 UAVs):
#: the paper counts 5000 episodes of a team.
FULL_EPISODE_AGENT_STEPS = 200 * 10


def _fail(where: str, message: str) -> None:
    raise ValueError(f"{where}: {message}")


def _mapping(where: str, value: Any) -> dict:
    if not isinstance(value, dict):
        _fail(where, f"must be a mapping, got {value!r}")
    return value


def _keys(where: str, value: dict, required: tuple[str, ...], optional: tuple[str, ...] = ()) -> None:
    unknown = sorted(set(value) - set(required) - set(optional))
    if unknown:
        _fail(where, f"unknown field(s) {unknown}; allowed: {sorted(required + optional)}")
    missing = [key for key in required if key not in value]
    if missing:
        _fail(where, f"missing field(s) {missing}")


def _positive_int(where: str, value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or value != int(value) or value < 1:
        _fail(where, f"must be a positive whole number, got {value!r}")
    return int(value)


def _env_kwargs(where: str, value: Any, env_id: str = ENV_ID) -> dict[str, Any]:
    """The environment's arguments, checked by its configuration."""
    kwargs = dict(_mapping(where, value or {}))
    try:
        check_env_kwargs(env_id, kwargs)
    except ValueError as error:
        _fail(where, f"not valid {env_id} arguments: {error}")
    return kwargs


@dataclass(frozen=True)
class Variant:
    """One compared method: a zoo algorithm and hyperparameter overrides (``-params``).

    :param algo: the zoo algorithm (``--algo``)
    :param hyperparams: overrides of its YAML's settings
    """

    algo: str
    hyperparams: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class Condition:
    """Where the cells train and are evaluated.

    :param train: the reserve's arguments in training
    :param eval: in evaluation (default: ``train``)
    :param fine_tune: fine-tuning stage: ``{"env_kwargs": ..., "fraction": f}`` trains ``(1 - f)`` of the budget on
        ``train`` and ``f`` on ``env_kwargs`` from there (the transfer experiment); None: no stage
    """

    train: dict[str, Any] = field(default_factory=dict)
    eval: dict[str, Any] | None = None
    fine_tune: dict[str, Any] | None = None

    @property
    def eval_kwargs(self) -> dict[str, Any]:
        return dict(self.train if self.eval is None else self.eval)


@dataclass(frozen=True)
class Budget:
    """How much every cell trains and is evaluated.

    :param n_timesteps: agent-steps of training
    :param seeds: training seeds (one cell per seed)
    :param eval_episodes: evaluation episodes per cell (the same episodes for every cell: seed ``eval_seed``)
    :param eval_seed: seed of the evaluation episodes
    """

    n_timesteps: int
    seeds: tuple[int, ...]
    eval_episodes: int
    eval_seed: int = 50_000


@dataclass(frozen=True)
class Output:
    """One table or figure: ``kind`` (see :data:`OUTPUT_KINDS`), the metric or tensorboard tag it draws."""

    kind: str
    metric: str | None = None


@dataclass(frozen=True)
class ExperimentSpec:
    """A checked experiment specification (see the module docstring)."""

    name: str
    title: str
    paper: str
    algorithms: dict[str, Variant]
    conditions: dict[str, Condition]
    metrics: tuple[str, ...]
    budgets: dict[str, Budget]
    outputs: tuple[Output, ...]
    reference: str | None = None
    claims: dict[str, Any] = field(default_factory=dict)
    notes: str = ""
    env: str = ENV_ID

    def cells(self, budget: str, conditions: Sequence[str] | None = None) -> list[tuple[str, str, int]]:
        """Every (algorithm, condition, seed) of ``budget``, seeds outermost (load drifts hit every method alike).

        :param budget: ``"quick"`` or ``"full"``
        :param conditions: only these conditions' cells (None: every condition)
        """
        if conditions is not None:
            unknown = [c for c in conditions if c not in self.conditions]
            if unknown or not conditions:
                raise ValueError(f"conditions of {self.name} are {list(self.conditions)}, got {list(conditions)}")
        chosen = [c for c in self.conditions if conditions is None or c in conditions]
        return [(a, c, s) for s in self.budgets[budget].seeds for c in chosen for a in self.algorithms]


def _algorithms(where: str, data: Any) -> dict[str, Variant]:
    from sb3_emmarl.zoo.algos import ZOO_ALGOS

    algorithms: dict[str, Variant] = {}
    for name, value in _mapping(f"{where}: algorithms", data).items():
        at = f"{where}: algorithms.{name}"
        if name in RESERVED_NAMES:
            _fail(at, f"{name!r} is the name of the report's folder beside the cells' folders; choose another name")
        value = _mapping(at, value)
        _keys(at, value, ("algo",), ("hyperparams",))
        if value["algo"] not in ZOO_ALGOS:
            _fail(f"{at}.algo", f"unknown algorithm {value['algo']!r}; the zoo trains {sorted(ZOO_ALGOS)}")
        algorithms[str(name)] = Variant(value["algo"], dict(_mapping(f"{at}.hyperparams", value.get("hyperparams") or {})))
    if not algorithms:
        _fail(f"{where}: algorithms", "must name at least one algorithm")
    return algorithms


def _conditions(where: str, data: Any, env_id: str = ENV_ID) -> dict[str, Condition]:
    conditions: dict[str, Condition] = {}
    for name, value in _mapping(f"{where}: conditions", data).items():
        at = f"{where}: conditions.{name}"
        value = _mapping(at, value or {})
        _keys(at, value, (), ("train", "eval", "fine_tune"))
        fine_tune = value.get("fine_tune")
        if fine_tune is not None:
            fine_tune = _mapping(f"{at}.fine_tune", fine_tune)
            _keys(f"{at}.fine_tune", fine_tune, ("env_kwargs", "fraction"))
            fraction = fine_tune["fraction"]
            if isinstance(fraction, bool) or not isinstance(fraction, (int, float)) or not 0 < fraction < 1:
                _fail(f"{at}.fine_tune.fraction", f"must be a number in (0, 1), got {fraction!r}")
            fine_tune = {"env_kwargs": _env_kwargs(f"{at}.fine_tune.env_kwargs", fine_tune["env_kwargs"], env_id),
                         "fraction": float(fraction)}
        evaluation = None if value.get("eval") is None else _env_kwargs(f"{at}.eval", value["eval"], env_id)
        conditions[str(name)] = Condition(_env_kwargs(f"{at}.train", value.get("train"), env_id), evaluation, fine_tune)
    if not conditions:
        _fail(f"{where}: conditions", "must name at least one condition ({} for the default reserve)")
    return conditions


def _metrics(where: str, metrics: Any) -> tuple[str, ...]:
    if not isinstance(metrics, list) or not metrics:
        _fail(f"{where}: metrics", f"must be a non-empty list, got {metrics!r}")
    for metric in metrics:
        if metric not in METRICS:
            _fail(f"{where}: metrics", f"unknown metric {metric!r}; allowed: {list(METRICS)}")
    return tuple(metrics)


def _budget(at: str, value: Any) -> Budget:
    value = _mapping(at, value)
    _keys(at, value, ("seeds", "eval_episodes"), ("n_timesteps", "episodes", "eval_seed"))
    if ("n_timesteps" in value) == ("episodes" in value):
        _fail(at, "give exactly one of n_timesteps (agent-steps) and episodes (team episodes)")
    steps = (_positive_int(f"{at}.n_timesteps", value["n_timesteps"]) if "n_timesteps" in value
             else _positive_int(f"{at}.episodes", value["episodes"]) * FULL_EPISODE_AGENT_STEPS)
    seeds = value["seeds"]
    if (not isinstance(seeds, list) or not seeds or len(set(seeds)) != len(seeds)
            or not all(isinstance(s, int) and not isinstance(s, bool) and s >= 0 for s in seeds)):
        _fail(f"{at}.seeds", f"must be a non-empty list of distinct ints >= 0, got {seeds!r}")
    eval_seed = value.get("eval_seed", 50_000)
    if isinstance(eval_seed, bool) or not isinstance(eval_seed, int) or eval_seed < 0:
        _fail(f"{at}.eval_seed", f"must be an int >= 0, got {eval_seed!r}")
    return Budget(steps, tuple(seeds), _positive_int(f"{at}.eval_episodes", value["eval_episodes"]), eval_seed)


def _outputs(where: str, data: Any) -> tuple[Output, ...]:
    if not isinstance(data, list) or not data:
        _fail(f"{where}: outputs", f"must be a non-empty list, got {data!r}")
    outputs = []
    for i, value in enumerate(data):
        at = f"{where}: outputs[{i}]"
        value = _mapping(at, value)
        _keys(at, value, ("kind",), ("metric",))
        if value["kind"] not in OUTPUT_KINDS:
            _fail(f"{at}.kind", f"unknown output {value['kind']!r}; allowed: {list(OUTPUT_KINDS)}")
        metric = value.get("metric")
        allowed = CURVE_TAGS if value["kind"] == "curves" else METRICS
        if value["kind"] in ("bars", "curves") and metric not in allowed:
            _fail(f"{at}.metric", f"{value['kind']} needs a metric among {list(allowed)}, got {metric!r}")
        outputs.append(Output(value["kind"], metric))
    return tuple(outputs)


def _check_claims(where: str, claims: dict, algorithms: dict, conditions: dict) -> None:
    for algorithm, by_condition in claims.items():
        if algorithm not in algorithms:
            _fail(f"{where}: claims", f"{algorithm!r} is not among the algorithms {list(algorithms)}")
        for condition, values in _mapping(f"{where}: claims.{algorithm}", by_condition).items():
            if condition not in conditions:
                _fail(f"{where}: claims.{algorithm}", f"{condition!r} is not among the conditions {list(conditions)}")
            for metric in _mapping(f"{where}: claims.{algorithm}.{condition}", values):
                if metric not in METRICS:
                    _fail(f"{where}: claims.{algorithm}.{condition}", f"unknown metric {metric!r}")


def parse_spec(data: Any, where: str = "specification") -> ExperimentSpec:
    """Check a specification's content and build it.

    :param data: the YAML's content
    :param where: how to name it in messages (its file)
    :raise ValueError: naming the first bad field
    """
    data = _mapping(where, data)
    _keys(where, data, ("name", "title", "paper", "algorithms", "conditions", "metrics", "budgets", "outputs"),
          ("reference", "claims", "notes", "env"))
    try:
        env_id = check_env_id(data.get("env", ENV_ID))
    except ValueError as error:
        _fail(f"{where}: env", str(error))
    for key in ("name", "title", "paper"):
        if not isinstance(data[key], str) or not data[key]:
            _fail(f"{where}: {key}", f"must be a non-empty string, got {data[key]!r}")
    algorithms = _algorithms(where, data["algorithms"])
    conditions = _conditions(where, data["conditions"], env_id)
    raw_budgets = _mapping(f"{where}: budgets", data["budgets"])
    _keys(f"{where}: budgets", raw_budgets, BUDGETS)
    budgets = {name: _budget(f"{where}: budgets.{name}", value) for name, value in raw_budgets.items()}
    reference = data.get("reference")
    if reference is not None and reference not in algorithms:
        _fail(f"{where}: reference", f"{reference!r} is not among the algorithms {list(algorithms)}")
    claims = _mapping(f"{where}: claims", data.get("claims") or {})
    _check_claims(where, claims, algorithms, conditions)
    outputs = _outputs(where, data["outputs"])
    if env_id != ENV_ID and any(output.kind == "trajectories" for output in outputs):
        _fail(f"{where}: outputs", f"trajectories are drawn on the reserve's map only, not on {env_id}")
    return ExperimentSpec(data["name"], data["title"], data["paper"], algorithms, conditions,
                          _metrics(where, data["metrics"]), budgets, outputs, reference,
                          claims, str(data.get("notes") or ""), env_id)


def load_spec(name_or_path: str | Path) -> ExperimentSpec:
    """A specification by name (``specs/<name>.yml`` in the package) or by path.

    :raise ValueError: for an unknown name, unreadable YAML or a bad field
    """
    path = Path(name_or_path)
    if not path.suffix:
        path = SPECS_DIR / f"{name_or_path}.yml"
        if not path.is_file():
            raise ValueError(f"unknown experiment {str(name_or_path)!r}; known: {list_specs()}")
    try:
        data = load_yaml(path, "the specification")
    except ValueError as error:
        raise ValueError(f"cannot read the specification: {error}") from None
    spec = parse_spec(data, str(path))
    if spec.name != path.stem:
        raise ValueError(f"{path}: name: {spec.name!r} must be the file's name {path.stem!r}")
    return spec


def list_specs() -> list[str]:
    """The names of the package's specifications."""
    return sorted(p.stem for p in SPECS_DIR.glob("*.yml"))
