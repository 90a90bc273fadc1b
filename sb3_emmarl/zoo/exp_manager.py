"""rl_zoo3's ``ExperimentManager``, taught to build the parameter-sharing vector environments of the reserve and
ZonePatrol (``--env WildlifeReserve-v1``, the default, or ``--env ZonePatrol-v0``).

rl_zoo3 reads the YAML hyperparameters, builds schedules, callbacks and action noise, saves runs in
its folder layout and tunes with optuna; all of that is reused. What changes:

- ``create_envs`` builds :func:`~sb3_emmarl.common.vec_env.make_vec_env` (``n_envs`` reserve copies,
  one vector entry per UAV) instead of ``gym.make`` copies, with the true mode for ``oracle_ppo`` (the EM
  algorithms add their belief wrapper themselves, to the evaluation environment too); the centralised algorithms keep
  rl_zoo3's own path
  through the Gymnasium id ``WildlifeReserve-v1``; ``ppo_gat`` / ``ppo_transformer`` get the neighbour messages
  (training and evaluation environments alike);
- ``oracle_ppo`` reads ``ppo.yml``: the same settings as PPO by construction;
- ``n_envs`` is counted in vector entries (copies x UAVs) once the YAML is read, so that rl_zoo3's
  ``--eval-freq`` / ``--save-freq`` / optuna arithmetic, which divides by ``n_envs``, stays right;
- the environment's arguments are validated before any folder is written;
- :class:`~sb3_emmarl.common.callbacks.TeamMetricsCallback` is added to the training callbacks (and
  :class:`~sb3_emmarl.common.callbacks.LatentMetricsCallback` for the EM algorithms), and every callback runs inside
  :class:`~sb3_emmarl.common.phases.PhaseTimes`, which times the run by phase (``time/`` in tensorboard, a table at
  the end);
- the hyperparameters are checked by :func:`~sb3_emmarl.common.trust.validation.check_hyperparams` before anything
  is built, and the YAML file must be a mapping holding the environment's entry; then, still before the run folder
  exists, what SB3 would only find in the first rollout or update (the constructors' annotations, the optimizer, the
  callbacks, the tensorboard folder: :meth:`ReserveExperimentManager._check_before_folder`), and a start that fails
  later removes the folders it made;
- ``-params`` and ``-optimize``'s samples update the YAML's ``latent_kwargs`` field by field and refit
  ``count_factors`` (:func:`~sb3_emmarl.zoo.algos.merge_hyperparams`);
- the periodic evaluations (``--eval-freq``) and optuna's trials count team episodes
  (:class:`~sb3_emmarl.common.callbacks.EvalCallback`, through :class:`~sb3_emmarl.common.callbacks.AtomicEvalCallback`
  and :class:`TeamTrialEvalCallback`), not the UAVs of one episode as SB3's does;
- every file is written atomically (:mod:`sb3_emmarl.common.trust.atomic_files`), ``config.yml`` and ``args.yml``
  as plain YAML (rl_zoo3 writes Python tags), checkpoints by
  :class:`~sb3_emmarl.common.checkpoints.ResumableCheckpointCallback` with the training state;
- the training environment is wrapped in :class:`~sb3_emmarl.common.vec_env.FiniteCheck` (SB3's
  ``VecCheckNan`` raising at the first NaN or inf, with the step);
- ``trained_agent`` (``-i``) is checked before use and loads its checkpoint's replay buffer and
  ``VecNormalize`` companions; ``resume_run`` continues a stopped run in its own folder from its newest
  checkpoint, with the training state, up to the run's ``n_timesteps``.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Any

import numpy as np
import rl_zoo3.exp_manager
import yaml
from rl_zoo3.callbacks import TrialEvalCallback
from rl_zoo3.exp_manager import ExperimentManager
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import CheckpointCallback, EvalCallback
from stable_baselines3.common.noise import NormalActionNoise, OrnsteinUhlenbeckActionNoise
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.vec_env import VecEnv

from sb3_emmarl.common.callbacks import AtomicEvalCallback, LatentMetricsCallback, TeamMetricsCallback
from sb3_emmarl.common.callbacks import EvalCallback as TeamEvalCallback
from sb3_emmarl.common.centralized import register_envs
from sb3_emmarl.common.checkpoints import (
    REPLAY_BUFFER,
    TRAINING_STATE,
    VEC_NORMALIZE,
    VEC_NORMALIZE_FILE,
    ResumableCheckpointCallback,
    SaveVecNormalize,
    companion,
)
from sb3_emmarl.common.env_ids import ENV_ID, check_env_id, parallel_env_fn
from sb3_emmarl.common.latent.config import lift_flat_settings
from sb3_emmarl.common.mode_aware import wrap_with_mode
from sb3_emmarl.common.model_files import check_model_file, check_saved_algorithm
from sb3_emmarl.common.phases import PhaseTimes
from sb3_emmarl.common.training_state import load_training_state, restore_environment_state, restore_random_generators
from sb3_emmarl.common.trust.atomic_files import save_model, save_pickle, write_text
from sb3_emmarl.common.trust.safe_config import IMPORT_KEYS, check_imports, is_plain, load_yaml, to_source
from sb3_emmarl.common.trust.safe_pickle import load_data_pickle, load_vec_normalize
from sb3_emmarl.common.trust.safe_zip import safe_data_objects
from sb3_emmarl.common.trust.validation import check_hyperparams, parse_policy_kwargs
from sb3_emmarl.common.vec_env import ZOO_VEC_ENVS, FiniteCheck, make_vec_env
from sb3_emmarl.message_ppo import MessagePPO
from sb3_emmarl.message_ppo.message_ppo import wrap_with_messages
from sb3_emmarl.oracle_ppo import OraclePPO
from sb3_emmarl.zoo.algos import (
    CENTRALIZED_ALGOS,
    LATENT_ALGOS,
    SHARED_HYPERPARAMS,
    STATE_ALGOS,
    ZOO_ALGOS,
    merge_hyperparams,
    register_algorithms,
)

#: The YAML files of the zoo (``sb3_emmarl/zoo/hyperparams/<algo>.yml``, package data: a wheel install has them).
HYPERPARAMS_DIR = Path(__file__).resolve().parent / "hyperparams"
#: Offset between the training seed and the seed of the evaluation environment.
EVAL_SEED_OFFSET = 10_000


def read_yaml(path: str | Path, what: str) -> Any:
    """A YAML file read as data (:func:`~sb3_emmarl.common.trust.safe_config.load_yaml`): a Python tag, an oversized file and
    aliases that expand beyond the limit are refused with a message naming the file.

    :param path: the file
    :param what: what the file is, for messages
    :raise ValueError: if the file does not parse, holds Python objects or is too large
    """
    return load_yaml(path, what)


#: The key of a YAML section that names the zoo file whose settings it starts from (``base: ppo``).
BASE_KEY = "base"


def yaml_section(content: Any, env_id: str, source: str | Path) -> dict[str, Any]:
    """The hyperparameters of ``env_id`` (else of ``default``) in a hyperparameter file's ``content``, with the
    settings of the zoo file its ``base`` key names underneath (recursively; its own keys win, a whole value at a
    time: a ``base`` file's ``env_kwargs`` are replaced, not merged). ``em_ppo.yml`` starts from ``ppo.yml`` this way,
    so the PPO settings the two share are written once; a user's own file may start from any zoo file too.

    :param content: the file's content (``read_yaml``)
    :param env_id: the environment's id
    :param source: the file, for messages
    :raise ValueError: no mapping for ``env_id``, a ``base`` that names no zoo file, or a cycle of ``base`` files
    """
    chain: list[str] = []
    layers: list[dict[str, Any]] = []
    while True:
        if not isinstance(content, dict):
            raise ValueError(f"{source} must map {env_id!r} to its hyperparameters, got {type(content).__name__}")
        section = content.get(env_id, content.get("default"))
        if not isinstance(section, dict):
            raise ValueError(f"{source} has no mapping of hyperparameters under {env_id!r}")
        layers.append({key: value for key, value in section.items() if key != BASE_KEY})
        if BASE_KEY not in section:
            break
        base = section[BASE_KEY]
        names = sorted(path.stem for path in HYPERPARAMS_DIR.glob("*.yml"))
        if not isinstance(base, str) or base not in names:
            raise ValueError(f"{source}: {BASE_KEY} must name a zoo hyperparameter file, one of {names}, got {base!r}")
        if base in chain:
            raise ValueError(f"{source}: the {BASE_KEY} files form a cycle: {' -> '.join([*chain, base])}")
        chain.append(base)
        source = HYPERPARAMS_DIR / f"{base}.yml"
        content = read_yaml(source, "a hyperparameter file")
    merged: dict[str, Any] = {}
    for layer in reversed(layers):
        merged.update(layer)
    return merged


def zoo_file(algo: str) -> Path:
    """The zoo's hyperparameter file of ``algo`` (``oracle_ppo`` reads ``ppo.yml``: :data:`SHARED_HYPERPARAMS`)."""
    return HYPERPARAMS_DIR / f"{SHARED_HYPERPARAMS.get(algo, algo)}.yml"


def zoo_hyperparams(algo: str, env_id: str = ENV_ID) -> dict[str, Any]:
    """The zoo's settings of ``algo`` for ``env_id``, as training reads them: its file (:func:`zoo_file`) with its
    ``base`` resolved (:func:`yaml_section`)."""
    path = zoo_file(algo)
    return yaml_section(read_yaml(path, "a hyperparameter file"), env_id, path)


def zoo_policy_kwargs(algo: str, env_id: str = ENV_ID, **changes: Any) -> dict[str, Any]:
    """The zoo YAML's ``policy_kwargs`` of ``algo`` for ``env_id`` as a dict (the YAML writes it as rl-zoo's
    ``"dict(...)"`` string), with ``changes`` laid over it key by key: for ``zoo_model(...,
    policy_kwargs=zoo_policy_kwargs(algo, env_id, belief_conditioning="film"))``, which keeps the YAML's ``net_arch``
    (an override's ``policy_kwargs`` otherwise replaces the YAML's whole, as in rl-zoo)."""
    base = zoo_hyperparams(algo, env_id).get("policy_kwargs") or {}
    return {**(parse_policy_kwargs(base) if isinstance(base, str) else dict(base)), **changes}


#: Settings of the zoo's YAML files that are not the algorithm's arguments.
ZOO_ONLY = ("n_timesteps", "n_envs", "normalize", "env_kwargs", "policy", "noise_type", "noise_std")
#: rl-zoo's ``noise_type`` values and the SB3 action noise each builds.
ACTION_NOISES = {"normal": NormalActionNoise, "ornstein-uhlenbeck": OrnsteinUhlenbeckActionNoise}


def zoo_model(algo: str, env: Any, seed: int, env_id: str = ENV_ID, **overrides: Any) -> BaseAlgorithm:
    """``algo`` built on ``env`` with the zoo YAML's settings for ``env_id`` (checked as training checks them;
    ``overrides`` win), for scripts that train outside the zoo's command line on the same settings.

    :param algo: a zoo algorithm name (``oracle_ppo`` reads ``ppo.yml``)
    :param env: the vector environment (``n_envs`` copies of ``env_id``, as the YAML says, for the same rollout)
    :param seed: the model's seed
    :param env_id: whose section of the YAML to read
    :raise ValueError: a YAML that normalises observations (the scripts do not), or a setting that fails its check
    """
    settings = check_hyperparams(algo, ZOO_ALGOS[algo], zoo_hyperparams(algo, env_id))
    if settings.get("normalize"):
        raise ValueError(f"{zoo_file(algo).name} normalizes observations on {env_id}; build the model through the zoo")
    kwargs = {key: value for key, value in settings.items() if key not in ZOO_ONLY}
    if settings.get("noise_type") is not None:  # as rl-zoo builds it (its method needs a whole manager)
        noise = ACTION_NOISES.get(str(settings["noise_type"]).strip())
        if noise is None:
            raise ValueError(f"noise_type must be one of {sorted(ACTION_NOISES)}, got {settings['noise_type']!r}")
        n_actions = int(np.prod(env.action_space.shape))
        kwargs["action_noise"] = noise(mean=np.zeros(n_actions), sigma=float(settings["noise_std"]) * np.ones(n_actions))
    return ZOO_ALGOS[algo](settings["policy"], env, seed=seed, **merge_hyperparams(kwargs, overrides))


def plain(value: Any) -> Any:
    """``value`` as plain YAML data (dicts, lists, str, numbers, bools, None) for ``yaml.safe_dump``."""
    if isinstance(value, dict):
        return {str(k): plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if hasattr(value, "item") and callable(value.item) and getattr(value, "shape", None) == ():
        return value.item()
    if value is None or isinstance(value, (str, int, float, bool)):
        return value
    return repr(value)


def write_yaml(path: str | Path, data: Any) -> None:
    """Write plain YAML atomically (readable with ``yaml.safe_load``)."""
    write_text(path, yaml.safe_dump(plain(data), sort_keys=True))


def check_tensorboard_folder(folder: str | None) -> None:
    """Refuse a tensorboard folder SB3 could not create or write in (it tries at the start of ``learn``): an
    existing file, or a path under a file, or under a folder this process may not write in.

    :param folder: ``-tb``'s folder (None or empty: no tensorboard)
    :raise ValueError: one line naming the folder and what is wrong
    """
    if not folder:
        return
    path = existing = Path(folder)
    while not existing.exists() and existing != existing.parent:  # the nearest part of the path that exists
        existing = existing.parent
    if not existing.is_dir():
        where = "is a file" if existing == path else f"is under {existing}, which is a file"
        raise ValueError(f"--tensorboard-log {folder!r} {where}: give a folder")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise ValueError(f"--tensorboard-log {folder!r}: cannot write in {existing}")


class TeamTrialEvalCallback(TrialEvalCallback, TeamEvalCallback):
    """rl_zoo3's ``TrialEvalCallback`` (an optuna trial's evaluations, reported to the pruner) whose evaluations count
    team episodes: its ``super()._on_step()`` is :class:`~sb3_emmarl.common.callbacks.EvalCallback`'s. Same arguments
    as rl_zoo3's."""


class ReserveExperimentManager(ExperimentManager):
    """rl_zoo3's experiment manager on the wildlife reserve (see the module docstring for what differs).

    Takes rl_zoo3's arguments; ``config`` defaults to ``sb3_emmarl/zoo/hyperparams/<algo>.yml``.
    """

    def __init__(self, args: Any, algo: str, env_id: str, *posargs: Any, resume_run: str | Path | None = None,
                 **kwargs: Any) -> None:
        register_envs()
        register_algorithms()
        if algo not in ZOO_ALGOS:
            raise ValueError(f"unknown algorithm {algo!r}; the zoo trains {sorted(ZOO_ALGOS)}")
        check_env_id(env_id)
        #: the environment's ``parallel_env``
        self.env_fn = parallel_env_fn(env_id)
        if kwargs.get("config") is None:
            kwargs["config"] = str(zoo_file(algo))
        if not Path(kwargs["config"]).is_file():
            raise ValueError(f"no hyperparameter file {kwargs['config']!r} for algorithm {algo!r}")
        if Path(kwargs["config"]).suffix not in (".yml", ".yaml"):
            raise ValueError(f"the hyperparameter file must be YAML (.yml or .yaml), got {kwargs['config']!r}")
        self.num_cpus = 0
        # rl-zoo's --vec-env picks SB3's DummyVecEnv or SubprocVecEnv; here it picks the parameter-sharing path:
        # "batched" (ReserveVecEnv in this process), "supersuit" or rl-zoo's "dummy" (SuperSuit in this process),
        # "subproc" (ReserveVecEnv with its copies split over this process and workers, one per core). rl_zoo3
        # itself only needs to know whether there are workers.
        self.vec_env_path = kwargs.get("vec_env_type", "batched")  # the command line's default
        if self.vec_env_path not in ZOO_VEC_ENVS:
            raise ValueError(f"vec_env_type must be one of {list(ZOO_VEC_ENVS)}, got {self.vec_env_path!r}")
        kwargs["vec_env_type"] = "subproc" if self.vec_env_path == "subproc" else "dummy"
        super().__init__(args, algo, env_id, *posargs, **kwargs)
        self.centralized = algo in CENTRALIZED_ALGOS
        self.agents_per_copy = 1
        # Periodic evaluations sample actions, as evaluate_team does (argmax locks identical UAVs together).
        self.deterministic_eval = self.centralized
        if self.trained_agent:
            check_model_file(self.trained_agent)
            check_saved_algorithm(self.trained_agent, ZOO_ALGOS[algo], ZOO_ALGOS)
            self.continue_training = True
        self.resume_run = resume_run
        self._training_state: dict[str, Any] | None = None
        if resume_run is not None:  # continue in the run's own folder, with the run's own hyperparameters
            self.save_path = str(resume_run)
            self.params_path = f"{self.save_path}/{self.env_name}"
            self.config = f"{self.params_path}/config.yml"
        #: True once this manager has created its run folder (a failed set-up removes only such a folder)
        self.created_folder = False
        self.created_root: Path | None = None

    def read_hyperparameters(self) -> tuple[dict[str, Any], dict[str, Any]]:
        """rl_zoo3's reading, checked (:func:`~sb3_emmarl.common.trust.validation.check_hyperparams`), except that
        ``--env-kwargs`` update the YAML's ``env_kwargs`` instead of replacing them (so ``ddpg.yml``'s
        ``continuous_actions: true`` survives ``--env-kwargs n_uavs:20``). A resumed run reads its own
        ``config.yml``."""
        content = read_yaml(self.config, "a hyperparameter file")
        if self.resume_run is not None:
            hyperparams = lift_flat_settings(content) if isinstance(content, dict) else content
        else:
            hyperparams = merge_hyperparams(yaml_section(content, self.env_name.gym_id, self.config),
                                            self.custom_hyperparams or {})
        original_policy_kwargs = hyperparams.get("policy_kwargs")
        try:
            hyperparams = check_hyperparams(self.algo, ZOO_ALGOS[self.algo], hyperparams)
        except ValueError as error:  # say where the setting comes from
            raise ValueError(f"{self.settings_source()}: {error}") from None
        yaml_env_kwargs = hyperparams.get("env_kwargs") or {}
        self.env_kwargs = {**yaml_env_kwargs, **(self.env_kwargs or {})}
        hyperparams["env_kwargs"] = self.env_kwargs
        if self._eval_env_kwargs_args is None:
            self.eval_env_kwargs = self.env_kwargs
        saved_hyperparams = {key: hyperparams[key] for key in sorted(hyperparams)}
        if self.n_timesteps > 0:  # -n: the budget the run uses, in config.yml as in args.yml
            saved_hyperparams["n_timesteps"] = self.n_timesteps
        for key, value in saved_hyperparams.items():  # a value holding classes: saved as the text that names them
            if not is_plain(value):
                saved_hyperparams[key] = to_source(value)
        if isinstance(original_policy_kwargs, str):  # saved as written
            saved_hyperparams["policy_kwargs"] = original_policy_kwargs
        if self.verbose > 0:
            print(f"Hyperparameters from {self.config}: {saved_hyperparams}")
        return dict(hyperparams), saved_hyperparams

    def _preprocess_hyperparams(self, hyperparams: dict[str, Any]):
        # rl_zoo3 evaluates these strings and imports dotted names: check_hyperparams has made them data (a guard)
        for key in ("policy_kwargs", "replay_buffer_class", "replay_buffer_kwargs", "monitor_kwargs", "normalize"):
            if isinstance(hyperparams.get(key), str):
                raise ValueError(f"{key}: refusing the unparsed string {hyperparams[key]!r} (rl_zoo3 would evaluate it)")
        if "." in str(hyperparams.get("policy", "")):
            raise ValueError(f"policy must be a policy name, not a module path: {hyperparams['policy']!r}")
        for key in IMPORT_KEYS:
            check_imports(key, hyperparams.get(key))
        processed = super()._preprocess_hyperparams(hyperparams)
        if self.n_timesteps <= 0:
            raise ValueError(f"n_timesteps must be >= 1, got {self.n_timesteps}")
        if self._eval_env_kwargs_args is None:  # rl_zoo3 only copies them when --env-kwargs is given
            self.eval_env_kwargs = self.env_kwargs
        # Validate the environment's arguments now, before any folder or process exists.
        prototype = self.env_fn(**self.env_kwargs)
        self.env_fn(**self.eval_env_kwargs).close()
        if not self.centralized:
            self.agents_per_copy = len(prototype.possible_agents)
            self.n_envs *= self.agents_per_copy  # rl_zoo3 divides step counts by n_envs: count vector entries
        if self.vec_env_class.__name__ == "SubprocVecEnv":
            self.num_cpus = min(os.cpu_count() or 1, max(1, self.n_envs // self.agents_per_copy))
        self._message_slots = int(processed[0].get("max_messages", 8))
        self._random_label = bool(processed[0].get("random_label", False))  # oracle_ppo's control: its envs' labels
        self._check_buffer_memory(processed[0], prototype)
        prototype.close()
        self._check_before_folder(processed[0], processed[2])
        return processed

    def settings_source(self) -> str:
        """Where the hyperparameters come from, for messages: the YAML file (a resumed run's ``config.yml``), and
        ``-params`` when given."""
        return f"{self.config}{' with -params' if self.custom_hyperparams and self.resume_run is None else ''}"

    def _check_before_folder(self, kwargs: dict[str, Any], callbacks: list[Any]) -> None:
        """What SB3 would only find in the first rollout or update, checked before the run folder exists: every
        constructor argument against the algorithm's annotations (``ent_coef: 'auto'`` is SAC's, not PPO's),
        ``policy_kwargs`` against the policy's, the optimizer stepped as SB3 steps it, the callbacks, and the
        tensorboard folder (:func:`check_tensorboard_folder`).

        :param kwargs: the algorithm's keyword arguments, as rl_zoo3 prepared them (schedules built)
        :param callbacks: the callbacks rl_zoo3 built from the ``callback`` key
        :raise ValueError: one line naming the setting
        """
        import torch as th
        from stable_baselines3.common.callbacks import BaseCallback

        from sb3_emmarl.common.trust.signatures import check_arguments, check_optimizer

        algo, source = ZOO_ALGOS[self.algo], self.settings_source()
        check_arguments(algo, {key: value for key, value in kwargs.items() if key not in ZOO_ONLY or key == "policy"},
                        source, unknown=False)
        policy_kwargs = kwargs.get("policy_kwargs") or {}
        policy = kwargs.get("policy")
        policy_class = (getattr(algo, "policy_aliases", {}) or {}).get(policy) if isinstance(policy, str) else policy
        if isinstance(policy_class, type):
            check_arguments(policy_class, policy_kwargs, f"{source}: policy_kwargs")
        for where, settings in ((source, kwargs), (f"{source}: policy_kwargs", policy_kwargs)):
            if "optimizer_class" in settings or "optimizer_kwargs" in settings:
                check_optimizer(settings.get("optimizer_class", th.optim.Adam), settings.get("optimizer_kwargs"), where)
        for callback in callbacks:
            if not isinstance(callback, BaseCallback):
                raise ValueError(f"{source}: callback: {type(callback).__name__} is not an SB3 callback (BaseCallback)")
        check_tensorboard_folder(self.tensorboard_log)

    def _check_buffer_memory(self, hyperparams: dict[str, Any], prototype: Any) -> None:
        """Refuse a replay or rollout buffer larger than this machine's memory before SB3 allocates it (numpy's
        lazily committed zeros would otherwise fail hours later, once the buffer fills)."""
        agent = prototype.possible_agents[0]
        obs_floats = int(np.prod(prototype.observation_space(agent).shape))
        if self.centralized:
            obs_floats = int(np.prod(prototype.state_space.shape)) if hasattr(prototype, "state_space") else obs_floats
        elif self.algo in STATE_ALGOS:  # MAPPO: in every observation (with the one-hot); QMIX: once per team
            state_floats = int(np.prod(prototype.state_space.shape))
            n_agents = len(prototype.possible_agents)
            obs_floats += state_floats + n_agents if "n_steps" in hyperparams else -(-state_floats // n_agents)
        if "buffer_size" in hyperparams:
            name, value = "buffer_size", int(hyperparams["buffer_size"])
            needed = value * (2 * obs_floats + 8) * 4
        elif "n_steps" in hyperparams:
            name, value = "n_steps", int(hyperparams["n_steps"])
            needed = value * self.n_envs * (obs_floats + 8) * 4
        else:
            return
        memory = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
        if needed > memory:
            raise ValueError(f"{name}={value} needs about {needed / 2**30:.1f} GiB of buffer for {obs_floats}-float "
                             f"observations ({self.n_envs} vector entries), more than this machine's "
                             f"{memory / 2**30:.1f} GiB")

    def create_log_folder(self) -> None:
        self.created_folder = not Path(self.save_path).exists()
        # the outermost folder this manager creates (the log folder itself when it did not exist)
        self.created_root = next((path for path in reversed(Path(self.params_path).parents) if not path.exists()),
                                 Path(self.params_path))
        super().create_log_folder()

    def remove_created_folders(self) -> None:
        """Remove the run folder this manager created and the parents it created for it that are left empty (the
        log folder, ``<log>/<algo>``): a failed start leaves nothing behind."""
        import shutil

        if not self.created_folder or self.created_root is None or not Path(self.save_path).is_dir():
            return
        shutil.rmtree(self.save_path)
        folder = Path(self.save_path).parent
        while folder.is_dir() and not any(folder.iterdir()) and (folder == self.created_root
                                                                 or self.created_root in folder.parents):
            folder.rmdir()
            folder = folder.parent

    def create_envs(self, n_envs: int, eval_env: bool = False, no_log: bool = False) -> VecEnv:
        """The parameter-sharing vector environment (``n_envs`` entries, rounded up to whole reserve copies), guarded
        by :class:`~sb3_emmarl.common.vec_env.FiniteCheck`.

        :param n_envs: vector entries wanted (copies x UAVs)
        :param eval_env: build the evaluation environment (its own seed, frozen normalisation)
        :param no_log: no monitor file
        """
        if self.centralized:
            if self.resume_run is not None:  # the stopped run's monitor files go on (rl_zoo3 writes <i>.monitor.csv)
                self.monitor_kwargs = {**(self.monitor_kwargs or {}), "override_existing": False}
            env = super().create_envs(n_envs, eval_env=eval_env, no_log=no_log)
        else:
            n_copies = max(1, -(-n_envs // self.agents_per_copy))
            monitor = None if eval_env or no_log else self.save_path
            if monitor is not None and self.resume_run is not None:  # keep the stopped run's monitor.csv
                monitor = os.path.join(self.save_path, f"resumed_{Path(self.trained_agent).stem}")
            env = make_vec_env(
                n_copies=n_copies,
                seed=self.seed + EVAL_SEED_OFFSET if eval_env else self.seed,
                env_kwargs=self.eval_env_kwargs if eval_env else self.env_kwargs,
                num_cpus=0 if eval_env else self.num_cpus,
                monitor_dir=monitor,
                vec_env_wrapper=self.vec_env_wrapper,
                with_state=self.algo in STATE_ALGOS and not eval_env,  # evaluations act on the plain observations
                env_fn=self.env_fn,
                vec_env_type="supersuit" if self.vec_env_path in ("supersuit", "dummy") else "batched",
            )
            env = self._maybe_normalize(env, eval_env)
            if ZOO_ALGOS[self.algo] is OraclePPO:
                env = wrap_with_mode(env, random_labels=self._random_label)
            elif ZOO_ALGOS[self.algo] is MessagePPO:  # evaluations need the messages too
                env = wrap_with_messages(env, self._message_slots)
        return FiniteCheck(env)

    def _maybe_normalize(self, env: VecEnv, eval_env: bool) -> VecEnv:
        """rl_zoo3's normalisation; continuing from a checkpoint, its own ``VecNormalize`` statistics are loaded."""
        stats = companion(self.trained_agent, VEC_NORMALIZE) if self.trained_agent else None
        if stats is None or not stats.is_file():
            return super()._maybe_normalize(env, eval_env)
        env = load_vec_normalize(stats, env)
        if eval_env:
            env.training, env.norm_reward = False, False
        return env

    def create_callbacks(self) -> None:
        super().create_callbacks()
        for i, callback in enumerate(self.callbacks):
            if type(callback) is CheckpointCallback:  # rl_zoo3's, written in place: ours is atomic and resumable
                self.callbacks[i] = ResumableCheckpointCallback(
                    callback.save_freq, callback.save_path, callback.name_prefix,
                    save_replay_buffer=self.save_replay_buffer, save_vecnormalize=bool(self.normalize),
                    verbose=callback.verbose)
            elif type(callback) is EvalCallback:  # SB3's: ours counts team episodes, and writes its files atomically
                assert callback.log_path is not None  # (rl_zoo3 gives its evaluations a folder)
                self.callbacks[i] = AtomicEvalCallback(
                    callback.eval_env, callback_on_new_best=SaveVecNormalize(self.params_path),
                    n_eval_episodes=callback.n_eval_episodes, eval_freq=callback.eval_freq,
                    log_path=os.path.dirname(callback.log_path), best_model_save_path=callback.best_model_save_path,
                    deterministic=callback.deterministic, verbose=callback.verbose)
        self.callbacks.append(TeamMetricsCallback())
        if self.algo in LATENT_ALGOS:
            self.callbacks.append(LatentMetricsCallback())
        #: the run's time by phase, around every other callback (printed by ``emmarl train`` at the run's end)
        self.phase_times = PhaseTimes(self.callbacks)
        self.callbacks = [self.phase_times]

    def objective(self, trial: Any) -> float:
        """rl_zoo3's optuna objective, its trial's evaluations counting team episodes (rl_zoo3 builds its
        ``TrialEvalCallback`` by its module's name, hence :class:`TeamTrialEvalCallback` there); an EM algorithm's
        sampled settings update the YAML's by :func:`~sb3_emmarl.zoo.algos.merge_hyperparams`.

        :param trial: the optuna trial
        """
        rl_zoo3.exp_manager.TrialEvalCallback = TeamTrialEvalCallback  # type: ignore[misc]
        if self.algo not in LATENT_ALGOS:
            return super().objective(trial)
        # rl_zoo3 updates the YAML's settings with the sampler's whole values: EM's latent_kwargs are merged instead,
        # and count_factors refitted to the sampled n_components (merge_hyperparams)
        samplers = rl_zoo3.exp_manager.HYPERPARAMS_SAMPLER
        sampler, base = samplers[self.algo], self._hyperparams
        rl_zoo3.exp_manager.HYPERPARAMS_SAMPLER = {  # type: ignore[misc]
            **samplers, self.algo: lambda *args: merge_hyperparams(base, sampler(*args))}
        try:
            return super().objective(trial)
        finally:
            rl_zoo3.exp_manager.HYPERPARAMS_SAMPLER = samplers  # type: ignore[misc]

    def _load_pretrained_agent(self, hyperparams: dict[str, Any], env: VecEnv) -> BaseAlgorithm:
        """Load ``-i`` / the checkpoint to resume (checked), with its replay buffer; resuming, its training state is
        kept for :meth:`learn`. With ``-i`` the hyperparameters (but the policy's) override the saved ones, as in
        rl_zoo3; a resumed run keeps the saved ones."""
        state_file = companion(self.trained_agent, TRAINING_STATE)
        resuming = self.resume_run is not None and state_file is not None and state_file.is_file()
        if self.verbose > 0:
            print(f"Loading {'the checkpoint to resume' if resuming else 'the trained agent'} {self.trained_agent}")
        overrides = {} if self.resume_run is not None else {
            key: value for key, value in hyperparams.items() if key not in ("policy", "policy_kwargs")}
        model = ZOO_ALGOS[self.algo].load(self.trained_agent, env=env, seed=self.seed, device=self.device,
                                          tensorboard_log=self.tensorboard_log, verbose=self.verbose,
                                          force_reset=not resuming,
                                          custom_objects=safe_data_objects(self.trained_agent), **overrides)
        buffer_file = companion(self.trained_agent, REPLAY_BUFFER)
        if buffer_file is None:
            buffer_file = Path(self.trained_agent).parent / "replay_buffer.pkl"
        if buffer_file.is_file() and hasattr(model, "replay_buffer"):
            model.replay_buffer = load_data_pickle(buffer_file)
            model.replay_buffer.device = model.device
        elif self.resume_run is not None and getattr(model, "replay_buffer", None) is not None:
            # Without its replay buffer (--save-replay-buffer) the run refills an empty one before learning again.
            assert isinstance(model, OffPolicyAlgorithm)  # (the algorithms with a replay buffer)
            model.learning_starts = model.num_timesteps + model.learning_starts
            print(f"warning: {self.trained_agent} has no saved replay buffer (train with --save-replay-buffer to resume "
                  f"exactly); learning resumes after {model.learning_starts} steps", file=sys.stderr)
        if resuming:
            assert state_file is not None  # (resuming)
            self._training_state = load_training_state(state_file)
            try:  # (a state not this run's is refused now, before anything else starts)
                restore_environment_state(model, self._training_state)
            except ValueError as error:
                raise ValueError(f"{state_file}: {error}") from None
        elif self.resume_run is not None:
            print(f"warning: {self.trained_agent} has no training state; the run resumes with new episodes",
                  file=sys.stderr)
        return model

    def learn(self, model: BaseAlgorithm) -> None:
        """rl_zoo3's ``learn``; a resumed run restores its training state last and trains up to its ``n_timesteps``."""
        if self.resume_run is None:
            return super().learn(model)
        if self._training_state is not None:
            restore_random_generators(self._training_state)
        remaining = self.n_timesteps - model.num_timesteps
        kwargs: dict[str, Any] = {"reset_num_timesteps": False, "callback": self.callbacks}
        if self.log_interval > -1:
            kwargs["log_interval"] = self.log_interval
        try:
            if remaining > 0:
                model.learn(remaining, **kwargs)
        finally:
            if self.callbacks:
                self.callbacks[0].on_training_end()
            assert model.env is not None  # (loaded with the run's environment)
            model.env.close()

    def save_trained_model(self, model: BaseAlgorithm) -> None:
        """rl_zoo3's files (model, replay buffer, ``VecNormalize`` statistics), each written atomically."""
        print(f"Saving to {self.save_path}")
        if hasattr(model, "save_replay_buffer") and self.save_replay_buffer:
            assert isinstance(model, OffPolicyAlgorithm)  # (the algorithms with a replay buffer)
            save_pickle(os.path.join(self.save_path, "replay_buffer.pkl"), model.replay_buffer)
        if self.normalize:
            save_pickle(os.path.join(self.params_path, VEC_NORMALIZE_FILE), model.get_vec_normalize_env())
        save_model(model, f"{self.save_path}/{self.env_name}.zip")

    def _save_config(self, saved_hyperparams: dict[str, Any]) -> None:
        """``config.yml``, ``args.yml`` and ``command.txt`` as plain data, written atomically (a resumed run keeps its
        own)."""
        if self.resume_run is not None:
            return
        write_yaml(os.path.join(self.params_path, "config.yml"), saved_hyperparams)
        write_yaml(os.path.join(self.params_path, "args.yml"), vars(self.args))
        write_text(Path(self.params_path) / "command.txt", " ".join(getattr(sys, "orig_argv", sys.argv)))
        print(f"Log path: {self.save_path}")
