"""VDN (Sunehag et al. 2018): QMIX's learner with the additive mixer ``Q_tot = sum_a Q_a``.

Everything but the mixer is :class:`~sb3_emmarl.qmix.QMIX`'s: one shared agent network (optionally told the
agent's index), team transitions of the joint replay buffer, double Q with target networks, epsilon-greedy
exploration on DQN's linear schedule. The sum needs no global state, so VDN trains on any parameter-sharing vector
environment with ``Discrete`` actions (and on a plain SB3 ``VecEnv``, as teams of one agent: double DQN).

Departures from the paper: by default an MLP agent network trained on single team transitions (the paper's agents
are recurrent, with a dueling head); ``recurrent=True`` gives QMIX's GRU agent network trained on stretches of
``sequence_length`` rows with a stored hidden state and a burn-in (no dueling head). The team reward is the mean of
the agents' rewards.
"""

from __future__ import annotations

from typing import Any, ClassVar, TypeVar

import torch as th
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback, Schedule

from sb3_emmarl.qmix.policies import VDNPolicy
from sb3_emmarl.qmix.qmix import QMIX

SelfVDN = TypeVar("SelfVDN", bound="VDN")


class VDN(QMIX):
    """VDN: parameter-shared agent Q-networks whose chosen-action values sum to the team value.

    :param policy: ``"MlpPolicy"`` or a :class:`~sb3_emmarl.qmix.policies.VDNPolicy` subclass
    :param env: the parameter-sharing vector environment (:func:`~sb3_emmarl.common.vec_env.make_vec_env`; no
        ``state()`` needed) with ``Discrete`` actions
    :param learning_rate: Adam's learning rate (or schedule)
    :param buffer_size: agent-transitions kept
    :param learning_starts: agent-steps of uniformly random actions before learning starts
    :param batch_size: team transitions per gradient step
    :param tau: target update coefficient (1: hard copy)
    :param gamma: discount factor
    :param train_freq: vector steps (or ``(n, "step")``) between updates
    :param gradient_steps: gradient steps per update
    :param target_update_interval: agent-steps between target updates
    :param exploration_fraction: fraction of the training over which epsilon goes from initial to final
    :param exploration_initial_eps: initial epsilon
    :param exploration_final_eps: final epsilon
    :param max_grad_norm: gradient clipping
    :param double_q: double Q-learning targets
    :param agent_id: the agent network also sees the one-hot agent index
    :param recurrent: a GRU agent network trained on stretches (QMIX's option; ``batch_size`` then counts stretches)
    :param rnn_hidden_dim: the GRU's hidden size
    :param sequence_length: rows per sampled stretch
    :param burn_in: first steps of each stretch without loss (in ``[0, sequence_length - 1]``)
    :param stats_window_size: episodes averaged in the rollout logs
    :param tensorboard_log: tensorboard folder
    :param policy_kwargs: policy arguments
    :param verbose: verbosity
    :param seed: seed
    :param device: torch device
    :param _init_setup_model: build the networks now
    :param kwargs: rejected (QMIX's mixing-network sizes have no meaning here)
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {"MlpPolicy": VDNPolicy}
    mixer_type: ClassVar[str] = "vdn"
    needs_state: ClassVar[bool] = False

    def __init__(
        self,
        policy: str | type[VDNPolicy],
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
        recurrent: bool = False,
        rnn_hidden_dim: int = 64,
        sequence_length: int = 16,
        burn_in: int = 4,
        stats_window_size: int = 100,
        tensorboard_log: str | None = None,
        policy_kwargs: dict[str, Any] | None = None,
        verbose: int = 0,
        seed: int | None = None,
        device: th.device | str = "auto",
        _init_setup_model: bool = True,
        **kwargs: Any,
    ) -> None:
        if kwargs:
            raise ValueError(f"VDN takes no {sorted(kwargs)}: its mixer is the sum of the agents' values (QMIX's mixing "
                             "network takes mixing_embed_dim, hypernet_embed, hypernet_layers)")
        super().__init__(policy, env, learning_rate=learning_rate, buffer_size=buffer_size,
                         learning_starts=learning_starts, batch_size=batch_size, tau=tau, gamma=gamma,
                         train_freq=train_freq, gradient_steps=gradient_steps,
                         target_update_interval=target_update_interval, exploration_fraction=exploration_fraction,
                         exploration_initial_eps=exploration_initial_eps, exploration_final_eps=exploration_final_eps,
                         max_grad_norm=max_grad_norm, double_q=double_q, agent_id=agent_id, recurrent=recurrent,
                         rnn_hidden_dim=rnn_hidden_dim, sequence_length=sequence_length, burn_in=burn_in,
                         stats_window_size=stats_window_size, tensorboard_log=tensorboard_log,
                         policy_kwargs=policy_kwargs, verbose=verbose, seed=seed, device=device,
                         _init_setup_model=_init_setup_model)

    def learn(self: SelfVDN, total_timesteps: int, callback: MaybeCallback = None, log_interval: int = 4,
              tb_log_name: str = "VDN", reset_num_timesteps: bool = True, progress_bar: bool = False) -> SelfVDN:
        return super().learn(total_timesteps, callback=callback, log_interval=log_interval, tb_log_name=tb_log_name,
                             reset_num_timesteps=reset_num_timesteps, progress_bar=progress_bar)
