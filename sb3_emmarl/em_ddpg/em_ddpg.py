"""EM-DDPG: parameter-shared DDPG whose actor and critic see a categorical latent posterior fitted by EM."""

from __future__ import annotations

from typing import Any, ClassVar, TypeVar

import numpy as np
import torch as th
from stable_baselines3 import DDPG
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.noise import ActionNoise, NormalActionNoise
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import GymEnv, Schedule

from sb3_emmarl.common.latent.algorithm import LatentAlgorithmMixin
from sb3_emmarl.common.latent.em import LatentBatch, team_groups, transitions_from_pairs
from sb3_emmarl.em_ddpg.buffers import LatentReplayBuffer
from sb3_emmarl.em_ddpg.policies import MlpPolicy

SelfEMDDPG = TypeVar("SelfEMDDPG", bound="EMDDPG")


class EMDDPG(LatentAlgorithmMixin, DDPG):
    """EM-DDPG (Taghavi & Farnoosh, Algorithm 2 with DDPG as the M-step).

    DDPG's actor and critic (and their targets) see, beside the observation, the posterior
    ``q_phi(z | h_t)`` of a categorical latent variable inferred by a GRU from the last ``history_length``
    steps. Every ``e_step_interval`` rollouts (a rollout is ``train_freq`` steps) the E-step fits the encoder
    and decoder on the last ``e_step_transitions`` transitions of the replay buffer and sets the prior to
    the mean responsibilities; DDPG's update is the M-step. See :class:`~sb3_emmarl.em_ppo.EMPPO` for the
    latent settings, which are the same.

    :param policy: ``"MlpPolicy"`` or a :class:`~sb3_emmarl.common.latent.policies.LatentTD3Policy` subclass
    :param env: the environment (``Box`` actions)
    :param learning_rate: learning rate of actor and critic
    :param buffer_size: replay buffer size
    :param learning_starts: steps before learning starts
    :param batch_size: minibatch size
    :param tau: soft update coefficient
    :param gamma: discount factor
    :param train_freq: steps between updates (a "rollout")
    :param gradient_steps: gradient steps per update
    :param action_noise: exploration noise (default: Gaussian with std 0.2)
    :param n_components: ``K``
    :param history_length: ``H``
    :param encoder_hidden: GRU hidden size
    :param decoder_hidden: decoder hidden layer sizes
    :param estimator: ``"enumerate"`` or ``"gumbel"``
    :param team_pooling: pool the agents of one reserve copy and step in the E-step
    :param e_step_interval: rollouts (``train_freq`` steps each) between E-steps
    :param e_step_transitions: steps of the replay buffer (per environment) the E-step fits on
    :param e_step_kwargs: overrides of the E-step defaults
    :param use_latent: False is the no-latent ablation
    :param freeze_e_step: ablation: encoder, decoder and prior never change
    :param freeze_m_step: ablation: actor and critic never change
    :param policy_kwargs: policy arguments
    :param tensorboard_log: tensorboard folder
    :param verbose: verbosity
    :param seed: seed
    :param device: torch device
    :param _init_setup_model: build the networks now
    :param kwargs: other DDPG arguments (``replay_buffer_class`` defaults to
        :class:`~sb3_emmarl.em_ddpg.buffers.LatentReplayBuffer`)
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {"MlpPolicy": MlpPolicy}

    def __init__(
        self,
        policy: str | type[MlpPolicy],
        env: GymEnv | str | None,
        learning_rate: float | Schedule = 1e-3,
        buffer_size: int = 200_000,
        learning_starts: int = 1000,
        batch_size: int = 256,
        tau: float = 0.005,
        gamma: float = 0.98,
        train_freq: int | tuple[int, str] = 10,
        gradient_steps: int = 5,
        action_noise: ActionNoise | None = None,
        n_components: int = 4,
        history_length: int = 8,
        encoder_hidden: int = 64,
        decoder_hidden: tuple[int, ...] = (64, 64),
        estimator: str = "enumerate",
        team_pooling: bool = False,
        e_step_interval: int = 20,
        e_step_transitions: int = 400,
        e_step_kwargs: dict[str, Any] | None = None,
        use_latent: bool = True,
        freeze_e_step: bool = False,
        freeze_m_step: bool = False,
        policy_kwargs: dict[str, Any] | None = None,
        tensorboard_log: str | None = None,
        verbose: int = 0,
        seed: int | None = None,
        device: str = "auto",
        _init_setup_model: bool = True,
        **kwargs: Any,
    ) -> None:
        e_step_kwargs = {"window": 1, **(e_step_kwargs or {})}  # the replay buffer already spans recent rollouts
        env, policy_kwargs = self._init_latent(env, history_length, n_components, encoder_hidden, decoder_hidden,
                                               use_latent, freeze_e_step, freeze_m_step, estimator, team_pooling,
                                               e_step_interval, e_step_kwargs, policy_kwargs, verbose)
        if e_step_transitions < 1:
            raise ValueError(f"e_step_transitions must be >= 1, got {e_step_transitions}")
        self.e_step_transitions = int(e_step_transitions)
        kwargs.setdefault("replay_buffer_class", LatentReplayBuffer)
        super().__init__(policy, env, learning_rate=learning_rate, buffer_size=buffer_size, learning_starts=learning_starts,
                         batch_size=batch_size, tau=tau, gamma=gamma, train_freq=train_freq, gradient_steps=gradient_steps,
                         action_noise=action_noise, policy_kwargs=policy_kwargs, tensorboard_log=tensorboard_log,
                         verbose=verbose, seed=seed, device=device, _init_setup_model=False, **kwargs)
        if _init_setup_model:
            self._setup_model()

    def _setup_model(self) -> None:
        super()._setup_model()
        if self.action_noise is None and self.env is not None:
            dim = int(np.prod(self.action_space.shape))
            self.action_noise = NormalActionNoise(np.zeros(dim), 0.2 * np.ones(dim))
        self._setup_e_step()

    def latent_batch(self) -> LatentBatch:
        """The E-step's data: the last ``e_step_transitions`` steps of the replay buffer."""
        buffer = self.replay_buffer
        if buffer.optimize_memory_usage:
            raise ValueError("EM-DDPG needs the replay buffer's next observations: optimize_memory_usage=False")
        size = buffer.buffer_size if buffer.full else buffer.pos
        steps = (buffer.pos - 1 - np.arange(min(self.e_step_transitions, size))) % buffer.buffer_size
        t, env = np.meshgrid(steps, np.arange(buffer.n_envs), indexing="ij")
        t, env = t.ravel(), env.ravel()
        groups = team_groups(t, env, buffer.n_envs, self.agents_per_copy)
        return transitions_from_pairs(self.layout, buffer.observations[t, env], buffer.next_observations[t, env], groups,
                                      self.device)

    def train(self, gradient_steps: int, batch_size: int = 100) -> None:
        """The M-step: DDPG's update (skipped when ``freeze_m_step``).

        With a :class:`~sb3_emmarl.em_ddpg.buffers.LatentReplayBuffer` (the default), the posterior of each
        sampled observation and next observation is computed once per batch, with the current encoder, and
        written into the sample, where the actor, the critic and their targets read it.
        """
        if self.freeze_m_step:
            self.logger.record("train/m_step_frozen", 1.0)
            return
        latent, buffer = self.policy.latent_model, self.replay_buffer
        if latent is None or not isinstance(buffer, LatentReplayBuffer):
            super().train(gradient_steps, batch_size)
            return
        buffer.on_sample = self._write_sample_posterior
        latent.precomputed = True
        try:
            super().train(gradient_steps, batch_size)
        finally:
            buffer.on_sample = None
            latent.precomputed = False

    def _write_sample_posterior(self, observations: th.Tensor) -> None:
        with th.no_grad():
            self.write_posterior(observations, self.policy.latent_model.posterior(self.layout.split(observations)[1]))

    def learn(self: SelfEMDDPG, total_timesteps: int, callback: BaseCallback | list | None = None, log_interval: int = 4,
              tb_log_name: str = "EMDDPG", reset_num_timesteps: bool = True, progress_bar: bool = False) -> SelfEMDDPG:
        return super().learn(total_timesteps, callback=self._with_em_callback(callback), log_interval=log_interval,
                             tb_log_name=tb_log_name, reset_num_timesteps=reset_num_timesteps, progress_bar=progress_bar)
