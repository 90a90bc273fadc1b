"""What EM-PPO and EM-DDPG share: the belief wrapper, the latent settings, the E-step and ``predict`` with a state.

Algorithm 2 of the paper, as implemented: the algorithm collects a rollout with policies that see the
belief ``q(z | o_{1:t}, a_{1:t-1})`` (lines 4-10; the :class:`BeliefWrapper` keeps it); its own ``train()``
then runs the E-step on the recent episodes (line 11, :class:`EStep`) and its update, the M-step (line 12).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np
import torch as th
from stable_baselines3.common.save_util import load_from_zip_file
from stable_baselines3.common.vec_env import VecEnv

from sb3_emmarl.common.appended.wrapping import WrapsObservations, ensure_wrapped, find_wrapper
from sb3_emmarl.common.latent.belief import BeliefTracker, BeliefWrapper, agents_per_copy
from sb3_emmarl.common.latent.config import (
    LatentConfig,
    check_latent_kwargs,
    reject_flat_latent_settings,
    upgrade_saved_settings,
)
from sb3_emmarl.common.latent.diagnostics import belief_entropy, belief_use
from sb3_emmarl.common.latent.em import EpisodeCounts, EStep, Transitions, episode_ids
from sb3_emmarl.common.latent.evidence import evidence_from_spec
from sb3_emmarl.common.latent.features import encode_actions
from sb3_emmarl.common.latent.layout import LatentLayout
from sb3_emmarl.common.latent.model import LatentModel

if TYPE_CHECKING:
    from stable_baselines3.common.buffers import ReplayBuffer, RolloutBuffer
    from stable_baselines3.common.logger import Logger

    from sb3_emmarl.common.latent.evidence import CountEvidence
    from sb3_emmarl.common.latent.policies import LatentPolicyMixin

def wrap_with_belief(env: Any, n_components: int, verbose: int = 0, strict: bool = True) -> VecEnv:
    """``env`` as a vector environment with a :class:`BeliefWrapper` of ``n_components`` (kept if it has one).

    :param strict: reject an existing wrapper of another size (False while loading, which sets the sizes after)
    """

    def mismatch(wrapper: BeliefWrapper) -> str | None:
        if not strict or wrapper.n_components == n_components:
            return None
        return f"the environment's BeliefWrapper has {wrapper.n_components} components, but n_components={n_components}"

    return ensure_wrapped(env, BeliefWrapper, lambda venv: BeliefWrapper(venv, n_components), mismatch, verbose)


def make_e_step(latent_model: LatentModel, config: LatentConfig, counter: CountEvidence | None, seed: int) -> EStep:
    """The E-step of ``latent_model`` with ``config``'s estimator, likelihood temperature, count factors and
    ``e_step_kwargs`` (the rest at :class:`~sb3_emmarl.common.latent.em.EStep`'s defaults, which are
    :data:`~sb3_emmarl.common.latent.config.E_STEP_DEFAULTS`); the count
    factors, rings and weight come with a ``counter`` (the environment's count evidence). A bad value in
    ``e_step_kwargs`` raises one ``ValueError`` naming ``e_step_kwargs``."""
    try:
        return EStep(latent_model, estimator=config.estimator, likelihood_temperature=config.likelihood_temperature,
                     seed=seed, count_factors=config.count_factors if counter is not None else None,
                     count_rings=counter.n_rings if counter is not None else 1,
                     count_weight=counter.weight if counter is not None else 1.0,
                     **(config.e_step_kwargs or {}))
    except ValueError as error:
        raise ValueError(f"e_step_kwargs: {error}") from None


def augmented_features(feature_fn: Callable[[np.ndarray], np.ndarray], observations: np.ndarray,
                       obs_dim: int) -> np.ndarray:
    """Compact features of augmented observations ``(..., total_dim)`` -> ``(..., d_x)`` (their first ``obs_dim``
    values are the environment's observation)."""
    flat = observations.reshape(-1, observations.shape[-1])[:, :obs_dim]
    return feature_fn(flat).reshape(*observations.shape[:-1], -1)


def make_transitions(features: np.ndarray, actions: np.ndarray, next_features: np.ndarray, new_episode: np.ndarray,
                     valid: np.ndarray, episode_counters: np.ndarray, encode_action: Callable[[np.ndarray], np.ndarray],
                     *, agents_per_copy: int = 1, team_pooling: bool = False, counter: CountEvidence | None = None,
                     next_observations: np.ndarray | Sequence[np.ndarray] | None = None,
                     device: th.device | str = "cpu") -> tuple[Transitions, EpisodeCounts | None]:
    """E-step data from ``(T, n, ...)`` arrays of features, actions taken, the features that followed, flags of steps
    that begin an episode, and flags of the transitions to keep; with a ``counter`` (the environment's count evidence),
    also the reading counts of the observations that followed (augmented ``(T, n, total_dim)``, or blocks
    ``(T_i, n, total_dim)`` that stack to it along time: read in place, not copied), summed per episode.

    :param episode_counters: episodes begun so far per vector entry ``(n,)``, continued in place (episode ids run on
        across calls, so that an episode spanning two rollouts is one episode)
    :param encode_action: the actions' encoding (:func:`~sb3_emmarl.common.latent.features.encode_actions`)
    :param agents_per_copy: agents per environment copy
    :param team_pooling: the agents of one copy share their episode's id
    :param device: torch device of the data
    """
    ids = episode_ids(episode_counters, new_episode, agents_per_copy, team_pooling)
    t, e = np.nonzero(valid)
    transitions = Transitions.from_numpy(features[t, e], encode_action(actions[t, e]), next_features[t, e], ids[t, e],
                                         device)
    if counter is None or next_observations is None:
        return transitions, None
    kept_ids = np.where(valid, ids, -1)  # the rows of the transitions left out are skipped
    return transitions, EpisodeCounts.from_observations(counter, next_observations, kept_ids, device)


TransitionsFn = Callable[..., tuple[Transitions, EpisodeCounts | None]]


def rollout_transitions(buffer: RolloutBuffer, last_obs: np.ndarray, last_episode_starts: np.ndarray,
                        features: Callable[[np.ndarray], np.ndarray], transitions: TransitionsFn,
                        start: int = 0, stop: int | None = None) -> tuple[Transitions, EpisodeCounts | None]:
    """The E-step's data from the rows ``start:stop`` of an on-policy rollout: every step whose successor is in the
    same episode (the one after the last row is the algorithm's next observation, ``last_obs``, whether the rollout is
    complete or, during it, ``stop`` is the buffer's position).

    :param features: compact features of augmented observations (:func:`augmented_features`)
    :param transitions: :func:`make_transitions` with the caller's counters and settings bound
    :param start: the first row
    :param stop: the row after the last (default: the buffer's size)
    """
    observations = buffer.observations[start:stop]
    # The observations are not stacked with the last ones: that would copy the rollout's (220 MiB at 200 UAVs)
    all_features = np.concatenate([features(observations), features(last_obs[None])])
    starts = np.concatenate([buffer.episode_starts[start:stop], np.asarray(last_episode_starts, dtype=np.float32)[None]])
    return transitions(all_features[:-1], buffer.actions[start:stop], all_features[1:], starts[:-1] > 0,
                       starts[1:] == 0, next_observations=(observations[1:], last_obs[None]))


def replay_transitions(buffer: ReplayBuffer, position: int, last_dones: np.ndarray,
                       features: Callable[[np.ndarray], np.ndarray], transitions: TransitionsFn,
                       ) -> tuple[tuple[Transitions, EpisodeCounts | None], int, np.ndarray]:
    """The replay buffer's rows added since ``position`` (the buffer's position at the last handover), as E-step data,
    with the buffer's position now and the done flags of the last row handed over (``last_dones``: of the row before
    the first one, all True at the start).

    :param features: compact features of augmented observations (:func:`augmented_features`)
    :param transitions: :func:`make_transitions` with the caller's counters and settings bound
    """
    rows = (position + np.arange((buffer.pos - position) % buffer.buffer_size)) % buffer.buffer_size
    dones = buffer.dones[rows] > 0
    new_episode = np.concatenate([last_dones[None], dones[:-1]])
    if len(rows):
        last_dones = dones[-1]
    data = transitions(features(buffer.observations[rows]), buffer.actions[rows], features(buffer.next_observations[rows]),
                       new_episode, np.ones_like(dones), next_observations=buffer.next_observations[rows])
    return data, buffer.pos, last_dones


def e_step_and_log(e_step: EStep, logger: Logger, train: bool = True) -> None:
    """Run one E-step on the transitions ``e_step`` keeps (``train=False``: frozen, it only reports) and record its
    statistics as ``latent/<name>``."""
    for key, value in e_step.step(train=train).items():
        logger.record(f"latent/{key}", value)


#: The latent settings' names (:class:`~sb3_emmarl.common.latent.config.LatentConfig`'s fields).
LATENT_FIELDS = frozenset(LatentConfig.names())


class LatentAlgorithmMixin(WrapsObservations):
    """Settings, E-step and stateful ``predict`` of an EM algorithm; mixed into SB3 algorithm classes before them.

    The latent settings are one record, :attr:`latent_config`, built from the constructor's ``latent_kwargs`` laid over
    the class's :attr:`latent_defaults`; the latent layout (sizes) is the policy's, built once from the environment.
    """

    #: The algorithm's own defaults of the latent settings (``latent_kwargs`` is laid over them)
    latent_defaults: ClassVar[LatentConfig] = LatentConfig()
    #: whether the algorithm runs E-steps every ``e_step_every`` agent-steps during its rollouts (EM-PPO)
    steps_e_step: ClassVar[bool] = False
    policy: LatentPolicyMixin
    replay_buffer: ReplayBuffer | None  # (the off-policy algorithms': EM-DDPG, VDN+EM)
    #: the latent settings (``e_step_kwargs`` with the E-step's defaults filled in); excluded from the saved data
    latent_config: LatentConfig
    #: the same settings as plain data: what the model saves and a loaded model's record is built from
    latent_kwargs: dict[str, Any]
    evidence_spec: dict[str, Any]
    # Set by _setup_latent (and _init_replay_e_step, off-policy).
    e_step: EStep | None
    _feature_fn: Callable[[np.ndarray], np.ndarray]
    _counter: CountEvidence | None
    _encode_action: Callable[[np.ndarray], np.ndarray]
    _episode_counters: np.ndarray
    _n_rollouts: int
    _e_step_steps: int
    _e_step_pos: int
    _last_dones: np.ndarray
    _e_step_in_data: bool

    def _init_latent(self, env: Any, latent_kwargs: LatentConfig | dict[str, Any] | None,
                     policy_kwargs: dict[str, Any] | None, verbose: int, loading: bool,
                     kwargs: dict[str, Any] | None = None) -> tuple[VecEnv | None, dict]:
        """Keep the latent settings, wrap the environment, and put the latent layout into ``policy_kwargs``.

        :param latent_kwargs: the constructor's ``latent_kwargs`` (laid over :attr:`latent_defaults`, validated here)
        :param policy_kwargs: the constructor's ``policy_kwargs``
        :param verbose: verbosity of the wrapping
        :param loading: building a model that ``load`` fills in (its environment is not checked strictly; its settings
            come from the saved data)
        :param kwargs: the constructor's other keyword arguments (latent settings among them are refused, naming
            ``latent_kwargs``)
        """
        reject_flat_latent_settings(type(self).__name__, kwargs or {})
        if not self.steps_e_step and check_latent_kwargs(latent_kwargs).get("e_step_every") is not None:
            raise ValueError(f"{type(self).__name__} runs its E-step every e_step_interval train() calls; "
                             "e_step_every (agent-steps, during the rollout) is EM-PPO's")
        config = self.latent_defaults.updated(latent_kwargs)
        self.latent_config, self.latent_kwargs = config, config.to_dict()
        self.e_step = None
        policy_kwargs = dict(policy_kwargs or {})
        if env is None:  # loading without an environment: the saved policy_kwargs hold the layout
            return None, policy_kwargs
        venv = wrap_with_belief(env, config.n_components, verbose, strict=not loading)
        wrapper = find_wrapper(venv, BeliefWrapper)
        assert wrapper is not None  # (wrap_with_belief gives an environment with one)
        self.evidence_spec = wrapper.evidence_spec
        policy_kwargs.update(latent_layout=wrapper.layout(config.decoder_hidden, config.reading_counts).to_dict(),
                             use_latent=config.use_latent, belief_input=config.belief_input)
        return venv, policy_kwargs

    def __setattr__(self, name: str, value: Any) -> None:
        """Refuse a latent setting set as an attribute of its own, which nothing would read (the settings are
        :attr:`latent_config`'s)."""
        if name in LATENT_FIELDS:
            raise AttributeError(f"{type(self).__name__}'s latent settings are its latent_config: "
                                 f"model.latent_config = dataclasses.replace(model.latent_config, {name}={value!r})")
        super().__setattr__(name, value)

    @property
    def latent_layout(self) -> LatentLayout:
        """The latent layout (sizes): the policy's."""
        return self.policy.latent_layout

    def _setup_model(self) -> None:
        """SB3's algorithm's, after the saved data of an older version is brought to today's form, then
        :meth:`_setup_latent`."""
        upgrade_saved_settings(self.__dict__)
        if self.latent_kwargs != self.latent_config.to_dict():  # (a loaded model's saved settings)
            self.latent_config = self.latent_defaults.updated(self.latent_kwargs)
            self.latent_kwargs = self.latent_config.to_dict()
        super()._setup_model()  # type: ignore[safe-super]  # the SB3 algorithm's (BaseAlgorithm declares it abstract)
        self._setup_latent()

    def _setup_latent(self) -> None:
        """After the policy exists: the E-step, the feature function and the belief wrapper's model."""
        evidence = evidence_from_spec(self.evidence_spec)
        self._feature_fn = evidence.features
        self._counter = evidence.counts if self.latent_layout.count_bins else None
        self._encode_action = encode_actions(self.action_space)[0]
        self.e_step = None
        if self.policy.latent_model is not None:
            self.e_step = make_e_step(self.policy.latent_model, self.latent_config, self._counter, self.seed or 0)
        # A loaded model keeps the counters it was saved with (they number the episodes of the E-step's data).
        if getattr(self, "_episode_counters", None) is None or len(self._episode_counters) != self.n_envs:
            self._episode_counters = np.zeros(self.n_envs, dtype=np.int64)
        self._n_rollouts = int(getattr(self, "_n_rollouts", 0))
        self._e_step_steps = int(getattr(self, "_e_step_steps", 0))  # agent-steps handed over since the last E-step
        self._attach_beliefs(self.env)

    def _attach_beliefs(self, env: VecEnv | None) -> None:
        wrapper = find_wrapper(env, BeliefWrapper) if env is not None else None
        if wrapper is not None:
            wrapper.attach(self.policy.latent_model, self.latent_config)

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "e_step", "_feature_fn", "_encode_action", "latent_config",
                "_counter"]

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        """SB3's, plus the E-step (its :meth:`EStep.state_dict`: optimizer, counters, generator, kept transitions), so
        that a loaded model trains on as if it had not stopped. It is written with ``torch.save`` as the weights are,
        not into the archive's JSON data, pickled and base64-encoded, which at a large E-step window raises the
        process's peak memory several times the E-step's size while saving."""
        state_dicts, variables = super()._get_torch_save_params()
        if getattr(self, "e_step", None) is not None and not getattr(self, "_e_step_in_data", False):
            state_dicts = [*state_dicts, "e_step"]
        return state_dicts, variables

    def set_parameters(self, load_path_or_dict: Any, exact_match: bool = True, device: Any = "auto") -> None:
        """As SB3's; an archive that keeps the E-step's state among its data (as older archives do) has no E-step among
        its parameters, and :meth:`load` restores it from the data."""
        if not isinstance(load_path_or_dict, dict):
            _, load_path_or_dict, _ = load_from_zip_file(load_path_or_dict, device=device, load_data=False)
        self._e_step_in_data = "e_step" not in load_path_or_dict
        try:
            super().set_parameters(load_path_or_dict, exact_match=exact_match, device=device)
        finally:
            del self._e_step_in_data

    @property
    def agents_per_copy(self) -> int:
        return agents_per_copy(self.env) if self.env is not None else 1

    # ------------------------------------------------------------------ the E-step, from train()
    def _features(self, observations: np.ndarray) -> np.ndarray:
        """Compact features of augmented observations ``(..., total_dim)`` -> ``(..., d_x)``."""
        return augmented_features(self._feature_fn, observations, self.latent_layout.obs_dim)

    def _transitions(self, features: np.ndarray, actions: np.ndarray, next_features: np.ndarray,
                     new_episode: np.ndarray, valid: np.ndarray,
                     next_observations: np.ndarray | Sequence[np.ndarray] | None = None,
                     ) -> tuple[Transitions, EpisodeCounts | None]:
        """E-step data from ``(T, n, ...)`` arrays of features, actions taken, the features that followed, flags of
        steps that begin an episode, and flags of the transitions to keep; with a count model, also the reading
        counts of the observations that followed (augmented ``(T, n, total_dim)``, or blocks ``(T_i, n, total_dim)``
        that stack to it along time: read in place, not copied), summed per episode."""
        return make_transitions(features, actions, next_features, new_episode, valid, self._episode_counters,
                                self._encode_action, agents_per_copy=self.agents_per_copy,
                                team_pooling=self.latent_config.team_pooling, counter=self._counter,
                                next_observations=next_observations, device=self.device)

    def _init_replay_e_step(self) -> None:
        """Off-policy EM algorithms: the E-step reads the replay buffer's rows added since its last handover (a loaded
        model keeps its position)."""
        if getattr(self, "_e_step_pos", None) is None:
            self._e_step_pos = 0  # the replay buffer's position at the last handover
        if getattr(self, "_last_dones", None) is None or len(self._last_dones) != self.n_envs:
            self._last_dones = np.ones(self.n_envs, dtype=bool)

    def _replay_transitions(self) -> tuple[Transitions, EpisodeCounts | None]:
        """The replay buffer's rows added since the last call, as E-step data (off-policy algorithms)."""
        buffer = self.replay_buffer
        assert buffer is not None  # (the E-step runs from train(), after the model was set up)
        if buffer.optimize_memory_usage:
            raise ValueError(f"{type(self).__name__} needs the replay buffer's next observations: "
                             "optimize_memory_usage=False")
        data, self._e_step_pos, self._last_dones = replay_transitions(buffer, self._e_step_pos, self._last_dones,
                                                                      self._features, self._transitions)
        return data

    def _run_e_step(self, data: tuple[Transitions, EpisodeCounts | None], agent_steps: int = 0) -> bool:
        """Remember the transitions handed over (and reading counts); run the E-step and log it every
        ``e_step_interval`` handovers, or, with ``e_step_every``, once the handovers since the last E-step hold that
        many agent-steps (``agent_steps``: this handover's). Returns whether it ran."""
        if self.e_step is None:
            return False
        self.e_step.add(*data)
        self._n_rollouts += 1
        every = self.latent_config.e_step_every
        if every is None:
            if self._n_rollouts % self.latent_config.e_step_interval:
                return False
        else:
            self._e_step_steps += agent_steps
            if self._e_step_steps < every:
                return False
            self._e_step_steps = 0
        e_step_and_log(self.e_step, self.logger, train=not self.latent_config.freeze_e_step)
        return True

    def _log_belief_use(self, observations: np.ndarray) -> None:
        """Log whether the policy reads its belief, on augmented ``observations`` it acted on: ``latent/belief_use``
        (:func:`~sb3_emmarl.common.latent.diagnostics.belief_use`: how far its actions move when the belief is permuted
        between components) and ``latent/belief_entropy`` (the beliefs' mean entropy, ``log K`` when uninformative)."""
        if self.policy.latent_model is None:
            return
        k = self.latent_layout.n_components
        self.logger.record("latent/belief_use", belief_use(self.policy, observations, k))
        self.logger.record("latent/belief_entropy", belief_entropy(observations.reshape(-1, observations.shape[-1])[:, -k:]))

    # ------------------------------------------------------------------ SB3's conventions
    def predict(  # type: ignore[override]  # the state is one array, where SB3's annotation has a tuple of them
        self, observation: np.ndarray | dict[str, np.ndarray], state: tuple[np.ndarray, ...] | np.ndarray | None = None,
        episode_start: np.ndarray | None = None, deterministic: bool = False,
    ) -> tuple[np.ndarray, np.ndarray | tuple[np.ndarray, ...] | None]:
        """Actions for plain observations, carrying each entry's belief in ``state`` (as RecurrentPPO carries its LSTM
        state): pass back the returned state and the episode starts, as ``evaluate_policy`` does. Observations that
        already hold the belief (from the model's own wrapped environment) are acted on as they are.

        :param observation: plain ``(obs_dim,)`` / ``(n, obs_dim)`` or augmented observations
        :param state: the previous call's state (None: every entry starts an episode)
        :param episode_start: ``(n,)`` flags of entries whose observation is an episode's first
        :param deterministic: the most likely actions
        :return: actions and the new state (None for augmented observations)
        """
        obs = np.asarray(observation)
        layout = self.latent_layout
        if obs.shape[-1] == layout.total_dim:
            return self.policy.predict(obs, None, episode_start, deterministic)
        if obs.shape[-1] != layout.obs_dim:
            raise ValueError(f"observations must have {layout.obs_dim} values (plain) or {layout.total_dim} (with the "
                             f"belief), got shape {obs.shape}")
        flat = obs.reshape(-1, layout.obs_dim).astype(np.float32)
        n = len(flat)
        tracker = BeliefTracker(n, layout.n_components, layout.feature_dim, layout.action_dim,
                                model=self.policy.latent_model,
                                likelihood_temperature=self.latent_config.likelihood_temperature,
                                counter=self._counter)
        starts = np.ones(n, dtype=bool)
        if state is not None:
            tracker.set_state(state[0] if isinstance(state, tuple) else state)
            starts = np.zeros(n, dtype=bool) if episode_start is None else np.asarray(episode_start, bool).reshape(n)
        features = self._feature_fn(flat)
        tracker.start(np.flatnonzero(starts), features[starts])
        tracker.advance(np.flatnonzero(~starts), features[~starts], flat[~starts] if self._counter is not None else None)
        augmented = np.concatenate([flat, tracker.beliefs()], axis=1).reshape(*obs.shape[:-1], layout.total_dim)
        actions, _ = self.policy.predict(augmented, None, None, deterministic)
        tracker.set_actions(self._encode_action(np.asarray(actions).reshape(n, -1)))
        return actions, tracker.get_state()

    def posterior(self, observations: np.ndarray) -> np.ndarray:
        """The beliefs held in augmented observations ``(n, total_dim)`` -> ``(n, K)``, a copy: a view would keep the
        whole observation array alive for as long as any of its beliefs is kept (the team metrics keep every step's
        beliefs for an episode: at hundreds of UAVs a view pinned hundreds of MiB of observations)."""
        return np.array(np.asarray(observations)[..., self.latent_layout.obs_dim:])

    def wrap_env(self, venv: VecEnv) -> VecEnv:
        """``venv`` with this model's belief wrapper (fusion along the links included), for evaluation and recording."""
        venv = wrap_with_belief(venv, self.latent_layout.n_components)
        self._attach_beliefs(venv)
        return venv

    # ------------------------------------------------------------------ training
    def train(self, *args: Any, **kwargs: Any) -> None:
        """The E-step, then the algorithm's own update, the M-step (skipped when ``freeze_m_step``).

        The E-step reads :meth:`_e_step_data` (EM-PPO: the rollout's transitions; the off-policy algorithms: the
        transitions of this call, kept until every ``e_step_interval`` calls an E-step runs on them) when there is a
        latent model; :meth:`_after_e_step` runs after each E-step that ran.
        """
        if self.e_step is not None and self._run_e_step(self._e_step_data()):
            self._after_e_step()
        if self.latent_config.freeze_m_step:
            self._update_learning_rate(self._m_step_optimizers())
            self.logger.record("train/m_step_frozen", 1.0)
            return
        super().train(*args, **kwargs)  # type: ignore[misc]  # the SB3 algorithm's (BaseAlgorithm declares no train)

    def _e_step_data(self) -> tuple[Transitions, EpisodeCounts | None]:
        """The transitions (and reading counts) this ``train()`` call hands the E-step."""
        raise NotImplementedError

    def _m_step_optimizers(self) -> Any:
        """The optimizers whose learning rate the schedule moves (also while the M-step is frozen)."""
        raise NotImplementedError

    def _after_e_step(self) -> None:
        """What runs after an E-step (nothing by default)."""

    @classmethod
    def _wrap_saved_env(cls, env: Any, data: dict[str, Any]) -> VecEnv:
        """An environment without the belief wrapper gets the one the model was trained with."""
        return wrap_with_belief(env, upgrade_saved_settings(data)["latent_kwargs"]["n_components"])

    @classmethod
    def load(cls, path: Any, env: Any = None, device: Any = "auto", custom_objects: dict | None = None,
             print_system_info: bool = False, force_reset: bool = True, **kwargs):
        """As SB3's ``load`` (an ``env`` gets the belief wrapper:
        :class:`~sb3_emmarl.common.appended.wrapping.WrapsObservations`), with the E-step's state restored."""
        model = super().load(path, env=env, device=device, custom_objects=custom_objects,
                             print_system_info=print_system_info, force_reset=force_reset, **kwargs)
        e_step_state = model.__dict__.pop("_e_step_state", None)  # (saved before 0.17.0: in the data)
        if e_step_state is not None and model.e_step is not None:
            model.e_step.load_state_dict(e_step_state)
        return model
