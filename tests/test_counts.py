"""The reading-count mixture: counts and exposures by (block, ring) on hand-built observations, its likelihood, and EM."""

import numpy as np
import pytest
from scipy.stats import poisson

from sb3_emmarl.common.latent.counts import PoissonMixture, ReadingCounter
from wildlife_reserve import reserve_v0
from wildlife_reserve.reserve.constants import CH_LEOPARD, CH_OCCLUSION, CH_SIGN


@pytest.fixture(scope="module")
def reserve():
    env = reserve_v0.parallel_env(n_uavs=2, grid_size=16, sensor_radius=1, belief_size=4)
    env.reset(seed=0)
    return env


def blank(env, row: int, col: int) -> np.ndarray:
    """An observation with an empty, fully transparent window, the UAV at (row, col)."""
    obs = np.zeros(env.obs_dim, dtype=np.float32)
    own = env.observation_layout["own"][0]
    obs[own.start:own.start + 2] = np.array([row, col]) / (np.array([env.height, env.width]) - 1)
    return obs


def test_counts_and_exposure_by_block_and_ring_on_a_hand_built_window(reserve):
    counter = ReadingCounter.from_env(reserve)
    assert (counter.n_channels, counter.n_rings, counter.n_bins) == (3, 2, 4 * 4 * 2)
    window_part, shape = reserve.observation_layout["window"]
    obs = blank(reserve, 5, 3)  # block (1, 0) of the 4 x 4 blocks of 4 x 4 cells; the window reaches col 4: block (1, 1)
    window = obs[window_part].reshape(shape)
    window[CH_SIGN, 1, 1] = 1.0  # under the UAV: ring 0, block 4
    window[CH_SIGN, 0, 2] = 1.0  # cell (4, 4): ring 1, block 5
    window[CH_LEOPARD, 2, 0] = 1.0  # cell (6, 2): ring 1, block 4
    window[CH_OCCLUSION, 0, 0] = 0.75  # cell (4, 2) is seen a quarter
    obs[window_part] = window.ravel()
    counts, exposure = counter(obs[None])
    assert counts.shape == (1, 3, 32) and exposure.shape == (1, 32)
    assert counts[0, 0, 4 * 2 + 0] == 1 and counts[0, 0, 5 * 2 + 1] == 1 and counts[0, 1, 4 * 2 + 1] == 1
    assert counts.sum() == 3
    assert exposure[0, 4 * 2 + 0] == 1.0  # the UAV's own cell
    # the five ring-1 cells in block 4 (cols 2-3 of rows 4-6), one seen a quarter
    assert exposure[0, 4 * 2 + 1] == pytest.approx(4.25)
    assert exposure[0, 5 * 2 + 1] == pytest.approx(3.0)  # col 4 of rows 4-6


def test_cells_outside_the_map_are_neither_counted_nor_exposed(reserve):
    counter = ReadingCounter.from_env(reserve)
    window_part, shape = reserve.observation_layout["window"]
    obs = blank(reserve, 0, 0)
    window = obs[window_part].reshape(shape)
    window[CH_SIGN] = 1.0  # every cell reads a sign, five of them off the map
    obs[window_part] = window.ravel()
    counts, exposure = counter(obs[None])
    assert counts.sum() == 4 and exposure.sum() == 4.0


def test_the_counter_rejects_bad_input(reserve):
    with pytest.raises(ValueError, match="observations must be"):
        ReadingCounter.from_env(reserve)(np.zeros(5))
    with pytest.raises(ValueError, match="belief_size must be an int in"):
        ReadingCounter(reserve.observation_layout, (16, 16), 17)
    with pytest.raises(ValueError, match="must have a 'own' part"):
        ReadingCounter({"window": reserve.observation_layout["window"]}, (16, 16), 4)


def test_the_log_likelihood_is_poissons_up_to_a_term_the_same_for_every_component():
    rng = np.random.default_rng(0)
    mixture = PoissonMixture(3, 2, 5)
    mixture.rates = rng.uniform(0.1, 2.0, (3, 2, 5))
    exposure = rng.uniform(0.0, 3.0, (4, 5))
    counts = rng.poisson(1.0, (4, 2, 5)).astype(float)
    exact = np.stack([poisson.logpmf(counts, exposure[:, None, :] * mixture.rates[k][None]).sum(axis=(1, 2))
                      for k in range(3)], axis=1)
    ours = mixture.log_likelihood(counts, exposure)
    np.testing.assert_allclose(ours - ours[:, :1], exact - exact[:, :1], rtol=1e-10, atol=1e-10)
    posterior = mixture.posterior(counts, exposure)
    np.testing.assert_allclose(posterior.sum(axis=1), 1.0)


def planted(seed: int, n: int = 300, k: int = 4, bins: int = 12):
    """Units drawn from k planted components: counts ~ Poisson(exposure * rate)."""
    rng = np.random.default_rng(seed)
    rates = rng.gamma(0.5, 1.0, (k, 2, bins))
    labels = rng.integers(k, size=n)
    exposure = rng.uniform(2.0, 6.0, (n, bins))
    counts = rng.poisson(exposure[:, None, :] * rates[labels]).astype(float)
    return rates, labels, counts, exposure


def test_told_fit_is_the_ratio_of_counts_to_exposure_with_the_prior():
    _, labels, counts, exposure = planted(1)
    mixture = PoissonMixture(4, 2, 12, prior_exposure=1e-9).fit_told(counts, exposure, labels)
    for k in range(4):
        mine = labels == k
        np.testing.assert_allclose(mixture.rates[k], counts[mine].sum(0) / exposure[mine].sum(0)[None], rtol=1e-6,
                                   atol=1e-9)
    np.testing.assert_allclose(np.exp(mixture.log_prior), np.bincount(labels, minlength=4) / len(labels), rtol=1e-4)


def test_annealed_em_recovers_planted_components_and_is_deterministic_under_a_seed():
    from sb3_emmarl.common.latent.metrics import align_components

    _, labels, counts, exposure = planted(2)
    mixture = PoissonMixture(4, 2, 12).fit(counts, exposure, n_iter=60, restarts=2, seed=3)
    posterior = mixture.posterior(counts, exposure)
    mapping = align_components(posterior, labels, 4)
    assert (mapping[posterior.argmax(1)] == labels).mean() > 0.95
    again = PoissonMixture(4, 2, 12).fit(counts, exposure, n_iter=60, restarts=2, seed=3)
    np.testing.assert_array_equal(again.rates, mixture.rates)


def test_the_mixture_rejects_bad_arguments_and_statistics():
    with pytest.raises(ValueError, match="n_components must be an int >= 1"):
        PoissonMixture(0, 1, 1)
    with pytest.raises(ValueError, match="prior_exposure must be a finite number > 0"):
        PoissonMixture(2, 1, 1, prior_exposure=0.0)
    mixture = PoissonMixture(2, 1, 3)
    with pytest.raises(ValueError, match=r"counts must have \(channels, bins\) = \(1, 3\)"):
        mixture.log_likelihood(np.zeros((2, 1, 4)), np.zeros((2, 4)))
    with pytest.raises(ValueError, match="finite and >= 0"):
        mixture.log_likelihood(-np.ones((2, 1, 3)), np.zeros((2, 3)))
    with pytest.raises(ValueError, match="anneal_from >= temperature"):
        mixture.fit(np.zeros((2, 1, 3)), np.ones((2, 3)), anneal_from=0.5)
    with pytest.raises(ValueError, match="labels must be"):
        mixture.fit_told(np.zeros((2, 1, 3)), np.ones((2, 3)), np.array([0, 2]))
