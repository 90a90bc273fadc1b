"""What knowing the hidden mode pays a learned team on ZonePatrol (or the reserve's zone raids), and how much of it
EM-PPO recovers.

``--task zone_patrol`` (the default) runs ZonePatrol version 1 (``zone_patrol_v1``; ``--task zone_patrol_v0`` the first
version); ``--task zone_raids`` runs the same protocol on the reserve with ``scenario="zone_raids"``
(docs/zone_raids.md): its modes are numbered as ZonePatrol's (``2 * strategy + weather``, the strategy deciding the
zone), so the told-wrong relabellings are the same; the settings are the zoo's ``WildlifeReserve-v1`` sections,
EM-PPO's belief is scored at step 100 of 200.

Four variants train with the same PPO settings (the zoo's, ``ppo.yml``'s section of the task) on 8 copies of the task
through the batched vector environment, each run in its own process with one torch thread: PPO told the mode
(``told``: ``OraclePPO``, the one-hot of the mode appended to every observation), plain PPO (``ppo``), the control told
a random label per episode instead (``control``: ``OraclePPO(random_label=True)``, the same input without the
information) and EM-PPO (``em_ppo``: ``em_ppo.yml``'s settings, fusion along the links). Reported beside them when
asked for (``--variants``): EM-PPO without fusion, EM-PPO with the team-scope belief (``fusion="team"``: centralised
inference, an ablation), ``exact_belief`` (ZonePatrol: PPO at the same settings trained on the exact posterior of the
readings that reached each UAV along the links, :class:`ExactBelief`: what a right belief pays a learner),
RecurrentPPO (``ppo_lstm.yml``) and MAPPO (``mappo.yml``), each with its zoo settings. Each run then plays the same
``--eval-episodes`` held-out team episodes (8 copies from seed 50,000; actions sampled, torch seeded), scored as team
episodes (one team reward per episode of a copy). ``told`` runs play them again told each wrong zone (the same
weather) and the wrong weather (the same zone), and on ZonePatrol acting on the exact belief in place of the mode
(``belief_executed``: trained told, executed on the belief); EM-PPO runs with their belief permuted between
components, and report how often their belief tells the mode and the zone at mid-episode (aligned accuracy) beside the
exact posterior of the whole team's readings on the same episodes (ZonePatrol). Told, control and EM-PPO runs report
how far their actions move when the one-hot or the belief is permuted over the visited observations
(:func:`~sb3_emmarl.common.latent.diagnostics.belief_use`: the swap KL). A run is *collapsed* when its mean team reward
is below the random team's on the same episodes (rule fixed before any run).

``run`` first prints the time still to go (each run's variant's seconds per agent-step in the folder's finished
runs), then writes one JSON file per run into ``--folder`` (atomically; an existing run is kept, so a killed sweep
resumes; a run saves a checkpoint every ``--checkpoint-every`` agent-steps in ``<variant>_<seed>.partial/``, and a
run killed mid-way continues from its newest one with the same result as if it had not stopped); ``report`` prints
each arm's settings and the paired tables (told against PPO, told against the control, the control against PPO, told
right against told wrong, EM-PPO against PPO, the arms beside), with paired t and Wilcoxon p-values, seeds higher,
medians, the share of the told gain each arm recovers with a 90% bootstrap interval over seeds, and the collapsed
runs.

Example: ``python benchmarks/zone_patrol_value.py run --seeds 0 1 2 3 4 5 6 7 8 9 --folder logs/zone_patrol_value``,
then ``python benchmarks/zone_patrol_value.py report --folder logs/zone_patrol_value``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from functools import partial
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from scipy import stats

#: Each variant's zoo algorithm (its settings: the zoo YAML's section of the task) and its arguments beyond them (a
#: ``policy_kwargs`` dict is laid over the YAML's policy arguments, :func:`variant_overrides`; the rest replace the YAML's).
ALGOS: dict[str, tuple[str, dict[str, Any]]] = {
         "told": ("oracle_ppo", {}), "ppo": ("ppo", {}), "control": ("oracle_ppo", {"random_label": True}),
         "told_film": ("oracle_ppo", {"policy_kwargs": {"belief_conditioning": "film"}}),
         "told_mixture": ("oracle_ppo", {"policy_kwargs": {"belief_conditioning": "mixture"}}),
         "em_ppo": ("em_ppo", {}), "em_ppo_nofusion": ("em_ppo", {"latent_kwargs": {"fusion": False}}),
         "em_ppo_mixture": ("em_ppo", {"policy_kwargs": {"belief_conditioning": "mixture"}}),
         "em_ppo_team": ("em_ppo", {"latent_kwargs": {"fusion": "team"}}), "exact_belief": ("ppo", {}),
         "ppo_lstm": ("ppo_lstm", {}),
         "mappo": ("mappo", {})}
VARIANTS = tuple(ALGOS)
#: The variants told the mode (scored told a wrong zone and the wrong weather too): concatenated, FiLM, a head per mode.
TOLD_VARIANTS = tuple(v for v in VARIANTS if v.startswith("told"))
#: The variants ``run`` trains unless ``--variants`` says otherwise (the protocol's four; the rest are reported beside).
DEFAULT_VARIANTS = ("told", "ppo", "control", "em_ppo")
EVAL_SEED = 50_000
#: Agent-steps per run unless ``-n`` says otherwise.
BUDGET = 1_000_000


class Task(NamedTuple):
    """A task the protocol runs on.

    :param name: the name in the report's heading
    :param env_id: its zoo id (the YAML sections the variants read)
    :param module: the module whose ``parallel_env`` builds it
    :param base_kwargs: its arguments before ``--env-kwargs``
    :param mid_episode: the step at which EM-PPO's belief is scored
    """

    name: str
    env_id: str
    module: str
    base_kwargs: tuple[tuple[str, object], ...]  # (a NamedTuple: the tests load this file without registering it)
    mid_episode: int

    def kwargs(self, env_kwargs: dict | None) -> dict:
        """The task's arguments with ``env_kwargs`` over them."""
        return {**dict(self.base_kwargs), **(env_kwargs or {})}

    def check(self, env_kwargs: dict) -> None:
        """Build the task once with ``env_kwargs`` (ValueError naming a bad argument)."""
        import importlib

        importlib.import_module(self.module).parallel_env(**self.kwargs(env_kwargs)).close()


