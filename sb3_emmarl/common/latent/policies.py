"""The policies of the EM algorithms: SB3's, reading ``[observation, belief]``, and owning the latent model.

The belief ``q(z | o_{1:t}, a_{1:t-1})`` arrives inside the observation (the
:class:`~sb3_emmarl.common.latent.belief.BeliefWrapper` appends it, ``predict`` does the same on plain
observations), so policy and value gradients never reach the latent model: the E-step alone fits it. The
policy owns the model so that it is saved and loaded with the policy; its optimizer excludes the model's
parameters.
"""

from __future__ import annotations

from typing import Any

from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.td3.policies import TD3Policy

from sb3_emmarl.common.extractors import SplitFeaturesExtractor
from sb3_emmarl.common.latent.layout import LatentLayout
from sb3_emmarl.common.latent.model import LatentModel


class LatentPolicyMixin:
    """Create the latent model with the policy and give every features extractor the latent layout.

    ``latent_kwargs`` holds the :class:`LatentLayout` fields; ``use_latent=False`` builds no model (the
    no-latent ablation). A ``features_extractor_class`` in ``policy_kwargs`` (e.g. the message extractors of
    :mod:`sb3_emmarl.common.extractors`) reads the environment's observation; the belief is appended to its features.
    """

    def __init__(self, observation_space, action_space, lr_schedule, *args, latent_kwargs: dict[str, Any],
                 use_latent: bool = True, **kwargs) -> None:
        layout = LatentLayout.from_dict(latent_kwargs)
        # Plain attributes: nn.Module.__init__ has not run yet, and the networks built by super().__init__ read them.
        object.__setattr__(self, "latent_layout", layout)
        object.__setattr__(self, "_latent_config", (layout.to_dict(), bool(use_latent)))
        super().__init__(observation_space, action_space, lr_schedule, *args, **kwargs)
        # A submodule only now, after the networks' optimizers were built without its parameters.
        self.latent_model = LatentModel(layout) if use_latent else None
        self.to(self.device)

    def make_features_extractor(self) -> SplitFeaturesExtractor:
        """``policy_kwargs``' features extractor (default: none) over the environment's observation, then the belief
        (dropped when ``use_latent=False``, the no-latent ablation)."""
        layout = self.latent_layout
        return SplitFeaturesExtractor(self.observation_space, layout.obs_dim, self.features_extractor_class,
                                      self.features_extractor_kwargs,
                                      keep=layout.total_dim if self._latent_config[1] else layout.obs_dim)

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        latent_kwargs, use_latent = self._latent_config
        data.update(latent_kwargs=latent_kwargs, use_latent=use_latent)
        return data


class LatentActorCriticPolicy(LatentPolicyMixin, ActorCriticPolicy):
    """SB3's ``ActorCriticPolicy`` whose policy and value networks see the belief (EM-PPO).

    Takes ``ActorCriticPolicy``'s arguments plus ``latent_kwargs`` (set by the algorithm) and ``use_latent``.
    """


class LatentTD3Policy(LatentPolicyMixin, TD3Policy):
    """SB3's ``TD3Policy`` whose actor and critics (and their targets) see the belief (EM-DDPG).

    Takes ``TD3Policy``'s arguments plus ``latent_kwargs`` and ``use_latent`` (see :class:`LatentActorCriticPolicy`).
    """
