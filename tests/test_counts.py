"""The reading-count mixture: counts and exposures by (block, ring) on hand-built observations, its likelihood, and EM."""

import numpy as np
import pytest
from scipy.stats import poisson

from sb3_emmarl.common.latent.counts import PoissonMixture
from sb3_emmarl.common.latent.reserve_evidence import COUNT_EVIDENCE_WEIGHT, ReadingCounter
from wildlife_reserve import reserve_v1
from wildlife_reserve.reserve.kernels.constants import CH_LEOPARD, CH_OCCLUSION, CH_SIGN


@pytest.fixture(scope="module")
def reserve():
    env = reserve_v1.parallel_env(n_uavs=2, grid_size=16, sensor_radius=1, belief_size=4)
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


# ---------------------------------------------------------------------- the count model inside EM-PPO


def test_em_ppo_on_the_reserve_has_a_count_model_and_off_it_none():
    import gymnasium as gym
    from stable_baselines3.common.env_util import make_vec_env as sb3_make_vec_env

    from sb3_emmarl import EMPPO
    from sb3_emmarl.common.vec_env import make_vec_env

    on = EMPPO("MlpPolicy", make_vec_env(env_kwargs={"n_uavs": 3, "grid_size": 20, "max_cycles": 30}), n_steps=32,
               batch_size=32, seed=0)
    assert (on.latent_layout.count_channels, on.latent_layout.count_bins) == (3, 8 * 8 * 4)
    assert on.policy.latent_model.has_counts
    off = EMPPO("MlpPolicy", sb3_make_vec_env(lambda: gym.make("CartPole-v1"), n_envs=2), n_steps=32, batch_size=32,
                seed=0)
    assert off.latent_layout.count_bins == 0 and not off.policy.latent_model.has_counts


def test_the_belief_adds_the_count_evidence_of_every_new_observation():
    import torch as th

    from sb3_emmarl import EMPPO
    from sb3_emmarl.common.vec_env import make_vec_env

    model = EMPPO("MlpPolicy", make_vec_env(env_kwargs={"n_uavs": 3, "grid_size": 20, "max_cycles": 30}, seed=4),
                  n_steps=32, batch_size=32, seed=0, latent_kwargs=dict(likelihood_temperature=0.5, fusion=False))
    latent = model.policy.latent_model
    with th.no_grad():
        latent.count_log_rates.copy_(th.randn(latent.count_log_rates.shape) - 2.0)
    venv = model.get_env()
    wrapper, obs_dim = venv, model.latent_layout.obs_dim
    observations = venv.reset()[:, :obs_dim]
    rng = np.random.default_rng(0)
    expected = np.zeros((venv.num_envs, latent.n_components))
    for _ in range(12):  # within one episode (30 steps)
        actions = rng.integers(15, size=venv.num_envs)
        following = venv.step(actions)[0][:, :obs_dim]
        with th.no_grad():
            x, a = th.as_tensor(model._feature_fn(observations)), th.as_tensor(model._encode_action(actions))
            x_next = th.as_tensor(model._feature_fn(following))
            counts, exposure = model._counter(following)
            read = latent.count_log_likelihood(th.as_tensor(counts.reshape(len(counts), -1), dtype=th.float32),
                                               th.as_tensor(exposure, dtype=th.float32))
            step = 0.5 * latent.transition_log_likelihood(x, a, x_next) + COUNT_EVIDENCE_WEIGHT * read
        expected += step.double().numpy()
        observations = following
    np.testing.assert_allclose(wrapper.tracker.evidence, expected, rtol=1e-3, atol=1e-2)
    assert np.abs(expected).max() > 1.0  # the counts did weigh in


def counted_e_step(window: int = 2):
    """An E-step over a latent model with a count model of 2 components, 1 channel and 3 bins."""
    import torch as th

    from sb3_emmarl.common.latent.em import EStep
    from sb3_emmarl.common.latent.layout import LatentLayout
    from sb3_emmarl.common.latent.model import LatentModel

    th.manual_seed(0)
    layout = LatentLayout(obs_dim=2, feature_dim=2, action_dim=1, n_components=2, count_channels=1, count_bins=3)
    # the transitions tell nothing here: only the counts weigh in the responsibilities
    return EStep(LatentModel(layout), n_epochs=1, window=window, starved_share=0.0, likelihood_temperature=1e-6,
                 count_weight=COUNT_EVIDENCE_WEIGHT)


