"""Latent-variable accuracy metrics: alignment, accuracy, KL to the smoothed ground truth, NMI, report."""

import itertools
import math

import numpy as np
import pytest

from sb3_emmarl.common.latent.metrics import (
    align_components,
    latent_accuracy,
    latent_kl,
    latent_report,
    normalized_mutual_information,
)

EPS = 1e-2


def one_hot(components, n_components: int) -> np.ndarray:
    """Posteriors putting all their mass on the given components."""
    return np.eye(n_components)[np.asarray(components)]


def reference_nmi(a, b) -> float:
    """NMI from the textbook formulas, one probability at a time (arithmetic-mean normalisation)."""
    n = len(a)
    la, lb = sorted(set(a)), sorted(set(b))
    if len(la) == len(lb) == 1:
        return 1.0
    pa = {x: sum(1 for u in a if u == x) / n for x in la}
    pb = {y: sum(1 for v in b if v == y) / n for y in lb}
    mi = 0.0
    for x in la:
        for y in lb:
            pxy = sum(1 for u, v in zip(a, b) if u == x and v == y) / n
            if pxy > 0:
                mi += pxy * math.log(pxy / (pa[x] * pb[y]))
    ha = -sum(p * math.log(p) for p in pa.values())
    hb = -sum(p * math.log(p) for p in pb.values())
    return mi / ((ha + hb) / 2)


# --- perfect posteriors ---------------------------------------------------------------------------------------------


def test_perfect_posteriors_with_permuted_components():
    modes = np.array([0, 1, 2, 0, 1, 2, 2])
    component_of_mode = np.array([2, 0, 1])  # mode m is learned as component component_of_mode[m]
    q = one_hot(component_of_mode[modes], 3)
    mapping = align_components(q, modes)
    np.testing.assert_array_equal(mapping, [1, 2, 0])  # component 0 -> mode 1, 1 -> 2, 2 -> 0
    assert mapping.dtype == np.int64 and mapping.shape == (3,)
    assert latent_accuracy(q, modes, mapping) == 1.0
    assert normalized_mutual_information(q.argmax(axis=1), modes) == pytest.approx(1.0)
    # One-hot q on the single aligned component: KL = 1 * log(1 / (1 - eps)).
    assert latent_kl(q, modes, mapping, epsilon=EPS) == pytest.approx(-math.log(1 - EPS))
    assert latent_kl(q, modes, mapping, epsilon=0.2) == pytest.approx(-math.log(0.8))


def test_report_on_perfect_posteriors():
    modes = np.array([1, 0, 1, 0])
    q = one_hot(1 - modes, 2)
    report = latent_report(q, modes, epsilon=EPS)
    assert set(report) == {"latent_accuracy", "latent_kl", "latent_nmi", "mapping"}
    assert report["mapping"] == [1, 0] and all(type(x) is int for x in report["mapping"])
    assert report["latent_accuracy"] == 1.0
    assert report["latent_nmi"] == pytest.approx(1.0)
    assert report["latent_kl"] == pytest.approx(-math.log(1 - EPS))
    assert all(isinstance(report[k], float) for k in ("latent_accuracy", "latent_kl", "latent_nmi"))


# --- K != M ---------------------------------------------------------------------------------------------------------


def test_more_components_than_modes_leaves_an_unused_component_unmatched():
    modes = np.array([0, 0, 1, 1])
    q = one_hot([1, 1, 0, 0], 3)  # component 2 is never the most likely
    mapping = align_components(q, modes)
    np.testing.assert_array_equal(mapping, [1, 0, -1])
    assert latent_accuracy(q, modes, mapping) == 1.0
    assert latent_kl(q, modes, mapping, EPS) == pytest.approx(-math.log(1 - EPS))


def test_more_components_than_modes_with_a_used_extra_component():
    modes = np.array([0, 0, 0, 1, 1])
    components = [0, 0, 2, 1, 1]  # component 2 catches one sample of mode 0
    q = one_hot(components, 3)
    mapping = align_components(q, modes)
    np.testing.assert_array_equal(mapping, [0, 1, -1])
    assert latent_accuracy(q, modes, mapping) == pytest.approx(4 / 5)
    # The stray sample: q one-hot on component 2, which gets p* = eps / (K - 1) = eps / 2, so KL = log(2 / eps).
    expected = (4 * -math.log(1 - EPS) + math.log(2 / EPS)) / 5
    assert latent_kl(q, modes, mapping, EPS) == pytest.approx(expected)
    report = latent_report(q, modes, epsilon=EPS)
    assert report["mapping"] == [0, 1, -1]
    assert report["latent_accuracy"] == pytest.approx(4 / 5) and report["latent_kl"] == pytest.approx(expected)


