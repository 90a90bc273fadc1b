"""The reserve's evidence for the latent model: its compact features and its reading counts (a plug-in).

The reserve's poacher strategy shows in where its signs lie (snares around the dens, vehicles along the road's side,
one camp, scattered traces) and the weather in how far the sensors read (see the environment's documentation of
signs). :class:`ReserveEvidence` gives the latent model (:mod:`~sb3_emmarl.common.latent.evidence`) two readings of
the reserve's flat observations:

- **features** (:func:`reserve_features`, ``d_x = 37`` at the default size): what the hidden mode changes, whose
  transitions the decoder models;
- **reading counts** (:class:`ReadingCounter`): for each step of a UAV, the readings of three window channels
  (signs, leopards, poachers) by *bin*: the block of the coarse ``belief_size x belief_size`` map the cell lies in,
  times the cell's ring (Chebyshev distance from the UAV, ``0..r``); and each bin's *exposure*: the window cells of
  the bin inside the map, each weighted by its visual transparency (``1 -`` the occlusion channel). The latent
  model's Poisson term (:mod:`~sb3_emmarl.common.latent.counts`) reads them: the transition mixture reads features
  that count readings in the window but cannot say where on the map they were made; fitted even *told* the mode,
  it tells the mode about half of the time from a whole team's evidence at mid-episode
  (``docs/lab/studies/mixture_ceiling.py``). The counts say where, and nothing else.

A sign read from consecutive steps is counted each time (the UAV moves at most ``uav_speed`` cells), so the
independence of the Poisson model overstates the evidence: the beliefs and the E-step weigh it by
:data:`COUNT_EVIDENCE_WEIGHT`. The bins are blocks x rings, so the rates can factor as where (the strategy) x how far
(the weather): EM-PPO's ``count_factors``.

Registered when ``sb3_emmarl`` is imported: it lives beside ``common/latent``, not in it, so that the generic latent
machinery knows nothing of the reserve, and in an existing package, so that the wheel's package list is unchanged.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
from numba import njit
from stable_baselines3.common.vec_env import VecEnv

from sb3_emmarl.common.latent.evidence import LatentEvidence, env_attribute, observation_size
from sb3_emmarl.common.latent.features import FeatureFn
from wildlife_reserve.reserve.kernels.constants import CH_LEOPARD, CH_OCCLUSION, CH_POACHER, CH_SIGN, CH_UAV

#: The window channels counted, in order: signs of poacher activity, leopards, poachers.
COUNTED_CHANNELS = ("sign", "leopard", "poacher")
#: The factor on the count log-likelihood in EM-PPO's beliefs and E-step responsibilities (the count model's
#: ``1 / temperature``): a reading is counted from about three consecutive steps. With the model fitted online, as
#: the E-step fits it, on 400 random-patrol episodes (docs/lab/studies/mixture_ceiling.py's episodes; an ad-hoc script, not
#: kept): a team's mid-episode accuracy 0.65 at 1/3, 0.63 at 1 and 0.48 at 1/10.
COUNT_EVIDENCE_WEIGHT = 1.0 / 3.0


class WindowGeometry(NamedTuple):
    """Where the cells of a reserve's observation window lie, for the compiled kernels: the observation's ``own`` part
    (row, column scaled to [0, 1]) and ``window`` part start at these columns; the window's ``occlusion`` channel and
    the counted ``channels`` ``(C,)``; the grid's ``height`` and ``width``; ``blocks``, the flat padded table of each
    cell's block (-1 off the map), ``width_padded`` wide; each window cell's flat ``offsets`` into it and its ``ring``
    ``(w * w,)``; the rings per block ``n_rings``.

    The kernels take it as a plain tuple and name it inside (``WindowGeometry(*geometry)``, at no cost): numba types a
    plain tuple argument in its C fast path and a named one in Python at every call."""

    own: int
    window: int
    occlusion: int
    channels: np.ndarray
    height: int
    width: int
    blocks: np.ndarray
    width_padded: int
    offsets: np.ndarray
    ring: np.ndarray
    n_rings: int


@njit(cache=True)
def _window_bins(observations: np.ndarray, i: int, geometry: WindowGeometry,
                 bins: np.ndarray) -> None:  # pragma: no cover (compiled)
    """Each window cell's bin of observation ``i`` into ``bins`` ``(w * w,)``, -1 off the map (see
    :meth:`ReadingCounter.cells`: the UAV's cell is its position floored, as the reserve places its window)."""
    height, width, own = geometry.height, geometry.width, geometry.own
    row = min(max(int(np.floor(np.float64(observations[i, own]) * (height - 1))), 0), height - 1)
    col = min(max(int(np.floor(np.float64(observations[i, own + 1]) * (width - 1))), 0), width - 1)
    corner = row * geometry.width_padded + col
    blocks, offsets, ring, n_rings = geometry.blocks, geometry.offsets, geometry.ring, geometry.n_rings
    for c in range(offsets.shape[0]):
        block = blocks[corner + offsets[c]]
        bins[c] = -1 if block < 0 else block * n_rings + ring[c]


