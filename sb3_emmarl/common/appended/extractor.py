"""The features extractor of observations with values appended (:class:`SplitFeaturesExtractor`)."""

from __future__ import annotations

from typing import Any

import torch as th
from gymnasium import spaces
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor, FlattenExtractor


class SplitFeaturesExtractor(BaseFeaturesExtractor):
    """Any SB3 features extractor over the first ``head_dim`` values of a flat observation; the values from
    ``head_dim`` to ``keep`` are appended to its features unchanged.

    How the algorithms that append to the environment's observation (the EM algorithms their belief, MAPPO its
    global state and agent id) take a user's ``features_extractor_class``: the extractor sees the environment's
    observation, as it would under PPO, and the networks after it see the extractor's features and the rest.
    (SB3 has no such composition; its ``CombinedExtractor`` needs a ``Dict`` observation space.)

    :param observation_space: the augmented observation space (a flat ``Box``)
    :param head_dim: values read by the inner extractor (the environment's observation)
    :param extractor_class: the inner extractor's class (SB3's ``FlattenExtractor`` passes the values through)
    :param extractor_kwargs: its keyword arguments
    :param keep: values kept in all (default: every value; ``keep = head_dim`` drops the rest)
    """

    def __init__(self, observation_space: spaces.Box, head_dim: int,
                 extractor_class: type[BaseFeaturesExtractor] = FlattenExtractor,
                 extractor_kwargs: dict[str, Any] | None = None, keep: int | None = None) -> None:
        if not isinstance(observation_space, spaces.Box) or len(observation_space.shape) != 1:
            raise ValueError(f"observation_space must be a flat Box, got {observation_space}")
        total = int(observation_space.shape[0])
        keep = total if keep is None else int(keep)
        if not 0 < int(head_dim) <= keep <= total:
            raise ValueError(f"need 0 < head_dim <= keep <= {total} (the observation's length), "
                             f"got head_dim={head_dim}, keep={keep}")
        head_space = spaces.Box(observation_space.low[:head_dim], observation_space.high[:head_dim],
                                dtype=observation_space.dtype)
        inner = extractor_class(head_space, **(extractor_kwargs or {}))
        super().__init__(observation_space, inner.features_dim + keep - int(head_dim))
        self.inner, self.head_dim, self.keep = inner, int(head_dim), keep
        # SB3's FlattenExtractor is the identity on a flat Box: then the features are a view of the observations.
        self._pass_through = type(inner) is FlattenExtractor

    def forward(self, observations: th.Tensor) -> th.Tensor:
        if self._pass_through:
            return observations[..., :self.keep]
        features = self.inner(observations[..., :self.head_dim])
        if self.keep == self.head_dim:
            return features
        return th.cat([features, observations[..., self.head_dim:self.keep]], dim=-1)