def test_fewer_components_than_modes_leaves_a_mode_unmatched():
    modes = np.array([0, 0, 1, 1, 2])
    q = one_hot([0, 0, 1, 1, 1], 2)  # contingency [[2, 0, 0], [0, 2, 1]]
    mapping = align_components(q, modes)
    np.testing.assert_array_equal(mapping, [0, 1])
    assert 2 not in mapping
    assert latent_accuracy(q, modes, mapping) == pytest.approx(4 / 5)
    # The mode-2 sample has no aligned component: p* is uniform (1/2, 1/2), KL(one-hot || uniform) = log 2.
    expected = (4 * -math.log(1 - EPS) + math.log(2)) / 5
    assert latent_kl(q, modes, mapping, EPS) == pytest.approx(expected)


def test_n_modes_larger_than_observed():
    modes = np.array([0, 1, 1])
    q = one_hot([1, 0, 0], 2)
    np.testing.assert_array_equal(align_components(q, modes, n_modes=5), [1, 0])
    assert latent_report(q, modes, n_modes=np.int64(5))["mapping"] == [1, 0]


def test_single_component_kl_is_zero():
    q = np.ones((3, 1))
    modes = np.array([0, 0, 1])
    mapping = align_components(q, modes)
    np.testing.assert_array_equal(mapping, [0])
    assert latent_accuracy(q, modes, mapping) == pytest.approx(2 / 3)
    # Mode 0: the single component holds all of p*; mode 1: no aligned component, p* uniform over 1 component.
    assert latent_kl(q, modes, mapping, EPS) == pytest.approx(0.0)


# --- Hungarian vs greedy --------------------------------------------------------------------------------------------


def test_hungarian_beats_greedy_matching():
    # Contingency (components x modes) [[3, 2], [2, 0]]: greedy takes the largest cell (0, 0) and is left with (1, 1),
    # matching 3 + 0 = 3 samples; the optimum crosses over, 2 + 2 = 4.
    components = [0, 0, 0, 0, 0, 1, 1]
    modes = np.array([0, 0, 0, 1, 1, 0, 0])
    q = one_hot(components, 2)
    mapping = align_components(q, modes)
    np.testing.assert_array_equal(mapping, [1, 0])
    assert latent_accuracy(q, modes, mapping) == pytest.approx(4 / 7)
    assert latent_accuracy(q, modes, np.array([0, 1])) == pytest.approx(3 / 7)  # the greedy answer


def test_hungarian_beats_greedy_on_three_components():
    # Contingency [[5, 4, 0], [4, 0, 0], [0, 0, 1]]: greedy takes (0, 0)=5, then (2, 2)=1, then (1, 1)=0 -> 6;
    # the optimum is (0, 1) + (1, 0) + (2, 2) = 4 + 4 + 1 = 9.
    table = np.array([[5, 4, 0], [4, 0, 0], [0, 0, 1]])
    components, modes = [], []
    for k, m in itertools.product(range(3), range(3)):
        components += [k] * table[k, m]
        modes += [m] * table[k, m]
    q = one_hot(components, 3)
    mapping = align_components(q, np.array(modes))
    np.testing.assert_array_equal(mapping, [1, 0, 2])
    assert latent_accuracy(q, np.array(modes), mapping) == pytest.approx(9 / table.sum())


@pytest.mark.parametrize("n_components,n_modes", [(3, 3), (4, 2), (2, 4), (4, 4)])
def test_alignment_matches_brute_force(n_components: int, n_modes: int):
    rng = np.random.default_rng(n_components * 10 + n_modes)
    for _ in range(20):
        n = 30
        logits = rng.normal(size=(n, n_components)) * 3
        q = np.exp(logits) / np.exp(logits).sum(axis=1, keepdims=True)
        modes = rng.integers(0, n_modes, size=n)
        mapping = align_components(q, modes, n_modes=n_modes)
        # One-to-one: every mode used at most once, exactly min(K, M) components matched.
        matched = mapping[mapping >= 0]
        assert len(matched) == min(n_components, n_modes) and len(set(matched.tolist())) == len(matched)
        best = 0.0
        for perm in itertools.permutations(range(max(n_components, n_modes)), n_components):
            candidate = np.array([m if m < n_modes else -1 for m in perm])
            best = max(best, latent_accuracy(q, modes, candidate))
        assert latent_accuracy(q, modes, mapping) == pytest.approx(best)