def rollout(episodes: list[int], rng: np.random.Generator, steps: int = 20):
    """Transitions (nothing to tell from them) and per-episode counts: episodes < 2 read bin 0, the others bin 2."""
    from sb3_emmarl.common.latent.em import EpisodeCounts, Transitions

    ids = np.repeat(episodes, steps)
    x = rng.standard_normal((len(ids), 2)).astype(np.float32)
    data = Transitions.from_numpy(x, np.zeros((len(ids), 1)), x, ids)
    exposure = np.ones((len(ids), 3))
    counts = rng.poisson(np.where((ids < 2)[:, None], [2.0, 0.1, 0.1], [0.1, 0.1, 2.0]))[:, None, :].astype(float)
    return data, EpisodeCounts.from_steps(ids, counts, exposure), exposure.sum()


def test_the_count_table_holds_each_episode_once_with_all_its_rollouts_and_its_age():
    import torch as th

    from sb3_emmarl.common.latent.em import COUNT_DECAY

    e_step, rng = counted_e_step(window=2), np.random.default_rng(0)
    first, first_counts, first_exposure = rollout([0, 1, 2, 3], rng)
    e_step.add(first, first_counts)
    e_step.step()
    second, second_counts, second_exposure = rollout([0, 1, 2, 3], rng)  # the same episodes, their next steps
    e_step.add(second, second_counts)
    e_step.step()
    table = e_step.count_table
    # the first rollout is still kept beside the second, yet each rollout joined the table once
    assert table["ids"].tolist() == [0, 1, 2, 3] and table["age"].tolist() == [0, 0, 0, 0]
    th.testing.assert_close(table["counts"], (first_counts.counts + second_counts.counts).double())
    assert float(table["exposure"].sum()) == pytest.approx(first_exposure + second_exposure)
    assert float(table["pooled"][1]) == pytest.approx(first_exposure + second_exposure)
    third, third_counts, _ = rollout([4, 5], rng)
    e_step.add(third, third_counts)
    e_step.step()
    assert e_step.count_table["ids"].tolist() == [0, 1, 2, 3, 4, 5]
    assert e_step.count_table["age"].tolist() == [1, 1, 1, 1, 0, 0]  # weights COUNT_DECAY ** age
    assert COUNT_DECAY < 1


def test_the_count_table_keeps_the_newest_episodes(monkeypatch):
    import sb3_emmarl.common.latent.em as em

    monkeypatch.setattr(em, "COUNT_TABLE_EPISODES", 6)
    e_step, rng = counted_e_step(window=1), np.random.default_rng(0)
    for episodes in ([0, 1, 2, 3], [4, 5, 6, 7]):
        data, counts, _ = rollout(episodes, rng)
        e_step.add(data, counts)
        e_step.step()
    assert e_step.count_table["ids"].tolist() == [2, 3, 4, 5, 6, 7]
    assert all(len(e_step.count_table[name]) == 6 for name in em.ROW_FIELDS)


