"""The belief for any SB3 algorithm: an ``EMCallback`` that refits the mixture model between rollouts.

EM-PPO, EM-DDPG and VDN+EM run their E-step inside their own ``train()``. A user of another SB3 algorithm (A2C, PPO,
DQN, SAC, TD3, ...) adds the same belief with three lines: the callback's :meth:`EMCallback.wrap_env` appends the
belief ``q(z | o_{1:t}, a_{1:t-1})`` to the environment's observations (the :class:`~.belief.BeliefWrapper` of the EM
algorithms, computed from the callback's :class:`~.model.LatentModel`), :attr:`EMCallback.policy_kwargs` gives the
policy the features extractor that reads ``[observation, belief]`` (:class:`~.policies.BeliefFeaturesExtractor`), and
``learn(..., callback=callback)`` refits the model. At the end of every rollout (on-policy: SB3's ``n_steps``;
off-policy: every ``train_freq`` collection) the callback hands the new transitions to the E-step, read from the
rollout buffer or from the rows the replay buffer gained, with the functions EM-PPO and EM-DDPG use
(:func:`~.algorithm.rollout_transitions`, :func:`~.algorithm.replay_transitions`, :func:`~.algorithm.make_transitions`);
every ``latent_kwargs["e_step_every"]`` agent-steps it runs one E-step (:class:`~.em.EStep`, built by
:func:`~.algorithm.make_e_step`) on the transitions of the last ``window`` such intervals. The algorithm's own update
then trains on observations that carry the belief, as EM-PPO's M-step does.
"""

from __future__ import annotations

from dataclasses import fields
from pathlib import Path
from typing import Any, ClassVar, TypeVar

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm
from stable_baselines3.common.vec_env import VecEnv

from sb3_emmarl.common.appended.conditioning import ContextActorCriticPolicy
from sb3_emmarl.common.appended.wrapping import find_wrapper
from sb3_emmarl.common.latent.algorithm import (
    augmented_features,
    e_step_and_log,
    make_e_step,
    make_transitions,
    replay_transitions,
    rollout_transitions,
    wrap_with_belief,
)
from sb3_emmarl.common.latent.belief import BeliefWrapper, agents_per_copy
from sb3_emmarl.common.latent.config import (
    LatentConfig,
    check_latent_kwargs,
    lift_flat_settings,
    reject_flat_latent_settings,
)
from sb3_emmarl.common.latent.em import EpisodeCounts, EStep, Transitions
from sb3_emmarl.common.latent.layout import LatentLayout
from sb3_emmarl.common.latent.model import LatentModel
from sb3_emmarl.common.latent.policies import BeliefFeaturesExtractor
from sb3_emmarl.common.trust.atomic_files import write_atomic
from sb3_emmarl.common.trust.validation import integer

Part = TypeVar("Part", Transitions, EpisodeCounts)


def _concatenate(parts: list[Part]) -> Part:
    """One part of E-step data from several (field by field, in order)."""
    kind = type(parts[0])
    return kind(*(th.cat([getattr(part, field.name) for part in parts]) for field in fields(kind)))