# --- KL -------------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("n_components", [2, 3, 5])
def test_uniform_posteriors_kl_by_hand(n_components: int):
    k = n_components
    modes = np.arange(k).repeat(2)
    q = np.full((len(modes), k), 1 / k)
    identity = np.arange(k)
    # One aligned component: p* = (1 - eps) on it, eps / (K - 1) on each of the K - 1 others, so
    # KL = (1/K) log((1/K) / (1 - eps)) + ((K - 1)/K) log((1/K) / (eps / (K - 1)))
    #    = -log K - (1/K) log(1 - eps) - ((K - 1)/K) log(eps / (K - 1)).
    expected = -math.log(k) - math.log(1 - EPS) / k - (k - 1) / k * math.log(EPS / (k - 1))
    assert latent_kl(q, modes, identity, EPS) == pytest.approx(expected)
    # Nothing aligned to any mode: p* is uniform too, KL = 0.
    assert latent_kl(q, modes, np.full(k, -1), EPS) == pytest.approx(0.0)
    # With K == M every mode gets a component from the Hungarian matching, so the report agrees with the identity.
    assert latent_report(q, modes, epsilon=EPS)["latent_kl"] == pytest.approx(expected)


def test_kl_of_a_confidently_wrong_posterior_is_finite():
    q = one_hot([1], 3)
    modes = np.array([0])
    # p*(1) = eps / 2, so KL = log(2 / eps).
    assert latent_kl(q, modes, np.array([0, 1, 2]), EPS) == pytest.approx(math.log(2 / EPS))


def test_kl_with_two_components_aligned_to_one_mode():
    q = np.array([[0.5, 0.25, 0.25]])
    modes = np.array([0])
    # Components 0 and 1 share 1 - eps; component 2 gets eps.
    p = np.array([(1 - EPS) / 2, (1 - EPS) / 2, EPS])
    expected = float(np.sum(q[0] * np.log(q[0] / p)))
    assert latent_kl(q, modes, np.array([0, 0, 1]), EPS) == pytest.approx(expected)


def test_kl_is_smallest_for_the_perfect_posterior():
    modes = np.array([0, 1, 0, 1])
    mapping = np.array([0, 1])
    perfect = one_hot(modes, 2)
    soft = np.array([[0.9, 0.1], [0.2, 0.8], [0.6, 0.4], [0.5, 0.5]])
    assert latent_kl(perfect, modes, mapping) < latent_kl(soft, modes, mapping)


# --- NMI ------------------------------------------------------------------------------------------------------------


def test_nmi_by_hand():
    a = [0, 0, 1, 1]
    b = [0, 0, 0, 1]
    # Joint: p(0,0) = 1/2, p(1,0) = 1/4, p(1,1) = 1/4; marginals p_a = (1/2, 1/2), p_b = (3/4, 1/4).
    mi = 0.5 * math.log(0.5 / (0.5 * 0.75)) + 0.25 * math.log(0.25 / (0.5 * 0.75)) + 0.25 * math.log(0.25 / (0.5 * 0.25))
    h_a = math.log(2)
    h_b = -(0.75 * math.log(0.75) + 0.25 * math.log(0.25))
    expected = mi / ((h_a + h_b) / 2)
    assert expected == pytest.approx(0.3437110, abs=1e-6)
    assert normalized_mutual_information(np.array(a), np.array(b)) == pytest.approx(expected)


def test_nmi_against_reference_formula():
    rng = np.random.default_rng(0)
    for _ in range(10):
        a = rng.integers(0, 3, size=25)
        b = (a + rng.integers(0, 2, size=25)) % 4
        assert normalized_mutual_information(a, b) == pytest.approx(reference_nmi(a.tolist(), b.tolist()))


def test_nmi_is_symmetric_and_invariant_to_relabelling():
    a = np.array([0, 0, 1, 1, 2, 2, 2, 0])
    b = np.array([1, 1, 1, 0, 0, 2, 2, 0])
    value = normalized_mutual_information(a, b)
    assert normalized_mutual_information(b, a) == pytest.approx(value)
    renamed_a = np.array([7, 3, 5])[a]
    renamed_b = np.array(["x", "y", "z"])[b]
    assert normalized_mutual_information(renamed_a, renamed_b) == pytest.approx(value)
    assert normalized_mutual_information(a, np.array([9, 4, 6])[a]) == pytest.approx(1.0)


def test_nmi_of_independent_labellings_is_zero():
    assert normalized_mutual_information([0, 0, 1, 1], [0, 1, 0, 1]) == pytest.approx(0.0)


def test_nmi_constant_labelling_conventions():
    assert normalized_mutual_information([3, 3, 3], [5, 5, 5]) == 1.0  # one cluster each: a perfect match
    assert normalized_mutual_information([0], [1]) == 1.0
    assert normalized_mutual_information([0, 0, 0, 0], [0, 1, 0, 1]) == 0.0  # one constant: MI = 0
    assert normalized_mutual_information([0, 1, 2, 3], [2, 2, 2, 2]) == 0.0