@njit(cache=True)
def _count_log_likelihood(observations: np.ndarray, plain: tuple,
                          table: np.ndarray) -> np.ndarray:  # pragma: no cover (compiled)
    """``ReadingCounter.binned(*cells(observations))`` times ``table`` ``(1 + channels, bins, K)`` summed over parts and
    bins, row by row, without the binned arrays (the belief's one call per step); ``plain``: a
    :class:`WindowGeometry` as a plain tuple."""
    geometry = WindowGeometry(*plain)
    window, occlusion, channels = geometry.window, geometry.occlusion, geometry.channels
    n, k, cells = observations.shape[0], table.shape[2], geometry.offsets.shape[0]
    out = np.zeros((n, k))
    bins = np.empty(cells, dtype=np.int64)
    for i in range(n):
        _window_bins(observations, i, geometry, bins)
        for c in range(cells):
            b = bins[c]
            if b < 0:
                continue
            seen = 1.0 - observations[i, window + occlusion * cells + c]
            for j in range(k):
                out[i, j] += seen * table[0, b, j]
            for p in range(channels.shape[0]):
                if observations[i, window + channels[p] * cells + c] > 0.5:
                    for j in range(k):
                        out[i, j] += table[1 + p, b, j]
    return out


@njit(cache=True)
def _grouped_counts(observations: np.ndarray, groups: np.ndarray, out: np.ndarray,
                    plain: tuple) -> np.ndarray:  # pragma: no cover (compiled)
    """``ReadingCounter.binned(*cells(observations), groups)`` without the off-map bin, in one pass, added to ``out``
    ``(n_groups, 1 + channels, n_bins)`` (returned); rows of a negative group are skipped; ``plain``: a
    :class:`WindowGeometry` as a plain tuple."""
    geometry = WindowGeometry(*plain)
    window, occlusion, channels = geometry.window, geometry.occlusion, geometry.channels
    cells = geometry.offsets.shape[0]
    bins = np.empty(cells, dtype=np.int64)
    for i in range(observations.shape[0]):
        g = groups[i]
        if g < 0:
            continue
        _window_bins(observations, i, geometry, bins)
        for c in range(cells):
            b = bins[c]
            if b < 0:
                continue
            out[g, 0, b] += 1.0 - observations[i, window + occlusion * cells + c]
            for p in range(channels.shape[0]):
                if observations[i, window + channels[p] * cells + c] > 0.5:
                    out[g, 1 + p, b] += 1.0
    return out


