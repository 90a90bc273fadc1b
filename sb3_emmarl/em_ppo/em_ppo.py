"""EM-PPO: parameter-shared PPO whose policy sees a belief over a categorical latent mode, fitted by EM."""

from __future__ import annotations

from typing import Any, ClassVar, TypeVar, cast

import numpy as np
import torch as th
from stable_baselines3 import PPO
from stable_baselines3.common.callbacks import BaseCallback, CallbackList
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import GymEnv, Schedule

from sb3_emmarl.common.appended.initialization import zero_tail_weights
from sb3_emmarl.common.latent.algorithm import LatentAlgorithmMixin, rollout_transitions
from sb3_emmarl.common.latent.config import LatentConfig
from sb3_emmarl.common.latent.em import EpisodeCounts, Transitions
from sb3_emmarl.common.trust.validation import RULES
from sb3_emmarl.em_ppo.policies import MlpPolicy

SelfEMPPO = TypeVar("SelfEMPPO", bound="EMPPO")


class EStepDuringRollout(BaseCallback):
    """EM-PPO's own callback when its E-steps run every ``latent_kwargs["e_step_every"]`` agent-steps: at each step of a
    rollout it lets the model hand the rows collected since the last handover to the E-step (SB3 calls a callback
    after each environment step, before the step is added to the buffer: the rows so far and the next observation are
    complete transitions)."""

    model: EMPPO

    def _on_rollout_start(self) -> None:
        self.model._e_step_row = 0

    def _on_step(self) -> bool:
        self.model._e_step_during_rollout()
        return True


