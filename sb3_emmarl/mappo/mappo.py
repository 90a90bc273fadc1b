"""MAPPO: parameter-shared PPO with a centralised critic over the agent-specific global state and value normalisation.

What it computes (Yu et al. 2022, "The Surprising Effectiveness of PPO in Cooperative Multi-Agent Games", and
their code, marlbenchmark/on-policy's ``R_MAPPO`` without recurrence):

- one actor shared by all agents, reading the agent's own observation only (decentralised execution);
- one critic shared by all agents, reading ``[own observation, global state, one-hot agent id]`` (the
  agent-specific global state: what the global state says, plus what this agent sees, plus who it is);
- the value head predicts returns normalised by :class:`~sb3_emmarl.mappo.policies.ValueNorm` (running,
  debiased mean and variance of the returns); the value loss is the Huber loss (``huber_delta``) between the
  normalised return and the prediction, clipped around the rollout's prediction as PPO clips the ratio, taking
  the larger of the clipped and unclipped losses (``clip_range_vf``);
- the PPO update with few epochs over the whole rollout as one minibatch (``batch_size=None``), gradients of
  the actor and of the critic clipped separately, on-policy's learning rate, entropy bonus and gradient bound.

Where it departs from on-policy (all within SB3's machinery, which it reuses: rollout collection, GAE, logging):

- the normaliser is updated once per rollout, with all its returns, before the epochs, rather than once per
  minibatch per epoch; as every update weighs about the same (``beta = 0.99999``) this is the same average
  when there is one minibatch (on-policy's default), and the targets stay put within an update;
- an episode cut at the time limit is bootstrapped from the critic's value of its last state (SB3's
  ``TimeLimit.truncated``; on-policy's default ``use_proper_time_limits=False`` treats it as an end);
- advantages are normalised per minibatch (SB3) instead of over the whole buffer: the same with one minibatch;
- one Adam optimiser over both networks (SB3) instead of one each: Adam is per parameter and the networks share
  none, so the two coincide when both learning rates are equal (on-policy's default);
- no recurrent policy (on-policy's ``rmappo``), no death masks (no agent leaves early), no available-actions mask.
"""

from __future__ import annotations

from contextlib import nullcontext
from typing import Any, ClassVar, TypeVar, cast

import numpy as np
import torch as th
import torch.nn.functional as F
from gymnasium import spaces
from stable_baselines3 import PPO
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import GymEnv, Schedule
from stable_baselines3.common.utils import explained_variance
from stable_baselines3.common.vec_env import VecEnv

from sb3_emmarl.common.appended.wrapping import WrapsEnv, find_wrapper
from sb3_emmarl.common.trust.validation import RULES, Rule, fail, no_schedule_string, number, optional
from sb3_emmarl.mappo.policies import VALUE_NORM_BETA, MAPPOPolicy, MlpPolicy
from sb3_emmarl.mappo.wrappers import GlobalStateWrapper, StateLayout, wrap_with_state

SelfMAPPO = TypeVar("SelfMAPPO", bound="MAPPO")


#: The rule of every MAPPO constructor argument it checks (PPO's from the zoo's rules, MAPPO's own below).
MAPPO_RULES: dict[str, Rule] = {
    "learning_rate": no_schedule_string(RULES["learning_rate"]),
    "n_steps": RULES["n_steps"],
    "batch_size": optional(RULES["batch_size"]),
    "n_epochs": RULES["n_epochs"],
    "gamma": RULES["gamma"],
    "gae_lambda": RULES["gae_lambda"],
    "clip_range": no_schedule_string(RULES["clip_range"]),
    "clip_range_vf": optional(no_schedule_string(number(0.0, 10.0, low_open=True, schedule=True))),
    "normalize_advantage": RULES["normalize_advantage"],
    "ent_coef": number(0.0, 100.0),
    "vf_coef": RULES["vf_coef"],
    "max_grad_norm": RULES["max_grad_norm"],
    "target_kl": optional(number(0.0, 100.0, low_open=True)),
    # MAPPO's own
    **{name: RULES[name] for name in ("agent_id", "use_value_norm", "value_norm_beta", "huber_delta")},
}


