"""Accuracy of a learned categorical latent variable against the true hidden modes.

A model with ``K`` latent components gives each of ``N`` samples a posterior ``q(z)`` over the components
(``posteriors``, shape ``(N, K)``); the environment knows each sample's true mode, one of ``M`` modes
(``true_modes``, integers in ``[0, M)``, shape ``(N,)``). Component indices are arbitrary, so the components
are first aligned to the modes (:func:`align_components`, Hungarian matching), then scored:

- :func:`latent_accuracy`: share of samples whose most likely component is aligned to their true mode;
- :func:`latent_kl`: mean ``KL(q(z) || p*(z))`` against a smoothed one-hot ground truth ``p*``;
- :func:`normalized_mutual_information`: NMI between most likely components and true modes (needs no alignment).

:func:`latent_report` computes all of them at once. Only numpy and scipy are used.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.special import rel_entr

#: Tolerance on the sum of each posterior row.
ROW_SUM_TOLERANCE = 1e-4
#: Fractions of an episode at which the latent accuracy is reported (evaluation and training logs alike).
EPISODE_FRACTIONS = (0.25, 0.5, 1.0)


def fraction_step(fraction: float, length: int) -> int:
    """Index of the step ``fraction`` of the way through an episode of ``length`` steps (the last for 1.0)."""
    return max(0, int(np.ceil(fraction * length)) - 1)


def fraction_label(fraction: float) -> str:
    """The percentage that names a fraction in metric keys: ``0.25`` -> ``"25"``."""
    return str(round(100 * fraction))


def _check_posteriors(posteriors: Any) -> np.ndarray:
    """Validate the posteriors and return them as a float array of shape (N, K).

    :param posteriors: one categorical distribution over the K components per sample
    :return: the posteriors as ``float64``
    """
    q = np.asarray(posteriors)
    if q.ndim != 2:
        raise ValueError(f"posteriors must be a 2-D array of shape (N, K), got {q.ndim} dimension(s) (shape {q.shape})")
    if q.shape[0] < 1 or q.shape[1] < 1:
        raise ValueError(f"posteriors must have at least one sample and one component (N >= 1, K >= 1), got shape {q.shape}")
    if not (np.issubdtype(q.dtype, np.floating) or np.issubdtype(q.dtype, np.integer)):
        raise ValueError(f"posteriors must hold real numbers, got dtype {q.dtype}")
    q = q.astype(np.float64)
    if not np.all(np.isfinite(q)):
        raise ValueError("posteriors must be finite (no NaN or inf)")
    if np.any(q < 0):
        raise ValueError(f"posteriors must be non-negative, got a minimum of {q.min()}")
    sums = q.sum(axis=1)
    bad = np.flatnonzero(np.abs(sums - 1.0) > ROW_SUM_TOLERANCE)
    if bad.size:
        raise ValueError(
            f"each row of posteriors must sum to 1 (tolerance {ROW_SUM_TOLERANCE}), "
            f"row {bad[0]} sums to {sums[bad[0]]} ({bad.size} bad row(s))"
        )
    return q


def _check_modes(true_modes: Any, n_samples: int) -> np.ndarray:
    """Validate the true modes and return them as an int64 array of shape (N,).

    :param true_modes: the true mode of each sample, integers in ``[0, M)``
    :param n_samples: N, the number of rows of the posteriors
    :return: the true modes as ``int64``
    """
    modes = np.asarray(true_modes)
    if modes.ndim != 1:
        raise ValueError(f"true_modes must be a 1-D array of shape (N,), got {modes.ndim} dimension(s) (shape {modes.shape})")
    if not np.issubdtype(modes.dtype, np.integer):
        raise ValueError(f"true_modes must hold integers (mode indices >= 0), got dtype {modes.dtype}")
    if modes.shape[0] != n_samples:
        raise ValueError(f"true_modes must have one entry per row of posteriors (N={n_samples}), got {modes.shape[0]}")
    if np.any(modes < 0):
        raise ValueError(f"true_modes must be non-negative mode indices, got a minimum of {modes.min()}")
    return modes.astype(np.int64)


def _check_mapping(mapping: Any, n_components: int) -> np.ndarray:
    """Validate a component-to-mode mapping and return it as an int64 array of shape (K,).

    :param mapping: for each component, its aligned mode or -1 when unmatched
    :param n_components: K, the number of columns of the posteriors
    :return: the mapping as ``int64``
    """
    m = np.asarray(mapping)
    if m.ndim != 1 or m.shape[0] != n_components:
        raise ValueError(f"mapping must be a 1-D array with one entry per component (K={n_components}), got shape {m.shape}")
    if not np.issubdtype(m.dtype, np.integer):
        raise ValueError(f"mapping must hold integers (a mode index, or -1 for unmatched), got dtype {m.dtype}")
    if np.any(m < -1):
        raise ValueError(f"mapping entries must be mode indices >= 0 or -1 for unmatched, got a minimum of {m.min()}")
    return m.astype(np.int64)


def _check_labels(labels: Any, name: str) -> np.ndarray:
    """Validate a labelling for :func:`normalized_mutual_information`.

    :param labels: one label per sample
    :param name: the argument's name, for error messages
    :return: the labels as an array
    """
    arr = np.asarray(labels)
    if arr.ndim != 1:
        raise ValueError(f"{name} must be a 1-D array of labels, got {arr.ndim} dimension(s) (shape {arr.shape})")
    if arr.shape[0] < 1:
        raise ValueError(f"{name} must have at least one label")
    return arr


def _contingency(rows: np.ndarray, cols: np.ndarray, n_rows: int, n_cols: int) -> np.ndarray:
    """Counts of each (row label, column label) pair.

    :param rows: row labels in ``[0, n_rows)``
    :param cols: column labels in ``[0, n_cols)``, same length as ``rows``
    :param n_rows: number of row labels
    :param n_cols: number of column labels
    :return: the contingency table, shape ``(n_rows, n_cols)``
    """
    table = np.zeros((n_rows, n_cols), dtype=np.int64)
    np.add.at(table, (rows, cols), 1)
    return table


def align_components(posteriors: np.ndarray, true_modes: np.ndarray, n_modes: int | None = None) -> np.ndarray:
    """Align the latent components to the true modes by Hungarian matching.

    Each sample is assigned its most likely component (``argmax`` of its posterior, the first one on ties),
    giving a ``(K, M)`` contingency table of (component, true mode) counts. A one-to-one matching between
    components and modes maximising the total number of matched samples is found with
    :func:`scipy.optimize.linear_sum_assignment`; rectangular tables work both ways, so ``min(K, M)`` pairs
    are matched. When ``K > M`` the extra components are left unmatched (-1); when ``K < M`` some modes have
    no component. Ties between equally good matchings are broken by scipy's deterministic solver.

    :param posteriors: posterior ``q(z)`` of each sample over the K components, shape ``(N, K)``
    :param true_modes: the true mode of each sample, integers in ``[0, M)``, shape ``(N,)``
    :param n_modes: M, the number of modes; default ``max(true_modes) + 1``
    :return: ``mapping`` of shape ``(K,)``: the mode each component is aligned to, or -1 if unmatched
    """
    q = _check_posteriors(posteriors)
    modes = _check_modes(true_modes, q.shape[0])
    observed = int(modes.max()) + 1
    if n_modes is None:
        n_modes = observed
    elif isinstance(n_modes, bool) or not isinstance(n_modes, (int, np.integer)) or n_modes < observed:
        raise ValueError(f"n_modes must be an integer >= max(true_modes) + 1 = {observed} (or None), got {n_modes!r}")
    n_components = q.shape[1]
    table = _contingency(q.argmax(axis=1), modes, n_components, int(n_modes))
    components, matched_modes = linear_sum_assignment(table, maximize=True)
    mapping = np.full(n_components, -1, dtype=np.int64)
    mapping[components] = matched_modes
    return mapping


def latent_accuracy(posteriors: np.ndarray, true_modes: np.ndarray, mapping: np.ndarray) -> float:
    """Share of samples whose most likely component is aligned to their true mode.

    A sample counts as correct when ``mapping[argmax q(z)] == true_mode`` (``argmax`` takes the first
    component on ties); samples whose most likely component is unmatched (-1) count as wrong.

    :param posteriors: posterior ``q(z)`` of each sample over the K components, shape ``(N, K)``
    :param true_modes: the true mode of each sample, integers in ``[0, M)``, shape ``(N,)``
    :param mapping: the mode of each component (-1 if unmatched), shape ``(K,)``, e.g. from :func:`align_components`
    :return: the accuracy, in ``[0, 1]``
    """
    q = _check_posteriors(posteriors)
    modes = _check_modes(true_modes, q.shape[0])
    m = _check_mapping(mapping, q.shape[1])
    return float(np.mean(m[q.argmax(axis=1)] == modes))


def latent_kl(posteriors: np.ndarray, true_modes: np.ndarray, mapping: np.ndarray, epsilon: float = 1e-2) -> float:
    """Mean over samples of ``KL(q(z) || p*(z))``, the divergence of the posterior from a smoothed ground truth.

    For a sample of true mode ``m``, let ``A = {k : mapping[k] == m}`` be the components aligned to ``m``
    (``a = |A|``; one at most for a Hungarian mapping, but any mapping is accepted). The ground truth over the
    K components is

    - ``p*(k) = (1 - epsilon) / a`` for ``k`` in ``A`` and ``p*(k) = epsilon / (K - a)`` otherwise, when ``0 < a < K``;
    - ``p*(k) = 1 / a`` for ``k`` in ``A`` when ``a == K`` (every component is aligned to ``m``, e.g. ``K == 1``);
    - ``p*(k) = 1 / K`` for every ``k`` when ``a == 0`` (no component is aligned to ``m``).

    The smoothing keeps ``p*`` positive, so the KL is finite. Per sample,
    ``KL(q || p*) = sum_k q(k) log(q(k) / p*(k))`` in nats, with ``0 log 0 = 0``; the result is its mean over
    the N samples. A one-hot posterior on the single aligned component scores ``-log(1 - epsilon)``, the lowest
    value a posterior can reach when exactly one component is aligned.

    :param posteriors: posterior ``q(z)`` of each sample over the K components, shape ``(N, K)``
    :param true_modes: the true mode of each sample, integers in ``[0, M)``, shape ``(N,)``
    :param mapping: the mode of each component (-1 if unmatched), shape ``(K,)``, e.g. from :func:`align_components`
    :param epsilon: probability mass ``p*`` spreads over the components not aligned to the true mode, in ``(0, 1)``
    :return: the mean KL divergence, in nats
    """
    q = _check_posteriors(posteriors)
    modes = _check_modes(true_modes, q.shape[0])
    m = _check_mapping(mapping, q.shape[1])
    if isinstance(epsilon, bool) or not isinstance(epsilon, (int, float, np.number)) or not 0.0 < epsilon < 1.0:
        raise ValueError(f"epsilon must be a number in the open interval (0, 1), got {epsilon!r}")
    n_components = q.shape[1]
    aligned = m[None, :] == modes[:, None]  # (N, K): component k aligned to sample i's mode
    n_aligned = aligned.sum(axis=1, keepdims=True)  # (N, 1)
    n_other = n_components - n_aligned
    on = np.where(n_other > 0, (1.0 - epsilon), 1.0) / np.maximum(n_aligned, 1)
    off = np.where(n_aligned > 0, epsilon, 1.0) / np.maximum(n_other, 1)
    target = np.where(aligned, on, off)  # rows with a == 0 are uniform: off = 1 / K
    return float(np.mean(rel_entr(q, target).sum(axis=1)))


def normalized_mutual_information(labels_a: np.ndarray, labels_b: np.ndarray) -> float:
    """Normalised mutual information between two labellings of the same samples.

    ``NMI = I(A; B) / ((H(A) + H(B)) / 2)`` with natural logarithms, the arithmetic-mean normalisation of
    scikit-learn's ``normalized_mutual_info_score`` (its default ``average_method="arithmetic"``). It is
    symmetric, invariant to renaming the labels of either side, 1 for labellings equal up to renaming and 0 for
    independent ones. As in scikit-learn, two constant labellings (one cluster each) score 1.0; when exactly
    one is constant the mutual information is 0, so the score is 0.0. The result is clipped to ``[0, 1]`` to
    absorb rounding.

    :param labels_a: one label per sample (any sortable values), shape ``(N,)``
    :param labels_b: one label per sample, same length as ``labels_a``
    :return: the NMI, in ``[0, 1]``
    """
    a = _check_labels(labels_a, "labels_a")
    b = _check_labels(labels_b, "labels_b")
    if a.shape[0] != b.shape[0]:
        raise ValueError(f"labels_a and labels_b must have the same length, got {a.shape[0]} and {b.shape[0]}")
    classes_a, a_idx = np.unique(a, return_inverse=True)
    classes_b, b_idx = np.unique(b, return_inverse=True)
    if len(classes_a) == len(classes_b) == 1:
        return 1.0
    joint = _contingency(a_idx.ravel(), b_idx.ravel(), len(classes_a), len(classes_b)) / a.shape[0]
    p_a, p_b = joint.sum(axis=1), joint.sum(axis=0)
    mutual_info = max(float(rel_entr(joint, np.outer(p_a, p_b)).sum()), 0.0)
    entropy_a = float(-np.sum(p_a * np.log(p_a)))  # every marginal entry is > 0
    entropy_b = float(-np.sum(p_b * np.log(p_b)))
    normalizer = (entropy_a + entropy_b) / 2.0  # > 0: at most one labelling is constant here
    return float(np.clip(mutual_info / normalizer, 0.0, 1.0))


def latent_report(
    posteriors: np.ndarray, true_modes: np.ndarray, n_modes: int | None = None, epsilon: float = 1e-2
) -> dict[str, float | list[int]]:
    """Every latent metric at once, after aligning the components to the modes.

    :param posteriors: posterior ``q(z)`` of each sample over the K components, shape ``(N, K)``
    :param true_modes: the true mode of each sample, integers in ``[0, M)``, shape ``(N,)``
    :param n_modes: M, the number of modes; default ``max(true_modes) + 1``
    :param epsilon: smoothing of the ground truth in :func:`latent_kl`, in ``(0, 1)``
    :return: ``{"latent_accuracy": float, "latent_kl": float, "latent_nmi": float, "mapping": list[int]}``,
        where ``latent_nmi`` is the NMI between the most likely components and the true modes and
        ``mapping`` is :func:`align_components`' output
    """
    q = _check_posteriors(posteriors)
    modes = _check_modes(true_modes, q.shape[0])
    mapping = align_components(q, modes, n_modes)
    return {
        "latent_accuracy": latent_accuracy(q, modes, mapping),
        "latent_kl": latent_kl(q, modes, mapping, epsilon),
        "latent_nmi": normalized_mutual_information(q.argmax(axis=1), modes),
        "mapping": [int(x) for x in mapping],
    }