class EMCallback(BaseCallback):
    """Give an SB3 algorithm a belief over a latent mode, refitted by EM between rollouts (docs/em.md, "Any SB3
    algorithm: EMCallback").

    Build the model on :meth:`wrap_env`'s environment (with :attr:`policy_kwargs`), train it with the callback, and
    evaluate it on another environment wrapped by :meth:`wrap_env` (SB3's ``evaluate_policy`` works on it). The
    latent model and the E-step live in the callback (:attr:`latent_model`, :attr:`e_step`), not in the SB3 model:
    the algorithm's optimizers never see them. The environment must give flat ``Box`` observations, and no wrapper
    that changes observations (e.g. ``VecNormalize``) may sit over the belief wrapper.

    :param latent_kwargs: the latent settings, a :class:`~sb3_emmarl.common.latent.config.LatentConfig` or a dict of
        its fields, laid over :attr:`latent_defaults` (EM-PPO's, with ``e_step_every=2000``: an E-step at the first
        rollout end at least that many agent-steps, ``num_timesteps``, after the last one; the E-step's ``window``
        counts E-step intervals here: the transitions of the last ``window`` intervals). The settings of an
        algorithm's own networks and training (``belief_input`` aside, which :attr:`policy_kwargs` carries) are the
        algorithm's: ``e_step_interval``, ``use_latent`` and ``freeze_m_step`` are refused
    :param seed: seed of the latent model's initial weights (drawn without touching torch's global generator) and of
        the E-step
    :param verbose: SB3's callback verbosity
    """

    #: the latent settings that belong to the algorithm being trained, not to the callback
    NOT_THE_CALLBACKS = ("e_step_interval", "use_latent", "freeze_m_step")
    #: the callback's own defaults of the latent settings (``latent_kwargs`` is laid over them)
    latent_defaults: ClassVar[LatentConfig] = LatentConfig(e_step_every=2000)

    def __init__(self, latent_kwargs: LatentConfig | dict[str, Any] | None = None, *,
                 seed: int = 0, verbose: int = 0, **kwargs: Any) -> None:
        super().__init__(verbose)
        reject_flat_latent_settings(type(self).__name__, kwargs)
        if kwargs:
            raise TypeError(f"EMCallback got unexpected keyword arguments {sorted(kwargs)}")
        given = check_latent_kwargs(latent_kwargs)
        foreign = [name for name in self.NOT_THE_CALLBACKS if name in given]
        if foreign:
            raise ValueError(f"latent_kwargs {foreign} are settings of the algorithm being trained, not of EMCallback "
                             "(which runs an E-step every e_step_every agent-steps)")
        #: the latent settings (``e_step_kwargs`` with the E-step's defaults filled in)
        self.config = self.latent_defaults.updated(given)
        if self.config.e_step_every is None:
            raise ValueError("EMCallback runs its E-steps every latent_kwargs['e_step_every'] agent-steps: an int >= 1, "
                             "got None")
        self.seed = integer(0, 2**63 - 1)("seed", seed)
        self.latent_model: LatentModel | None = None
        self.e_step: EStep | None = None
        self._wrapper: BeliefWrapper | None = None  # the first wrapper: its features, action encoding and counter
        self._pending: list[tuple[Transitions, EpisodeCounts | None]] = []
        self._episode_counters = np.zeros(0, dtype=np.int64)
        self._replay_pos, self._last_dones = 0, np.zeros(0, dtype=bool)
        self._last_e_step = 0
        self._saved: dict[str, Any] | None = None  # a loaded callback's state, until wrap_env builds its model

    # ------------------------------------------------------------------ what the user builds the model with
    @property
    def layout(self) -> LatentLayout:
        """The latent layout (sizes), known once :meth:`wrap_env` has seen an environment."""
        if self.latent_model is None:
            raise ValueError("EMCallback has no latent model yet: call callback.wrap_env(env) first")
        return self.latent_model.layout

    def wrap_env(self, env: Any) -> VecEnv:
        """``env`` (a vector or Gymnasium environment) with the belief appended to its observations, computed with the
        callback's latent model (built from the first environment wrapped; later ones must have its sizes)."""
        venv = wrap_with_belief(env, self.config.n_components, self.verbose)
        wrapper = find_wrapper(venv, BeliefWrapper)
        assert wrapper is not None  # (wrap_with_belief gives an environment with one)
        if self.latent_model is None:
            self._build(wrapper)
        layout = self.layout
        sizes = (wrapper.obs_dim, wrapper.feature_dim, wrapper.action_dim)
        if sizes != (layout.obs_dim, layout.feature_dim, layout.action_dim):
            raise ValueError(f"the environment's (observation, feature, action) sizes are {sizes}, the callback's "
                             f"latent model's {(layout.obs_dim, layout.feature_dim, layout.action_dim)}: wrap "
                             "environments of the task it was built for")
        wrapper.attach(self.latent_model, self.config)
        return venv

    @property
    def policy_kwargs(self) -> dict[str, Any]:
        """``policy_kwargs`` whose features extractor reads ``[observation, belief]`` in the form ``belief_input``
        names (:class:`~sb3_emmarl.common.latent.policies.BeliefFeaturesExtractor`), for any SB3 policy."""
        return {"features_extractor_class": BeliefFeaturesExtractor,
                "features_extractor_kwargs": {"head_dim": self.layout.obs_dim, "belief_input": self.config.belief_input}}

    def conditioned_policy(self, belief_conditioning: str) -> tuple[type[ContextActorCriticPolicy], dict[str, Any]]:
        """The policy class and ``policy_kwargs`` of an actor-critic algorithm (PPO, A2C) whose networks read the belief
        as ``belief_conditioning`` says (:mod:`sb3_emmarl.common.appended.conditioning`):
        ``policy, kwargs = callback.conditioned_policy("film"); PPO(policy, venv, policy_kwargs=kwargs)``.

        :param belief_conditioning: ``"concat"``, ``"mixture"`` or ``"film"``
        """
        kwargs = self.policy_kwargs
        layout = self.layout
        space = spaces.Box(-np.inf, np.inf, (layout.total_dim,), np.float32)
        width = BeliefFeaturesExtractor(space, **kwargs["features_extractor_kwargs"]).belief_width
        return ContextActorCriticPolicy, {**kwargs, "context_dim": width, "belief_conditioning": belief_conditioning}

    def _build(self, wrapper: BeliefWrapper) -> None:
        """The latent model and the E-step, sized by ``wrapper``'s environment (with a loaded callback's state)."""
        config = self.config
        counter = wrapper.counter if config.reading_counts else None
        layout = wrapper.layout(config.decoder_hidden, config.reading_counts)
        with th.random.fork_rng(devices=[]):  # the model's initial weights from the callback's seed alone
            th.manual_seed(self.seed)
            model = LatentModel(layout)
        e_step = make_e_step(model, config, counter, self.seed)
        saved, self._saved = self._saved, None
        if saved is not None:
            if saved["layout"] != layout.to_dict():
                raise ValueError(f"the environment gives the latent layout {layout.to_dict()}, the saved callback was "
                                 f"made for {saved['layout']}: wrap environments of the task it was trained on")
            model.load_state_dict(saved["latent_model"])
            e_step.load_state_dict(saved["e_step"])
            self._episode_counters = saved["episode_counters"].numpy().astype(np.int64)
            transitions, counts = saved["pending"]
            if transitions is not None:
                self._pending = [(Transitions(*transitions), None if counts is None else EpisodeCounts(*counts))]
        self.latent_model, self.e_step, self._wrapper = model, e_step, wrapper

    # ------------------------------------------------------------------ save and load
    def save(self, path: str | Path) -> None:
        """Write the callback (its settings, the latent model's layout and weights, the E-step's state, the episode
        counters and the transitions not yet fitted) to ``path`` with ``torch.save``, atomically: :meth:`load` gives a
        callback that wraps environments with the same belief and trains on as if it had not stopped. Save it beside
        the SB3 model's zip."""
        e_step = self.e_step
        if self.latent_model is None or e_step is None:
            raise ValueError("EMCallback has no latent model yet: call callback.wrap_env(env) first")
        latent_kwargs = {name: value for name, value in self.config.to_dict().items()
                         if name not in self.NOT_THE_CALLBACKS}
        arguments = {"latent_kwargs": latent_kwargs, "seed": self.seed}
        state = {"arguments": arguments, "layout": self.layout.to_dict(),
                 "latent_model": self.latent_model.state_dict(), "e_step": e_step.state_dict(),
                 "episode_counters": th.as_tensor(self._episode_counters),
                 "pending": [None if part is None else [getattr(part, field.name) for field in fields(part)]
                             for part in self._joined_pending()]}
        write_atomic(path, lambda file: th.save(state, file))

    @classmethod
    def load(cls, path: str | Path, verbose: int = 0) -> EMCallback:
        """A callback written by :meth:`save` (read with ``torch.load(weights_only=True)``: tensors and plain values
        only, nothing that runs code). Its latent model is built again by the first :meth:`wrap_env`, from the
        environment (which must give the saved sizes), and then takes the saved weights and E-step state."""
        state = th.load(Path(path), map_location="cpu", weights_only=True)
        callback = cls(**lift_flat_settings(state["arguments"]), verbose=verbose)  # (saved before latent_kwargs too)
        callback._saved = state
        return callback

    # ------------------------------------------------------------------ SB3's callback hooks
    def _init_callback(self) -> None:
        env = self.model.get_env()
        wrapper = find_wrapper(env, BeliefWrapper) if env is not None else None
        if env is None or wrapper is None:
            raise ValueError("EMCallback: the model's environment has no belief; build the model on "
                             "callback.wrap_env(env)")
        self.wrap_env(env)  # (attaches the latent model to the model's belief wrapper)
        if self.model.observation_space.shape != (self.layout.total_dim,):
            raise ValueError(f"EMCallback: the model reads observations of shape {self.model.observation_space.shape}, "
                             f"the belief wrapper gives ({self.layout.total_dim},): no wrapper may change observations "
                             "over it")
        n_envs = env.num_envs
        if len(self._episode_counters) != n_envs:
            self._episode_counters = np.zeros(n_envs, dtype=np.int64)
        if isinstance(self.model, OffPolicyAlgorithm):
            buffer = self.model.replay_buffer
            assert buffer is not None  # (set up with the model)
            if buffer.optimize_memory_usage:
                raise ValueError("EMCallback needs the replay buffer's next observations: optimize_memory_usage=False")
            self._replay_pos, self._last_dones = buffer.pos, np.ones(n_envs, dtype=bool)
        elif not isinstance(self.model, OnPolicyAlgorithm):
            raise ValueError(f"EMCallback works with SB3's on-policy and off-policy algorithms, got "
                             f"{type(self.model).__name__}")
        self._last_e_step = self.model.num_timesteps

    def _on_step(self) -> bool:
        return True

    def _on_rollout_end(self) -> None:
        """Hand the rollout's transitions to the E-step's queue; run an E-step when ``e_step_every`` steps have passed."""
        data = self._rollout_data()
        if len(data[0]):
            self._pending.append(data)
        assert self.config.e_step_every is not None  # (checked by the constructor)
        if self.model.num_timesteps - self._last_e_step < self.config.e_step_every or not self._pending:
            return
        e_step = self.e_step
        transitions, counts = self._joined_pending()
        assert e_step is not None and transitions is not None  # (built with the latent model; pending data)
        e_step.add(transitions, counts)
        e_step_and_log(e_step, self.logger, train=not self.config.freeze_e_step)
        self._pending, self._last_e_step = [], self.model.num_timesteps

    # ------------------------------------------------------------------ the E-step's data
    def _joined_pending(self) -> tuple[Transitions | None, EpisodeCounts | None]:
        """The transitions and reading counts handed over since the last E-step, each as one part (None: none)."""
        transitions = [part[0] for part in self._pending]
        counts = [part[1] for part in self._pending if part[1] is not None]
        return (_concatenate(transitions) if transitions else None,
                _concatenate(counts) if counts and len(counts) == len(transitions) else None)

    def _features(self, observations: np.ndarray) -> np.ndarray:
        assert self._wrapper is not None  # (built with the latent model)
        return augmented_features(self._wrapper.feature_fn, observations, self.layout.obs_dim)

    def _transitions(self, features: np.ndarray, actions: np.ndarray, next_features: np.ndarray,
                     new_episode: np.ndarray, valid: np.ndarray,
                     next_observations: np.ndarray | tuple[np.ndarray, ...] | None = None,
                     ) -> tuple[Transitions, EpisodeCounts | None]:
        assert self._wrapper is not None  # (built with the latent model)
        env = self.model.get_env()
        counter = self._wrapper.counter if self.layout.count_bins else None
        return make_transitions(features, actions, next_features, new_episode, valid, self._episode_counters,
                                self._wrapper.encode_action, agents_per_copy=agents_per_copy(env) if env is not None else 1,
                                team_pooling=self.config.team_pooling, counter=counter,
                                next_observations=next_observations)

    def _rollout_data(self) -> tuple[Transitions, EpisodeCounts | None]:
        """The transitions collected since the last rollout end: the rollout buffer (on-policy) or the rows the replay
        buffer gained (off-policy)."""
        model = self.model
        if isinstance(model, OffPolicyAlgorithm):
            assert model.replay_buffer is not None  # (set up with the model)
            data, self._replay_pos, self._last_dones = replay_transitions(model.replay_buffer, self._replay_pos,
                                                                          self._last_dones, self._features,
                                                                          self._transitions)
            return data
        assert isinstance(model, OnPolicyAlgorithm)  # (checked when training began)
        last_obs, starts = model._last_obs, model._last_episode_starts
        assert isinstance(last_obs, np.ndarray) and starts is not None  # (set by the rollout; flat Box observations)
        return rollout_transitions(model.rollout_buffer, last_obs, starts, self._features, self._transitions)