def test_the_count_rates_are_batch_em_over_every_remembered_episode(monkeypatch):
    """At EM's fixed point the rates are the closed form of the whole table, each episode weighted by its
    responsibilities (from the counts alone here) times ``COUNT_DECAY ** age``, not only of the fresh rollout's."""
    import torch as th

    import sb3_emmarl.common.latent.em as em
    from sb3_emmarl.common.latent.counts import PRIOR_EXPOSURE

    monkeypatch.setattr(em, "COUNT_ITERATIONS", 200)  # run EM to its fixed point
    e_step, rng = counted_e_step(window=1), np.random.default_rng(3)
    for episodes in ([0, 1, 2, 3], [4, 5, 6, 7], [8, 9, 10, 11]):
        data, counts, _ = rollout([e % 4 for e in episodes], rng)
        data.episodes += episodes[0]
        counts.episodes += episodes[0]
        e_step.add(data, counts)
        e_step.step()
    table, model = e_step.count_table, e_step.model
    assert len(table["ids"]) == 12 and table["age"].tolist() == [2] * 4 + [1] * 4 + [0] * 4
    with th.no_grad():
        evidence = COUNT_EVIDENCE_WEIGHT * model.count_log_likelihood(table["counts"].float(), table["exposure"].float())
    # the transitions say (almost) nothing here (likelihood temperature 1e-6)
    r = th.softmax(evidence.double() + model.log_prior.double(), dim=1) * em.COUNT_DECAY ** table["age"][:, None]
    pooled = table["pooled"][0] / table["pooled"][1]
    rates = ((r.T @ table["counts"]).reshape(2, 1, 3) + PRIOR_EXPOSURE * pooled) / (
        (r.T @ table["exposure"])[:, None] + PRIOR_EXPOSURE)
    th.testing.assert_close(model.count_log_rates.exp().double(), rates, rtol=1e-4, atol=1e-6)
    # the two kinds of episode (bin 0 against bin 2) went to different components
    assert sorted(rates[:, 0, [0, 2]].argmax(dim=1).tolist()) == [0, 1]


def test_the_counts_alone_tell_two_kinds_of_episode_apart_after_a_few_e_steps():
    from sb3_emmarl.common.latent.metrics import align_components

    e_step, rng = counted_e_step(window=1), np.random.default_rng(1)
    for round_ in range(15):
        episodes = list(range(4 * round_, 4 * round_ + 4))
        data, counts, _ = rollout([e % 4 for e in episodes], rng)
        data.episodes += 4 * round_
        counts.episodes += 4 * round_
        e_step.add(data, counts)
        e_step.step()
    log_r, _, _ = e_step.responsibilities(data)
    posterior, kinds = log_r.exp().numpy(), np.array([0, 0, 1, 1])
    assert (align_components(posterior, kinds, 2)[posterior.argmax(1)] == kinds).all()
    assert posterior.max(axis=1).min() > 0.9


def test_episode_counts_from_observations_sum_the_per_step_counts():
    from sb3_emmarl.common.latent.em import EpisodeCounts
    from sb3_emmarl.common.vec_env import make_vec_env

    venv = make_vec_env(n_copies=2, seed=1, env_kwargs={"n_uavs": 3, "grid_size": 20, "max_cycles": 30})
    counter = ReadingCounter.from_env(venv.unwrapped.prototype)
    rng, rows = np.random.default_rng(0), [venv.reset()]
    for _ in range(20):
        rows.append(venv.step(rng.integers(15, size=venv.num_envs))[0])
    observations = np.concatenate(rows)
    episodes = rng.integers(5, 9, size=len(observations))  # any ids
    grouped = EpisodeCounts.from_observations(counter, observations, episodes)
    counts, exposure = counter(observations)
    assert counts.sum() > 0
    steps = EpisodeCounts.from_steps(episodes, counts, exposure)
    np.testing.assert_array_equal(grouped.episodes.numpy(), [5, 6, 7, 8])
    np.testing.assert_allclose(grouped.counts.numpy(), steps.counts.numpy(), rtol=1e-6)
    np.testing.assert_allclose(grouped.exposure.numpy(), steps.exposure.numpy(), rtol=1e-5)
    # Blocks of augmented rows (extra columns after the observation, as the beliefs), read in place, with rows to skip
    # (-1), give the sums of the kept rows stacked, to the bit.
    augmented = np.concatenate([observations, rng.random((len(observations), 4), dtype=np.float32)], axis=1)
    skipped = episodes.copy()
    skipped[::3] = -1
    kept = skipped >= 0
    alone = EpisodeCounts.from_observations(counter, observations[kept], episodes[kept])
    half = len(augmented) // 2
    blocks = EpisodeCounts.from_observations(counter, (augmented[:half], augmented[half:][None]), skipped)
    np.testing.assert_array_equal(blocks.episodes.numpy(), alone.episodes.numpy())
    np.testing.assert_array_equal(blocks.counts.numpy(), alone.counts.numpy())
    np.testing.assert_array_equal(blocks.exposure.numpy(), alone.exposure.numpy())
    with pytest.raises(ValueError, match="one entry per observation"):
        EpisodeCounts.from_observations(counter, (augmented[:half],), skipped)
    with pytest.raises(ValueError, match="at least one block"):
        EpisodeCounts.from_observations(counter, [], skipped[:0])


