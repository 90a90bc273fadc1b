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
``likelihood_temperature`` does for the transition model. The posterior's argmax does not depend on it.

EM (:meth:`PoissonMixture.fit`): responsibilities are the posterior of each training unit (an episode's team or
UAV), the rates ``(sum_n r_nk counts_n + a * pooled) / (sum_n r_nk exposure_n + a)`` (a Gamma prior worth ``a``
cells of exposure at the channel's pooled rate keeps bins never seen finite) and the prior the mean
responsibilities, all in closed form. The counts of a whole episode run into the thousands, so plain EM makes
its assignments hard at once and stops in a poor optimum; deterministic annealing (the log-likelihood divided
by a temperature falling geometrically from ``anneal_from`` to ``temperature``) and restarts keep the best of
several fits by their log-evidence.

This module is the model and its fit; EM-PPO's belief and E-step do not use it yet (docs/em.md).
"""

from __future__ import annotations

import numpy as np
from scipy.special import logsumexp, softmax

#: The window channels counted, in order: signs of poacher activity, leopards, poachers.
COUNTED_CHANNELS = ("sign", "leopard", "poacher")


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
        self.channels = (CH_SIGN, CH_LEOPARD, CH_POACHER)
        if max(self.channels) >= n_channels:
            raise ValueError(f"the window needs channels {self.channels}, it has {n_channels}")
        self.occlusion = CH_OCCLUSION
        offsets = np.indices((w, w)).reshape(2, -1) - self.r
        self._offsets = offsets.T  # (w * w, 2) cell offsets from the UAV
        self._ring = np.abs(offsets).max(axis=0)  # (w * w,)
        self.n_rings = self.r + 1
        self.n_bins = self.belief_size**2 * self.n_rings

    @classmethod
    def from_env(cls, env) -> ReadingCounter:
        """The counter of a reserve (``ReserveParallelEnv``, or anything with its ``observation_layout``, ``height``,
        ``width`` and ``config.belief_size``)."""
        return cls(env.observation_layout, (env.height, env.width), env.config.belief_size)

    @property
    def n_channels(self) -> int:
        return len(self.channels)

    def bins(self, observations: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Each window cell's bin and whether it lies inside the map, both ``(n, w * w)``."""
        own = observations[:, self.own_part]
        cell = np.rint(own[:, :2] * [self.height - 1, self.width - 1]).astype(np.int64)
        where = cell[:, None, :] + self._offsets[None]  # (n, w * w, 2)
        inside = (where[..., 0] >= 0) & (where[..., 0] < self.height) & (where[..., 1] >= 0) & (where[..., 1] < self.width)
        rows = np.clip(where[..., 0], 0, self.height - 1) * self.belief_size // self.height
        cols = np.clip(where[..., 1], 0, self.width - 1) * self.belief_size // self.width
        return (rows * self.belief_size + cols) * self.n_rings + self._ring[None], inside

    def __call__(self, observations: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Counts ``(n, n_channels, n_bins)`` and exposures ``(n, n_bins)`` of the readings in each observation.

        A reading is a window cell whose channel is above 0.5 (the channels are 0/1 without sensor noise).

        :param observations: ``(n, obs_dim)`` flat observations of the reserve
        """
        observations = np.asarray(observations)
        if observations.ndim != 2 or observations.shape[1] < self.own_part.stop:
            raise ValueError(f"observations must be (n, obs_dim >= {self.own_part.stop}), got shape {observations.shape}")
        n = len(observations)
        window = observations[:, self.window_part].reshape(n, -1, self._ring.size)
        bins, inside = self.bins(observations)
        flat = (np.arange(n)[:, None] * self.n_bins + bins).ravel()
        seen = (1.0 - window[:, self.occlusion]) * inside
        exposure = np.bincount(flat, weights=seen.ravel(), minlength=n * self.n_bins).reshape(n, self.n_bins)
        counts = np.stack([np.bincount(flat, weights=((window[:, c] > 0.5) & inside).ravel(),
                                       minlength=n * self.n_bins).reshape(n, self.n_bins) for c in self.channels], 1)
        return counts, exposure


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
    """

    def __init__(self, n_components: int, n_channels: int, n_bins: int, prior_exposure: float = 1.0) -> None:
        for name, value in (("n_components", n_components), ("n_channels", n_channels), ("n_bins", n_bins)):
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                raise ValueError(f"{name} must be an int >= 1, got {value!r}")
        if isinstance(prior_exposure, bool) or not np.isfinite(prior_exposure) or prior_exposure <= 0:
            raise ValueError(f"prior_exposure must be a finite number > 0, got {prior_exposure!r}")
        self.n_components, self.n_channels, self.n_bins = int(n_components), int(n_channels), int(n_bins)
        self.prior_exposure = float(prior_exposure)
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
        a = self.prior_exposure
        numerator = np.einsum("nk,ncb->kcb", r, counts) + a * np.maximum(pooled, 1e-12)[None, :, None]
        denominator = (r.T @ exposure)[:, None, :] + a
        self.rates = numerator / denominator
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
