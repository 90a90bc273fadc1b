"""What EM-PPO and EM-DDPG share: the history wrapper, the latent model's settings, the E-step and its callback.

Algorithm 2 of the paper, as implemented: the algorithm collects a rollout with policies that see
``q_phi(z | h_t)`` (lines 4-10); :class:`~sb3_emmarl.common.latent.em.EMCallback` then runs the E-step
on that rollout and a few recent ones (line 11); the algorithm's own update is the M-step (line 12).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch as th
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import CallbackList
from stable_baselines3.common.save_util import load_from_zip_file
from stable_baselines3.common.vec_env import VecEnv

from sb3_emmarl.common.latent.em import EMCallback, EStep, LatentBatch
from sb3_emmarl.common.latent.history import HistoryLayout, HistoryWrapper, find_history_wrapper

#: Defaults of the E-step (see :class:`~sb3_emmarl.common.latent.em.EStep`).
E_STEP_DEFAULTS: dict[str, Any] = {"learning_rate": 1e-3, "n_epochs": 2, "batch_size": 1024, "window": 2,
                                   "temperature": 1.0, "min_temperature": 0.1, "anneal_rate": 0.05,
                                   "max_samples": 2048, "starved_share": 0.1}


def wrap_with_history(env: Any, history_length: int, verbose: int = 0) -> VecEnv:
    """``env`` as a vector environment with a :class:`HistoryWrapper` (kept if it already has one)."""
    venv = BaseAlgorithm._wrap_env(env, verbose) if not isinstance(env, VecEnv) else env
    wrapper = find_history_wrapper(venv)
    if wrapper is None:
        return HistoryWrapper(venv, history_length=history_length)
    if wrapper.layout.history_length != history_length:
        raise ValueError(f"the environment's HistoryWrapper keeps {wrapper.layout.history_length} steps, "
                         f"but history_length={history_length}")
    return venv


class LatentAlgorithmMixin:
    """Settings and E-step of an EM algorithm; mixed into SB3 algorithm classes before them."""

    e_step: EStep | None

    def _init_latent(self, env: Any, history_length: int, n_components: int, encoder_hidden: int,
                     decoder_hidden: tuple[int, ...], use_latent: bool, freeze_e_step: bool, freeze_m_step: bool,
                     estimator: str, team_pooling: bool, e_step_interval: int, e_step_kwargs: dict[str, Any] | None,
                     policy_kwargs: dict[str, Any] | None, verbose: int) -> tuple[VecEnv | None, dict[str, Any]]:
        """Validate the EM settings, wrap the environment, and put the latent settings into ``policy_kwargs``."""
        for name, value, low in (("history_length", history_length, 1), ("n_components", n_components, 1),
                                 ("encoder_hidden", encoder_hidden, 1), ("e_step_interval", e_step_interval, 1)):
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
                raise ValueError(f"{name} must be an int >= {low}, got {value!r}")
        if estimator not in ("enumerate", "gumbel"):
            raise ValueError(f"estimator must be 'enumerate' or 'gumbel', got {estimator!r}")
        unknown = set(e_step_kwargs or {}) - set(E_STEP_DEFAULTS)
        if unknown:
            raise ValueError(f"e_step_kwargs keys must be among {sorted(E_STEP_DEFAULTS)}, got {sorted(unknown)}")
        # Denormal floats appear in the GRU's arithmetic during training and slow CPU kernels down tenfold or more;
        # flushing them to zero changes no result that matters here.
        th.set_flush_denormal(True)
        self.history_length, self.n_components = int(history_length), int(n_components)
        self.encoder_hidden, self.decoder_hidden = int(encoder_hidden), tuple(int(h) for h in decoder_hidden)
        self.use_latent, self.freeze_e_step, self.freeze_m_step = bool(use_latent), bool(freeze_e_step), bool(freeze_m_step)
        self.estimator, self.team_pooling, self.e_step_interval = estimator, bool(team_pooling), int(e_step_interval)
        self.e_step_kwargs = {**E_STEP_DEFAULTS, **(e_step_kwargs or {})}
        self.e_step = None
        policy_kwargs = dict(policy_kwargs or {})
        if env is None:  # loading: the saved policy_kwargs already hold the latent settings
            return None, policy_kwargs
        venv = wrap_with_history(env, self.history_length, verbose)
        layout = find_history_wrapper(venv).layout
        policy_kwargs["latent_kwargs"] = {"obs_dim": layout.obs_dim, "history_length": layout.history_length,
                                          "feature_dim": layout.feature_dim, "action_dim": layout.action_dim,
                                          "n_components": self.n_components, "encoder_hidden": self.encoder_hidden,
                                          "decoder_hidden": self.decoder_hidden}
        policy_kwargs["use_latent"] = self.use_latent
        return venv, policy_kwargs

    @property
    def layout(self) -> HistoryLayout:
        kwargs = self.policy_kwargs["latent_kwargs"]
        return HistoryLayout(kwargs["obs_dim"], kwargs["history_length"], kwargs["feature_dim"], kwargs["action_dim"])

    def _setup_e_step(self) -> None:
        if self.use_latent:
            self.e_step = EStep(self.policy.latent_model, estimator=self.estimator, team_pooling=self.team_pooling,
                                seed=self.seed or 0, **self.e_step_kwargs)

    def _with_em_callback(self, callback: Any) -> Any:
        """The user's callbacks plus the EM callback (E-step after each rollout) when there is a latent model."""
        if not self.use_latent:
            return callback
        if callback is None:
            return EMCallback()
        if isinstance(callback, list):
            return [*callback, EMCallback()]
        return CallbackList([callback, EMCallback()])

    def latent_batch(self) -> LatentBatch:  # pragma: no cover - provided by each algorithm
        raise NotImplementedError

    def start_collection(self) -> None:
        """Called by the EM callback when a rollout starts (nothing to do by default)."""

    def record_collection_step(self) -> None:
        """Called by the EM callback after each collection step (nothing to do by default)."""

    @property
    def agents_per_copy(self) -> int:
        return int(getattr(self.env, "agents_per_copy", 1))

    def wrap_env(self, venv: VecEnv) -> VecEnv:
        """``venv`` with the history wrapper this model reads (for evaluation and recording)."""
        return wrap_with_history(venv, self.layout.history_length)

    def posterior(self, observations: np.ndarray) -> np.ndarray:
        """``q_phi(z | h_t)`` for augmented observations ``(n, total_dim)`` -> ``(n, K)`` (uniform without a model)."""
        if self.policy.latent_model is None:
            return np.full((len(observations), self.n_components), 1.0 / self.n_components)
        with th.no_grad():
            obs = th.as_tensor(np.asarray(observations), dtype=th.float32, device=self.device)
            return self.policy.latent_model.posterior(self.layout.split(obs)[1]).cpu().numpy()

    def write_posterior(self, observations: Any, posterior: Any) -> None:
        """Write posteriors ``(..., K)`` over the start of the history windows of augmented observations (numpy or
        torch, in place), where the features extractors read them while the latent model is ``precomputed``.

        Only for observations whose windows were already read: the window's first slot is overwritten.
        """
        observations[..., self.layout.posterior_columns(self.n_components)] = posterior

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "e_step"]

    @classmethod
    def load(cls, path: Any, env: Any = None, device: Any = "auto", custom_objects: dict | None = None,
             print_system_info: bool = False, force_reset: bool = True, **kwargs):
        """As SB3's ``load``; an ``env`` without the history wrapper gets the one the model was trained with."""
        if env is not None:
            data, _, _ = load_from_zip_file(path, device="cpu", custom_objects=custom_objects)
            env = wrap_with_history(env, data["policy_kwargs"]["latent_kwargs"]["history_length"])
        return super().load(path, env=env, device=device, custom_objects=custom_objects,
                            print_system_info=print_system_info, force_reset=force_reset, **kwargs)