class ReadingCounter:
    """Per-step reading counts and exposures by (block, ring) bin, from the reserve's flat observations.

    :param observation_layout: the reserve's ``observation_layout`` (name -> (slice, shape)); it needs
        ``window`` (channels, w, w) and ``own`` (row, col, ... scaled to [0, 1])
    :param grid_shape: ``(height, width)`` of the reserve's grid
    :param belief_size: side of the coarse maps (the blocks)
    """

    #: the count log-likelihood's factor in the beliefs and the E-step (:data:`COUNT_EVIDENCE_WEIGHT`)
    weight = COUNT_EVIDENCE_WEIGHT

    def __init__(self, observation_layout: dict, grid_shape: tuple[int, int], belief_size: int) -> None:
        for name in ("window", "own"):
            if name not in observation_layout:
                raise ValueError(f"observation_layout must have a {name!r} part, got parts {sorted(observation_layout)}")
        height, width = (int(side) for side in grid_shape)
        if height < 1 or width < 1:
            raise ValueError(f"grid_shape must be two sides >= 1, got {grid_shape}")
        if isinstance(belief_size, bool) or not isinstance(belief_size, (int, np.integer)) or \
                not 1 <= belief_size <= min(height, width):
            raise ValueError(f"belief_size must be an int in [1, {min(height, width)}], got {belief_size!r}")
        self.window_part, (n_channels, w, _) = observation_layout["window"]
        self.own_part = observation_layout["own"][0]
        self.height, self.width, self.belief_size, self.r = height, width, int(belief_size), w // 2
        self.channels = tuple({"sign": CH_SIGN, "leopard": CH_LEOPARD, "poacher": CH_POACHER}[name]
                              for name in COUNTED_CHANNELS)
        if max(self.channels) >= n_channels:
            raise ValueError(f"the window needs channels {self.channels}, it has {n_channels}")
        self.occlusion = CH_OCCLUSION
        self.n_rings = self.r + 1
        self.n_bins = self.belief_size**2 * self.n_rings
        # Every window cell's bin as one table lookup: table[row + r + d_row, col + r + d_col] for the UAV at (row,
        # col) is the block of the cell (as the reserve's coarse maps place it) times its ring, -1 off the map.
        rows = np.arange(height) * self.belief_size // height
        cols = np.arange(width) * self.belief_size // width
        blocks = np.full((height + 2 * self.r, width + 2 * self.r), -1, dtype=np.int64)
        blocks[self.r:self.r + height, self.r:self.r + width] = rows[:, None] * self.belief_size + cols[None, :]
        offsets = np.indices((w, w)).reshape(2, -1)  # (2, w * w): a window cell's place in the padded table
        ring = np.abs(offsets - self.r).max(axis=0)
        self._blocks, self._ring = blocks, ring
        self._width_padded = blocks.shape[1]
        self._flat_offsets = offsets[0] * blocks.shape[1] + offsets[1]  # (w * w,)
        # What the compiled kernels need to place and read every window cell (a plain tuple: see WindowGeometry).
        self._geometry = tuple(WindowGeometry(self.own_part.start, self.window_part.start, self.occlusion,
                                              np.array(self.channels, dtype=np.int64), height, width, blocks.ravel(),
                                              self._width_padded, self._flat_offsets, ring, self.n_rings))

    @classmethod
    def from_env(cls, env: Any) -> ReadingCounter:
        """The counter of a reserve (``ReserveParallelEnv``, or anything with its ``observation_layout``, ``height``,
        ``width`` and ``config.belief_size``).

        :param env: the reserve
        """
        return cls(env.observation_layout, (env.height, env.width), env.config.belief_size)

    @property
    def n_channels(self) -> int:
        return len(self.channels)

    def _checked(self, observations: np.ndarray) -> np.ndarray:
        observations = np.asarray(observations)
        if observations.ndim != 2 or observations.shape[1] < self.own_part.stop:
            raise ValueError(f"observations must be (n, obs_dim >= {self.own_part.stop}), got shape {observations.shape}")
        return observations

    def cells(self, observations: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Each window cell's bin (``n_bins`` off the map) ``(n, w * w)``, its exposure ``(n, w * w)`` (transparency, 0
        off the map) and its readings ``(n, n_channels, w * w)`` (bool: the channel above 0.5; the channels are 0/1
        without sensor noise).

        :param observations: ``(n, obs_dim)`` flat observations of the reserve
        """
        observations = self._checked(observations)
        n = len(observations)
        # The UAV's cell is its position floored, as the reserve places its window. The observation holds the
        # position scaled to [0, 1] in float32, which cannot tell a position on a cell's edge from one a hair below
        # (where the reserve's bounds hold UAVs): on random patrols 7% of the cells found are one off, the bins of
        # their windows shifted by a cell; the fit and the beliefs read them alike.
        own = observations[:, self.own_part.start:self.own_part.start + 2].astype(np.float64)
        row = np.clip(np.floor(own[:, 0] * (self.height - 1)), 0, self.height - 1).astype(np.int64)
        col = np.clip(np.floor(own[:, 1] * (self.width - 1)), 0, self.width - 1).astype(np.int64)
        corner = row * self._width_padded + col  # the window's top-left cell in the padded table
        block = self._blocks.ravel()[corner[:, None] + self._flat_offsets[None]]
        inside = block >= 0
        bins = np.where(inside, block * self.n_rings + self._ring[None], self.n_bins)
        window = observations[:, self.window_part].reshape(n, -1, self._ring.size)
        exposure = np.where(inside, 1.0 - window[:, self.occlusion], 0.0)
        readings = (window[:, list(self.channels)] > 0.5) & inside[:, None, :]
        return bins, exposure, readings

    def __call__(self, observations: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Counts ``(n, n_channels, n_bins)`` and exposures ``(n, n_bins)`` of the readings in each observation.

        :param observations: ``(n, obs_dim)`` flat observations of the reserve
        """
        summed = self.binned(*self.cells(observations))
        return summed[:, 1:, :self.n_bins], summed[:, 0, :self.n_bins]

    def log_likelihood(self, observations: np.ndarray, table: np.ndarray) -> np.ndarray:
        """``(n, K)``: each observation's exposures and counts by bin (:meth:`binned`) times a ``(1 + n_channels,
        n_bins, K)`` table (minus the rates, then each channel's log-rates), summed: the count log-likelihood of one
        step, in one compiled call."""
        observations = np.ascontiguousarray(self._checked(observations), dtype=np.float32)
        return _count_log_likelihood(observations, self._geometry, np.ascontiguousarray(table, dtype=np.float64))

    def grouped(self, observations: np.ndarray, groups: np.ndarray, n_groups: int | None = None,
                out: np.ndarray | None = None) -> np.ndarray:
        """The exposures and counts of the observations in each group, by bin: ``(G, 1 + n_channels, n_bins)``, what
        :meth:`binned` of :meth:`cells` gives with ``groups`` (without the off-map bin), in one compiled pass (the
        E-step's per-episode sums of a rollout).

        :param observations: ``(n, d)`` flat observations of the reserve (``d >= obs_dim``: columns after the
            observation, as the beliefs of augmented observations, are not read, so no copy is made of them)
        :param groups: ``(n,)`` ints in ``[0, n_groups)``, or -1 for a row to skip
        :param n_groups: ``G`` (None: ``max(groups) + 1``, or ``len(out)``)
        :param out: a float64 ``(G, 1 + n_channels, n_bins)`` array to add the sums to (returned), or None (zeros): the
            sums of several blocks of rows, added in turn, equal those of the stacked blocks to the bit
        """
        observations = np.ascontiguousarray(self._checked(observations), dtype=np.float32)
        groups = np.asarray(groups, dtype=np.int64).reshape(-1)
        if len(groups) != len(observations):
            raise ValueError(f"groups must have one entry per observation ({len(observations)}), got {len(groups)}")
        if n_groups is None:
            n_groups = len(out) if out is not None else (int(groups.max()) + 1 if len(groups) else 0)
        n_groups = int(n_groups)
        if len(groups) and (groups.min() < -1 or groups.max() >= n_groups):
            raise ValueError(f"groups must lie in [0, {n_groups}) or be -1 (skipped), got [{groups.min()}, "
                             f"{groups.max()}]")
        shape = (n_groups, 1 + self.n_channels, self.n_bins)
        if out is None:
            out = np.zeros(shape)
        elif out.shape != shape or out.dtype != np.float64:
            raise ValueError(f"out must be a float64 array of shape {shape}, got {out.dtype} {out.shape}")
        return _grouped_counts(observations, groups, out, self._geometry)

    def binned(self, bins: np.ndarray, exposure: np.ndarray, readings: np.ndarray,
               groups: np.ndarray | None = None) -> np.ndarray:
        """:meth:`cells` summed by bin: ``(n, 1 + n_channels, n_bins + 1)``, the exposures then each channel's counts,
        the last bin holding what lay off the map; with ``groups`` (``(n,)`` ints in ``[0, G)``), summed by group too:
        ``(G, 1 + n_channels, n_bins + 1)``."""
        n, size, parts = len(bins), self.n_bins + 1, 1 + self.n_channels
        weights = np.concatenate([exposure[:, None], readings], axis=1)  # (n, 1 + channels, w * w)
        unit = np.arange(n) if groups is None else np.asarray(groups, dtype=np.int64)
        n_units = n if groups is None else (int(unit.max()) + 1 if n else 0)
        index = ((unit[:, None, None] * parts + np.arange(parts)[None, :, None]) * size + bins[:, None, :]).ravel()
        return np.bincount(index, weights=weights.ravel(), minlength=n_units * parts * size).reshape(n_units, parts, size)


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


