"""The count model: a mixture of Poisson models of what is read *where*, fitted by EM in closed form.

An environment's plug-in may count its readings by *bin* (:class:`~sb3_emmarl.common.latent.evidence.CountEvidence`:
on the reserve, three window channels by map block and window ring, :mod:`sb3_emmarl.common.latent.reserve_evidence`), with
each bin's *exposure* (how much of the bin was looked at). Under component ``k`` a bin's count of channel ``c`` is
Poisson with mean ``exposure * rate[k, c, bin]``, independently over bins and steps.

Counts and exposures add over steps, so a unit's (an agent's or a team's) evidence up to any step is the sum of its
steps', and the log-likelihood is linear in it: ``sum counts * log(rate) - exposure * rate`` (the ``log(count!)`` term
is the same for every component and left out). The exact posterior of a per-episode ``z`` is therefore a softmax of a
product of the summed statistics with ``log(rate)`` and ``rate``, at constant cost per step.

A reading seen at several steps is counted each time, so the independence assumption overstates the evidence; the
plug-in's ``weight`` multiplies the log-likelihood (``1 / temperature``), as EM-PPO's ``likelihood_temperature`` does
for the transition model. The posterior's argmax does not depend on it; EM's fit does.

EM (:meth:`PoissonMixture.fit`): responsibilities are the posterior of each training unit (an episode's team or
agent), the rates ``(sum_n r_nk counts_n + a * pooled) / (sum_n r_nk exposure_n + a)`` (a Gamma prior worth ``a``
cells of exposure at the channel's pooled rate keeps bins never seen finite) and the prior the mean
responsibilities, all in closed form. The counts of a whole episode run into the thousands, so plain EM makes
its assignments hard at once and stops in a poor optimum; deterministic annealing (the log-likelihood divided
by a temperature falling geometrically from ``anneal_from`` to ``temperature``) and restarts keep the best of
several fits by their log-evidence.

EM-PPO, EM-DDPG and VDN+EM add this model's evidence to their transition model's when the environment's plug-in has
counts (``reading_counts``): the belief (``belief.py``) adds each new observation's count log-likelihood, the E-step
(``em.py``) reads each episode's counts in the responsibilities and sets the rates in closed form from running sums,
as :meth:`PoissonMixture.m_step` does from a batch.
"""

from __future__ import annotations

import numpy as np
from scipy.special import logsumexp, softmax

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
#: ``docs/lab/studies/mixture_ceiling.py`` are the same at 3 and at 10.
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
    ``docs/lab/studies/mixture_ceiling.py``'s episodes a team's mode at mid-episode 0.76 against 0.61 unfactored.

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
