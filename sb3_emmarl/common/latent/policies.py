"""The latent feature extractor and the policies that own the latent model.

The policy (actor-critic for EM-PPO, TD3-style for EM-DDPG) owns one :class:`LatentModel`, saved and
loaded with it. Every features extractor of the policy (actor, critic and their targets) reads the
same model: it splits the augmented observation into the original observation and the history
window and returns ``[observation, q_phi(z | h_t)]``, the posterior detached, so that policy and
value gradients never reach the encoder (the E-step alone trains it). The policies' optimizers
exclude the latent model's parameters for the same reason.
"""

from __future__ import annotations

from typing import Any

import torch as th
from gymnasium import spaces
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from stable_baselines3.td3.policies import TD3Policy

from sb3_emmarl.common.latent.history import HistoryLayout
from sb3_emmarl.common.latent.model import LatentModel


class LatentFeaturesExtractor(BaseFeaturesExtractor):
    """``[observation, q_phi(z | h_t).detach()]`` from an augmented observation (``observation`` alone without a model).

    :param observation_space: the augmented observation space
    :param layout: the history layout
    :param latent_model: the policy's latent model (not a submodule here: the policy owns it); None for the
        no-latent ablation
    """

    def __init__(self, observation_space: spaces.Box, layout: HistoryLayout, latent_model: LatentModel | None) -> None:
        super().__init__(observation_space, layout.obs_dim + (latent_model.n_components if latent_model else 0))
        self.layout = layout
        object.__setattr__(self, "latent_model", latent_model)  # a reference, so the model is saved once
        #: The posterior of the last batch it computed (EM-PPO keeps the ones its rollout was collected with).
        self.latest_posterior: th.Tensor | None = None

    def forward(self, observations: th.Tensor) -> th.Tensor:
        raw, window = self.layout.split(observations)
        if self.latent_model is None:
            return raw
        if self.latent_model.precomputed:  # the posterior already sits where the window starts (see EMPPO.train)
            posterior = observations[..., self.layout.posterior_columns(self.latent_model.n_components)]
        else:
            with th.no_grad():
                posterior = self.latent_model.posterior(window)
            self.latest_posterior = posterior
        return th.cat([raw, posterior], dim=-1)


class LatentPolicyMixin:
    """Create the latent model before the policy builds its networks, and hand it to every features extractor.

    ``latent_kwargs`` holds the :class:`HistoryLayout` fields and the model's sizes (``n_components``,
    ``encoder_hidden``, ``decoder_hidden``); ``use_latent=False`` builds no model (the no-latent ablation).
    """

    def __init__(self, observation_space, action_space, lr_schedule, *args, latent_kwargs: dict[str, Any],
                 use_latent: bool = True, **kwargs) -> None:
        sizes = dict(latent_kwargs)
        layout = HistoryLayout(**{k: int(sizes.pop(k)) for k in ("obs_dim", "history_length", "feature_dim", "action_dim")})
        # Plain attributes: nn.Module.__init__ has not run yet, and the networks built by super().__init__ read them.
        object.__setattr__(self, "_latent_layout", layout)
        object.__setattr__(self, "_pending_latent_model", LatentModel(layout, **sizes) if use_latent else None)
        object.__setattr__(self, "_latent_config", (dict(latent_kwargs), use_latent))
        super().__init__(observation_space, action_space, lr_schedule, *args, **kwargs)
        # A submodule only now, after the networks' optimizers were built without its parameters.
        self.latent_model = self._pending_latent_model
        self.to(self.device)

    def make_features_extractor(self) -> LatentFeaturesExtractor:
        return LatentFeaturesExtractor(self.observation_space, self._latent_layout, self._pending_latent_model)

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        latent_kwargs, use_latent = self._latent_config
        data.update(latent_kwargs=latent_kwargs, use_latent=use_latent)
        return data


class LatentActorCriticPolicy(LatentPolicyMixin, ActorCriticPolicy):
    """SB3's ``ActorCriticPolicy`` whose policy and value networks see the latent posterior (EM-PPO).

    Takes ``ActorCriticPolicy``'s arguments plus ``latent_kwargs`` (history layout and latent model sizes,
    set by the algorithm) and ``use_latent`` (False: the no-latent ablation).
    """


class LatentTD3Policy(LatentPolicyMixin, TD3Policy):
    """SB3's ``TD3Policy`` whose actor and critics (and their targets) see the latent posterior (EM-DDPG).

    Takes ``TD3Policy``'s arguments plus ``latent_kwargs`` and ``use_latent`` (see :class:`LatentActorCriticPolicy`).
    """
