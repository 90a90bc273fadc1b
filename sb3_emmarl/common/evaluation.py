"""Team evaluation: deterministic episodes on a seed, one record per episode, ready for tables."""

from __future__ import annotations

import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv, VecMonitor, VecNormalize

from sb3_emmarl.common.environments import ENV_ID, parallel_env_fn
from sb3_emmarl.common.latent.diagnostics import BELIEF_USE_ROWS, belief_use
from sb3_emmarl.common.vec_env import make_vec_env


class Predictor(Protocol):
    """Anything with SB3's ``predict`` signature (an algorithm, a policy, :class:`RandomPolicy`)."""

    def predict(self, observation: np.ndarray, state: Any = None, episode_start: np.ndarray | None = None,
                deterministic: bool = False) -> tuple[np.ndarray, Any]: ...


class RandomPolicy:
    """Uniform random actions with SB3's ``predict`` signature: the reference every table compares against.

    :param action_space: the (per-entry) action space
    :param seed: seed of the draws
    """

    def __init__(self, action_space: spaces.Space, seed: int | None = None) -> None:
        self.action_space = action_space
        self.rng = np.random.default_rng(seed)

    def predict(self, observation: np.ndarray, state: Any = None, episode_start: np.ndarray | None = None,
                deterministic: bool = False) -> tuple[np.ndarray, None]:
        n = len(observation)
        if isinstance(self.action_space, spaces.Discrete):
            return self.rng.integers(0, self.action_space.n, size=n), None
        if isinstance(self.action_space, spaces.MultiDiscrete):
            return self.rng.integers(0, self.action_space.nvec, size=(n, *self.action_space.nvec.shape)), None
        if isinstance(self.action_space, spaces.Box):
            low, high = self.action_space.low, self.action_space.high
            return self.rng.uniform(low, high, size=(n, *self.action_space.shape)).astype(self.action_space.dtype), None
        raise ValueError(f"RandomPolicy supports Discrete, MultiDiscrete and Box action spaces, not {self.action_space}")


def make_eval_env(seed: int, env_kwargs: dict[str, Any] | None = None, centralized: bool = False,
                  vec_normalize_path: str | None = None, model: Any = None,
                  vec_env_wrapper: Callable[[VecEnv], VecEnv] | None = None, env_id: str = ENV_ID) -> VecEnv:
    """One copy of the environment for evaluation: the parameter-sharing view, or the centralised one.

    :param seed: seed of the first episode (later episodes follow from it)
    :param env_kwargs: the reserve's arguments
    :param centralized: the single-agent view over the global state and the joint action
    :param vec_normalize_path: ``VecNormalize`` statistics saved in training (applied frozen)
    :param model: a model with ``wrap_env`` (EM-PPO, EM-DDPG, oracle PPO) gets its wrapper on top
    :param vec_env_wrapper: the wrapper the model was trained under (rl-zoo's ``vec_env_wrapper``, e.g.
        ``HideObservationParts``), applied where training applied it: on the plain parameter-sharing view
    :param env_id: the environment (:data:`~sb3_emmarl.common.environments.ENV_MODULES`; default the reserve)
    """
    env_kwargs = dict(env_kwargs or {})
    if centralized and vec_env_wrapper is not None:
        raise ValueError("vec_env_wrapper applies to the parameter-sharing view, not to the centralised one")
    if centralized:
        from sb3_emmarl.common.centralized import centralized_env

        venv: VecEnv = VecMonitor(DummyVecEnv([lambda: centralized_env(env_id, **env_kwargs)]))
        venv.seed(seed)
    else:
        venv = make_vec_env(n_copies=1, seed=seed, env_kwargs=env_kwargs, vec_env_wrapper=vec_env_wrapper,
                            env_fn=parallel_env_fn(env_id), vec_env_type="batched")
    if vec_normalize_path is not None:
        venv = VecNormalize.load(vec_normalize_path, venv)
        venv.training = False
        venv.norm_reward = False
    if hasattr(model, "wrap_env"):
        venv = model.wrap_env(venv)
    return venv


def is_centralized(model: Predictor, env_kwargs: dict[str, Any] | None = None, env_id: str = ENV_ID) -> bool:
    """Whether a model acts on the global state (the centralised view) rather than on one UAV's observation."""
    space = getattr(model, "observation_space", None)
    if space is None:
        return False
    prototype = parallel_env_fn(env_id)(**dict(env_kwargs or {}))
    return space.shape == prototype.state_space.shape and space.shape != prototype.observation_space("uav_0").shape


