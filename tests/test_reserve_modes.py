"""The hidden mode matters (poachers enter and move differently) and is learnable from a history only."""

import itertools

import numpy as np
import pytest
from scipy import stats

from wildlife_reserve import reserve_v1
from wildlife_reserve.reserve import actors
from wildlife_reserve.reserve.kernels.constants import CH_LEOPARD, CH_POACHER, POACHER_ACTIVE
from wildlife_reserve.reserve.modes import MODE_NAMES, N_MODES, STRATEGIES, WEATHERS, decode_mode


def test_mode_indices_decode_to_strategy_and_weather():
    assert N_MODES == len(STRATEGIES) * len(WEATHERS) == len(MODE_NAMES) == 8
    for m in range(N_MODES):
        strategy, weather = decode_mode(m)
        assert MODE_NAMES[m] == f"{strategy.name}/{weather.name}"


def poacher_statistics(strategy_index, episodes=40):
    """Entry times, within-episode spread of entry cells, and per-step progress toward the target den
    while still on the way (further than a poacher's sight from it)."""
    env = reserve_v1.parallel_env(n_uavs=1, grid_size=60, n_poachers=6, max_cycles=120, terrain_seed=None)
    times, spreads, progress = [], [], []
    for seed in range(episodes):
        env.reset(seed=seed, options={"mode": 2 * strategy_index, "uav_positions": [[0, 0]]})
        times.extend(env.poacher_entry_time / env.max_cycles)
        spreads.append(env.poacher_entry.std(axis=0).sum())
        previous = None
        while env.agents:
            env.step({"uav_0": 0})
            active = env.poacher_status == POACHER_ACTIVE
            dist = np.abs(env.poacher_pos - env.poacher_target).sum(-1)
            if previous is not None:
                both = active & previous[1] & (previous[0] > 2 * actors.POACHER_SIGHT)
                progress.extend(previous[0][both] - dist[both])
            previous = (dist, active)
    return np.array(times), np.array(spreads), np.array(progress)


def test_strategies_produce_different_entry_and_movement_distributions():
    samples = [poacher_statistics(s) for s in range(len(STRATEGIES))]
    for a, b in itertools.combinations(range(len(STRATEGIES)), 2):
        p_values = [stats.ks_2samp(x, y).pvalue for x, y in zip(samples[a], samples[b])]
        assert min(p_values) < 1e-4, f"{STRATEGIES[a].name} vs {STRATEGIES[b].name}: p = {p_values}"
    # Spot checks of what each strategy is meant to do.
    times, spreads, progress = zip(*samples)
    assert np.mean(times[0]) < np.mean(times[3])  # raids come early, dispersed poachers late
    assert np.median(spreads[2]) < 3.0 < np.median(spreads[3])  # the group enters together
    assert np.mean(progress[0]) > np.mean(progress[1]) > np.mean(progress[3])  # raiders head straight in


def test_the_first_observation_is_the_same_in_every_mode():
    env = reserve_v1.parallel_env()
    for seed in range(3):
        first, _ = env.reset(seed=seed, options={"mode": 0})
        for mode in range(1, N_MODES):
            obs, infos = env.reset(seed=seed, options={"mode": mode})
            assert infos["uav_0"]["mode"] == mode
            for agent in env.agents:
                np.testing.assert_array_equal(obs[agent], first[agent])