#: The tasks: ZonePatrol (60 steps) and the reserve's zone raids (200 steps).
TASKS = {"zone_patrol": Task("ZonePatrol", "ZonePatrol-v1", "wildlife_reserve.zone_patrol_v1", (), 30),
         "zone_patrol_v0": Task("ZonePatrol v0", "ZonePatrol-v0", "wildlife_reserve.zone_patrol_v0", (), 30),
         "zone_raids": Task("the reserve's zone raids", "WildlifeReserve-v1", "wildlife_reserve.reserve_v1",
                            (("scenario", "zone_raids"),), 100)}


def make_env(seed: int, n_copies: int | None = None, env_kwargs: dict | None = None, task: str = "zone_patrol"):
    """``n_copies`` copies of the task (default: the zoo YAML's ``n_envs``) with its arguments ``env_kwargs``,
    through the batched vector environment."""
    import importlib

    from sb3_emmarl.common.vec_env import make_vec_env
    from sb3_emmarl.zoo.exp_manager import zoo_hyperparams

    spec = TASKS[task]
    n_copies = n_copies or int(zoo_hyperparams("ppo", spec.env_id)["n_envs"])
    return make_vec_env(n_copies, seed=seed, env_fn=importlib.import_module(spec.module).parallel_env,
                        env_kwargs=spec.kwargs(env_kwargs), vec_env_type="batched")


def variant_overrides(variant: str, task: str = "zone_patrol") -> tuple[str, dict]:
    """The variant's zoo algorithm and its arguments beyond the YAML (:data:`ALGOS`), a ``policy_kwargs`` dict laid over
    the YAML's policy arguments (so that ``told_film`` keeps the YAML's ``net_arch``)."""
    from sb3_emmarl.zoo.exp_manager import zoo_policy_kwargs

    algo, overrides = ALGOS[variant]
    if isinstance(overrides.get("policy_kwargs"), dict):
        overrides = {**overrides, "policy_kwargs": zoo_policy_kwargs(algo, TASKS[task].env_id, **overrides["policy_kwargs"])}
    return algo, overrides


def build(variant: str, seed: int, env_kwargs: dict | None = None, task: str = "zone_patrol"):
    """The variant's model with its zoo YAML's settings on the task (with ``env_kwargs``)."""
    from sb3_emmarl.zoo.exp_manager import zoo_model

    algo, overrides = variant_overrides(variant, task)
    env = make_env(seed, env_kwargs=env_kwargs, task=task)
    if variant != "exact_belief":
        return zoo_model(algo, env, seed, TASKS[task].env_id, **overrides)
    from sb3_emmarl.common.appended.initialization import zero_tail_weights

    model = zoo_model(algo, ExactBelief(env), seed, TASKS[task].env_id, **overrides)
    zero_tail_weights(model.policy, 8)  # (as OraclePPO starts the weights on its one-hot)
    return model


def play(model, venv, episodes: int, seed: int, random: bool = False, beliefs: list | None = None,
         mid_episode: int = 30, exact: list | None = None) -> tuple[list[float], np.ndarray]:
    """Team rewards of ``episodes`` team episodes (the first agent of each copy reports its copy's), and one visited
    observation per step (as the model saw it); ``random`` plays uniformly random actions instead. ``beliefs``, if
    given, receives ``(belief, mode)`` of every UAV at step ``mid_episode`` (the observations' last 8 values);
    ``exact`` (ZonePatrol), ``(log-likelihood of each mode, mode)`` of every copy's whole team from the readings of its
    observations up to step ``mid_episode`` (:func:`~wildlife_reserve.zone_patrol.posterior.reading_log_likelihoods`:
    the exact team posterior of the readings, on the same episodes as the beliefs)."""
    import torch as th

    per_copy = int(getattr(venv, "agents_per_copy", 1))
    rewards: list[float] = []
    visited = []
    rng = np.random.default_rng(seed)
    config = venv.get_attr("config", [0])[0] if exact is not None else None
    with th.random.fork_rng():
        th.manual_seed(seed)
        obs = venv.reset()
        state, starts = None, np.ones(venv.num_envs, dtype=bool)
        steps = np.zeros(venv.num_envs, dtype=np.int64)
        if config is not None:
            from wildlife_reserve.zone_patrol.posterior import reading_log_likelihoods

            team_evidence = reading_log_likelihoods(config, obs)
        while len(rewards) < episodes:
            if len(visited) < 1024:
                visited.append(np.array(obs[0]))
            if random:
                actions = rng.integers(venv.action_space.n, size=venv.num_envs)
            else:
                actions, state = model.predict(obs, state=state, episode_start=starts, deterministic=False)
            obs, _, starts, infos = venv.step(actions)
            steps = np.where(starts, 0, steps + 1)
            if beliefs is not None:
                beliefs.extend((obs[i, -8:], infos[i]["mode"]) for i in np.flatnonzero(steps == mid_episode))
            if config is not None:
                step_evidence = reading_log_likelihoods(config, obs)
                team_evidence = np.where(starts[:, None], step_evidence, team_evidence + step_evidence)
                for copy in np.flatnonzero(steps[::per_copy] == mid_episode):
                    rows = slice(copy * per_copy, (copy + 1) * per_copy)
                    exact.append((team_evidence[rows].sum(0), infos[copy * per_copy]["mode"]))
            for i in np.flatnonzero(starts):
                if i % per_copy == 0:
                    rewards.append(float(infos[i]["metrics"]["team_reward"]))
    venv.close()
    return rewards[:episodes], np.stack(visited)


