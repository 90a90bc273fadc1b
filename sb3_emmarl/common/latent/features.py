"""What the latent model reads of each step: compact features of the observation and the encoded action.

The decoder ``p(x_{t+1} | x_t, a_t, z)`` models compact features ``x`` of the observation rather than the
raw observation: the reserve's own summary (:func:`reserve_features`) on the reserve, where tracks lie relative to
the zones (:func:`zone_features`) on an environment with a ``zone_map`` (ZonePatrol), otherwise the observation itself
when small or a fixed random projection of it (:func:`generic_features`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np
from gymnasium import spaces
from numba import njit
from stable_baselines3.common.vec_env import VecEnv

if TYPE_CHECKING:
    from sb3_emmarl.common.latent.counts import ReadingCounter

#: Observations larger than this are reduced to this many compact features by a fixed projection.
MAX_GENERIC_FEATURES = 32

FeatureFn = Callable[[np.ndarray], np.ndarray]


@njit(cache=True)
def _reserve_features(obs: np.ndarray, window: int, cells: int, read: np.ndarray, uav: int, ring: np.ndarray,
                      maps: np.ndarray, out: np.ndarray) -> None:  # pragma: no cover (compiled)
    """:func:`reserve_features` of every row of ``obs`` into ``out``, in one pass (see there for what they are)."""
    n_read = read.shape[0]
    for i in range(obs.shape[0]):
        animals, outer = 0.0, 0.0
        for p in range(n_read):
            base, count = window + read[p] * cells, 0.0
            for c in range(cells):
                if obs[i, base + c] > 0.5:
                    count += 1.0
                    if p < 2 and ring[c]:
                        outer += 1.0
            if p < 2:
                animals += count
            out[i, p] = min(count, 5.0) / 5.0
        out[i, n_read] = outer / max(animals, 1.0)
        uavs = 0.0
        if uav >= 0:
            for c in range(cells):
                if obs[i, window + uav * cells + c] > 0.5:
                    uavs += 1.0
        out[i, n_read + 1] = min(uavs, 5.0) / 5.0
        column = n_read + 2
        for m in range(maps.shape[0]):
            start, h, w = maps[m, 0], maps[m, 1], maps[m, 2]
            for a in range(0, h, 2):
                for b in range(0, w, 2):
                    best = -np.inf
                    for da in range(2):
                        for db in range(2):  # cells past an odd side count as 0, as a zero padding would
                            value = obs[i, start + (a + da) * w + b + db] if a + da < h and b + db < w else 0.0
                            best = max(best, value)
                    out[i, column] = best
                    column += 1


def reserve_features(layout: dict) -> FeatureFn:
    """Compact features of the reserve's observation: what the hidden mode changes (37 by default).

    Counts of poacher, leopard and sign readings in the window, capped at 5 and scaled to [0, 1], and the share
    of poacher and leopard readings on its outer ring (4); other UAVs in the window (1); the belief map and the
    map of known signs, each pooled 2 x 2 by max (16 + 16 on the default 8 x 8 maps). The sign readings and
    the sign map are where the poacher strategy shows, the readings where the weather does (see the
    environment's documentation of signs). The UAV's own position, velocity and battery are left out: they
    follow from its actions in every mode alike, and modelling them would only add noise to the evidence.
    One compiled pass over each row (the belief computes them for every agent at every step).

    :param layout: the reserve's ``observation_layout`` (name -> (slice, shape))
    """
    from wildlife_reserve.reserve.constants import CH_LEOPARD, CH_POACHER, CH_SIGN, CH_UAV

    window_part, window_shape = layout["window"]
    channels, width = window_shape[0], window_shape[1]
    r = width // 2
    ring = np.maximum(*np.abs(np.indices((width, width)) - r)).ravel() == r
    read = np.array([c for c in (CH_POACHER, CH_LEOPARD, CH_SIGN) if c < channels], dtype=np.int64)
    maps = np.array([[layout[name][0].start, *layout[name][1]] for name in ("belief", "signs") if name in layout],
                    dtype=np.int64).reshape(-1, 3)
    dim = len(read) + 2 + sum(-(-int(h) // 2) * -(-int(w) // 2) for _, h, w in maps)
    uav = CH_UAV if CH_UAV < channels else -1

    def features(obs: np.ndarray) -> np.ndarray:
        obs = np.asarray(obs, dtype=np.float32)
        out = np.empty((len(obs), dim), dtype=np.float32)
        _reserve_features(obs, window_part.start, width * width, read, uav, ring, maps, out)
        return out

    return features


def zone_features(zone_map: dict) -> tuple[FeatureFn, int]:
    """Compact features of an observation made of an egocentric window and the UAV's cell, on a map with zones where
    the hidden mode puts its events (ZonePatrol's ``zone_map``): ``2 * zones + 2``, by default 10 (14 with
    ZonePatrol's ``zone_cue``).

    Per zone, the window cells of the zone that hold a track (capped at 5, over 5) and the window cells of the zone
    (over the window's cells, the exposure); then the visibility reading as observed, the window's detection cells
    this step and, when the observation has them (``zone_cue``), the zone readings as observed. The zone is where the
    mode shows, so the features say *where* the tracks were seen, which an egocentric window alone does not; the
    visibility is where the weather shows. On ZonePatrol's episodes of the best scripted blind team, EM fitted with
    team pooling tells the mode at mid-episode 0.75 of the time from these features against 0.56 from
    :func:`generic_features` (``docs/lab/2026-12-05/zone_patrol_latent_ceiling.py``, one seed).

    :param zone_map: plain values: ``grid_size``, ``zone_size``, ``window_radius``, ``zone_origins`` (top-left cells),
        the observation's ``tracks``, ``detections`` and ``own`` parts as ``[start, stop]`` (``own``: row and column
        scaled to [-1, 1]), the index of its ``visibility`` and its ``cues`` as ``[start, stop]`` or None
    """
    g, size, r = int(zone_map["grid_size"]), int(zone_map["zone_size"]), int(zone_map["window_radius"])
    origins = np.asarray(zone_map["zone_origins"], dtype=np.int64).reshape(-1, 2)
    n_zones, side = len(origins), 2 * r + 1
    zone_of = np.full((g, g), -1, dtype=np.int64)
    for z, (top, left) in enumerate(origins):
        zone_of[top:top + size, left:left + size] = z
    # The zone of each window cell, for each cell the UAV can be in: (g, g, side * side), -1 off the zones or the map.
    rows, cols = np.indices((g, g))
    da, db = (np.indices((side, side)).reshape(2, -1) - r)
    at_rows, at_cols = rows[..., None] + da, cols[..., None] + db
    inside = (at_rows >= 0) & (at_rows < g) & (at_cols >= 0) & (at_cols < g)
    window_zones = np.where(inside, zone_of[np.clip(at_rows, 0, g - 1), np.clip(at_cols, 0, g - 1)], -1)
    tracks, detections, own = (slice(*zone_map[part]) for part in ("tracks", "detections", "own"))
    cues = slice(*zone_map["cues"]) if zone_map.get("cues") else slice(0, 0)
    visibility, n_cues = int(zone_map["visibility"]), cues.stop - cues.start
    dim = 2 * n_zones + 2 + n_cues

    def features(obs: np.ndarray) -> np.ndarray:
        obs = np.asarray(obs, dtype=np.float32)
        cell = np.clip(np.rint((obs[:, own] + 1.0) / 2.0 * (g - 1)).astype(np.int64), 0, g - 1)
        zones = window_zones[cell[:, 0], cell[:, 1]]  # (N, side * side)
        marked = obs[:, tracks] > 0
        out = np.empty((len(obs), dim), dtype=np.float32)
        for z in range(n_zones):
            here = zones == z
            out[:, z] = np.minimum((marked & here).sum(1), 5) / 5.0
            out[:, n_zones + z] = here.sum(1) / (side * side)
        out[:, 2 * n_zones] = obs[:, visibility]
        out[:, 2 * n_zones + 1] = (obs[:, detections] > 0).sum(1)
        out[:, 2 * n_zones + 2:] = obs[:, cues]
        return out

    return features, dim


def generic_features(obs_dim: int, seed: int = 0) -> tuple[FeatureFn, int]:
    """The observation itself when small, else a fixed random projection to :data:`MAX_GENERIC_FEATURES` dims."""
    if obs_dim <= MAX_GENERIC_FEATURES:
        return (lambda obs: obs.astype(np.float32)), obs_dim
    projection = np.random.default_rng(seed).standard_normal((obs_dim, MAX_GENERIC_FEATURES)) / np.sqrt(obs_dim)
    projection = projection.astype(np.float32)
    return (lambda obs: obs.astype(np.float32) @ projection), MAX_GENERIC_FEATURES


def default_features(venv: VecEnv) -> tuple[FeatureFn, dict, int]:
    """The reserve's compact features when ``venv`` is the reserve, :func:`zone_features` when its environment has a
    ``zone_map`` (ZonePatrol), otherwise :func:`generic_features`.

    :return: the feature function, its specification (plain values, saved with a model so that
        :func:`features_from_spec` rebuilds the same function without an environment) and ``d_x``
    """
    assert venv.observation_space.shape is not None  # (a Box)
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
        try:
            zone_map = venv.get_attr("zone_map", indices=[0])[0]
        except (AttributeError, NotImplementedError):
            zone_map = None
        spec = ({"kind": "zones", "obs_dim": obs_dim, "zone_map": zone_map} if isinstance(zone_map, dict)
                else {"kind": "generic", "obs_dim": obs_dim})
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
    if spec.get("kind") == "zones":
        return zone_features(spec["zone_map"])
    if spec.get("kind") == "generic":
        return generic_features(obs_dim)
    raise ValueError(f"feature specification kind must be 'reserve', 'zones' or 'generic', got {spec.get('kind')!r}")


def counter_from_spec(spec: dict) -> ReadingCounter | None:
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
