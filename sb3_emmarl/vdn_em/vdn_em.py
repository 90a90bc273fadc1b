"""VDN+EM (the paper's "VDN+EM" row): VDN whose agents see a belief over the hidden mode, fitted by EM.

The agents' shared Q-network reads, beside each UAV's observation, its belief ``q(z | o_{1:t}, a_{1:t-1})``
over a categorical latent mode, kept exactly as in :class:`~sb3_emmarl.em_ppo.EMPPO` (the same belief wrapper,
fusion along the links, latent model and E-step; see docs/em.md). The joint replay buffer stores each
observation with the belief the agent saw. Each ``train()`` first hands the rows collected since the last one to
the E-step (which runs every ``e_step_interval`` calls on the last ``window`` calls' rows, as EM-DDPG does), then
runs VDN's update, the M-step. Exploration is VDN's epsilon-greedy on the belief-aware greedy actions.

The paper gives no details of its VDN+EM; this is the construction of its Algorithm 2 with VDN as the M-step.
"""

from __future__ import annotations

from typing import Any, ClassVar, TypeVar

import numpy as np
import torch as th
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback, Schedule

from sb3_emmarl.common.latent.algorithm import LatentAlgorithmMixin
from sb3_emmarl.common.latent.config import LatentConfig
from sb3_emmarl.common.latent.em import EpisodeCounts, Transitions
from sb3_emmarl.qmix.buffers import JointReplayBuffer
from sb3_emmarl.vdn import VDN
from sb3_emmarl.vdn_em.policies import LatentVDNPolicy

SelfEMVDN = TypeVar("SelfEMVDN", bound="EMVDN")


class EMVDN(LatentAlgorithmMixin, VDN):
    """VDN+EM: VDN's agents see their belief over the hidden mode, fitted by EM (see the module docstring).

    :param policy: ``"MlpPolicy"`` or a :class:`~sb3_emmarl.vdn_em.policies.LatentVDNPolicy` subclass
    :param env: the parameter-sharing vector environment with ``Discrete`` actions
    :param learning_rate: Adam's learning rate (or schedule)
    :param buffer_size: agent-transitions kept
    :param learning_starts: agent-steps of uniformly random actions before learning starts
    :param batch_size: team transitions per gradient step
    :param tau: target update coefficient (1: hard copy)
    :param gamma: discount factor
    :param train_freq: vector steps between updates
    :param gradient_steps: gradient steps per update
    :param target_update_interval: agent-steps between target updates
    :param exploration_fraction: fraction of the training over which epsilon goes from initial to final
    :param exploration_initial_eps: initial epsilon
    :param exploration_final_eps: final epsilon
    :param max_grad_norm: gradient clipping of the M-step
    :param double_q: double Q-learning targets
    :param agent_id: the agent network also sees the one-hot agent index
    :param latent_kwargs: the latent settings, a :class:`~sb3_emmarl.common.latent.config.LatentConfig` or a dict of
        its fields, laid over :attr:`latent_defaults` (VDN+EM's: ``e_step_interval`` and the E-step's ``window`` count
        ``train()`` calls)
    :param stats_window_size: episodes averaged in the rollout logs
    :param tensorboard_log: tensorboard folder
    :param policy_kwargs: policy arguments
    :param verbose: verbosity
    :param seed: seed
    :param device: torch device
    :param _init_setup_model: build the networks now
    :param kwargs: none (a latent setting given here is refused, naming ``latent_kwargs``)
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {"MlpPolicy": LatentVDNPolicy}
    #: The latent defaults: at ``train_freq=4``, an E-step every 2,000 steps (as EM-PPO's every rollout of 2,048 and
    #: EM-DDPG's default) on the last 4,000 steps (the E-step must see many episodes, docs/em.md section 5)
    latent_defaults: ClassVar[LatentConfig] = LatentConfig(e_step_interval=500, e_step_kwargs={"window": 1000})
    policy: LatentVDNPolicy
    replay_buffer: JointReplayBuffer

    def __init__(
        self,
        policy: str | type[LatentVDNPolicy],
        env: GymEnv | str | None,
        learning_rate: float | Schedule = 5e-4,
        buffer_size: int = 200_000,
        learning_starts: int = 10_000,
        batch_size: int = 32,
        tau: float = 1.0,
        gamma: float = 0.99,
        train_freq: int | tuple[int, str] = 4,
        gradient_steps: int = 1,
        target_update_interval: int = 2000,
        exploration_fraction: float = 0.1,
        exploration_initial_eps: float = 1.0,
        exploration_final_eps: float = 0.05,
        max_grad_norm: float = 10.0,
        double_q: bool = True,
        agent_id: bool = False,
        latent_kwargs: LatentConfig | dict[str, Any] | None = None,
        stats_window_size: int = 100,
        tensorboard_log: str | None = None,
        policy_kwargs: dict[str, Any] | None = None,
        verbose: int = 0,
        seed: int | None = None,
        device: th.device | str = "auto",
        _init_setup_model: bool = True,
        **kwargs: Any,
    ) -> None:
        env, policy_kwargs = self._init_latent(env, latent_kwargs, policy_kwargs, verbose, loading=not _init_setup_model,
                                               kwargs=kwargs)
        if kwargs:  # (VDN takes no other arguments; a latent setting among them was named above)
            raise TypeError(f"EMVDN got unexpected keyword arguments {sorted(kwargs)}")
        super().__init__(policy, env, learning_rate=learning_rate, buffer_size=buffer_size,
                         learning_starts=learning_starts, batch_size=batch_size, tau=tau, gamma=gamma,
                         train_freq=train_freq, gradient_steps=gradient_steps,
                         target_update_interval=target_update_interval, exploration_fraction=exploration_fraction,
                         exploration_initial_eps=exploration_initial_eps, exploration_final_eps=exploration_final_eps,
                         max_grad_norm=max_grad_norm, double_q=double_q, agent_id=agent_id,
                         stats_window_size=stats_window_size, tensorboard_log=tensorboard_log,
                         policy_kwargs=policy_kwargs, verbose=verbose, seed=seed, device=device,
                         _init_setup_model=False)
        if _init_setup_model:
            self._setup_model()

    def _setup_model(self) -> None:
        super()._setup_model()
        self._init_replay_e_step()

    def predict(self, observation: np.ndarray | dict[str, np.ndarray], state: Any = None,
                episode_start: np.ndarray | None = None,
                deterministic: bool = False) -> tuple[np.ndarray, Any]:
        """The EM algorithms' stateful ``predict`` (plain observations: the belief travels in ``state``), with VDN's
        epsilon-greedy exploration unless ``deterministic``."""
        actions, state = LatentAlgorithmMixin.predict(self, observation, state, episode_start, deterministic)
        return (actions if deterministic else self._explore(actions)), state

    def _e_step_data(self) -> tuple[Transitions, EpisodeCounts | None]:
        return self._replay_transitions()

    def _m_step_optimizers(self) -> th.optim.Optimizer:
        return self.policy.optimizer

    def learn(self: SelfEMVDN, total_timesteps: int, callback: MaybeCallback = None, log_interval: int = 4,
              tb_log_name: str = "EMVDN", reset_num_timesteps: bool = True, progress_bar: bool = False) -> SelfEMVDN:
        return super().learn(total_timesteps, callback=callback, log_interval=log_interval, tb_log_name=tb_log_name,
                             reset_num_timesteps=reset_num_timesteps, progress_bar=progress_bar)
