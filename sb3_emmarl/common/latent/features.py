"""What the latent model reads of each step: compact features of the observation and the encoded action.

The decoder ``p(x_{t+1} | x_t, a_t, z)`` models compact features ``x`` of the observation rather than the
raw observation: the reserve's own summary (:func:`reserve_features`) on the reserve, otherwise the
observation itself when small or a fixed random projection of it (:func:`generic_features`).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.vec_env import VecEnv

#: Observations larger than this are reduced to this many compact features by a fixed projection.
MAX_GENERIC_FEATURES = 32

FeatureFn = Callable[[np.ndarray], np.ndarray]


def product(x: np.ndarray, weight: th.Tensor, bias: th.Tensor | None = None) -> np.ndarray:
    """``x @ weight (+ bias)`` for the small float32 products of the per-step belief, through torch.

    Not numpy's ``@``: numpy's OpenBLAS starts worker threads for products of a few dozen rows and they keep
    spinning between calls (measured: 16% of a second core over a whole EM-PPO run, for no speed), where torch's
    matrix product obeys ``torch.set_num_threads`` as the networks do.

    :param x: ``(n, a)`` float32 array
    :param weight: ``(a, b)`` float32 tensor on the CPU
    :param bias: ``(b,)`` float32 tensor, or None
    """
    with th.inference_mode():
        rows = th.from_numpy(np.ascontiguousarray(x, dtype=np.float32))
        return (th.mm(rows, weight) if bias is None else th.addmm(bias, rows, weight)).numpy()


def reserve_features(layout: dict) -> FeatureFn:
    """Compact features of the reserve's observation: what the hidden mode changes (37 by default).

    Counts of poacher, leopard and sign readings in the window, capped at 5 and scaled to [0, 1], and the share
    of poacher and leopard readings on its outer ring (4); other UAVs in the window (1); the belief map and the
    map of known signs, each pooled 2 x 2 by max (16 + 16 on the default 8 x 8 maps). The sign readings and
    the sign map are where the poacher strategy shows, the readings where the weather does (see the
    environment's documentation of signs). The UAV's own position, velocity and battery are left out: they
    follow from its actions in every mode alike, and modelling them would only add noise to the evidence.

    :param layout: the reserve's ``observation_layout`` (name -> (slice, shape))
    """
    from wildlife_reserve.reserve.constants import CH_LEOPARD, CH_POACHER, CH_SIGN, CH_UAV

    window_part, window_shape = layout["window"]
    maps = [layout[name] for name in ("belief", "signs") if name in layout]
    channels, width = window_shape[0], window_shape[1]
    r = width // 2
    ring = (np.maximum(*np.abs(np.indices((width, width)) - r)) == r).ravel()
    read = [c for c in (CH_POACHER, CH_LEOPARD, CH_SIGN) if c < channels]
    # Every count is a sum of readings (> 0.5) over some window cells: one product with a 0/1 matrix over the
    # window gives them all (columns: each read channel's count, the animals' count on the outer ring, the UAVs).
    cells = width * width
    counting = th.zeros((channels * cells, len(read) + 2), dtype=th.float32)
    for column, channel in enumerate(read):
        counting[channel * cells:(channel + 1) * cells, column] = 1.0
    for channel in read[:2]:  # poachers and leopards
        counting[channel * cells:(channel + 1) * cells, len(read)] = th.from_numpy(ring.astype(np.float32))
    if CH_UAV < channels:
        counting[CH_UAV * cells:(CH_UAV + 1) * cells, len(read) + 1] = 1.0

    def pool(values: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
        n, (h, w) = len(values), shape
        grid = values.reshape(n, h, w)
        if h % 2 or w % 2:
            grid = np.pad(grid, ((0, 0), (0, h % 2), (0, w % 2)))
        pooled = np.maximum(np.maximum(grid[:, 0::2, 0::2], grid[:, 0::2, 1::2]),
                            np.maximum(grid[:, 1::2, 0::2], grid[:, 1::2, 1::2]))
        return pooled.reshape(n, -1)

    def features(obs: np.ndarray) -> np.ndarray:
        counts = product((obs[:, window_part] > 0.5).astype(np.float32), counting)
        animals = counts[:, :min(len(read), 2)].sum(axis=1)
        outer = counts[:, len(read)] / np.maximum(animals, 1.0)
        return np.concatenate([np.minimum(counts[:, :len(read)], 5.0) / 5.0, outer[:, None],
                               np.minimum(counts[:, -1:], 5.0) / 5.0,
                               *[pool(obs[:, part], shape) for part, shape in maps]], axis=1, dtype=np.float32)

    return features


def generic_features(obs_dim: int, seed: int = 0) -> tuple[FeatureFn, int]:
    """The observation itself when small, else a fixed random projection to :data:`MAX_GENERIC_FEATURES` dims."""
    if obs_dim <= MAX_GENERIC_FEATURES:
        return (lambda obs: obs.astype(np.float32)), obs_dim
    projection = np.random.default_rng(seed).standard_normal((obs_dim, MAX_GENERIC_FEATURES)) / np.sqrt(obs_dim)
    projection = projection.astype(np.float32)
    return (lambda obs: obs.astype(np.float32) @ projection), MAX_GENERIC_FEATURES


def default_features(venv: VecEnv) -> tuple[FeatureFn, dict, int]:
    """The reserve's compact features when ``venv`` is the reserve, otherwise :func:`generic_features`.

    :return: the feature function, its specification (plain values, saved with a model so that
        :func:`features_from_spec` rebuilds the same function without an environment) and ``d_x``
    """
    obs_dim = int(np.prod(venv.observation_space.shape))
    try:
        layout = venv.get_attr("observation_layout", indices=[0])[0]
    except (AttributeError, NotImplementedError):
        layout = None
    if isinstance(layout, dict) and {"window", "own", "belief"} <= set(layout):
        spec = {"kind": "reserve", "obs_dim": obs_dim,
                "layout": {name: [part.start, part.stop, list(shape)] for name, (part, shape) in layout.items()}}
        try:  # the grid's sides place each window cell on the map, for the reading counts
            spec["grid"] = [int(venv.get_attr(side, indices=[0])[0]) for side in ("height", "width")]
        except (AttributeError, NotImplementedError):
            pass
    else:
        spec = {"kind": "generic", "obs_dim": obs_dim}
    fn, dim = features_from_spec(spec)
    return fn, spec, dim


def layout_from_spec(spec: dict) -> dict:
    """The reserve's ``observation_layout`` (name -> (slice, shape)) as a :func:`default_features` specification
    records it."""
    return {name: (slice(start, stop), tuple(shape)) for name, (start, stop, shape) in spec["layout"].items()}


def features_from_spec(spec: dict) -> tuple[FeatureFn, int]:
    """The feature function of a :func:`default_features` specification, and ``d_x``."""
    obs_dim = int(spec["obs_dim"])
    if spec.get("kind") == "reserve":
        fn = reserve_features(layout_from_spec(spec))
        return fn, int(fn(np.zeros((1, obs_dim), dtype=np.float32)).shape[1])
    if spec.get("kind") == "generic":
        return generic_features(obs_dim)
    raise ValueError(f"feature specification kind must be 'reserve' or 'generic', got {spec.get('kind')!r}")


def counter_from_spec(spec: dict):
    """The :class:`~sb3_emmarl.common.latent.counts.ReadingCounter` of a :func:`default_features` specification: one
    on the reserve (when the specification knows its grid: models saved before the count model have none), else
    None."""
    from sb3_emmarl.common.latent.counts import ReadingCounter

    if spec.get("kind") != "reserve" or "grid" not in spec:
        return None
    layout = layout_from_spec(spec)
    return ReadingCounter(layout, tuple(spec["grid"]), int(layout["belief"][1][0]))


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
