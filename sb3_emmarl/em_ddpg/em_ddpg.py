"""EM-DDPG: parameter-shared DDPG whose actor and critic see a belief over a categorical latent mode fitted by EM."""

from __future__ import annotations

from typing import Any, ClassVar, TypeVar, cast

import numpy as np
import torch as th
from stable_baselines3 import DDPG
from stable_baselines3.common.noise import ActionNoise, NormalActionNoise
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import GymEnv, Schedule

from sb3_emmarl.common.latent.algorithm import LatentAlgorithmMixin
from sb3_emmarl.common.latent.config import LatentConfig
from sb3_emmarl.common.latent.em import EpisodeCounts, Transitions
from sb3_emmarl.em_ddpg.policies import MlpPolicy

SelfEMDDPG = TypeVar("SelfEMDDPG", bound="EMDDPG")


class EMDDPG(LatentAlgorithmMixin, DDPG):
    """EM-DDPG (Taghavi & Farnoosh, Algorithm 2 with DDPG as the M-step).

    DDPG's actor and critic (and their targets) see, beside the observation, the agent's belief over a categorical
    latent mode, kept as in :class:`~sb3_emmarl.em_ppo.EMPPO` (whose latent settings these are). The replay buffer
    stores each observation with the belief the actor saw. Each ``train()`` first hands the transitions collected
    since the last one to the E-step (which runs every ``e_step_interval`` calls, on the last ``window`` calls'
    transitions), then runs DDPG's update, the M-step.

    :param policy: ``"MlpPolicy"`` or a :class:`~sb3_emmarl.common.latent.policies.LatentTD3Policy` subclass
    :param env: the environment (``Box`` actions)
    :param learning_rate: learning rate of actor and critic
    :param buffer_size: replay buffer size
    :param learning_starts: steps before learning starts
    :param batch_size: minibatch size
    :param tau: soft update coefficient
    :param gamma: discount factor
    :param train_freq: steps between updates
    :param gradient_steps: gradient steps per update
    :param action_noise: exploration noise (default: Gaussian with std 0.2)
    :param latent_kwargs: the latent settings, a :class:`~sb3_emmarl.common.latent.config.LatentConfig` or a dict of
        its fields, laid over :attr:`latent_defaults` (EM-DDPG's: ``e_step_interval`` and the E-step's ``window``
        count ``train()`` calls)
    :param policy_kwargs: policy arguments
    :param tensorboard_log: tensorboard folder
    :param verbose: verbosity
    :param seed: seed
    :param device: torch device
    :param _init_setup_model: build the networks now
    :param kwargs: other DDPG arguments
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {"MlpPolicy": MlpPolicy}
    #: The latent defaults: at ``train_freq=10``, an E-step every 2,000 steps on the transitions of the last 400
    #: ``train()`` calls (4,000 steps per entry), as EM-PPO's after every rollout of 2,048 steps on the last two (why
    #: not fewer: docs/lab/results-history.md, EM-DDPG against DDPG)
    latent_defaults: ClassVar[LatentConfig] = LatentConfig(e_step_interval=200, e_step_kwargs={"window": 400})
    policy: MlpPolicy

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
        latent_kwargs: LatentConfig | dict[str, Any] | None = None,
        policy_kwargs: dict[str, Any] | None = None,
        tensorboard_log: str | None = None,
        verbose: int = 0,
        seed: int | None = None,
        device: str = "auto",
        _init_setup_model: bool = True,
        **kwargs: Any,
    ) -> None:
        env, policy_kwargs = self._init_latent(env, latent_kwargs, policy_kwargs, verbose, loading=not _init_setup_model,
                                               kwargs=kwargs)
        # (env is None when loading: SB3 takes it, though DDPG's annotation leaves None out)
        super().__init__(policy, cast(GymEnv, env), learning_rate=learning_rate, buffer_size=buffer_size,
                         learning_starts=learning_starts, batch_size=batch_size, tau=tau, gamma=gamma, train_freq=train_freq,
                         gradient_steps=gradient_steps, action_noise=action_noise, policy_kwargs=policy_kwargs,
                         tensorboard_log=tensorboard_log, verbose=verbose, seed=seed, device=device, _init_setup_model=False,
                         **kwargs)
        if _init_setup_model:
            self._setup_model()

    def _setup_model(self) -> None:
        super()._setup_model()
        if self.action_noise is None and self.env is not None:
            assert self.action_space.shape is not None  # (a Box)
            dim = int(np.prod(self.action_space.shape))
            self.action_noise = NormalActionNoise(np.zeros(dim), 0.2 * np.ones(dim))
        self._init_replay_e_step()

    def _e_step_data(self) -> tuple[Transitions, EpisodeCounts | None]:
        return self._replay_transitions()

    def _m_step_optimizers(self) -> list[th.optim.Optimizer]:
        return [self.actor.optimizer, self.critic.optimizer]

    def learn(self: SelfEMDDPG, total_timesteps: int, callback: Any = None, log_interval: int = 4,
              tb_log_name: str = "EMDDPG", reset_num_timesteps: bool = True, progress_bar: bool = False) -> SelfEMDDPG:
        return super().learn(total_timesteps, callback=callback, log_interval=log_interval, tb_log_name=tb_log_name,
                             reset_num_timesteps=reset_num_timesteps, progress_bar=progress_bar)