class ExactBelief:
    """A vector environment wrapper (built lazily: SB3's ``VecEnvWrapper`` is imported by the workers only) whose
    observations end with each UAV's exact posterior of the mode from the readings that reached it along the links
    (:func:`~wildlife_reserve.zone_patrol.posterior.reading_log_likelihoods`, fused as EM-PPO's beliefs are, terminal
    observations included): what the ``exact_belief`` variant trains on, and what told runs act on in place of the mode
    in their ``belief_executed`` evaluation."""

    def __new__(cls, venv):
        from gymnasium import spaces
        from stable_baselines3.common.vec_env import VecEnvWrapper

        from sb3_emmarl.common.latent.belief import BeliefTracker
        from wildlife_reserve.zone_patrol.posterior import reading_log_likelihoods

        class Wrapper(VecEnvWrapper):
            def __init__(self, venv) -> None:
                space = venv.observation_space
                super().__init__(venv, observation_space=spaces.Box(
                    np.concatenate([space.low, np.zeros(8, np.float32)]),
                    np.concatenate([space.high, np.ones(8, np.float32)])))
                self.config = venv.get_attr("config", [0])[0]
                self.tracker = BeliefTracker(venv.num_envs, 8, 1, 1, agents_per_copy=venv.agents_per_copy)

            def _augment(self, obs):
                return np.concatenate([obs, self.tracker.beliefs()], axis=1).astype(np.float32)

            def get_state(self):  # (a checkpoint resumes mid-episode)
                return self.tracker.get_state()

            def set_state(self, state):
                self.tracker.set_state(state)

            def reset(self):
                obs = self.venv.reset()
                self.tracker.start(np.arange(self.num_envs), np.zeros((self.num_envs, 1)))
                self.tracker.evidence[:] = reading_log_likelihoods(self.config, obs)
                return self._augment(obs)

            def step_wait(self):
                obs, rewards, dones, infos = self.venv.step_wait()
                seen = np.array(obs, copy=True)
                done = np.flatnonzero(dones)
                for i in done:
                    seen[i] = infos[i]["terminal_observation"]
                self.tracker.evidence += reading_log_likelihoods(self.config, seen)
                self.tracker.fuse(infos)
                if len(done):  # (the terminal observations with the episode's last belief, as SB3's rollouts read them)
                    infos = list(infos)
                    for i, belief in zip(done, self.tracker.beliefs(done)):
                        infos[i] = {**infos[i], "terminal_observation": np.concatenate([seen[i], belief]).astype(np.float32)}
                self.tracker.start(done, np.zeros((len(done), 1)))
                self.tracker.evidence[done] = reading_log_likelihoods(self.config, obs[done])
                return self._augment(obs), rewards, dones, infos

        return Wrapper(venv)


def exact_belief(env_kwargs: dict | None = None, task: str = "zone_patrol"):
    """The evaluation episodes with :class:`ExactBelief`."""
    return ExactBelief(make_env(EVAL_SEED, env_kwargs=env_kwargs, task=task))


def wrong(relabel: list[int], env_kwargs: dict | None = None, task: str = "zone_patrol"):
    """A vector environment maker whose observations end with the one-hot of ``relabel[mode]``."""
    from sb3_emmarl.common.mode_aware import ModeObservationWrapper

    return lambda: ModeObservationWrapper(make_env(EVAL_SEED, env_kwargs=env_kwargs, task=task), relabel=relabel)