class EMPPO(LatentAlgorithmMixin, PPO):
    """EM-PPO (Taghavi & Farnoosh, "Latent Variable Modeling in Multi-Agent Reinforcement Learning via
    Expectation-Maximization for UAV-Based Wildlife Protection", Algorithm 2).

    PPO's policy and value networks see, beside the observation, the agent's belief
    ``q(z | o_{1:t}, a_{1:t-1})`` over a categorical latent mode with ``n_components`` components: the exact
    posterior given every transition of the episode so far under a learned mixture of transition models
    ``p(x_{t+1} | x_t, a_t, z)``, updated once per step, and on the reserve fused with the evidence of the
    teammates whose messages reached the agent (``fusion``). A
    :class:`~sb3_emmarl.common.latent.belief.BeliefWrapper` appends it to the environment's observations
    during training; ``predict(obs, state, episode_start)`` computes it on plain observations, so SB3's
    ``evaluate_policy`` works on the plain environment. Each ``train()`` runs the E-step (EM over the
    recent episodes, every ``latent_kwargs["e_step_interval"]`` rollouts), then PPO's update, the M-step.

    :param policy: ``"MlpPolicy"`` or a :class:`~sb3_emmarl.common.latent.policies.LatentActorCriticPolicy` subclass
    :param env: the environment (a ``VecEnv`` or a Gymnasium env, flat ``Box`` observations)
    :param learning_rate: PPO's learning rate (or schedule)
    :param n_steps: steps per environment per rollout
    :param batch_size: PPO minibatch size
    :param n_epochs: PPO epochs per rollout (10, PPO's own default; why not fewer: docs/em.md, "Reading the belief")
    :param gamma: discount factor
    :param gae_lambda: GAE lambda
    :param clip_range: PPO clipping (or schedule)
    :param ent_coef: entropy coefficient
    :param latent_kwargs: the latent settings, a :class:`~sb3_emmarl.common.latent.config.LatentConfig` or a dict of
        its fields, laid over :attr:`latent_defaults` (EM-PPO's: an E-step after every rollout, ``e_step_interval=1``,
        on the last two rollouts' transitions)
    :param zero_belief_weights: start at zero the weights with which the policy's and the value's first layers read
        the belief, so that the networks start as PPO's (as ``OraclePPO`` does for the told mode; see
        :mod:`sb3_emmarl.common.appended.initialization`); off by default (what it changes: docs/lab/results-history.md)
    :param policy_kwargs: policy arguments (``net_arch``, ...)
    :param tensorboard_log: tensorboard folder
    :param verbose: verbosity
    :param seed: seed
    :param device: torch device
    :param _init_setup_model: build the networks now
    :param kwargs: other PPO arguments
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {"MlpPolicy": MlpPolicy}
    policy: MlpPolicy
    steps_e_step: ClassVar[bool] = True
    #: the rollout's first row not yet handed to the E-step (0 without ``e_step_every``)
    _e_step_row: int = 0

    def __init__(
        self,
        policy: str | type[MlpPolicy],
        env: GymEnv | str | None,
        learning_rate: float | Schedule = 3e-4,
        n_steps: int = 128,
        batch_size: int = 128,
        n_epochs: int = 10,
        gamma: float = 0.99,
        gae_lambda: float = 0.95,
        clip_range: float | Schedule = 0.2,
        ent_coef: float = 0.01,
        latent_kwargs: LatentConfig | dict[str, Any] | None = None,
        zero_belief_weights: bool = False,
        policy_kwargs: dict[str, Any] | None = None,
        tensorboard_log: str | None = None,
        verbose: int = 0,
        seed: int | None = None,
        device: str = "auto",
        _init_setup_model: bool = True,
        **kwargs: Any,
    ) -> None:
        self.zero_belief_weights = RULES["zero_belief_weights"]("zero_belief_weights", zero_belief_weights)
        env, policy_kwargs = self._init_latent(env, latent_kwargs, policy_kwargs, verbose, loading=not _init_setup_model,
                                               kwargs=kwargs)
        # (env is None when loading: SB3 takes it, though PPO's annotation leaves None out)
        super().__init__(policy, cast(GymEnv, env), learning_rate=learning_rate, n_steps=n_steps, batch_size=batch_size,
                         n_epochs=n_epochs, gamma=gamma, gae_lambda=gae_lambda, clip_range=clip_range, ent_coef=ent_coef,
                         policy_kwargs=policy_kwargs, tensorboard_log=tensorboard_log, verbose=verbose, seed=seed,
                         device=device, _init_setup_model=False, **kwargs)
        if _init_setup_model:
            self._setup_model()

    def _setup_model(self) -> None:
        super()._setup_model()
        if self.zero_belief_weights and self.policy.latent_model is not None:
            zero_tail_weights(self.policy, self.policy.features_extractor.belief_width)

    def _rollout_transitions(self, stop: int | None = None) -> tuple[Transitions, EpisodeCounts | None]:
        """The E-step's data from the rollout's rows not yet handed over, up to ``stop`` (during the rollout: the rows
        handed over so far then end there) or to the rollout's end: every step whose successor is in the same episode
        (the one after the last row is the algorithm's next observation, during the rollout as after it)."""
        last_obs = self._last_obs
        starts = self._last_episode_starts
        assert isinstance(last_obs, np.ndarray) and starts is not None  # (set by the rollout; flat Box observations)
        start = self._e_step_row
        if stop is not None:
            self._e_step_row = stop
        return rollout_transitions(self.rollout_buffer, last_obs, starts, self._features, self._transitions,
                                   start=start, stop=stop)

    def _e_step_data(self) -> tuple[Transitions, EpisodeCounts | None]:
        return self._rollout_transitions()

    def _run_e_step(self, data: tuple[Transitions, EpisodeCounts | None], agent_steps: int = 0) -> bool:
        """As the mixin's, from ``train()``: ``data`` holds the rollout's rows from :attr:`_e_step_row` on (those not
        handed over during it), whose agent-steps count here."""
        return super()._run_e_step(data, (self.rollout_buffer.buffer_size - self._e_step_row) * self.n_envs)

    def _e_step_during_rollout(self) -> None:
        """With ``e_step_every``: at each step of a rollout, once that many agent-steps were collected since the last
        E-step, hand the rows not yet handed over to the E-step and run it (:class:`EStepDuringRollout` calls this)."""
        every = self.latent_config.e_step_every
        assert every is not None  # (the callback is there only with e_step_every)
        start, stop = self._e_step_row, self.rollout_buffer.pos
        if self._e_step_steps + (stop - start) * self.n_envs < every:
            return
        if super()._run_e_step(self._rollout_transitions(stop), (stop - start) * self.n_envs):
            self._log_belief_use(self.rollout_buffer.observations[start:stop])

    def _init_callback(self, callback: Any, progress_bar: bool = False) -> BaseCallback:
        """SB3's, with :class:`EStepDuringRollout` after the user's callbacks when E-steps run every ``e_step_every``
        agent-steps."""
        callback = super()._init_callback(callback, progress_bar)
        if self.e_step is None or self.latent_config.e_step_every is None:
            return callback
        both = CallbackList([callback, EStepDuringRollout()])
        both.init_callback(self)
        return both

    def _m_step_optimizers(self) -> th.optim.Optimizer:
        return self.policy.optimizer

    def _after_e_step(self) -> None:
        """Whether the rollout's policy read its belief (``latent/belief_use``, ``latent/belief_entropy``: a few
        forward passes, so at the E-step's pace)."""
        self._log_belief_use(self.rollout_buffer.observations)

    def learn(self: SelfEMPPO, total_timesteps: int, callback: Any = None, log_interval: int = 1,
              tb_log_name: str = "EMPPO", reset_num_timesteps: bool = True, progress_bar: bool = False) -> SelfEMPPO:
        return super().learn(total_timesteps, callback=callback, log_interval=log_interval, tb_log_name=tb_log_name,
                             reset_num_timesteps=reset_num_timesteps, progress_bar=progress_bar)
