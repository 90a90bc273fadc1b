"""The policies of the EM algorithms: SB3's, reading ``[observation, belief]``, and owning the latent model.

The belief ``q(z | o_{1:t}, a_{1:t-1})`` arrives inside the observation (the
:class:`~sb3_emmarl.common.latent.belief.BeliefWrapper` appends it, ``predict`` does the same on plain
observations), so policy and value gradients never reach the latent model: the E-step alone fits it. The
policy owns the model so that it is saved and loaded with the policy; its optimizer excludes the model's
parameters.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, cast

import torch as th
from gymnasium import spaces
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor, FlattenExtractor
from stable_baselines3.td3.policies import TD3Policy

from sb3_emmarl.common.appended.conditioning import ConditionedPolicyMixin, ConditionedTD3Mixin
from sb3_emmarl.common.appended.extractor import SplitFeaturesExtractor
from sb3_emmarl.common.latent.layout import LatentLayout
from sb3_emmarl.common.latent.model import LatentModel

#: How the networks read the belief (``belief_input``): the probabilities as they are; the one-hot of the most likely
#: component (the form of a told mode); or both, the one-hot after the probabilities.
BELIEF_INPUTS = ("probabilities", "map", "both")

if TYPE_CHECKING:  # the type checker sees the SB3 policy the mixin is placed before; at run time it is a plain class
    from stable_baselines3.common.policies import BasePolicy as _PolicyBase
else:
    _PolicyBase = object


class BeliefFeaturesExtractor(SplitFeaturesExtractor):
    """:class:`~sb3_emmarl.common.extractors.SplitFeaturesExtractor` over ``[observation, belief]`` whose appended
    belief takes the form ``belief_input`` names (:data:`BELIEF_INPUTS`).

    :param observation_space: the augmented observation space
    :param head_dim: the environment's observation size
    :param extractor_class: the extractor over the environment's observation
    :param extractor_kwargs: its keyword arguments
    :param keep: values kept in all (``head_dim``: the belief is dropped, the no-latent ablation)
    :param belief_input: ``"probabilities"``, ``"map"`` or ``"both"``
    """

    def __init__(self, observation_space: spaces.Box, head_dim: int,
                 extractor_class: type[BaseFeaturesExtractor] = FlattenExtractor,
                 extractor_kwargs: dict[str, Any] | None = None, keep: int | None = None,
                 belief_input: str = "probabilities") -> None:
        if belief_input not in BELIEF_INPUTS:
            raise ValueError(f"belief_input must be one of {list(BELIEF_INPUTS)}, got {belief_input!r}")
        super().__init__(observation_space, head_dim, extractor_class, extractor_kwargs, keep)
        self.belief_input = belief_input
        self.n_belief = self.keep - self.head_dim
        if belief_input == "both":
            self._features_dim += self.n_belief
        #: features that come from the belief (at the end of the features)
        self.belief_width = self._features_dim - self.inner.features_dim

    def forward(self, observations: th.Tensor) -> th.Tensor:
        features = super().forward(observations)
        if self.belief_input == "probabilities" or self.n_belief == 0:
            return features
        k = self.n_belief
        most_likely = th.nn.functional.one_hot(features[..., -k:].argmax(-1), k).to(features.dtype)
        if self.belief_input == "map":
            return th.cat([features[..., :-k], most_likely], dim=-1)
        return th.cat([features, most_likely], dim=-1)


class LatentPolicyMixin(_PolicyBase):
    """Create the latent model with the policy and give every features extractor the latent layout.

    ``latent_layout`` holds the :class:`LatentLayout` fields (set by the algorithm); ``use_latent=False`` builds no model (the
    no-latent ablation); ``belief_input`` is how the networks read the belief (:data:`BELIEF_INPUTS`). A
    ``features_extractor_class`` in ``policy_kwargs`` (e.g. the message extractors of
    :mod:`sb3_emmarl.common.extractors`) reads the environment's observation; the belief is appended to its features.
    """

    latent_layout: LatentLayout
    #: ``(latent_layout, use_latent, belief_input)`` as given to the constructor
    _latent_config: tuple[dict[str, Any], bool, str]
    latent_model: LatentModel | None

    def __init__(self, observation_space, action_space, lr_schedule, *args, latent_layout: dict[str, Any],
                 use_latent: bool = True, belief_input: str = "probabilities", **kwargs) -> None:
        layout = LatentLayout.from_dict(latent_layout)
        if kwargs.get("belief_conditioning") == "mixture" and belief_input == "both":
            raise ValueError("belief_conditioning='mixture' weighs one head per component by the belief: it needs "
                             "belief_input 'probabilities' or 'map', got 'both'")
        # Plain attributes: nn.Module.__init__ has not run yet, and the networks built by super().__init__ read them.
        object.__setattr__(self, "latent_layout", layout)
        object.__setattr__(self, "_latent_config", (layout.to_dict(), bool(use_latent), belief_input))
        super().__init__(observation_space, action_space, lr_schedule, *args, **kwargs)
        # A submodule only now, after the networks' optimizers were built without its parameters.
        self.latent_model = LatentModel(layout) if use_latent else None
        self.to(self.device)

    def make_features_extractor(self) -> BeliefFeaturesExtractor:
        """``policy_kwargs``' features extractor (default: none) over the environment's observation, then the belief
        in the form ``belief_input`` names (dropped when ``use_latent=False``, the no-latent ablation)."""
        layout = self.latent_layout
        _, use_latent, belief_input = self._latent_config
        # (the belief wrapper's observations are a flat Box)
        return BeliefFeaturesExtractor(cast(spaces.Box, self.observation_space), layout.obs_dim, self.features_extractor_class,
                                       self.features_extractor_kwargs, keep=layout.total_dim if use_latent else layout.obs_dim,
                                       belief_input=belief_input)

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        latent_layout, use_latent, belief_input = self._latent_config
        data.update(latent_layout=latent_layout, use_latent=use_latent, belief_input=belief_input)
        return data


class LatentActorCriticPolicy(LatentPolicyMixin, ConditionedPolicyMixin, ActorCriticPolicy):
    """SB3's ``ActorCriticPolicy`` whose policy and value networks see the belief (EM-PPO), read as
    ``belief_conditioning`` says (:mod:`sb3_emmarl.common.appended.conditioning`).

    Takes ``ActorCriticPolicy``'s arguments plus ``latent_layout`` (set by the algorithm), ``use_latent``,
    ``belief_input`` and ``belief_conditioning``.
    """

    features_extractor: BeliefFeaturesExtractor

    def context_width(self) -> int:
        """The belief's features (none without a latent model)."""
        return self.features_extractor.belief_width if self._latent_config[1] else 0


class LatentTD3Policy(LatentPolicyMixin, ConditionedTD3Mixin, TD3Policy):
    """SB3's ``TD3Policy`` whose actor and critics (and their targets) see the belief (EM-DDPG), read as
    ``belief_conditioning`` says (:mod:`sb3_emmarl.common.appended.conditioning`).

    Takes ``TD3Policy``'s arguments plus ``latent_layout``, ``use_latent``, ``belief_input`` and ``belief_conditioning``
    (see :class:`LatentActorCriticPolicy`).
    """

    def context_width(self) -> int:
        """The belief's features (none without a latent model), as the actor's and the critics' extractors give them
        (TD3's policy keeps no extractor of its own)."""
        return self.make_features_extractor().belief_width if self._latent_config[1] else 0