#: Held while an evaluation draws from torch's global generator: two evaluations in threads of one process (the
#: zoo's comparisons evaluate each run in a thread as the next trains) would otherwise interleave their draws, and
#: the same model on the same seed scored 12.5 in one comparison and 8.7 when evaluated alone. Loading a model
#: draws from it too (building the networks), hence :func:`load_for_evaluation`.
_TORCH_RNG_LOCK = threading.Lock()


def load_for_evaluation(algo_class: type[BaseAlgorithm], path: str | Path, **kwargs: Any) -> Any:
    """``algo_class.load(path, **kwargs)`` holding the lock :func:`evaluate_team` holds: building a model's networks
    draws from torch's global generator, so a model loaded in one thread while another evaluates changed that
    evaluation's sampled actions (tests/test_evaluation.py shows it).

    :param algo_class: an SB3 algorithm class
    :param path: the saved model
    :param kwargs: ``load``'s other arguments
    """
    with _TORCH_RNG_LOCK, th.random.fork_rng():
        return algo_class.load(path, **kwargs)


def evaluate_team(
    model: Predictor,
    n_episodes: int = 10,
    seed: int = 0,
    env_kwargs: dict[str, Any] | None = None,
    deterministic: bool = False,
    vec_env: VecEnv | None = None,
    vec_normalize_path: str | None = None,
    vec_env_wrapper: Callable[[VecEnv], VecEnv] | None = None,
    env_id: str = ENV_ID,
) -> list[dict[str, Any]]:
    """Play ``n_episodes`` evaluation episodes and return each one's team metrics and true mode.

    Episodes run one after another on one reserve seeded with ``seed``; the reserve draws each
    episode's map, mode and poacher plan at its reset from that seed alone, so two policies
    evaluated on the same seed face the same sequence of episodes. The evaluation is deterministic
    given the seed: sampled actions come from torch's generator seeded with ``seed`` (the caller's
    generator state is restored afterwards).

    Actions are sampled from the policy by default: with one policy shared by identical UAVs, the
    most likely action is the same for two UAVs that see the same thing, so two UAVs in one cell
    stay together for good (a collision every step) under ``deterministic=True``.

    :param model: an SB3 algorithm (or anything with its ``predict``), recurrent ones included
    :param n_episodes: episodes to play
    :param seed: evaluation seed
    :param env_kwargs: the reserve's arguments (as in training)
    :param deterministic: the most likely actions instead of sampled ones
    :param vec_env: evaluate on this vector environment instead (one reserve copy; its seed is yours); a model with
        ``wrap_env`` (EM, oracle and message models) gets its wrapper on top, as on its own environment
    :param vec_normalize_path: ``VecNormalize`` statistics saved in training, if the model used them
    :param vec_env_wrapper: the ``vec_env_wrapper`` the model was trained under, if any (see :func:`make_eval_env`);
        not with ``vec_env``
    :param env_id: the environment (default the reserve; ``"ZonePatrol-v0"``: ZonePatrol), not with ``vec_env``
    :return: one dict per episode: every metric of the episode, ``mode``, ``episode`` and ``seed``
    """
    if n_episodes < 1:
        raise ValueError(f"n_episodes must be >= 1, got {n_episodes}")
    if vec_env is not None and vec_env_wrapper is not None:
        raise ValueError("give vec_env_wrapper or vec_env, not both: a vec_env you build carries its own wrappers")
    own_env = vec_env is None
    if vec_env is None:  # (own_env)
        vec_env = make_eval_env(seed, env_kwargs, is_centralized(model, env_kwargs, env_id), vec_normalize_path, model,
                                vec_env_wrapper, env_id)
    elif hasattr(model, "wrap_env"):  # kept when it is already there
        vec_env = model.wrap_env(vec_env)
    per_copy = int(getattr(vec_env, "agents_per_copy", 1))
    has_latent = getattr(getattr(model, "policy", None), "latent_model", None) is not None
    latent = LatentTracker(model, vec_env) if has_latent else None
    records: list[dict[str, Any]] = []
    with _TORCH_RNG_LOCK, th.random.fork_rng():
        th.manual_seed(seed)
        observations = vec_env.reset()
        assert isinstance(observations, np.ndarray)  # (Box observations, the UAVs' or the global state)
        if latent is not None:
            latent.observe(observations, vec_env.unwrapped.reset_infos, len(records))
        state, starts = None, np.ones(vec_env.num_envs, dtype=bool)
        while len(records) < n_episodes:
            actions, state = model.predict(observations, state=state, episode_start=starts, deterministic=deterministic)
            observations, _, starts, infos = vec_env.step(actions)
            assert isinstance(observations, np.ndarray)
            for i in np.flatnonzero(starts):
                if i % per_copy == 0 and "metrics" in infos[i]:
                    records.append({**infos[i]["metrics"], "episode": len(records), "seed": seed})
            if latent is not None:
                latent.observe(observations, infos, len(records), starts)
    if own_env:
        vec_env.close()
    records = records[:n_episodes]
    if latent is not None:
        latent.annotate(records)
    return records