#: Told each wrong zone (``shift`` zones on, the same weather) and the wrong weather (the same zone); modes are
#: 2 * zone + weather.
WRONG = {**{f"wrong_zone_{shift}": [(2 * ((m // 2 + shift) % 4)) + m % 2 for m in range(8)] for shift in (1, 2, 3)},
         "wrong_weather": [2 * (m // 2) + 1 - m % 2 for m in range(8)]}


#: Agent-steps between a run's checkpoints unless ``--checkpoint-every`` says otherwise.
CHECKPOINT_EVERY = 100_000
#: The checkpoints' file prefix (SB3's names: ``<prefix>_<steps>_steps.zip``, its companions beside it).
PREFIX = "run"


def partial_folder(folder: str | Path, variant: str, seed: int) -> Path:
    """Where a run keeps its checkpoints until its record is written."""
    return Path(folder) / f"{variant}_{seed}.partial"


def checkpoint_files(partial: Path, steps: int) -> list[Path]:
    """A checkpoint's files: its zip, its training state and its seconds so far."""
    from sb3_emmarl.common.checkpoints import TRAINING_STATE, checkpoint_path

    return [checkpoint_path(partial, PREFIX, steps), checkpoint_path(partial, PREFIX, steps, TRAINING_STATE),
            partial / f"{PREFIX}_progress_{steps}_steps.json"]


def train(variant: str, seed: int, budget: int, env_kwargs: dict, task: str, partial: Path | None = None,
          every: int = CHECKPOINT_EVERY) -> tuple[Any, dict]:
    """The variant's model trained for ``budget`` agent-steps, and the training's record (its seconds, by phase, and
    the machine's load). With ``partial``, a checkpoint is saved there every ``every`` agent-steps (at the start of a
    rollout, with the environments mid-episode and the random generators: see
    :class:`~sb3_emmarl.common.checkpoints.ResumableCheckpointCallback`) and at the end, and a run killed mid-way
    continues from its newest one as if it had not stopped (its seconds are those of the training that made the
    model: each segment's, up to its last checkpoint)."""
    from sb3_emmarl.common.checkpoints import ResumableCheckpointCallback, check_checkpoint, list_checkpoints
    from sb3_emmarl.common.phases import PHASES, PhaseTimes, machine_load
    from sb3_emmarl.common.trust.atomic_files import write_text

    so_far = {"seconds": 0.0, "phase_seconds": dict.fromkeys(PHASES, 0.0), "load": {"start": machine_load()},
              "resumed_at": []}
    found = list_checkpoints(partial, PREFIX) if partial is not None else []
    if not found:
        model = build(variant, seed, env_kwargs, task)
    else:
        from sb3_emmarl.common.training_state import load_training_state, restore_environment_state, restore_random_generators
        from sb3_emmarl.common.trust.safe_zip import safe_data_objects
        from sb3_emmarl.zoo.algos import ZOO_ALGOS

        steps, path = found[-1]
        check_checkpoint(path)
        algo, _ = variant_overrides(variant, task)
        env = make_env(seed, env_kwargs=env_kwargs, task=task)
        model = ZOO_ALGOS[algo].load(path, env=ExactBelief(env) if variant == "exact_belief" else env, seed=seed,
                                     device="cpu", force_reset=False, custom_objects=safe_data_objects(path))
        _, state_file, progress_file = checkpoint_files(partial, steps)
        state = load_training_state(state_file)
        restore_environment_state(model, state)
        so_far = json.loads(progress_file.read_text())
        so_far["resumed_at"].append(steps)
        restore_random_generators(state)  # (last: loading draws from them)

    def progress(seconds: float) -> dict:
        """The training's record so far: the earlier segments' seconds and phases and this one's (``seconds``)."""
        return {**so_far, "seconds": so_far["seconds"] + seconds,
                "phase_seconds": {name: so_far["phase_seconds"][name] + value for name, value in times.seconds.items()}}

    class Checkpoints(ResumableCheckpointCallback):
        """The run's checkpoints: its seconds so far written first, the zip last; older ones removed."""

        def save_checkpoint(self) -> Path:
            steps = self.model.num_timesteps
            write_text(checkpoint_files(partial, steps)[2], json.dumps(progress(time.perf_counter() - start)))
            path = super().save_checkpoint()
            for older, _ in list_checkpoints(partial, PREFIX)[:-1]:
                for file in checkpoint_files(partial, older):
                    file.unlink(missing_ok=True)
            return path

    callbacks = []
    if partial is not None:
        partial.mkdir(parents=True, exist_ok=True)
        checkpoints = Checkpoints(max(1, every // model.n_envs), str(partial), PREFIX, save_training_state=True)
        callbacks.append(checkpoints)
    times = PhaseTimes(callbacks)
    start = time.perf_counter()
    if budget > model.num_timesteps:
        model.learn(budget - model.num_timesteps, callback=times, reset_num_timesteps=not found)
    if partial is not None and not (found and found[-1][0] >= budget):
        checkpoints.save_checkpoint()  # (the trained model: a kill during the evaluations does not train it again)
    record = progress(times.wall)
    return model, {**record, "load": {"start": record["load"]["start"], "end": machine_load()}}


def run(variant: str, seed: int, budget: int, episodes: int, env_kwargs: dict | None = None,
        task: str = "zone_patrol", partial: Path | None = None, every: int = CHECKPOINT_EVERY) -> dict:
    import torch as th

    from sb3_emmarl.common.latent.diagnostics import belief_use, permute_beliefs

    th.set_num_threads(1)
    env_kwargs = dict(env_kwargs or {})
    model, training = train(variant, seed, budget, env_kwargs, task, partial, every)
    record = {"variant": variant, "seed": seed, "budget": budget, "env_kwargs": env_kwargs, "task": task,
              "belief_conditioning": getattr(model.policy, "belief_conditioning", "concat"), **training}
    evaluating = time.perf_counter()
    wrap = getattr(model, "wrap_env", ExactBelief if variant == "exact_belief" else lambda v: v)
    beliefs: list = []
    exact: list = []
    latent, zone_patrol = variant.startswith("em_ppo"), task.startswith("zone_patrol")
    evaluation = make_env(EVAL_SEED, env_kwargs=env_kwargs, task=task)
    record["team_reward"], visited = play(model, wrap(evaluation), episodes, EVAL_SEED,
                                          beliefs=beliefs if latent else None, mid_episode=TASKS[task].mid_episode,
                                          exact=exact if latent and zone_patrol else None)
    if beliefs:
        from sb3_emmarl.common.latent.metrics import align_components

        posteriors, modes = np.stack([b for b, _ in beliefs]), np.array([m for _, m in beliefs])
        aligned = align_components(posteriors, modes, 8)[posteriors.argmax(1)]
        record["belief_accuracy"] = float(np.mean(aligned == modes))
        record["belief_zone_accuracy"] = float(np.mean(aligned // 2 == modes // 2))
    if exact:
        evidence, modes = np.stack([e for e, _ in exact]), np.array([m for _, m in exact])
        record["exact_team_accuracy"] = float(np.mean(evidence.argmax(1) == modes))
        record["exact_team_zone_accuracy"] = float(np.mean(evidence.argmax(1) // 2 == modes // 2))
    if variant in (*TOLD_VARIANTS, "control") or latent:
        record["swap_kl"] = belief_use(model.policy, visited, 8)
    if variant in TOLD_VARIANTS:
        for name, relabel in WRONG.items():
            record[name] = play(model, wrong(relabel, env_kwargs, task)(), episodes, EVAL_SEED)[0]
        if zone_patrol:  # acting on the exact posterior of the readings that reached each UAV, in place of the mode
            record["belief_executed"] = play(model, exact_belief(env_kwargs, task), episodes, EVAL_SEED)[0]
    if variant.startswith("em_ppo"):
        from stable_baselines3.common.vec_env import VecEnvWrapper

        class Permuted(VecEnvWrapper):
            def reset(self):
                return permute_beliefs(self.venv.reset(), 8)

            def step_wait(self):
                obs, rewards, dones, infos = self.venv.step_wait()
                return permute_beliefs(obs, 8), rewards, dones, infos

        record["permuted"] = play(model, Permuted(wrap(make_env(EVAL_SEED, env_kwargs=env_kwargs, task=task))),
                                  episodes, EVAL_SEED)[0]
    record["evaluation_seconds"] = time.perf_counter() - evaluating
    return record


def run_and_save(folder: str, variant: str, seed: int, budget: int, episodes: int, env_kwargs: dict | None = None,
                 task: str = "zone_patrol", every: int = CHECKPOINT_EVERY) -> str:
    import shutil

    path = Path(folder) / f"{variant}_{seed}.json"
    if path.exists():
        return f"{path.name}: kept"
    partial = partial_folder(folder, variant, seed)
    record = run(variant, seed, budget, episodes, env_kwargs, task, partial, every)
    from sb3_emmarl.common.phases import load_title, phase_table
    from sb3_emmarl.common.trust.atomic_files import write_text
    from sb3_emmarl.version import __version__

    write_text(path, json.dumps({**record, "version": __version__}))
    shutil.rmtree(partial, ignore_errors=True)
    return (f"{path.name}: team reward {np.mean(record['team_reward']):.3f} ({record['seconds']:.0f} s)\n"
            + phase_table(record["phase_seconds"], record["seconds"],
                          load_title(record["load"]["start"], record["load"]["end"])))


def estimate(folder: Path, jobs: list[tuple], n_jobs: int) -> str:
    """The protocol's time still to go, before it starts: each run still to do (its checkpointed agent-steps taken
    off) at its variant's median seconds per agent-step (training and evaluations) over the folder's finished runs
    (any variant's, for a variant with none), ``n_jobs`` at a time."""
    from sb3_emmarl.common.checkpoints import list_checkpoints
    from sb3_emmarl.experiments.runner import time_at_medians

    rates: dict[str, list[float]] = {}
    for path in folder.glob("*.json"):
        record = json.loads(path.read_text())
        total = record["seconds"] + record.get("evaluation_seconds", 0.0)
        rates.setdefault(record["variant"], []).append(total / record["budget"])
    todo = [(variant, seed, budget) for _, variant, seed, budget, *_ in jobs
            if not (folder / f"{variant}_{seed}.json").exists()]
    head = f"{len(todo)} of {len(jobs)} runs to do ({len(jobs) - len(todo)} kept in {folder})"
    if not todo:
        return head
    if not rates:
        return f"{head}; no finished run in the folder yet to estimate their time from"
    def steps_left(variant: str, seed: int, budget: int) -> int:
        saved = [steps for steps, _ in list_checkpoints(partial_folder(folder, variant, seed), PREFIX)]
        return max(budget - max(saved, default=0), 0)

    left = [(variant, steps_left(variant, seed, budget)) for variant, seed, budget in todo]
    per_run = ", ".join(f"{variant} {np.median(values) * 1e6:.0f}" for variant, values in sorted(rates.items()))
    return (f"{head}: about {time_at_medians(rates, left, n_jobs)} at {n_jobs} at a time (microseconds per agent-step, "
            f"training and evaluations, medians of the folder's finished runs, on the machine as loaded then: "
            f"{per_run})")


def paired(name_a: str, a: np.ndarray, name_b: str, b: np.ndarray) -> str:
    from sb3_emmarl.common.statistics import paired_p_value, wilcoxon_p_value

    diff = a - b
    wilcoxon, t = wilcoxon_p_value(a, b), paired_p_value(a, b)
    return (f"{name_a} {a.mean():.3f} +- {a.std():.3f} (median {np.median(a):.3f}) against {name_b} {b.mean():.3f} +- "
            f"{b.std():.3f} (median {np.median(b):.3f}): difference {diff.mean():+.3f} +- {diff.std():.3f}, paired t p "
            f"{t:.3g}, Wilcoxon p {wilcoxon:.3g}, higher on {int((diff > 0).sum())} of {len(diff)}")


#: The protocol's bar for "a above b" over seeds: paired t p and Wilcoxon p below these, higher on this share of seeds.
BAR_T, BAR_WILCOXON, BAR_SHARE = 0.01, 0.05, 0.8


def passes_bar(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether ``a`` is above ``b`` by the protocol's bar (:data:`BAR_T`, :data:`BAR_WILCOXON`, :data:`BAR_SHARE`)."""
    from sb3_emmarl.common.statistics import paired_p_value, wilcoxon_p_value

    diff = a - b
    return bool(diff.mean() > 0 and paired_p_value(a, b) < BAR_T and wilcoxon_p_value(a, b) < BAR_WILCOXON
                and (diff > 0).sum() >= BAR_SHARE * len(diff))


def null_calibration(label: dict[int, list[float]], plain: dict[int, list[float]], draws: int = 2000,
                     seed: int = 0) -> tuple[bool, float]:
    """The protocol run with a random label in place of the mode (the control against PPO), and how often its bar is
    passed by chance: each draw resamples every run's evaluation episodes (the same episodes for both runs of a seed:
    they played the same ones) and swaps the two runs of each seed with probability 1/2, which the null (the label
    carries nothing) allows.

    :param label: ``{seed: team reward per episode}`` of the control runs
    :param plain: the same for the PPO runs (the same seeds and episodes)
    :return: whether the bar passes on the runs themselves, and the share of draws that pass it
    """
    seeds = sorted(set(label) & set(plain))
    a, b = np.array([label[s] for s in seeds]), np.array([plain[s] for s in seeds])
    observed = passes_bar(a.mean(1), b.mean(1))
    rng = np.random.default_rng(seed)
    hits = 0
    for _ in range(draws):
        episodes = rng.integers(a.shape[1], size=a.shape[1])
        ma, mb = a[:, episodes].mean(1), b[:, episodes].mean(1)
        swap = rng.random(len(seeds)) < 0.5
        hits += passes_bar(np.where(swap, mb, ma), np.where(swap, ma, mb))
    return observed, hits / draws


def recovered(by: dict[str, dict[int, dict]], variant: str, key: str = "team_reward", name: str | None = None
              ) -> list[str]:
    """The share of the told gain a variant recovers, ``(variant - ppo) / (told - ppo)`` with a 90% bootstrap
    interval over seeds, and, for an EM variant, the variant against itself with its belief permuted (over the seeds
    all three ran). ``key`` is the variant's score (``"belief_executed"``: the told runs acting on the exact belief),
    ``name`` what the report calls it."""
    seeds = sorted(set(by["told"]) & set(by["ppo"]) & {s for s, r in by[variant].items() if key in r})
    if len(seeds) < 2:
        return []
    name = name or variant

    means = partial(seed_means, by, seeds=seeds)

    em, told, ppo = means(variant, key), means("told"), means("ppo")
    if (told - ppo).mean() == 0:
        share = f"({name} - ppo) / (told - ppo): undefined, told and ppo score alike"
    else:
        draws = np.random.default_rng(0).integers(len(seeds), size=(10_000, len(seeds)))
        with np.errstate(divide="ignore", invalid="ignore"):
            boot = (em[draws] - ppo[draws]).mean(1) / (told[draws] - ppo[draws]).mean(1)
        low, high = np.nanpercentile(boot, [5, 95])
        share = (f"({name} - ppo) / (told - ppo) = {(em - ppo).mean() / (told - ppo).mean():.3f}, 90% bootstrap "
                 f"interval over seeds [{low:.3f}, {high:.3f}] (seeds {seeds})")
    if "permuted" not in by[variant][seeds[0]]:
        return [share, paired(name, em, "ppo", ppo)]
    permuted = means(variant, "permuted")
    return [share, paired(variant, em, f"{variant}, belief permuted", permuted),
            exceeds(f"{variant} - {variant} permuted", em - permuted, f"({variant} - ppo) / 2", (em - ppo) / 2)]


def exceeds(name_a: str, a: np.ndarray, name_b: str, b: np.ndarray) -> str:
    """Whether the per-seed ``a`` exceed ``b``: their means and the one-sided paired t p-value."""
    excess = a - b
    p = float(stats.ttest_1samp(excess, 0.0, alternative="greater").pvalue) if np.any(excess != 0) else 1.0
    return f"{name_a} = {a.mean():.3f}, {name_b} = {b.mean():.3f}: one-sided paired t p (the first above the second) {p:.3g}"


#: The EM variants (their beliefs are scored).
EM_VARIANTS = tuple(v for v in VARIANTS if v.startswith("em_ppo"))


def conditioning_of(record: dict) -> str:
    """How a run's networks read the mode or the belief: its record's ``belief_conditioning``; a record written before
    it was kept (0.22.0), by its variant's own arguments (the YAMLs then read it by concatenation)."""
    given = ALGOS[record["variant"]][1].get("policy_kwargs", {})
    return record.get("belief_conditioning") or given.get("belief_conditioning", "concat")


def settings(variant: str, task: str = "zone_patrol", conditioning: str | None = None) -> str:
    """The settings a variant trains with (PROTOCOL item 10: every comparison names them): its zoo YAML section's PPO
    settings, and its latent settings (EM) or what it appends to the observation; ``conditioning``: its runs'
    ``belief_conditioning`` (:func:`conditioning_of`), in place of today's YAML's."""
    from sb3_emmarl.zoo.algos import merge_hyperparams
    from sb3_emmarl.zoo.exp_manager import zoo_hyperparams, zoo_policy_kwargs

    algo, overrides = variant_overrides(variant, task)
    if conditioning is not None and algo in ("em_ppo", "oracle_ppo"):  # (a variant's own policy_kwargs: the YAML's too)
        kwargs = overrides.get("policy_kwargs") or zoo_policy_kwargs(algo, TASKS[task].env_id)
        overrides = {**overrides, "policy_kwargs": {**kwargs, "belief_conditioning": conditioning}}
    section = merge_hyperparams(zoo_hyperparams(algo, TASKS[task].env_id), overrides)
    section = {**section, **section.pop("latent_kwargs", {})}  # (EM's settings named one by one)
    if variant == "exact_belief":
        section["belief"] = "the exact posterior of the readings along the links, its weights started at zero"
    keys = ("n_envs", "n_steps", "batch_size", "n_epochs", "ent_coef", "learning_rate", "policy_kwargs", "n_components",
            "fusion", "team_pooling", "likelihood_temperature", "zero_belief_weights", "e_step_interval", "e_step_kwargs",
            "random_label", "belief", "policy")
    return f"{variant} ({algo}): " + ", ".join(f"{k} {section[k]}" for k in keys if k in section)


def heading(runs: list[dict]) -> str:
    """The report's first line: the task and the budget, which every run must share (else SystemExit)."""
    budgets = {r["budget"] for r in runs}
    if len(budgets) != 1:
        raise SystemExit(f"runs of different budgets {sorted(budgets)}: report one budget at a time")
    tasks = {r.get("task", "zone_patrol") for r in runs}
    if len(tasks) != 1:
        raise SystemExit(f"runs of different tasks {sorted(tasks)}: report one task at a time")
    name = TASKS[tasks.pop()].name
    kwargs = {json.dumps(r.get("env_kwargs") or {}, sort_keys=True) for r in runs}
    if len(kwargs) != 1:
        raise SystemExit(f"runs of different {name} arguments {sorted(kwargs)}: report one task at a time")
    task = kwargs.pop()
    return (f"{name}{'' if task == '{}' else ' ' + task}, {budgets.pop():,} agent-steps per run; mean team reward "
            f"over each run's evaluation episodes")


def seed_means(by: dict[str, dict[int, dict]], variant: str, key: str = "team_reward",
               seeds: list[int] | None = None) -> np.ndarray:
    """Per seed of ``seeds`` (default: every run of the variant), the variant's mean of ``key`` over the episodes."""
    return np.array([np.mean(by[variant][s][key]) for s in (sorted(by[variant]) if seeds is None else seeds)])


def told_lines(by: dict[str, dict[int, dict]]) -> list[str]:
    """Each told variant's report on its label: told right against told a wrong zone and the wrong weather, and the
    label's cost against half the told gain over PPO."""
    lines: list[str] = []
    means = partial(seed_means, by)
    for told in TOLD_VARIANTS:
        told_seeds = sorted(by[told])
        if len(told_seeds) < 2:
            continue
        right, label = means(told, seeds=told_seeds), "" if told == "told" else f"{told}: "
        zones = np.mean([means(told, f"wrong_zone_{shift}", told_seeds) for shift in (1, 2, 3)], axis=0)
        for name, wrong_means in (("told a wrong zone (mean of the three)", zones),
                                  ("told the wrong weather", means(told, "wrong_weather", told_seeds))):
            lines.append(paired(f"{label}told right", right, name, wrong_means))
        seeds = sorted(set(told_seeds) & set(by["ppo"]))
        if len(seeds) >= 2:
            loss = means(told, seeds=seeds) - np.mean(
                [means(told, f"wrong_zone_{shift}", seeds) for shift in (1, 2, 3)], axis=0)
            gain = means(told, seeds=seeds) - means("ppo", seeds=seeds)
            lines.append(exceeds(f"{label}told right - told a wrong zone", loss, f"({told} - ppo) / 2", gain / 2))
    return lines


def report(runs: list[dict], random_team: float | None = None) -> str:
    by = {v: {r["seed"]: r for r in runs if r["variant"] == v} for v in VARIANTS}
    lines = [heading(runs)]
    task = runs[0].get("task", "zone_patrol")
    for v in (v for v in VARIANTS if by[v]):
        conditionings = sorted({conditioning_of(r) for r in by[v].values()})
        if len(conditionings) > 1:
            raise SystemExit(f"the {v} runs read the mode or the belief in different ways {conditionings} (the default "
                             "changed between them): report them apart")
        lines.append("settings: " + settings(v, task, conditionings[0]))

    means = partial(seed_means, by)

    for a, b in (("told", "ppo"), ("told", "control"), ("control", "ppo"), ("em_ppo", "ppo"), ("told", "em_ppo"),
                 ("em_ppo", "em_ppo_nofusion"), ("em_ppo_team", "ppo"), ("em_ppo_team", "em_ppo"), ("exact_belief", "ppo"),
                 ("exact_belief", "em_ppo"), ("ppo_lstm", "ppo"),
                 ("em_ppo", "ppo_lstm"), ("mappo", "ppo"), ("told_film", "ppo"), ("told_film", "told"),
                 ("told_mixture", "ppo"), ("told_mixture", "told"), ("em_ppo_mixture", "ppo"),
                 ("em_ppo_mixture", "em_ppo"), ("told_mixture", "em_ppo_mixture")):
        seeds = sorted(set(by[a]) & set(by[b]))
        if len(seeds) >= 2:
            ma, mb = means(a, seeds=seeds), means(b, seeds=seeds)
            verdict = "passes" if passes_bar(ma, mb) else "does not pass"
            lines.append(paired(a, ma, b, mb) + f" (seeds {seeds}); {verdict} the protocol's bar for {a} above {b}")
    lines += told_lines(by)
    for variant in EM_VARIANTS:
        lines += recovered(by, variant)
    lines += recovered(by, "exact_belief")
    lines += recovered(by, "told", "belief_executed", "told, acting on the exact belief along the links")
    for variant in (*TOLD_VARIANTS, "control", *EM_VARIANTS):
        if by[variant]:
            kl = np.array([by[variant][s]["swap_kl"] for s in sorted(by[variant])])
            lines.append(f"{variant}: swap KL {kl.mean():.4f} +- {kl.std():.4f}")
    mid = TASKS[task].mid_episode
    for variant in EM_VARIANTS:
        if by[variant]:
            seeds = sorted(by[variant])
            acc = np.array([by[variant][s]["belief_accuracy"] for s in seeds])
            lines.append(f"{variant}: belief tells the mode at step {mid} {acc.mean():.3f} +- {acc.std():.3f} "
                         f"(lowest {acc.min():.3f})")
            if all("exact_team_zone_accuracy" in by[variant][s] for s in seeds):
                zone, exact = (np.array([by[variant][s][k] for s in seeds])
                               for k in ("belief_zone_accuracy", "exact_team_zone_accuracy"))
                lines.append(f"{variant}: belief tells the zone at step {mid} {zone.mean():.3f} +- {zone.std():.3f}; the "
                             f"exact posterior of the whole team's readings on the same episodes {exact.mean():.3f} +- "
                             f"{exact.std():.3f}; ratio {zone.mean() / exact.mean():.3f} (per seed: lowest "
                             f"{(zone / exact).min():.3f})")
    lines.append("training seconds per run (median): " + ", ".join(
        f"{v} {np.median([r['seconds'] for r in by[v].values()]):.0f}" for v in VARIANTS if by[v]))
    seeds = sorted(set(by["control"]) & set(by["ppo"]))
    if len(seeds) >= 2:
        observed, rate = null_calibration({s: by["control"][s]["team_reward"] for s in seeds},
                                          {s: by["ppo"][s]["team_reward"] for s in seeds})
        lines.append(f"null calibration (the protocol with the random label in place of the mode, control against ppo): "
                     f"{'passes' if observed else 'fails'} the bar; passed by chance in {rate:.1%} of 2000 resamplings "
                     f"(episodes resampled, the two runs of each seed swapped at random)")
    if random_team is not None:
        collapsed = [f"{r['variant']} seed {r['seed']}" for r in runs if np.mean(r["team_reward"]) < random_team]
        lines.append(f"random team {random_team:.3f}; collapsed runs (below it): {', '.join(collapsed) or 'none'}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    from sb3_emmarl.common.trust.arguments import json_object

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    commands = parser.add_subparsers(dest="command", required=True)
    run_parser = commands.add_parser("run", help="train and evaluate the runs missing from --folder")
    run_parser.add_argument("--variants", nargs="+", default=list(DEFAULT_VARIANTS), choices=list(VARIANTS))
    run_parser.add_argument("--seeds", type=int, nargs="+", default=list(range(10)))
    run_parser.add_argument("-n", type=int, default=BUDGET, help="agent-steps per run")
    run_parser.add_argument("--eval-episodes", type=int, default=200)
    run_parser.add_argument("--n-jobs", type=int, default=2, help="runs at once, each in its own process (1: here)")
    run_parser.add_argument("--checkpoint-every", type=int, default=CHECKPOINT_EVERY,
                            help="agent-steps between a run's checkpoints (a run killed mid-way continues from its newest)")
    run_parser.add_argument("--folder", required=True)
    run_parser.add_argument("--task", choices=sorted(TASKS), default="zone_patrol",
                            help="ZonePatrol or the reserve with scenario='zone_raids'")
    run_parser.add_argument("--env-kwargs", type=json_object, default={},
                            help="the task's arguments as JSON, e.g. '{\"zone_cue\": 0.2}' (ZonePatrol)")
    report_parser = commands.add_parser("report", help="the tables of the runs in --folder (several: their runs "
                                                       "together, e.g. a protocol's seeds and its confirmation's)")
    report_parser.add_argument("--folder", required=True, nargs="+")
    args = parser.parse_args(argv)
    if args.command == "report":
        runs = [json.loads(p.read_text()) for folder in args.folder for p in sorted(Path(folder).glob("*.json"))]
        if not runs:
            raise SystemExit(f"no runs in {' '.join(args.folder)}: run `zone_patrol_value.py run --folder F` first")
        keys = [(run["variant"], run["seed"]) for run in runs]
        if len(set(keys)) != len(keys):
            twice = sorted({key for key in keys if keys.count(key) > 1})
            raise SystemExit(f"the folders hold the same runs twice (variant, seed): {twice[:5]}")
        episodes = len(runs[0]["team_reward"])
        task = runs[0].get("task", "zone_patrol")
        random_team = float(np.mean(play(None, make_env(EVAL_SEED, env_kwargs=runs[0].get("env_kwargs"), task=task),
                                         episodes, EVAL_SEED, random=True)[0]))
        print(report(runs, random_team))
        return 0
    folder = Path(args.folder)
    if args.n < 1 or args.eval_episodes < 2 or args.n_jobs < 1 or args.checkpoint_every < 1 \
            or len(set(args.seeds)) != len(args.seeds):
        parser.error(f"-n, --n-jobs and --checkpoint-every must be >= 1 (got {args.n}, {args.n_jobs}, "
                     f"{args.checkpoint_every}), --eval-episodes >= 2 (got {args.eval_episodes}) and --seeds distinct")
    env_kwargs = args.env_kwargs
    try:
        TASKS[args.task].check(env_kwargs)
    except ValueError as error:
        parser.error(f"--env-kwargs: {error}")
    folder.mkdir(parents=True, exist_ok=True)
    jobs = [(str(folder), v, s, args.n, args.eval_episodes, env_kwargs, args.task, args.checkpoint_every)
            for s in args.seeds for v in args.variants]
    print(estimate(folder, jobs, args.n_jobs), flush=True)
    if args.n_jobs == 1:  # in this process (each run sets torch to one thread, as the workers do)
        for job in jobs:
            print(run_and_save(*job), flush=True)
        return 0
    from sb3_emmarl.experiments.runner import die_with_parent

    # (a worker ends with this process: a killed protocol leaves no run going on beside the next one)
    with ProcessPoolExecutor(max_workers=args.n_jobs, initializer=die_with_parent, initargs=(os.getpid(),)) as pool:
        for line in pool.map(run_and_save, *zip(*jobs)):
            print(line, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
