"""What the latent model reads of each step, for every environment: the encoded action, and generic features.

The decoder ``p(x_{t+1} | x_t, a_t, z)`` models compact features ``x`` of the observation rather than the raw
observation; an environment's plug-in (:mod:`~sb3_emmarl.common.latent.evidence`) chooses them. Without one, they
are the observation itself when small or a fixed random projection of it (:func:`generic_features`).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from gymnasium import spaces

#: Observations larger than this are reduced to this many compact features by a fixed projection.
MAX_GENERIC_FEATURES = 32

FeatureFn = Callable[[np.ndarray], np.ndarray]


def generic_features(obs_dim: int, seed: int = 0) -> tuple[FeatureFn, int]:
    """The observation itself when small, else a fixed random projection to :data:`MAX_GENERIC_FEATURES` dims."""
    if obs_dim <= MAX_GENERIC_FEATURES:
        return (lambda obs: obs.astype(np.float32)), obs_dim
    projection = np.random.default_rng(seed).standard_normal((obs_dim, MAX_GENERIC_FEATURES)) / np.sqrt(obs_dim)
    projection = projection.astype(np.float32)
    return (lambda obs: obs.astype(np.float32) @ projection), MAX_GENERIC_FEATURES


def encode_actions(action_space: spaces.Space) -> tuple[Callable[[np.ndarray], np.ndarray], int]:
    """How actions enter the window: one-hot (``Discrete``, ``MultiDiscrete``) or as they are (``Box``)."""
    if isinstance(action_space, spaces.Discrete):
        n = int(action_space.n)
        return (lambda a: np.eye(n, dtype=np.float32)[np.asarray(a, dtype=np.int64).reshape(-1) - action_space.start]), n
    if isinstance(action_space, spaces.MultiDiscrete):
        sizes = action_space.nvec.ravel().astype(np.int64)
        offsets = np.concatenate([[0], np.cumsum(sizes)[:-1]])

        def one_hot(a: np.ndarray) -> np.ndarray:
            a = np.asarray(a, dtype=np.int64).reshape(len(a), -1)
            out = np.zeros((len(a), int(sizes.sum())), dtype=np.float32)
            out[np.arange(len(a))[:, None], offsets + a] = 1.0
            return out

        return one_hot, int(sizes.sum())
    if isinstance(action_space, spaces.Box):
        dim = int(np.prod(action_space.shape))
        return (lambda a: np.asarray(a, dtype=np.float32).reshape(len(a), dim)), dim
    raise ValueError(f"the latent model supports Discrete, MultiDiscrete and Box actions, not {action_space}")