def test_nmi_lies_in_unit_interval():
    rng = np.random.default_rng(1)
    for _ in range(20):
        value = normalized_mutual_information(rng.integers(0, 4, size=12), rng.integers(0, 3, size=12))
        assert 0.0 <= value <= 1.0


# --- validation -----------------------------------------------------------------------------------------------------

GOOD_Q = np.array([[0.7, 0.3], [0.1, 0.9]])
GOOD_MODES = np.array([0, 1])


@pytest.mark.parametrize(
    "posteriors,match",
    [
        (np.array([0.5, 0.5]), "posteriors must be a 2-D array"),
        (np.ones((2, 1, 1)), "posteriors must be a 2-D array"),
        (np.zeros((0, 2)), "at least one sample and one component"),
        (np.zeros((2, 0)), "at least one sample and one component"),
        (np.array([["a", "b"], ["c", "d"]]), "posteriors must hold real numbers"),
        (np.array([[1.2, -0.2], [0.5, 0.5]]), "posteriors must be non-negative"),
        (np.array([[np.nan, 1.0], [0.5, 0.5]]), "posteriors must be finite"),
        (np.array([[0.5, 0.5], [0.5, 0.6]]), "row 1 sums to"),
        (np.array([[0.5, 0.5], [0.5, 0.501]]), "must sum to 1"),
    ],
)
def test_bad_posteriors(posteriors, match):
    with pytest.raises(ValueError, match=match):
        align_components(posteriors, GOOD_MODES)
    with pytest.raises(ValueError, match=match):
        latent_report(posteriors, GOOD_MODES)


def test_row_sum_tolerance():
    q = np.array([[0.5, 0.50005], [0.2, 0.8]])
    np.testing.assert_array_equal(align_components(q, GOOD_MODES), [0, 1])


@pytest.mark.parametrize(
    "modes,match",
    [
        (np.array([[0, 1]]), "true_modes must be a 1-D array"),
        (np.array([0.0, 1.0]), "true_modes must hold integers"),
        (np.array([True, False]), "true_modes must hold integers"),
        (np.array([0, 1, 1]), r"one entry per row of posteriors \(N=2\), got 3"),
        (np.array([0, -1]), "true_modes must be non-negative"),
    ],
)
def test_bad_true_modes(modes, match):
    for call in (
        lambda: align_components(GOOD_Q, modes),
        lambda: latent_accuracy(GOOD_Q, modes, np.array([0, 1])),
        lambda: latent_kl(GOOD_Q, modes, np.array([0, 1])),
        lambda: latent_report(GOOD_Q, modes),
    ):
        with pytest.raises(ValueError, match=match):
            call()


@pytest.mark.parametrize("n_modes", [1, 0, 2.0, True, "2"])
def test_bad_n_modes(n_modes):
    with pytest.raises(ValueError, match=r"n_modes must be an integer >= max\(true_modes\) \+ 1 = 2"):
        align_components(GOOD_Q, GOOD_MODES, n_modes=n_modes)


@pytest.mark.parametrize(
    "mapping,match",
    [
        (np.array([0, 1, 2]), r"one entry per component \(K=2\)"),
        (np.array([[0, 1]]), r"one entry per component \(K=2\)"),
        (np.array([0.0, 1.0]), "mapping must hold integers"),
        (np.array([0, -2]), "-1 for unmatched"),
    ],
)
def test_bad_mapping(mapping, match):
    with pytest.raises(ValueError, match=match):
        latent_accuracy(GOOD_Q, GOOD_MODES, mapping)
    with pytest.raises(ValueError, match=match):
        latent_kl(GOOD_Q, GOOD_MODES, mapping)


@pytest.mark.parametrize("epsilon", [0.0, 1.0, -0.1, 1.5, float("nan"), True, "0.1"])
def test_bad_epsilon(epsilon):
    with pytest.raises(ValueError, match=r"epsilon must be a number in the open interval \(0, 1\)"):
        latent_kl(GOOD_Q, GOOD_MODES, np.array([0, 1]), epsilon=epsilon)
    with pytest.raises(ValueError, match="epsilon"):
        latent_report(GOOD_Q, GOOD_MODES, epsilon=epsilon)


@pytest.mark.parametrize(
    "a,b,match",
    [
        ([[0, 1]], [0, 1], "labels_a must be a 1-D array"),
        ([0, 1], [[0, 1]], "labels_b must be a 1-D array"),
        ([], [], "labels_a must have at least one label"),
        ([0, 1, 1], [0, 1], "same length, got 3 and 2"),
    ],
)
def test_bad_labels(a, b, match):
    with pytest.raises(ValueError, match=match):
        normalized_mutual_information(a, b)