class MAPPO(WrapsEnv, PPO):
    """MAPPO (Yu et al. 2022): PPO with one actor shared by all agents on their own observations and one critic on
    the agent-specific global state, with value normalisation, on the parameter-sharing vector environment.

    The environment (and any environment given to ``load`` or ``set_env``) gets a
    :class:`~sb3_emmarl.mappo.wrappers.GlobalStateWrapper`, which switches its global state on and appends it (and
    the agent's one-hot) to every observation, so that SB3's rollout buffer holds the critic's input. The actor reads
    the agent's own observation only: ``predict`` takes plain observations, and SB3's ``evaluate_policy`` runs on the
    plain environment (augmented observations are accepted too). See the module docstring for where this follows
    and where it departs from the paper's code.

    :param policy: ``"MlpPolicy"`` or a :class:`~sb3_emmarl.mappo.policies.MAPPOPolicy` subclass
    :param env: the parameter-sharing vector environment (:func:`~sb3_emmarl.common.vec_env.make_vec_env`) of a
        PettingZoo parallel environment with ``state()`` and ``state_space`` (built with or without ``with_state``)
    :param learning_rate: learning rate of both networks (or schedule); on-policy's 5e-4
    :param n_steps: steps per vector entry per rollout; on-policy's ``episode_length`` 200
    :param batch_size: minibatch size; None (default): the whole rollout in one minibatch, as the paper advises
    :param n_epochs: epochs per rollout; the paper advises at most 10 on hard tasks (15 on easy ones, 5 on the
        hardest)
    :param gamma: discount factor
    :param gae_lambda: GAE lambda
    :param clip_range: PPO's ratio clipping (or schedule); the paper advises at most 0.2
    :param clip_range_vf: clipping of the value prediction around the rollout's, in normalised units, with the larger
        of the clipped and unclipped losses (on-policy's ``use_clipped_value_loss`` with ``clip_param``); None: no
        clipping
    :param normalize_advantage: normalise the advantages (per minibatch)
    :param ent_coef: entropy coefficient
    :param vf_coef: value loss coefficient; the loss is ``1/2 error^2`` below ``huber_delta``, so 1 here weighs it as
        SB3's PPO's 0.5 weighs its ``error^2``
    :param max_grad_norm: bound on the gradient norm, of the actor and of the critic separately
    :param agent_id: the critic's input ends with a one-hot of the agent (``agents_per_copy`` floats)
    :param use_value_norm: normalise the value targets (:class:`~sb3_emmarl.mappo.policies.ValueNorm`)
    :param value_norm_beta: the normaliser's averaging factor, in (0, 1)
    :param huber_delta: the Huber loss's threshold on the (normalised) value error; None: squared error
    :param target_kl: stop an update's epochs early beyond this KL divergence (None: never)
    :param stats_window_size: episodes averaged in the rollout logs
    :param tensorboard_log: tensorboard folder
    :param policy_kwargs: policy arguments (``net_arch``, ``activation_fn``, ``layer_norm``, ``ortho_init``, ...)
    :param verbose: verbosity
    :param seed: seed
    :param device: torch device
    :param _init_setup_model: build the networks now
    :param kwargs: other PPO arguments (``use_sde``, ``rollout_buffer_class``, ...)
    :raise ValueError: for a bad argument (naming it, its value and what is allowed), or an environment without
        global state
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {"MlpPolicy": MlpPolicy}
    policy: MAPPOPolicy

    def __init__(
        self,
        policy: str | type[MAPPOPolicy],
        env: GymEnv | None,
        learning_rate: float | Schedule = 5e-4,
        n_steps: int = 200,
        batch_size: int | None = None,
        n_epochs: int = 10,
        gamma: float = 0.99,
        gae_lambda: float = 0.95,
        clip_range: float | Schedule = 0.2,
        clip_range_vf: float | Schedule | None = 0.2,
        normalize_advantage: bool = True,
        ent_coef: float = 0.01,
        vf_coef: float = 1.0,
        max_grad_norm: float = 10.0,
        agent_id: bool = True,
        use_value_norm: bool = True,
        value_norm_beta: float = VALUE_NORM_BETA,
        huber_delta: float | None = 10.0,
        target_kl: float | None = None,
        stats_window_size: int = 100,
        tensorboard_log: str | None = None,
        policy_kwargs: dict[str, Any] | None = None,
        verbose: int = 0,
        seed: int | None = None,
        device: th.device | str = "auto",
        _init_setup_model: bool = True,
        **kwargs: Any,
    ) -> None:
        arguments = {"learning_rate": learning_rate, "n_steps": n_steps, "batch_size": batch_size, "n_epochs": n_epochs,
                     "gamma": gamma, "gae_lambda": gae_lambda, "clip_range": clip_range, "clip_range_vf": clip_range_vf,
                     "normalize_advantage": normalize_advantage, "ent_coef": ent_coef, "vf_coef": vf_coef,
                     "max_grad_norm": max_grad_norm, "target_kl": target_kl, "agent_id": agent_id,
                     "use_value_norm": use_value_norm, "value_norm_beta": value_norm_beta, "huber_delta": huber_delta}
        for name, value in arguments.items():
            MAPPO_RULES[name](name, value)
        if normalize_advantage and batch_size is not None and batch_size < 2:
            fail("batch_size", batch_size, "an int >= 2 (or None) when normalize_advantage is true")
        if isinstance(policy, type) and not issubclass(policy, MAPPOPolicy):
            raise ValueError(f"policy must be 'MlpPolicy' or a MAPPOPolicy subclass, got {policy.__name__}")
        if policy_kwargs is not None and not isinstance(policy_kwargs, dict):
            fail("policy_kwargs", policy_kwargs, "a dict or None")
        loading = not _init_setup_model
        if env is None and not loading:
            raise ValueError("env must be the parameter-sharing vector environment of an environment with state() "
                             "(None only when loading), got None")
        self.agent_id, self.use_value_norm = bool(agent_id), bool(use_value_norm)
        self.value_norm_beta = float(value_norm_beta)
        self.huber_delta = None if huber_delta is None else float(huber_delta)
        policy_kwargs = dict(policy_kwargs or {})
        own: dict[str, Any] = {"value_norm": self.use_value_norm, "value_norm_beta": self.value_norm_beta}
        if env is not None:
            env = wrap_with_state(env, self.agent_id, verbose, strict=not loading)
            state_wrapper = find_wrapper(env, GlobalStateWrapper)
            assert state_wrapper is not None  # (wrap_with_state gives an environment with one)
            own["state_layout"] = state_wrapper.layout.to_dict()
        for key, value in own.items():
            if key in policy_kwargs and policy_kwargs[key] != value and not loading:
                raise ValueError(f"policy_kwargs[{key!r}] is set by MAPPO (to {value!r} here), got {policy_kwargs[key]!r}")
        policy_kwargs.update(own)
        whole_rollout = max(2, n_steps * env.num_envs) if env is not None else 2
        # (env is None when loading: SB3 takes it, though PPO's annotation leaves None out)
        super().__init__(policy, cast(GymEnv, env), learning_rate=learning_rate, n_steps=n_steps,
                         batch_size=whole_rollout if batch_size is None else batch_size, n_epochs=n_epochs, gamma=gamma,
                         gae_lambda=gae_lambda, clip_range=clip_range, clip_range_vf=clip_range_vf,
                         normalize_advantage=normalize_advantage, ent_coef=ent_coef, vf_coef=vf_coef,
                         max_grad_norm=max_grad_norm, target_kl=target_kl, stats_window_size=stats_window_size,
                         tensorboard_log=tensorboard_log, policy_kwargs=policy_kwargs, verbose=verbose, seed=seed,
                         device=device, _init_setup_model=False, **kwargs)
        self.batch_size = batch_size  # type: ignore[assignment]  # None (PPO's is an int): the whole rollout, for train()
        if _init_setup_model:
            self._setup_model()

    def _setup_model(self) -> None:
        super()._setup_model()
        layout = self.state_layout
        if layout.agent_id != self.agent_id:
            raise ValueError(f"agent_id={self.agent_id}, but the policy was built with agent_id={layout.agent_id} "
                             "(it cannot change after training began)")
        if (self.policy.value_norm is not None) != self.use_value_norm:
            raise ValueError(f"use_value_norm={self.use_value_norm}, but the policy was built with value_norm="
                             f"{self.policy.value_norm is not None} (it cannot change after training began)")

    @property
    def state_layout(self) -> StateLayout:
        """Where the observation, the state and the agent id sit in the critic's input."""
        return self.policy.state_layout

    # ------------------------------------------------------------------ the update
    def _value_loss(self, error: th.Tensor) -> th.Tensor:
        """Per-sample value loss: Huber (``1/2 e^2`` below ``huber_delta``) or ``1/2 e^2``."""
        if self.huber_delta is None:
            return 0.5 * error**2
        return F.huber_loss(error, th.zeros_like(error), reduction="none", delta=self.huber_delta)

    def _minibatch_value_loss(self, values: th.Tensor, returns: th.Tensor, old_values: th.Tensor,
                              old_stats: tuple[th.Tensor, th.Tensor] | None, clip_range_vf: float | None) -> th.Tensor:
        """MAPPO's value loss of a minibatch: the (normalised) returns against the value head's predictions, the
        larger of the plain and the clipped loss (``clip_range_vf``), averaged.

        :param values: the value head's predictions (normalised units with value normalisation)
        :param returns: the returns (the returns' units)
        :param old_values: the rollout's predictions (the returns' units)
        :param old_stats: the normaliser's mean and variance when the rollout was collected (None: no normalisation)
        :param clip_range_vf: the clipping of the predictions around the rollout's (None: none)
        """
        value_norm = self.policy.value_norm
        if value_norm is not None and old_stats is not None:
            returns = value_norm.normalize(returns)
            old_values = ((old_values.double() - old_stats[0]) / old_stats[1].sqrt()).to(values.dtype)
        value_loss = self._value_loss(returns - values)
        if clip_range_vf is not None:
            clipped = old_values + th.clamp(values - old_values, -clip_range_vf, clip_range_vf)
            value_loss = th.max(value_loss, self._value_loss(returns - clipped))
        return value_loss.mean()

    def _record_train_logs(self, entropy_losses: list[float], pg_losses: list[float], value_losses: list[float],
                           approx_kl_divs: list[Any], clip_fractions: list[float], *, actor_norms: list[float],
                           critic_norms: list[float], last_loss: float | None, clip_range: float,
                           clip_range_vf: float | None) -> None:
        """PPO's ``train/`` logs, and MAPPO's: the gradient norms and the value normaliser's statistics.

        :param entropy_losses: each minibatch's entropy loss
        :param pg_losses: each minibatch's policy-gradient loss
        :param value_losses: each minibatch's value loss
        :param approx_kl_divs: the last epoch's approximate KL divergences
        :param clip_fractions: each minibatch's fraction of clipped ratios
        :param actor_norms: each update's actor gradient norm (before clipping)
        :param critic_norms: each update's critic gradient norm (before clipping)
        :param last_loss: the last minibatch's total loss (None: no minibatch)
        :param clip_range: the policy's clip range of this update
        :param clip_range_vf: the value clip range of this update (None: none)
        """
        buffer = self.rollout_buffer
        explained_var = explained_variance(buffer.values.flatten(), buffer.returns.flatten())
        self.logger.record("train/entropy_loss", np.mean(entropy_losses))
        self.logger.record("train/policy_gradient_loss", np.mean(pg_losses))
        self.logger.record("train/value_loss", np.mean(value_losses))
        self.logger.record("train/approx_kl", np.mean(approx_kl_divs))
        self.logger.record("train/clip_fraction", np.mean(clip_fractions))
        if last_loss is not None:
            self.logger.record("train/loss", last_loss)
        self.logger.record("train/explained_variance", explained_var)
        if actor_norms:
            self.logger.record("train/actor_grad_norm", np.mean(actor_norms))
            self.logger.record("train/critic_grad_norm", np.mean(critic_norms))
        if hasattr(self.policy, "log_std"):
            self.logger.record("train/std", th.exp(self.policy.log_std).mean().item())
        if self.policy.value_norm is not None:
            mean, std = self.policy.value_norm.mean_std()
            self.logger.record("train/value_norm_mean", mean)
            self.logger.record("train/value_norm_std", std)
        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        self.logger.record("train/clip_range", clip_range)
        if clip_range_vf is not None:
            self.logger.record("train/clip_range_vf", clip_range_vf)

    def train(self) -> None:
        """MAPPO's update on the rollout just collected: update the value normaliser with its returns, then
        ``n_epochs`` passes of PPO's clipped surrogate, MAPPO's clipped Huber value loss on normalised targets and the
        entropy bonus, with the actor's and the critic's gradients clipped separately."""
        # With _epochs, SB3's PPO.train with MAPPO's value loss and separate clipping: the two read side by side, and a
        # change in SB3's carries over line by line.
        self.policy.set_training_mode(True)
        self._update_learning_rate(self.policy.optimizer)
        # (schedules since _setup_model, though PPO annotates them as floats or schedules)
        clip_range = cast(Schedule, self.clip_range)(self._current_progress_remaining)
        clip_range_vf = (cast(Schedule, self.clip_range_vf)(self._current_progress_remaining)
                         if self.clip_range_vf is not None else None)
        buffer = self.rollout_buffer
        batch_size = self.batch_size or buffer.buffer_size * buffer.n_envs
        value_norm = self.policy.value_norm
        old_stats: tuple[th.Tensor, th.Tensor] | None = None
        if value_norm is not None:  # the rollout's predictions were made with the statistics before this update
            mean, var = value_norm.mean_var()
            old_stats = (mean.clone(), var.clone())
            value_norm.update(buffer.returns)
        actor_parameters, critic_parameters = self.policy.actor_parameters(), self.policy.critic_parameters()
        # The whole rollout as one batch (batch_size None): gathered once, its groups of equal global states found once
        # (MAPPOPolicy.grouped); each epoch's permutation of its rows would change the sums' order only.
        whole = next(buffer.get(batch_size)) if self.batch_size is None else None
        grouped = self.policy.grouped(whole.observations) if whole is not None else nullcontext()
        with grouped:
            self._epochs(whole, batch_size, clip_range, clip_range_vf, old_stats, actor_parameters, critic_parameters)

    def _epochs(self, whole: Any, batch_size: int, clip_range: float, clip_range_vf: float | None,
                old_stats: tuple[th.Tensor, th.Tensor] | None, actor_parameters: list, critic_parameters: list) -> None:
        """:meth:`train`'s ``n_epochs`` passes (over ``whole``, the rollout as one batch, or the buffer's minibatches)
        and their logs."""
        entropy_losses, pg_losses, value_losses, clip_fractions = [], [], [], []
        approx_kl_divs: list[np.ndarray] = []
        actor_norms, critic_norms = [], []
        continue_training = True
        buffer = self.rollout_buffer
        for epoch in range(self.n_epochs):
            approx_kl_divs = []
            for rollout_data in ([whole] if whole is not None else buffer.get(batch_size)):
                actions = rollout_data.actions
                if isinstance(self.action_space, spaces.Discrete):
                    actions = rollout_data.actions.long().flatten()
                values, log_prob, entropy = self.policy.evaluate_actions_normalized(rollout_data.observations, actions)
                values = values.flatten()
                advantages = rollout_data.advantages
                if self.normalize_advantage and len(advantages) > 1:
                    advantages = (advantages - advantages.mean()) / (advantages.std() + 1e-8)

                ratio = th.exp(log_prob - rollout_data.old_log_prob)
                policy_loss = -th.min(advantages * ratio, advantages * th.clamp(ratio, 1 - clip_range, 1 + clip_range)).mean()
                pg_losses.append(policy_loss.item())
                clip_fractions.append(th.mean((th.abs(ratio - 1) > clip_range).float()).item())

                value_loss = self._minibatch_value_loss(values, rollout_data.returns, rollout_data.old_values,
                                                        old_stats, clip_range_vf)
                value_losses.append(value_loss.item())

                entropy_loss = -th.mean(-log_prob) if entropy is None else -th.mean(entropy)
                entropy_losses.append(entropy_loss.item())
                loss = policy_loss + self.ent_coef * entropy_loss + self.vf_coef * value_loss

                with th.no_grad():
                    log_ratio = log_prob - rollout_data.old_log_prob
                    approx_kl_div = th.mean((th.exp(log_ratio) - 1) - log_ratio).cpu().numpy()
                    approx_kl_divs.append(approx_kl_div)
                if self.target_kl is not None and approx_kl_div > 1.5 * self.target_kl:
                    continue_training = False
                    if self.verbose >= 1:
                        print(f"Early stopping at step {epoch} due to reaching max kl: {approx_kl_div:.2f}")
                    break

                self.policy.optimizer.zero_grad()
                loss.backward()
                actor_norms.append(float(th.nn.utils.clip_grad_norm_(actor_parameters, self.max_grad_norm)))
                critic_norms.append(float(th.nn.utils.clip_grad_norm_(critic_parameters, self.max_grad_norm)))
                self.policy.optimizer.step()

            self._n_updates += 1
            if not continue_training:
                break

        self._record_train_logs(entropy_losses, pg_losses, value_losses, approx_kl_divs, clip_fractions,
                                actor_norms=actor_norms, critic_norms=critic_norms,
                                last_loss=loss.item() if value_losses else None, clip_range=clip_range,
                                clip_range_vf=clip_range_vf)

    def learn(self: SelfMAPPO, total_timesteps: int, callback: Any = None, log_interval: int = 1,
              tb_log_name: str = "MAPPO", reset_num_timesteps: bool = True, progress_bar: bool = False) -> SelfMAPPO:
        return super().learn(total_timesteps, callback=callback, log_interval=log_interval, tb_log_name=tb_log_name,
                             reset_num_timesteps=reset_num_timesteps, progress_bar=progress_bar)

    # ------------------------------------------------------------------ environments
    def _wrap_own_env(self, env: Any) -> VecEnv:
        """The global state appended (a plain environment included)."""
        return wrap_with_state(env, self.agent_id, self.verbose)

    @classmethod
    def _wrap_saved_env(cls, env: Any, data: dict[str, Any]) -> VecEnv:
        """The global state appended as in training (without ``env`` a loaded model acts through ``predict`` on plain
        observations)."""
        layout = StateLayout.from_dict(data["policy_kwargs"]["state_layout"])
        return wrap_with_state(env, layout.agent_id, data.get("verbose", 0))