def layout_from_spec(spec: dict[str, Any]) -> dict[str, tuple[slice, tuple[int, ...]]]:
    """The reserve's ``observation_layout`` (name -> (slice, shape)) as a :class:`ReserveEvidence` specification
    records it."""
    return {name: (slice(start, stop), tuple(shape)) for name, (start, stop, shape) in spec["layout"].items()}


class ReserveEvidence(LatentEvidence):
    """The reserve's evidence: :func:`reserve_features` and, when the specification knows the grid (models saved
    before the count model do not), the :class:`ReadingCounter` as its counts.

    :param spec: ``kind`` ``"reserve"``, ``obs_dim``, the observation's ``layout`` (name -> ``[start, stop, shape]``)
        and the grid's sides ``grid`` ``[height, width]``
    """

    kind = "reserve"

    def __init__(self, spec: dict[str, Any]) -> None:
        super().__init__(spec)
        layout = layout_from_spec(spec)
        self._fn = reserve_features(layout)
        self.feature_dim = int(self._fn(np.zeros((1, self.obs_dim), dtype=np.float32)).shape[1])
        self.counts = ReadingCounter(layout, tuple(spec["grid"]), int(layout["belief"][1][0])) if "grid" in spec else None

    @classmethod
    def from_env(cls, venv: VecEnv) -> ReserveEvidence | None:
        """The reserve's (an environment whose ``observation_layout`` has a ``window``, ``own`` and ``belief`` part)."""
        layout = env_attribute(venv, "observation_layout")
        if not (isinstance(layout, dict) and {"window", "own", "belief"} <= set(layout)):
            return None
        spec: dict[str, Any] = {"kind": cls.kind, "obs_dim": observation_size(venv),
                                "layout": {name: [part.start, part.stop, list(shape)] for name, (part, shape) in
                                           layout.items()}}
        grid = [env_attribute(venv, side) for side in ("height", "width")]
        if None not in grid:  # the grid's sides place each window cell on the map, for the reading counts
            spec["grid"] = [int(side) for side in grid]
        return cls(spec)

    def features(self, observations: np.ndarray) -> np.ndarray:
        return self._fn(observations)