def history_features(env, history):
    """What a team could compute from its observation history: where, when and how far out readings occur."""
    r = env.r
    ring = np.maximum(*np.abs(np.indices((2 * r + 1, 2 * r + 1)) - r))
    readings, outer, total, leopards = [], 0, 0, 0
    for t, obs in enumerate(history):
        parts = env.split_observation(obs)
        cells = np.floor(parts["own"][:, :2] * [env.height - 1, env.width - 1]).astype(int)
        signals = parts["window"][:, [CH_POACHER, CH_LEOPARD]] > 0.5
        total += signals.sum()
        outer += signals[:, :, ring == r].sum()
        leopards += signals[:, 1].sum()
        uav, dr, dc = np.nonzero(signals[:, 0])
        readings += [(t, cells[i, 0] + a - r, cells[i, 1] + b - r) for i, a, b in zip(uav, dr, dc)]
    first = np.array(readings[:6], float).reshape(-1, 3)
    if not len(first):
        first = np.array([[len(history), env.height / 2, env.width / 2]])
    t, row, col = first.T
    edge = np.stack([row, env.height - 1 - row, col, env.width - 1 - col], 1)
    side = np.bincount(edge.argmin(1), minlength=4).max() / len(first)
    burst = max(((t >= s) & (t < s + 5)).sum() for s in t) / len(first)
    return np.array([outer / max(total, 1), leopards, len(readings), t[0], t.mean(), t.std(), edge.min(1).mean(),
                     row.std() + col.std(), side, burst])


def nearest_centroid_accuracy(features, labels, seed=0):
    """Train on three quarters, test on the rest; standardised features, nearest class mean."""
    train = np.random.default_rng(seed).permutation(len(features)) % 4 != 0
    mean, std = features[train].mean(0), features[train].std(0) + 1e-9
    z = (features - mean) / std
    classes = np.unique(labels)
    centroids = np.stack([z[train & (labels == c)].mean(0) for c in classes])
    predicted = classes[((z[~train, None, :] - centroids[None]) ** 2).sum(-1).argmin(1)]
    return float((predicted == labels[~train]).mean())


@pytest.fixture(scope="module")
def random_patrol_episodes():
    env = reserve_v1.parallel_env(grid_size=40, n_poachers=6, max_cycles=150, terrain_seed=None)
    rng = np.random.default_rng(0)
    histories, modes = [], []
    for episode in range(240):
        obs, _ = env.reset(seed=episode, options={"mode": episode % N_MODES})
        history = [np.stack(list(obs.values()))]
        while env.agents:
            obs, *_ = env.step(dict(zip(env.agents, rng.integers(0, 5, env.n).tolist())))
            history.append(np.stack(list(obs.values())))
        histories.append(history)
        modes.append(episode % N_MODES)
    return env, histories, np.array(modes)


def test_a_history_identifies_the_mode_far_above_chance(random_patrol_episodes):
    env, histories, modes = random_patrol_episodes
    features = np.stack([history_features(env, h) for h in histories])
    assert nearest_centroid_accuracy(features, modes) > 3 * (1 / N_MODES)
    assert nearest_centroid_accuracy(features, modes // len(WEATHERS)) > 1.6 * (1 / len(STRATEGIES))
    assert nearest_centroid_accuracy(features, modes % len(WEATHERS)) > 0.9


def test_no_single_observation_reveals_the_mode(random_patrol_episodes):
    env, histories, modes = random_patrol_episodes
    history_accuracy = nearest_centroid_accuracy(np.stack([history_features(env, h) for h in histories]), modes)
    for step in (10, 75, 149):
        single = np.stack([h[step][0] for h in histories])  # what one UAV sees at one step
        accuracy = nearest_centroid_accuracy(single, modes)
        assert accuracy < 0.3 and accuracy < history_accuracy - 0.2, (step, accuracy, history_accuracy)
        assert nearest_centroid_accuracy(single, modes // len(WEATHERS)) < 0.4
        assert nearest_centroid_accuracy(single, modes % len(WEATHERS)) < 0.7


def test_the_card_states_each_strategy_as_the_code_has_it():
    from pathlib import Path

    card = (Path(__file__).resolve().parents[1] / "docs" / "env.md").read_text().splitlines()
    for strategy in STRATEGIES:
        row = next(line for line in card if f"`{strategy.name}`" in line and line.startswith("|"))
        low, high = strategy.entry_window
        assert f"| {low:g}-{high:g} (" in row, row
        wait = 1.0 - strategy.move_prob - strategy.wander_prob
        probabilities = f"| {strategy.move_prob:.2f} / {strategy.wander_prob:.2f} / {wait:.2f} | {strategy.evasion_prob:g} |"
        assert probabilities in row, row