def test_the_compiled_step_likelihood_equals_the_binned_counts_times_the_table():
    from sb3_emmarl.common.vec_env import make_vec_env

    venv = make_vec_env(n_copies=2, seed=2)
    counter = ReadingCounter.from_env(venv.unwrapped.prototype)
    rng = np.random.default_rng(0)
    venv.reset()
    for _ in range(40):
        observations = venv.step(rng.integers(15, size=venv.num_envs))[0]
        table = rng.standard_normal((1 + counter.n_channels, counter.n_bins, 4))
        binned = counter.binned(*counter.cells(observations))[..., :counter.n_bins]
        np.testing.assert_allclose(counter.log_likelihood(observations, table), np.einsum("npb,pbk->nk", binned, table),
                                   rtol=1e-10, atol=1e-10)


def test_grouped_counts_reject_groups_that_do_not_fit(reserve):
    counter = ReadingCounter.from_env(reserve)
    observations = np.stack([blank(reserve, 5, 3)] * 3)
    with pytest.raises(ValueError, match="one entry per observation"):
        counter.grouped(observations, [0, 1])
    with pytest.raises(ValueError, match=r"groups must lie in \[0, 2\)"):
        counter.grouped(observations, [0, 1, 2], n_groups=2)
    summed = counter.grouped(observations, [1, 1, 1], n_groups=3)
    assert summed.shape == (3, 1 + counter.n_channels, counter.n_bins)
    np.testing.assert_allclose(summed[1], 3 * counter.grouped(observations[:1], [0])[0])
    assert not summed[[0, 2]].any()
    # A row of group -1 is skipped; out accumulates (float64 of the right shape only).
    np.testing.assert_allclose(counter.grouped(observations, [1, -1, 1], n_groups=3)[1], 2 * summed[1] / 3)
    total = counter.grouped(observations[:1], [1], n_groups=3)
    assert counter.grouped(observations[1:], [1, 1], out=total) is total
    np.testing.assert_array_equal(total, summed)
    with pytest.raises(ValueError, match=r"or be -1"):
        counter.grouped(observations, [0, -2, 1], n_groups=2)
    with pytest.raises(ValueError, match="out must be a float64 array of shape"):
        counter.grouped(observations, [0, 0, 0], out=np.zeros((1, 1 + counter.n_channels, counter.n_bins), np.float32))


def test_factored_rates_recover_planted_where_and_how_far_factors():
    from sb3_emmarl.common.latent.counts import factored_rates

    rng = np.random.default_rng(0)
    f1, f2, channels, blocks, rings = 3, 2, 2, 5, 4
    a = rng.normal(-1.0, 0.5, (f1, 1, channels, blocks, 1))
    b = rng.normal(0.0, 0.5, (1, f2, channels, 1, rings))
    true = np.exp(a + b).reshape(f1 * f2, channels, blocks * rings)
    exposure = rng.uniform(5e4, 1e5, (f1 * f2, blocks * rings))
    counts = rng.poisson(true * exposure[:, None, :]).astype(float)
    pooled = counts.sum(axis=(0, 2)) / exposure.sum()
    rates = factored_rates(counts, exposure, pooled, (f1, f2), rings, rounds=20)
    np.testing.assert_allclose(rates, true, rtol=0.05)
    # the fit is factored: two components of one first factor differ by a ring profile, the same in every block
    ratio = (rates[0] / rates[1]).reshape(channels, blocks, rings)
    np.testing.assert_allclose(ratio, np.broadcast_to(ratio[:, :1], ratio.shape), rtol=1e-9)
    with pytest.raises(ValueError, match="do not fit factors"):
        factored_rates(counts, exposure, pooled, (2, 2), rings)