class LatentTracker:
    """Beliefs of an EM model during evaluation, paired with the true mode of each entry's episode.

    :meth:`annotate` aligns components to modes over all evaluated episodes (Hungarian matching) and adds
    to each record its episode's ``latent_accuracy`` (over all its steps), ``latent_accuracy_25``,
    ``latent_accuracy_50`` and ``latent_accuracy_100`` (at the step a quarter, half and all of the way
    through the episode, over the team's agents), ``latent_kl``, the overall ``latent_nmi`` and, for a policy with
    a distribution or an actor, the overall ``belief_use``: how far its actions move when the belief is permuted
    between components, over one observation per evaluated step (at most
    :data:`~sb3_emmarl.common.latent.diagnostics.BELIEF_USE_ROWS`; see
    :func:`~sb3_emmarl.common.latent.diagnostics.belief_use`), 0 for a policy that ignores its belief.
    """

    def __init__(self, model: Any, vec_env: VecEnv) -> None:
        self.model = model
        self.steps = np.zeros(vec_env.num_envs, dtype=np.int64)
        self.posteriors: list[np.ndarray] = []
        self.modes: list[np.ndarray] = []
        self.episodes: list[np.ndarray] = []
        self.step_index: list[np.ndarray] = []
        #: one augmented observation per step (the first entry's), for the policy's belief use
        self.visited: list[np.ndarray] = []

    def observe(self, observations: np.ndarray, infos: list[dict], episode: int, starts: np.ndarray | None = None) -> None:
        if starts is not None:
            self.steps = np.where(starts, 0, self.steps + 1)
        keep = np.flatnonzero(np.array(["mode" in info for info in infos]))
        if len(keep):
            self.posteriors.append(self.model.posterior(observations[keep]))
            self.modes.append(np.array([infos[i]["mode"] for i in keep], dtype=np.int64))
            self.episodes.append(np.full(len(keep), episode))
            self.step_index.append(self.steps[keep].copy())
            if len(self.visited) < BELIEF_USE_ROWS:
                self.visited.append(np.array(observations[keep[0]]))

    def annotate(self, records: list[dict[str, Any]]) -> None:
        from sb3_emmarl.common.latent.metrics import (
            EPISODE_FRACTIONS,
            align_components,
            fraction_label,
            fraction_step,
            latent_kl,
            normalized_mutual_information,
        )

        if not self.posteriors:
            return
        posteriors, modes, episodes, steps = (np.concatenate(x) for x in
                                              (self.posteriors, self.modes, self.episodes, self.step_index))
        mapping = align_components(posteriors, modes)
        correct = mapping[posteriors.argmax(1)] == modes
        nmi = normalized_mutual_information(posteriors.argmax(1), modes)
        policy = getattr(self.model, "policy", None)
        use = None
        if policy is not None and (hasattr(policy, "get_distribution") or hasattr(policy, "actor")):
            use = belief_use(policy, np.stack(self.visited), posteriors.shape[1])
        for record in records:
            mine = episodes == record["episode"]
            if not mine.any():
                continue
            record["latent_accuracy"] = float(correct[mine].mean())
            record["latent_kl"] = latent_kl(posteriors[mine], modes[mine], mapping)
            record["latent_nmi"] = nmi
            if use is not None:
                record["belief_use"] = use
            length = int(steps[mine].max()) + 1  # steps acted on in this episode
            for fraction in EPISODE_FRACTIONS:
                at = mine & (steps == fraction_step(fraction, length))
                record[f"latent_accuracy_{fraction_label(fraction)}"] = float(correct[at].mean())
