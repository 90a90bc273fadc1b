"""The statistics of the comparisons over seeds, shared by the zoo's benchmark, the experiments' reports and the
benchmark scripts: paired tests (scipy's) that stay defined on degenerate data, and the paired t-test's sample size."""

from __future__ import annotations

import numpy as np
from scipy import stats


def paired_p_value(a: np.ndarray, b: np.ndarray) -> float:
    """The p-value of the paired t-test of ``a`` against ``b`` (``scipy.stats.ttest_rel``).

    :param a: one value per pair
    :param b: the other value of each pair, in the same order
    :return: the two-sided p-value; 1.0 when there are fewer than two pairs or every difference is 0
        (the test is undefined there, and there is no evidence of a difference)
    """
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    return float(stats.ttest_rel(a, b).pvalue) if len(a) > 1 and np.any(a != b) else 1.0


def wilcoxon_p_value(a: np.ndarray, b: np.ndarray) -> float:
    """The p-value of the Wilcoxon signed-rank test of ``a`` against ``b`` (``scipy.stats.wilcoxon``, two-sided).

    :param a: one value per pair
    :param b: the other value of each pair, in the same order
    :return: the p-value; 1.0 when every difference is 0 (the test is undefined there)
    """
    diff = np.asarray(a, dtype=float) - np.asarray(b, dtype=float)
    return float(stats.wilcoxon(diff).pvalue) if np.any(diff != 0) else 1.0


def seeds_needed(effect: float, sd: float, alpha: float = 0.05, power: float = 0.8, max_n: int = 100_000) -> int | None:
    """How many pairs a two-sided paired t-test needs to find a mean difference ``effect`` at level ``alpha`` with
    probability ``power``, when the differences spread with standard deviation ``sd``.

    The power of the test at ``n`` pairs is the noncentral t distribution's mass beyond the critical values
    (noncentrality ``effect / sd * sqrt(n)``, ``n - 1`` degrees of freedom); scipy has the distribution, not the
    solver, and statsmodels' would be a dependency for this one function.

    :param effect: the mean difference to find
    :param sd: standard deviation of the paired differences (> 0)
    :param alpha: the test's level
    :param power: the probability of finding it
    :param max_n: give up above this many pairs
    :return: the smallest such number of pairs (at least 2), or None if ``effect`` is 0 or more than ``max_n`` are needed
    """
    if not sd > 0:
        raise ValueError(f"sd must be > 0, got {sd!r}")
    if not 0 < alpha < 1 or not 0 < power < 1:
        raise ValueError(f"alpha and power must be in (0, 1), got {alpha!r} and {power!r}")
    if effect == 0:
        return None

    def power_at(n: int) -> float:
        critical = stats.t.ppf(1 - alpha / 2, n - 1)
        shift = abs(effect) / sd * np.sqrt(n)
        return float(stats.nct.sf(critical, n - 1, shift) + stats.nct.cdf(-critical, n - 1, shift))

    low, high = 2, 2
    while power_at(high) < power:  # doubling, then bisection: the power grows with n
        if high >= max_n:
            return None
        low, high = high, min(2 * high, max_n)
    while low < high:
        middle = (low + high) // 2
        if power_at(middle) >= power:
            high = middle
        else:
            low = middle + 1
    return high