def test_factored_mixture_finds_where_x_how_far_modes_that_the_unfactored_one_misses():
    """Four modes = 2 'where' (which blocks are busy) x 2 'how far' (the outer ring read less), sparse counts: the
    factored mixture pools the ring effect over every block and finds the modes; the unfactored one, with each
    component's every bin its own, finds them hardly more often than half the time."""
    from sb3_emmarl.common.latent.metrics import align_components

    rng = np.random.default_rng(1)
    blocks, rings, n = 32, 4, 300
    where = np.where(rng.random((2, blocks)) < 0.5, 2.0, 0.5)
    far = np.array([[1.0, 1.0, 1.0, 1.0], [1.0, 1.0, 1.0, 0.3]])
    modes = rng.integers(4, size=n)
    rates = (where[modes // 2][:, :, None] * far[modes % 2][:, None, :]).reshape(n, 1, blocks * rings)
    exposure = np.full((n, blocks * rings), 0.1)
    counts = rng.poisson(rates * exposure[:, None, :]).astype(float)

    def accuracy(mixture):
        posterior = mixture.fit(counts, exposure, seed=0).posterior(counts, exposure)
        guess = align_components(posterior, modes, 4)[posterior.argmax(axis=1)]
        return float((guess == modes).mean())

    factored = accuracy(PoissonMixture(4, 1, blocks * rings, factors=(2, 2), n_rings=rings))
    assert factored > 0.7
    assert factored > accuracy(PoissonMixture(4, 1, blocks * rings)) + 0.1


def test_count_factors_are_checked_against_n_components():
    from sb3_emmarl import EMPPO
    from sb3_emmarl.common.latent.counts import check_factors
    from sb3_emmarl.common.vec_env import make_vec_env

    assert check_factors(None, 8) is None and check_factors([4, 2], 8) == (4, 2)
    for bad, message in (([4, 3], "must multiply to n_components = 8"), ([8], "two ints"), ((4, True), "two ints")):
        with pytest.raises(ValueError, match=message):
            check_factors(bad, 8)
    with pytest.raises(ValueError, match="count_factors"):
        EMPPO("MlpPolicy", make_vec_env(env_kwargs={"n_uavs": 3, "grid_size": 20, "max_cycles": 30}), n_steps=32,
              batch_size=32, latent_kwargs=dict(n_components=8, count_factors=(3, 2)))
    with pytest.raises(ValueError, match="count_factors"):
        PoissonMixture(8, 1, 4, factors=(2, 2))


def test_em_ppo_with_count_factors_fits_factored_rates_and_keeps_them_through_save_and_load(tmp_path):
    from sb3_emmarl import EMPPO
    from sb3_emmarl.common.vec_env import make_vec_env

    def env():
        return make_vec_env(env_kwargs={"n_uavs": 3, "grid_size": 20, "max_cycles": 30}, seed=3)

    # no re-seeding of starved components: a split perturbs the rates until the next E-step fits them again
    model = EMPPO("MlpPolicy", env(), n_steps=32, batch_size=32, seed=0,
                  latent_kwargs=dict(n_components=4, count_factors=(2, 2), e_step_kwargs={"starved_share": 0.0}))
    assert model.e_step.count_factors == (2, 2) and model.e_step.count_rings == 4
    model.learn(3 * 32 * 3)
    log_rates = model.policy.latent_model.count_log_rates.double().numpy()  # (K, channels, blocks * rings)
    difference = (log_rates[0] - log_rates[1]).reshape(log_rates.shape[1], -1, 4)  # same first factor
    np.testing.assert_allclose(difference, np.broadcast_to(difference[:, :1], difference.shape), atol=1e-4)
    assert np.abs(log_rates[0] - log_rates[2]).max() > 1e-3  # another first factor: another profile
    model.save(tmp_path / "model.zip")
    loaded = EMPPO.load(tmp_path / "model.zip", env=env())
    assert loaded.latent_config.count_factors == (2, 2) and loaded.e_step.count_factors == (2, 2)
