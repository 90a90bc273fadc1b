"""Reading counts: a mixture of Poisson models of what the UAVs read *where*, fitted by EM in closed form.

The reserve's poacher strategy shows in where its signs lie (snares around the dens, vehicles along the road's
side, one camp, scattered traces) and the weather in how far the sensors read (see the environment's
documentation of signs). EM-PPO's transition mixture (:mod:`~sb3_emmarl.common.latent.model`) reads compact
features that count readings in the window but cannot say where on the map they were made; fitted even *told*
the mode, it tells the mode about half of the time from a whole team's evidence at mid-episode
(``benchmarks/mixture_ceiling.py``). This model says where, and nothing else.

For each step of a UAV, :class:`ReadingCounter` counts the readings of three window channels (signs, leopards,
poachers) by *bin*: the block of the coarse ``belief_size x belief_size`` map the cell lies in, times the cell's
ring (Chebyshev distance from the UAV, ``0..r``); and each bin's *exposure*: the window cells of the bin inside
the map, each weighted by its visual transparency (``1 -`` the occlusion channel). Under component ``k`` a bin's
count is Poisson with mean ``exposure * rate[k, channel, bin]``, independently over bins and steps.

Counts and exposures add over steps, so a UAV's (or a team's) evidence up to any step is the sum of its steps',
and the log-likelihood is linear in it: ``sum counts * log(rate) - exposure * rate`` (the ``log(count!)`` term
is the same for every component and left out). The exact posterior of a per-episode ``z`` is therefore a
softmax of a product of the summed statistics with ``log(rate)`` and ``rate``, at constant cost per step.

A sign read from consecutive steps is counted each time (the UAV moves at most ``uav_speed`` cells), so the
independence assumption overstates the evidence; ``temperature`` divides the log-likelihood, as EM-PPO's
``likelihood_temperature`` does for the transition model. The posterior's argmax does not depend on it; EM's fit
does, and EM-PPO weighs the count evidence by :data:`COUNT_EVIDENCE_WEIGHT` in its beliefs and responsibilities.

EM (:meth:`PoissonMixture.fit`): responsibilities are the posterior of each training unit (an episode's team or
UAV), the rates ``(sum_n r_nk counts_n + a * pooled) / (sum_n r_nk exposure_n + a)`` (a Gamma prior worth ``a``
cells of exposure at the channel's pooled rate keeps bins never seen finite) and the prior the mean
responsibilities, all in closed form. The counts of a whole episode run into the thousands, so plain EM makes
its assignments hard at once and stops in a poor optimum; deterministic annealing (the log-likelihood divided
by a temperature falling geometrically from ``anneal_from`` to ``temperature``) and restarts keep the best of
several fits by their log-evidence.

EM-PPO, EM-DDPG and VDN+EM add this model's evidence to their transition model's on the reserve: the belief
(``belief.py``) adds each new observation's count log-likelihood, the E-step (``em.py``) reads each episode's
counts in the responsibilities and sets the rates in closed form from running sums, as :meth:`PoissonMixture.m_step`
does from a batch.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from scipy.special import logsumexp, softmax

#: The window channels counted, in order: signs of poacher activity, leopards, poachers.
COUNTED_CHANNELS = ("sign", "leopard", "poacher")
#: The factor on the count log-likelihood in EM-PPO's beliefs and E-step responsibilities (the count model's
#: ``1 / temperature``): a reading is counted from about three consecutive steps. With the model fitted online, as
#: the E-step fits it, on 400 random-patrol episodes (benchmarks/mixture_ceiling.py's episodes; an ad-hoc script, not
#: kept): a team's mid-episode accuracy 0.65 at 1/3, 0.63 at 1 and 0.48 at 1/10.
COUNT_EVIDENCE_WEIGHT = 1.0 / 3.0
#: ``a``: the Gamma prior on the rates, in cells of exposure at the channel's pooled rate.
PRIOR_EXPOSURE = 1.0


def closed_form_rates(counts: np.ndarray, exposure: np.ndarray, pooled: np.ndarray,
                      prior_exposure: float = PRIOR_EXPOSURE) -> np.ndarray:
    """The M-step's rates ``(K, channels, bins)``: ``(counts + a * pooled) / (exposure + a)``.

    :param counts: responsibility-weighted sums of counts ``(K, channels, bins)``
    :param exposure: responsibility-weighted sums of exposures ``(K, bins)``
    :param pooled: each channel's rate over all the data ``(channels,)`` (the prior's centre; floored at 1e-12)
    :param prior_exposure: ``a``
    """
    pooled = np.maximum(np.asarray(pooled, dtype=np.float64), 1e-12)
    return (counts + prior_exposure * pooled[None, :, None]) / (exposure[:, None, :] + prior_exposure)


#: Rounds of the factored rates' coordinate ascent (each factor in closed form given the other); the fits of
#: ``benchmarks/mixture_ceiling.py`` are the same at 3 and at 10.
FACTOR_ROUNDS = 3


def check_factors(factors: tuple[int, int] | None, n_components: int) -> tuple[int, int] | None:
    """``factors`` as a pair of ints >= 1 whose product is ``n_components``, or None; else a ValueError."""
    if factors is None:
        return None
    if not isinstance(factors, (list, tuple)) or len(factors) != 2 or any(
            isinstance(f, bool) or not isinstance(f, (int, np.integer)) or f < 1 for f in factors):
        raise ValueError(f"count_factors must be null or two ints >= 1 (where x how far), got {factors!r}")
    if factors[0] * factors[1] != n_components:
        raise ValueError(f"count_factors {list(factors)} must multiply to n_components = {n_components}")
    return int(factors[0]), int(factors[1])


def check_rings(n_rings: int, n_bins: int, name: str = "n_rings") -> int:
    """``n_rings`` as an int >= 1 that divides ``n_bins`` (bins are blocks x rings), else a ValueError naming ``name``."""
    if isinstance(n_rings, bool) or not isinstance(n_rings, (int, np.integer)) or n_rings < 1 or n_bins % n_rings:
        raise ValueError(f"{name} must be an int >= 1 that divides the {n_bins} bins, got {n_rings!r}")
    return int(n_rings)


def factored_rates(counts: np.ndarray, exposure: np.ndarray, pooled: np.ndarray, factors: tuple[int, int],
                   n_rings: int, prior_exposure: float = PRIOR_EXPOSURE, rounds: int = FACTOR_ROUNDS) -> np.ndarray:
    """The rates of a *factored* mixture from responsibility-weighted sums: component ``k = i * F2 + j`` has
    ``rate[k, c, (block, ring)] = exp(a[i, c, block] + b[j, c, ring])``, where readings are made depending on the
    first factor and how far from the UAV on the second (on the reserve: the poacher strategy decides where its
    signs lie, the weather how far the sensors read; mode ``m`` is strategy ``m // 2`` and weather ``m % 2``).

    Poisson maximum likelihood of a log-linear model by coordinate ascent, each factor in closed form given the
    other (iterative proportional fitting), ``rounds`` times from ``b = 0``; the Gamma prior of
    :func:`closed_form_rates` pulls ``a`` toward the pooled rate and ``b`` toward 0. Far fewer rates than
    ``K x bins`` (``(F1 x blocks + F2 x rings)`` per channel), and EM finds the modes much more often: on
    ``benchmarks/mixture_ceiling.py``'s episodes a team's mode at mid-episode 0.76 against 0.61 unfactored.

    :param counts: ``(K, channels, bins)`` with ``K = F1 * F2`` and ``bins = blocks * n_rings`` (block-major)
    :param exposure: ``(K, bins)``
    :param pooled: each channel's rate over all the data ``(channels,)``
    :param factors: ``(F1, F2)``
    :param n_rings: rings per block
    :param prior_exposure: ``a``
    :param rounds: coordinate-ascent rounds, int >= 1
    """
    f1, f2 = factors
    k, channels, bins = counts.shape
    if k != f1 * f2 or bins % n_rings or exposure.shape != (k, bins):
        raise ValueError(f"counts (K, channels, bins) = {counts.shape} and exposure {exposure.shape} do not fit "
                         f"factors {factors} and {n_rings} rings")
    pooled = np.maximum(np.asarray(pooled, dtype=np.float64), 1e-12)
    y = np.asarray(counts, dtype=np.float64).reshape(f1, f2, channels, bins // n_rings, n_rings)
    e = np.asarray(exposure, dtype=np.float64).reshape(f1, f2, 1, bins // n_rings, n_rings)
    y_where, y_far = y.sum(axis=(1, 4)), y.sum(axis=(0, 3))  # (F1, C, blocks), (F2, C, rings)
    b = np.zeros((1, f2, channels, 1, n_rings))
    for _ in range(rounds):
        a = np.log((y_where + prior_exposure * pooled[None, :, None])
                   / ((e * np.exp(b)).sum(axis=(1, 4)) + prior_exposure))[:, None, :, :, None]
        b = np.log((y_far + prior_exposure) / ((e * np.exp(a)).sum(axis=(0, 3)) + prior_exposure))[None, :, :, None, :]
    return np.exp(a + b).reshape(k, channels, bins)


def count_rates(counts: np.ndarray, exposure: np.ndarray, pooled: np.ndarray, factors: tuple[int, int] | None = None,
                n_rings: int = 1, prior_exposure: float = PRIOR_EXPOSURE) -> np.ndarray:
    """The count model's rates from responsibility-weighted sums: :func:`factored_rates` with ``factors``, else
    :func:`closed_form_rates` (every component's every bin its own)."""
    if factors is None:
        return closed_form_rates(counts, exposure, pooled, prior_exposure)
    return factored_rates(counts, exposure, pooled, factors, n_rings, prior_exposure)


@njit(cache=True)
def _window_bins(observations: np.ndarray, i: int, own: int, height: int, width: int, blocks: np.ndarray,
                 width_padded: int, offsets: np.ndarray, ring: np.ndarray, n_rings: int,
                 bins: np.ndarray) -> None:  # pragma: no cover (compiled)
    """Each window cell's bin of observation ``i`` into ``bins`` ``(w * w,)``, -1 off the map (see
    :meth:`ReadingCounter.cells`: the UAV's cell is its position floored, as the reserve places its window)."""
    row = min(max(int(np.floor(np.float64(observations[i, own]) * (height - 1))), 0), height - 1)
    col = min(max(int(np.floor(np.float64(observations[i, own + 1]) * (width - 1))), 0), width - 1)
    corner = row * width_padded + col
    for c in range(offsets.shape[0]):
        block = blocks[corner + offsets[c]]
        bins[c] = -1 if block < 0 else block * n_rings + ring[c]


@njit(cache=True)
def _count_log_likelihood(observations: np.ndarray, own: int, window: int, occlusion: int, channels: np.ndarray,
                          height: int, width: int, blocks: np.ndarray, width_padded: int, offsets: np.ndarray,
                          ring: np.ndarray, n_rings: int, table: np.ndarray) -> np.ndarray:  # pragma: no cover (compiled)
    """``ReadingCounter.binned(*cells(observations))`` times ``table`` ``(1 + channels, bins, K)`` summed over parts and
    bins, row by row, without the binned arrays (the belief's one call per step)."""
    n, k, cells = observations.shape[0], table.shape[2], offsets.shape[0]
    out = np.zeros((n, k))
    bins = np.empty(cells, dtype=np.int64)
    for i in range(n):
        _window_bins(observations, i, own, height, width, blocks, width_padded, offsets, ring, n_rings, bins)
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
def _grouped_counts(observations: np.ndarray, groups: np.ndarray, out: np.ndarray, own: int, window: int,
                    occlusion: int, channels: np.ndarray, height: int, width: int, blocks: np.ndarray,
                    width_padded: int, offsets: np.ndarray, ring: np.ndarray, n_rings: int,
                    n_bins: int) -> np.ndarray:  # pragma: no cover (compiled)
    """``ReadingCounter.binned(*cells(observations), groups)`` without the off-map bin, in one pass, added to ``out``
    ``(n_groups, 1 + channels, n_bins)`` (returned); rows of a negative group are skipped."""
    cells = offsets.shape[0]
    bins = np.empty(cells, dtype=np.int64)
    for i in range(observations.shape[0]):
        g = groups[i]
        if g < 0:
            continue
        _window_bins(observations, i, own, height, width, blocks, width_padded, offsets, ring, n_rings, bins)
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

    def __init__(self, observation_layout: dict, grid_shape: tuple[int, int], belief_size: int) -> None:
        from wildlife_reserve.reserve.constants import CH_LEOPARD, CH_OCCLUSION, CH_POACHER, CH_SIGN

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
        # What the compiled kernels need to place and read every window cell, in their argument order.
        self._geometry = (self.own_part.start, self.window_part.start, self.occlusion,
                          np.array(self.channels, dtype=np.int64), height, width, blocks.ravel(), self._width_padded,
                          self._flat_offsets, ring, self.n_rings)

    @classmethod
    def from_env(cls, env) -> ReadingCounter:
        """The counter of a reserve (``ReserveParallelEnv``, or anything with its ``observation_layout``, ``height``,
        ``width`` and ``config.belief_size``)."""
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
        return _count_log_likelihood(observations, *self._geometry, np.ascontiguousarray(table, dtype=np.float64))

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
        return _grouped_counts(observations, groups, out, *self._geometry, self.n_bins)

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


def _check_statistics(counts: np.ndarray, exposure: np.ndarray, shape: tuple[int, int] | None = None) -> tuple[
        np.ndarray, np.ndarray]:
    counts, exposure = np.asarray(counts, dtype=np.float64), np.asarray(exposure, dtype=np.float64)
    if counts.ndim != 3 or exposure.shape != (counts.shape[0], counts.shape[2]):
        raise ValueError(f"counts must be (N, channels, bins) and exposure (N, bins), got {counts.shape} and "
                         f"{exposure.shape}")
    if shape is not None and counts.shape[1:] != shape:
        raise ValueError(f"counts must have (channels, bins) = {shape}, got {counts.shape[1:]}")
    if not (np.all(np.isfinite(counts)) and np.all(np.isfinite(exposure))) or counts.min(initial=0) < 0 \
            or exposure.min(initial=0) < 0:
        raise ValueError("counts and exposure must be finite and >= 0")
    return counts, exposure


class PoissonMixture:
    """``K`` components, each a Poisson rate per (channel, bin), with a categorical prior; see the module's text.

    :param n_components: K, int >= 1
    :param n_channels: channels counted, int >= 1
    :param n_bins: bins per channel, int >= 1
    :param prior_exposure: ``a``, the Gamma prior's weight in cells of exposure at the pooled rate, number > 0
    :param factors: ``(F1, F2)`` with ``F1 * F2 = n_components``: the rates factor as where x how far
        (:func:`factored_rates`); None: every component's every bin its own
    :param n_rings: rings per block of the bins (with ``factors``; ``n_bins`` must be a multiple)
    """

    def __init__(self, n_components: int, n_channels: int, n_bins: int, prior_exposure: float = PRIOR_EXPOSURE,
                 factors: tuple[int, int] | None = None, n_rings: int = 1) -> None:
        for name, value in (("n_components", n_components), ("n_channels", n_channels), ("n_bins", n_bins)):
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                raise ValueError(f"{name} must be an int >= 1, got {value!r}")
        if isinstance(prior_exposure, bool) or not np.isfinite(prior_exposure) or prior_exposure <= 0:
            raise ValueError(f"prior_exposure must be a finite number > 0, got {prior_exposure!r}")
        self.n_components, self.n_channels, self.n_bins = int(n_components), int(n_channels), int(n_bins)
        self.prior_exposure = float(prior_exposure)
        self.factors = check_factors(factors, self.n_components)
        self.n_rings = check_rings(n_rings, self.n_bins)
        self.rates = np.ones((self.n_components, self.n_channels, self.n_bins))
        self.log_prior = np.full(self.n_components, -np.log(self.n_components))

    def log_likelihood(self, counts: np.ndarray, exposure: np.ndarray) -> np.ndarray:
        """``(N, K)`` log-likelihood of each unit's summed statistics under each component (without ``log count!``).

        :param counts: ``(N, n_channels, n_bins)``
        :param exposure: ``(N, n_bins)``
        """
        counts, exposure = _check_statistics(counts, exposure, (self.n_channels, self.n_bins))
        log_rates = np.log(self.rates).reshape(self.n_components, -1)
        return counts.reshape(len(counts), -1) @ log_rates.T - exposure @ self.rates.sum(axis=1).T

    def posterior(self, counts: np.ndarray, exposure: np.ndarray, temperature: float = 1.0) -> np.ndarray:
        """``(N, K)`` posterior of each unit: ``softmax(log prior + log-likelihood / temperature)``."""
        return softmax(self.log_prior + self.log_likelihood(counts, exposure) / temperature, axis=1)

    def m_step(self, responsibilities: np.ndarray, counts: np.ndarray, exposure: np.ndarray) -> None:
        """Rates and prior in closed form from the units' responsibilities ``(N, K)``."""
        counts, exposure = _check_statistics(counts, exposure, (self.n_channels, self.n_bins))
        r = np.asarray(responsibilities, dtype=np.float64)
        if r.shape != (len(counts), self.n_components):
            raise ValueError(f"responsibilities must be (N, K) = {(len(counts), self.n_components)}, got {r.shape}")
        pooled = counts.sum(axis=(0, 2)) / max(exposure.sum(), 1e-12)  # (channels,)
        self.rates = count_rates(np.einsum("nk,ncb->kcb", r, counts), r.T @ exposure, pooled, self.factors, self.n_rings,
                                 self.prior_exposure)
        shares = np.maximum(r.mean(axis=0), 1e-6)
        self.log_prior = np.log(shares / shares.sum())

    def fit_told(self, counts: np.ndarray, exposure: np.ndarray, labels: np.ndarray) -> PoissonMixture:
        """The M-step with every unit's responsibility on its label (component ``k`` is label ``k``)."""
        labels = np.asarray(labels)
        if labels.shape != (len(counts),) or labels.min(initial=0) < 0 or labels.max(initial=0) >= self.n_components:
            raise ValueError(f"labels must be (N,) = ({len(counts)},) ints in [0, {self.n_components - 1}], got "
                             f"shape {labels.shape}")
        self.m_step(np.eye(self.n_components)[labels], counts, exposure)
        return self

    def fit(self, counts: np.ndarray, exposure: np.ndarray, n_iter: int = 120, anneal_from: float = 300.0,
            restarts: int = 4, temperature: float = 1.0, seed: int = 0) -> PoissonMixture:
        """Unsupervised EM with deterministic annealing; keeps the restart of highest log-evidence.

        :param counts: ``(N, n_channels, n_bins)`` summed statistics of the training units
        :param exposure: ``(N, n_bins)``
        :param n_iter: EM iterations per restart, int >= 1
        :param anneal_from: first temperature (>= ``temperature``); it falls geometrically to ``temperature``
        :param restarts: EM runs from random responsibilities, int >= 1
        :param temperature: the last temperature, the one the evidence is scored at, number > 0
        :param seed: seed of the random starting responsibilities
        """
        counts, exposure = _check_statistics(counts, exposure, (self.n_channels, self.n_bins))
        for name, value in (("n_iter", n_iter), ("restarts", restarts)):
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                raise ValueError(f"{name} must be an int >= 1, got {value!r}")
        if not np.isfinite(temperature) or temperature <= 0 or not np.isfinite(anneal_from) or anneal_from < temperature:
            raise ValueError(f"temperature must be > 0 and anneal_from >= temperature, got {temperature!r} and "
                             f"{anneal_from!r}")
        rng = np.random.default_rng(seed)
        temperatures = np.geomspace(anneal_from, temperature, n_iter)
        best: tuple[float, np.ndarray, np.ndarray] | None = None
        for _ in range(restarts):
            r = rng.dirichlet(np.ones(self.n_components), size=len(counts))
            for temp in temperatures:
                self.m_step(r, counts, exposure)
                r = self.posterior(counts, exposure, temp)
            self.m_step(r, counts, exposure)
            evidence = float(logsumexp(self.log_prior + self.log_likelihood(counts, exposure) / temperature, axis=1).sum())
            if best is None or evidence > best[0]:
                best = (evidence, self.rates.copy(), self.log_prior.copy())
        assert best is not None
        self.rates, self.log_prior = best[1], best[2]
        return self
