"""Team evaluation: deterministic episodes on a seed, one record per episode, ready for tables
(:func:`evaluate_team`); and SB3's ``evaluate_policy`` counting team episodes (:func:`evaluate_policy`)."""

from __future__ import annotations

import numbers
import threading
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any, Protocol

import gymnasium as gym
import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common import evaluation as sb3_evaluation
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv, VecMonitor, is_vecenv_wrapped

from sb3_emmarl.common.appended.wrapping import find_wrapper
from sb3_emmarl.common.env_ids import ENV_ID, parallel_env_fn
from sb3_emmarl.common.latent.diagnostics import BELIEF_USE_ROWS, belief_use
from sb3_emmarl.common.trust.safe_pickle import load_vec_normalize
from sb3_emmarl.common.trust.safe_zip import safe_data_objects
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
    :param env_id: the environment (:data:`~sb3_emmarl.common.env_ids.ENV_MODULES`; default the reserve)
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
        venv = load_vec_normalize(vec_normalize_path, venv)
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
    kwargs["custom_objects"] = safe_data_objects(path, kwargs.get("custom_objects"))  # data only: nothing in it runs
    with _TORCH_RNG_LOCK, th.random.fork_rng():
        return algo_class.load(path, **kwargs)


def evaluate_team(
    model: Predictor,
    n_episodes: int = 10,
    seed: int = 0,
    *,
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


def check_episode_count(n_eval_episodes: Any) -> int:
    """``n_eval_episodes`` as an int, refused with one line unless it is a whole number >= 1 (SB3's own
    ``evaluate_policy`` takes 0 and returns nan)."""
    if isinstance(n_eval_episodes, bool) or not isinstance(n_eval_episodes, numbers.Integral) or n_eval_episodes < 1:
        raise ValueError(f"n_eval_episodes must be a whole number >= 1, got {n_eval_episodes!r}")
    return int(n_eval_episodes)


def _team_episode(info: dict[str, Any], monitored: bool, reward: float, length: int) -> tuple[float, int] | None:
    """The team reward and length of the episode that ended with ``info`` (a copy's first entry's): the team reward
    the environment reports in its episode metrics (what :func:`evaluate_team` records), else as SB3 reads an
    episode: the Monitor's record (None, no episode's end, without it), or the rewards and steps counted here."""
    team_reward = info.get("metrics", {}).get("team_reward")
    if team_reward is not None:
        return float(team_reward), int(info["episode"]["l"]) if "episode" in info else length
    if monitored:
        return (float(info["episode"]["r"]), int(info["episode"]["l"])) if "episode" in info else None
    return reward, length


def evaluate_policy(
    model: Predictor,
    env: gym.Env | VecEnv,
    n_eval_episodes: int = 10,
    deterministic: bool = True,
    *,
    render: bool = False,
    callback: Callable[[dict[str, Any], dict[str, Any]], None] | None = None,
    reward_threshold: float | None = None,
    return_episode_rewards: bool = False,
    warn: bool = True,
) -> tuple[float, float] | tuple[list[float], list[int]]:
    """SB3's ``evaluate_policy`` (same arguments in SB3's order, those after ``deterministic`` by keyword only; same
    return values) counting team episodes on a parameter-sharing vector environment.

    Each vector entry of :func:`~sb3_emmarl.common.vec_env.make_vec_env` is one UAV, and every UAV of a copy receives
    the team reward: SB3's own function counts each UAV's episode as an episode, so ``n_eval_episodes=10`` on a team of
    ten scores the ten UAVs of one team episode (ten equal rewards, a std of 0). Here one episode is one episode of a
    copy (``agents_per_copy`` entries): its reward is the copy's team reward, read from its first entry (the episode's
    ``infos[i]["metrics"]["team_reward"]`` when the environment reports it, as the reserve and ZonePatrol do: the very
    number :func:`evaluate_team` records; otherwise that entry's Monitor return), its length the episode's steps.
    Episodes are divided among the copies as SB3 divides them among entries (copy ``c`` plays
    ``(n_eval_episodes + c) // n_copies``, a static division that does not favour short episodes). Recurrent
    policies and EM models get ``state`` and ``episode_start`` back at every step, as in SB3.

    A model with ``wrap_env`` (EM-PPO, EM-DDPG, VDN+EM, OraclePPO, MessagePPO) is evaluated on ``model.wrap_env(env)``:
    pass the plain environment it was trained on (an environment that already carries the wrapper is kept as it is).
    On any other environment (no ``agents_per_copy``, or one agent per copy) this is SB3's ``evaluate_policy``.

    :param model: the agent: anything with SB3's ``predict`` (an algorithm or a policy)
    :param env: the evaluation environment: a parameter-sharing vector environment, or any Gymnasium or vector env
    :param n_eval_episodes: team episodes to play (a whole number >= 1)
    :param deterministic: the most likely actions (SB3's default; with one policy shared by identical UAVs, two UAVs
        that see the same thing then act alike, see :func:`evaluate_team`)
    :param render: render the environment at every step
    :param callback: called after each step once per copy still counting, with ``locals()`` and ``globals()``
        (``i`` the copy's first entry, ``reward``, ``done`` and ``info`` that entry's), as SB3 calls it once per entry
    :param reward_threshold: minimum expected mean team reward (an ``AssertionError`` below it, as in SB3)
    :param return_episode_rewards: return the per-episode team rewards and lengths instead of the mean and std
    :param warn: warn when the environment has no ``Monitor`` / ``VecMonitor`` wrapper (as SB3)
    :return: the mean and std of the team reward per episode, or, with ``return_episode_rewards``, the list of team
        rewards and the list of episode lengths (in steps), one item per team episode
    """
    # Long because it is SB3's evaluate_policy in one piece, its loop per copy instead of per entry: the two read side by
    # side, and a change in SB3's carries over line by line.
    n_eval_episodes = check_episode_count(n_eval_episodes)
    if hasattr(model, "wrap_env"):
        env = model.wrap_env(env)
    per_copy = int(getattr(env, "agents_per_copy", 1)) if isinstance(env, VecEnv) else 1
    if per_copy <= 1:
        return sb3_evaluation.evaluate_policy(model, env, n_eval_episodes, deterministic,  # type: ignore[arg-type]
                                              render=render, callback=callback, reward_threshold=reward_threshold,
                                              return_episode_rewards=return_episode_rewards, warn=warn)
    assert isinstance(env, VecEnv)  # (only a vector environment has agents_per_copy here)
    if env.num_envs % per_copy:
        raise ValueError(f"the environment has {env.num_envs} entries, not a whole number of copies of "
                         f"{per_copy} agents")
    is_monitor_wrapped = is_vecenv_wrapped(env, VecMonitor) or env.env_is_wrapped(Monitor)[0]
    if not is_monitor_wrapped and warn:
        warnings.warn(
            "Evaluation environment is not wrapped with a ``Monitor`` wrapper. "
            "This may result in reporting modified episode lengths and rewards, if other wrappers happen to modify these. "
            "Consider wrapping environment first with ``Monitor`` wrapper.",
            UserWarning,
        )
    n_copies = env.num_envs // per_copy
    firsts = np.arange(n_copies) * per_copy  # the entry that speaks for each copy
    episode_rewards: list[float] = []
    episode_lengths: list[int] = []
    episode_counts = np.zeros(n_copies, dtype="int")
    # Divides episodes among the copies as evenly as possible (SB3's division among entries).
    episode_count_targets = np.array([(n_eval_episodes + c) // n_copies for c in range(n_copies)], dtype="int")
    current_rewards = np.zeros(n_copies)
    current_lengths = np.zeros(n_copies, dtype="int")
    observations = env.reset()
    states = None
    episode_starts = np.ones((env.num_envs,), dtype=bool)
    while (episode_counts < episode_count_targets).any():
        actions, states = model.predict(
            observations,  # type: ignore[arg-type]
            state=states,
            episode_start=episode_starts,
            deterministic=deterministic,
        )
        new_observations, rewards, dones, infos = env.step(actions)
        current_rewards += rewards[firsts]
        current_lengths += 1
        episode_starts = np.array(dones, dtype=bool)  # every entry's, the other UAVs' states reset with their copy's
        for c, i in enumerate(firsts):
            if episode_counts[c] < episode_count_targets[c]:
                # unpack values so that the callback can access the local variables (as in SB3)
                reward, done, info = rewards[i], dones[i], infos[i]
                if callback is not None:
                    callback(locals(), globals())
                if done:
                    episode = _team_episode(info, is_monitor_wrapped, float(current_rewards[c]),
                                            int(current_lengths[c]))
                    if episode is not None:
                        episode_rewards.append(episode[0])
                        episode_lengths.append(episode[1])
                        episode_counts[c] += 1
                    current_rewards[c] = 0
                    current_lengths[c] = 0
        observations = new_observations
        if render:
            env.render()
    mean_reward = np.mean(episode_rewards)
    std_reward = np.std(episode_rewards)
    if reward_threshold is not None:
        assert mean_reward > reward_threshold, f"Mean reward below threshold: {mean_reward:.2f} < {reward_threshold:.2f}"
    if return_episode_rewards:
        return episode_rewards, episode_lengths
    return float(mean_reward), float(std_reward)


class LatentTracker:
    """Beliefs of an EM model during evaluation, paired with the true mode of each entry's episode.

    :meth:`annotate` aligns components to modes over all evaluated episodes (Hungarian matching) and adds
    to each record its episode's ``latent_accuracy`` (over all its steps), ``latent_accuracy_25``,
    ``latent_accuracy_50`` and ``latent_accuracy_100`` (at the step a quarter, half and all of the way
    through the episode, over the team's agents), ``latent_kl``, the overall ``latent_nmi`` and, for a policy with
    a distribution or an actor, the overall ``belief_use``: how far its actions move when the belief is permuted
    between components, over one observation per evaluated step (at most
    :data:`~sb3_emmarl.common.latent.diagnostics.BELIEF_USE_ROWS`; see
    :func:`~sb3_emmarl.common.latent.diagnostics.belief_use`), 0 for a policy that ignores its belief. On a team with
    links (the model's belief wrapper tracks more than one agent per copy) it adds ``evidence_reach_25``, ``_50`` and
    ``_100``: the share of the team's evidence in the beliefs at those steps, over the team's agents
    (:meth:`~sb3_emmarl.common.latent.belief.BeliefTracker.evidence_reach`).
    """

    def __init__(self, model: Any, vec_env: VecEnv) -> None:
        from sb3_emmarl.common.latent.belief import BeliefWrapper

        self.model = model
        self.steps = np.zeros(vec_env.num_envs, dtype=np.int64)
        self.posteriors: list[np.ndarray] = []
        self.modes: list[np.ndarray] = []
        self.episodes: list[np.ndarray] = []
        self.step_index: list[np.ndarray] = []
        wrapper = find_wrapper(vec_env, BeliefWrapper)
        self.tracker = wrapper.tracker if wrapper is not None and wrapper.tracker.agents_per_copy > 1 else None
        self.reach: list[np.ndarray] = []
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
            if self.tracker is not None:
                self.reach.append(self.tracker.evidence_reach(keep))
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
        reach = np.concatenate(self.reach) if self.reach else None
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
                if reach is not None:
                    record[f"evidence_reach_{fraction_label(fraction)}"] = float(reach[at].mean())
