"""Hand-built cases: detection, occlusion and fog, coverage, collisions, poaching, communication, battery."""

import numpy as np
import pytest

from wildlife_reserve import reserve_v1
from wildlife_reserve.reserve import actors
from wildlife_reserve.reserve.kernels.constants import (
    CH_POACHER,
    CH_STALENESS,
    COMM_BROADCAST,
    N_MOVES,
    POACHER_ACTIVE,
    POACHER_CAUGHT,
)
from wildlife_reserve.reserve.terrain import FOREST, MOUNTAIN, OPEN

STAY, UP, DOWN, LEFT, RIGHT = range(N_MOVES)
CLEAR, FOG = 0, 1  # modes 0 and 1: hotspot raid in clear weather and in fog


def broadcast(move=STAY):
    return move + N_MOVES * COMM_BROADCAST


def make(size=15, ground=OPEN, **kwargs):
    kwargs.setdefault("n_uavs", 1)
    kwargs.setdefault("n_leopards", 0)
    kwargs.setdefault("n_poachers", 1)
    kwargs.setdefault("mode", CLEAR)
    return reserve_v1.parallel_env(grid_size=size, terrain=np.full((size, size), ground), **kwargs)


def put_poacher(env, cell, index=0):
    """Make poacher ``index`` active at ``cell`` now (its planned entry is pushed past the episode)."""
    env.poacher_entry_time[index] = 10**6
    env.poacher_status[index] = POACHER_ACTIVE
    env.poacher_pos[index] = cell


def window(env, obs):
    return env.split_observation(obs)["window"]


def belief(env, obs):
    return env.split_observation(obs)["belief"]


def detection_rate(ground, mode, trials=300):
    env = make(ground=ground, mode=mode)
    hits = 0
    for seed in range(trials):
        env.reset(seed=seed, options={"uav_positions": [[7, 7]]})
        put_poacher(env, [7, 7])
        env.step({"uav_0": STAY})
        hits += env.poacher_status[0] == POACHER_CAUGHT
    return hits / trials


def test_noiseless_uav_beside_a_poacher_in_the_open_detects_it():
    env = make()
    for seed in range(30):
        env.reset(seed=seed, options={"uav_positions": [[7, 7]]})
        put_poacher(env, [7, 7])
        obs, rewards, *_ = env.step({"uav_0": STAY})
        assert env.poacher_status[0] == POACHER_CAUGHT
        assert env.metrics["poachers_detected"] == 1
        # The reading sits in the window where the poacher is (it may have stepped one cell).
        offset = env.poacher_pos[0] - 7 + env.r
        assert window(env, obs["uav_0"])[CH_POACHER, offset[0], offset[1]] == 1.0
        assert rewards["uav_0"] > env.config.reward_weights["detection"] - 1.0


def test_forest_mountain_and_fog_lower_the_detection_rate():
    open_clear = detection_rate(OPEN, CLEAR)
    forest = detection_rate(FOREST, CLEAR)
    mountain = detection_rate(MOUNTAIN, CLEAR)
    fog = detection_rate(OPEN, FOG)
    forest_fog = detection_rate(FOREST, FOG)
    assert open_clear == 1.0
    assert forest < 0.85 and mountain < forest
    assert fog < 0.85
    assert forest_fog < min(forest, fog)


def test_fog_shrinks_the_sensing_range():
    clear, fog = make(mode=CLEAR), make(mode=FOG)
    for env in (clear, fog):
        env.reset(seed=0)
    assert clear.reach == clear.r == 3
    assert fog.reach == 2


def test_coverage_efficiency_on_a_scripted_path():
    size = 15
    rng = np.random.default_rng(3)
    risk = (rng.random((size, size)) < 0.3).astype(float)  # about 30% high-risk cells
    path = [RIGHT] * 5 + [DOWN] * 4 + [LEFT] * 2
    env = reserve_v1.parallel_env(
        n_uavs=1, grid_size=size, risk=risk, sensor_radius=1, uav_speed=1.0, n_poachers=0, n_leopards=0,
        mode=CLEAR, max_cycles=len(path),
    )
    env.reset(seed=0, options={"uav_positions": [[2, 2]]})
    infos = None
    for move in path:
        _, _, _, _, infos = env.step({"uav_0": move})
    # The cells the UAV flew over, walked by hand.
    cell = np.array([2, 2])
    seen = set()
    for move in [STAY, *path]:
        cell = cell + {STAY: (0, 0), UP: (-1, 0), DOWN: (1, 0), LEFT: (0, -1), RIGHT: (0, 1)}[move]
        for dr in (-1, 0, 1):
            for dc in (-1, 0, 1):
                r, c = cell[0] + dr, cell[1] + dc
                if 0 <= r < size and 0 <= c < size:
                    seen.add((r, c))
    high = {(r, c) for r in range(size) for c in range(size) if risk[r, c] >= 0.5}
    expected = len(seen & high) / len(high)
    assert infos["uav_0"]["metrics"]["coverage_efficiency"] == pytest.approx(expected)
    assert 0.0 < expected < 1.0


def test_two_uavs_in_one_cell_count_a_collision():
    weights = {"detection": 0.0, "coverage": 0.0, "poaching": 0.0, "collision": 1.0, "energy": 0.0}
    env = make(n_uavs=3, n_poachers=0, reward_weights=weights)
    env.reset(seed=0, options={"uav_positions": [[5, 5], [5, 5], [9, 9]]})
    _, rewards, *_ = env.step(dict.fromkeys(env.agents, STAY))
    assert env.metrics["collisions"] == 1
    assert rewards == {"uav_0": -1.0, "uav_1": -1.0, "uav_2": -1.0}
    env.step({"uav_0": STAY, "uav_1": RIGHT, "uav_2": STAY})  # speed 2: they part
    assert env.metrics["collisions"] == 1


def test_undetected_poacher_kept_beside_a_leopard_poaches_it(monkeypatch):
    monkeypatch.setattr(actors, "LEOPARD_MOVE_PROB", 0.0)
    env = make(size=30, n_leopards=1, poaching_time=3)
    env.reset(seed=0, options={"uav_positions": [[0, 0]]})  # far out of sight
    env.leopard_pos[0] = [20, 20]
    env.leopard_home[0] = [20, 20]
    put_poacher(env, [20, 20])
    rewards = []
    for _ in range(3):
        _, r, *_ = env.step({"uav_0": STAY})
        rewards.append(r["uav_0"])
    assert env.metrics["poaching_events"] == 1
    assert not env.leopard_alive[0]
    assert rewards[-1] < -env.config.reward_weights["poaching"] + 1.0


def test_detected_poacher_does_not_poach(monkeypatch):
    monkeypatch.setattr(actors, "LEOPARD_MOVE_PROB", 0.0)
    env = make(size=30, n_leopards=1, poaching_time=3)
    env.reset(seed=0, options={"uav_positions": [[20, 20]]})
    env.leopard_pos[0] = env.leopard_home[0] = [20, 20]
    put_poacher(env, [20, 20])
    for _ in range(4):
        env.step({"uav_0": STAY})
    assert env.metrics["poaching_events"] == 0 and env.leopard_alive[0]


def comm_setup(**kwargs):
    """UAV 0 broadcasts a certain detection; UAV 1 is 7 cells away, UAV 2 is 15 cells away (R_c = 10)."""
    env = make(size=40, n_uavs=3, comm_radius=10.0, **kwargs)
    env.reset(seed=0, options={"uav_positions": [[20, 5], [20, 12], [20, 20]]})
    put_poacher(env, [20, 5])
    obs, *_ = env.step({"uav_0": broadcast(), "uav_1": STAY, "uav_2": STAY})
    return env, obs


def test_a_broadcast_reaches_uavs_inside_the_comm_radius_only():
    env, obs = comm_setup()
    assert env.poacher_status[0] == POACHER_CAUGHT
    assert env.comm_links[0].tolist() == [False, True, False]
    assert env.knowledge[1, 0] == env.t and env.knowledge[2, 0] < env.t
    # The shared detection shows in UAV 1's belief map, not in UAV 2's.
    assert belief(env, obs["uav_1"]).max() > 0.5
    assert belief(env, obs["uav_2"]).max() == 0.0
    assert np.array_equal(belief(env, obs["uav_0"]), belief(env, obs["uav_1"]))


def test_shared_visits_lower_the_staleness_the_receiver_sees():
    env, _ = comm_setup()
    # UAV 1 flies to where UAV 0 was: it knows those cells were seen one step ago; UAV 2 does not.
    env.uav_pos[1] = env.uav_pos[0]
    env.uav_pos[2] = env.uav_pos[0] + [0, 1]
    env.uav_pos[0] = [39.5, 39.5]
    obs, *_ = env.step(dict.fromkeys(env.agents, STAY))
    stale_1 = window(env, obs["uav_1"])[CH_STALENESS]
    stale_2 = window(env, obs["uav_2"])[CH_STALENESS]
    assert stale_1.max() < stale_2.max()


def test_a_query_pulls_from_the_nearest_neighbour():
    env = make(size=40, n_uavs=3, comm_radius=10.0)
    env.reset(seed=0, options={"uav_positions": [[20, 5], [20, 12], [20, 20]]})
    put_poacher(env, [20, 5])
    query = STAY + N_MOVES * 2
    env.step({"uav_0": STAY, "uav_1": query, "uav_2": STAY})
    assert env.comm_links[:, 1].tolist() == [True, False, False]


def test_with_total_communication_loss_nothing_is_received():
    env, obs = comm_setup(comm_loss=1.0)
    assert not env.comm_links.any() and not env.beacons.any()
    assert env.knowledge[1, 0] < env.t
    assert belief(env, obs["uav_1"]).max() == 0.0
    assert not env.split_observation(obs["uav_1"])["neighbours"].any()


def test_neighbours_within_the_comm_radius_are_listed():
    env = make(size=40, n_uavs=3, comm_radius=10.0)
    obs, _ = env.reset(seed=0, options={"uav_positions": [[20, 5], [20, 12], [20, 20]]})
    block = env.split_observation(obs["uav_0"])["neighbours"]
    assert block[0].tolist() == pytest.approx([0.0, 0.7, 1.0])  # UAV 1: 7 cells right, R_c = 10
    assert not block[1:].any()  # UAV 2 is out of range


def test_an_empty_battery_grounds_a_uav_and_it_stays_an_agent():
    env = make(n_uavs=2, n_poachers=0)
    env.reset(seed=0, options={"uav_positions": [[3, 3], [10, 10]]})
    env.battery[0] = 1e-4
    start = env.uav_pos[0].copy()
    _, _, terms, _, _ = env.step({"uav_0": RIGHT, "uav_1": RIGHT})
    assert env.grounded.tolist() == [True, False]
    assert env.agents == ["uav_0", "uav_1"] and not any(terms.values())
    assert env.uav_pos[0].tolist() == (start + [0, 2]).tolist()  # the last move the battery paid for
    for _ in range(2):
        env.step({"uav_0": RIGHT, "uav_1": STAY})
        assert env.uav_pos[0].tolist() == (start + [0, 2]).tolist()  # grounded: no further moves
    assert env.battery[0] == 0.0
    env.battery[1] = 1e-4
    _, _, terms, _, infos = env.step({"uav_0": STAY, "uav_1": RIGHT})
    assert all(terms.values()) and "metrics" in infos["uav_1"]
    assert env.agents == []


def test_episode_metrics_arrive_on_the_last_step():
    env = reserve_v1.parallel_env(max_cycles=30)
    env.reset(seed=0)
    infos = {}
    while env.agents:
        _, _, _, truncs, infos = env.step({a: env.action_space(a).sample() for a in env.agents})
    metrics = infos["uav_0"]["metrics"]
    assert all(truncs.values())
    assert set(metrics) >= {"team_reward", "coverage_efficiency", "detection_rate", "false_alarms", "poaching_events",
                            "collisions", "energy", "time_to_first_detection", "mode"}
    assert metrics["mode"] == infos["uav_0"]["mode"] == env.mode
    assert 0.0 <= metrics["coverage_efficiency"] <= 1.0 and metrics["episode_length"] == 30


def test_continuous_actions_move_and_broadcast():
    env = make(size=40, n_uavs=2, continuous_actions=True, comm_radius=10.0)
    env.reset(seed=0, options={"uav_positions": [[20, 20], [20, 25]]})
    env.step({"uav_0": np.array([0.0, 0.5, 1.0], np.float32), "uav_1": np.zeros(3, np.float32)})
    assert env.uav_pos[0].tolist() == pytest.approx([20.5, 21.5])  # half speed (2 cells) to the right
    assert env.comm_links[0, 1] and not env.comm_links[1, 0]


def test_out_of_range_discrete_actions_are_rejected():
    env = make()
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"the action of uav_0 must be an int in \[0, 14\] or None, got 15"):
        env.step({"uav_0": 15})
    with pytest.raises(ValueError, match=r"discrete actions must be 1 ints in \[0, 14\]"):
        env.step_arrays(np.array([15]))


def _subnormal(values: np.ndarray) -> np.ndarray:
    return (values != 0) & (np.abs(values) < np.finfo(np.float32).tiny)


@pytest.mark.parametrize("region", ["mixed", "forest"])
def test_observations_hold_no_float32_subnormals(region):
    # The hotspots' Gaussian tails once reached 1e-39..1e-45 in the risk channel, which slows every network
    # reading the window (matrix products over subnormal inputs) by about half.
    env = reserve_v1.parallel_env(region=region)
    rng = np.random.default_rng(0)
    observations, _ = env.reset(seed=3)
    assert not _subnormal(env.unwrapped.risk).any()
    for _ in range(120):
        assert not any(_subnormal(obs).any() for obs in observations.values())
        observations, *_ = env.step({agent: int(rng.integers(15)) for agent in env.agents})


def test_a_custom_risk_map_keeps_no_value_below_the_floor():
    from wildlife_reserve.reserve.terrain import RISK_FLOOR

    risk = np.full((15, 15), 1e-40)
    risk[0, :5] = [0.0, 0.5 * RISK_FLOOR, RISK_FLOOR, 0.3, 1.0]
    env = make(risk=risk)
    env.reset(seed=0)
    kept = env.unwrapped.risk
    assert kept.dtype == np.float32 and not _subnormal(kept).any()
    np.testing.assert_array_equal(kept[0, :5], np.float32([0.0, 0.0, RISK_FLOOR, 0.3, 1.0]))
    assert (kept[1:] == 0).all()


def test_agent_ids_end_each_observation_with_the_uavs_one_hot_and_change_nothing_else():
    kwargs = {"n_uavs": 4, "grid_size": 30, "max_cycles": 40}
    plain, tagged = reserve_v1.parallel_env(**kwargs), reserve_v1.parallel_env(agent_ids=True, **kwargs)
    assert tagged.obs_dim == plain.obs_dim + 4
    assert tagged.observation_layout["agent_id"][0] == slice(plain.obs_dim, plain.obs_dim + 4)
    for observed in side_by_side(plain, tagged):  # the same episodes with and without the ids
        for (a, base), other in zip(observed[0].items(), observed[1].values()):
            np.testing.assert_array_equal(other[:plain.obs_dim], base)
            np.testing.assert_array_equal(other[plain.obs_dim:], np.eye(4)[plain.possible_agents.index(a)])


def side_by_side(plain, other, steps=60):
    """The observations of two reserves stepped with the same random actions, ``steps`` times across an episode end
    (reset with seed 3, then 4)."""
    rng = np.random.default_rng(0)
    observed = [plain.reset(seed=3)[0], other.reset(seed=3)[0]]
    for _ in range(steps):
        yield observed
        if not plain.agents:
            observed = [plain.reset(seed=4)[0], other.reset(seed=4)[0]]
            continue
        actions = {a: int(rng.integers(15)) for a in plain.agents}
        observed = [plain.step(actions)[0], other.step(actions)[0]]


def test_compass_points_at_the_nearest_den_and_road_entry_and_changes_nothing_else():
    kwargs = {"n_uavs": 4, "grid_size": 30, "max_cycles": 40}
    plain, guided = reserve_v1.parallel_env(**kwargs), reserve_v1.parallel_env(compass=True, agent_ids=True, **kwargs)
    assert guided.obs_dim == plain.obs_dim + 4 + 4
    assert guided.observation_layout["compass"] == (slice(plain.obs_dim, plain.obs_dim + 4), (2, 2))
    for observed in side_by_side(plain, guided):  # the same episodes, the compass appended
        dens, entries = guided.hotspots.dens, guided.hotspots.road_entries
        assert len(dens) and len(entries)
        for index, (a, base) in enumerate(observed[0].items()):
            other = observed[1][a]
            np.testing.assert_array_equal(other[:plain.obs_dim], base)
            cell = guided._cells[index]
            for row, points in zip(guided.split_observation(other)["compass"], (dens, entries)):
                distance = np.abs(points - cell).max(axis=1)  # Chebyshev, as everything on the grid
                target = cell + row * 29  # (side - 1) = 29
                np.testing.assert_allclose(target, np.round(target), atol=1e-4)
                assert np.abs(np.round(target) - cell).max() == distance.min()
                assert any((np.round(target) == p).all() for p in points[distance == distance.min()])


def test_sectors_split_cells_by_angle_into_equal_counts():
    from wildlife_reserve.reserve.terrain import sectors

    cells = np.zeros((10, 10), dtype=bool)
    # Angles around the centre (5, 5), ascending: north (-pi/2), east (0), south (pi/2), west (pi).
    for cell in [(5, 0), (5, 1), (0, 5), (1, 5), (5, 9), (5, 8), (9, 5), (8, 5)]:
        cells[cell] = True
    out = sectors(cells, 4)
    assert (out[~cells] == -1).all()
    assert out[0, 5] == out[1, 5] == 0 and out[5, 9] == out[5, 8] == 1
    assert out[9, 5] == out[8, 5] == 2 and out[5, 0] == out[5, 1] == 3
    assert sorted(np.bincount(sectors(cells, 3)[cells])) == [2, 3, 3]
    assert (sectors(cells, 1)[cells] == 0).all()
    assert (sectors(np.zeros((4, 4), dtype=bool), 4) == -1).all()
    env = reserve_v1.parallel_env()
    env.reset(seed=0)
    counts = np.bincount(sectors(env.high_risk, 4)[env.high_risk], minlength=4)
    assert counts.sum() == env.high_risk.sum() and counts.max() - counts.min() <= 1


@pytest.mark.parametrize("terrain_seed", [0, None])
def test_coverage_sectors_pay_coverage_in_the_strategys_sector_only_and_change_nothing_else(terrain_seed):
    from wildlife_reserve.reserve.config import DEFAULT_REWARD_WEIGHTS
    from wildlife_reserve.reserve.modes import N_MODES, STRATEGIES, WEATHERS
    from wildlife_reserve.reserve.terrain import sectors

    only_coverage = {term: 0.0 for term in DEFAULT_REWARD_WEIGHTS} | {"coverage": 1.0}
    kwargs = {"n_uavs": 4, "grid_size": 40, "max_cycles": 40, "terrain_seed": terrain_seed,
              "reward_weights": only_coverage}
    plain, paid = reserve_v1.parallel_env(**kwargs), reserve_v1.parallel_env(coverage_sectors=True, **kwargs)
    for mode in range(N_MODES):
        rng = np.random.default_rng(mode)
        observed = [plain.reset(seed=mode, options={"mode": mode})[0], paid.reset(seed=mode, options={"mode": mode})[0]]
        sector = sectors(paid.high_risk, len(STRATEGIES)) == mode // len(WEATHERS)
        assert sector.any() and not sector.all()
        np.testing.assert_array_equal(paid.high_risk, plain.high_risk)  # what the state counts is unchanged
        inner = (slice(paid.r, paid.r + paid.height), slice(paid.r, paid.r + paid.width))
        seen_at_reset = paid.visited[inner].copy()
        totals = np.zeros(2)
        while plain.agents:
            for base, other in zip(observed[0].values(), observed[1].values()):
                np.testing.assert_array_equal(other, base)  # the same episodes: only the reward differs
            actions = {a: int(rng.integers(15)) for a in plain.agents}
            steps = [plain.step(actions), paid.step(actions)]
            observed = [steps[0][0], steps[1][0]]
            totals += [steps[0][1]["uav_0"], steps[1][1]["uav_0"]]
        visited = paid.visited[inner]
        np.testing.assert_array_equal(visited, plain.visited[inner])
        assert totals[0] == (visited & plain.high_risk & ~seen_at_reset).sum()
        assert totals[1] == (visited & sector & ~seen_at_reset).sum()  # the strategy's sector alone pays
        metrics = paid.episode_metrics()
        assert metrics["coverage_efficiency"] == pytest.approx((visited & sector).sum() / sector.sum())


def test_compass_on_hand_built_cells_and_without_roads():
    from wildlife_reserve.reserve.observation import compass

    cells = np.array([[0, 0], [10, 10], [5, 9]])
    dens = np.array([[2, 9], [10, 4]])
    inv = np.array([0.1, 0.05])
    out = compass(cells, (dens, np.zeros((0, 2), dtype=np.int64)), inv)
    # [0, 0]: den (2, 9) is 9 away, (10, 4) 10 away; [10, 10]: 8 and 6; [5, 9]: 3 and 5.
    np.testing.assert_allclose(out[:, 0], [[0.2, 0.45], [0.0, -0.3], [-0.3, 0.0]])
    assert (out[:, 1] == 0).all()  # no road entry on the map: zeros
    env = reserve_v1.parallel_env(n_uavs=2, grid_size=20, compass=True, risk=np.eye(20))  # a custom map has no roads
    obs, _ = env.reset(seed=0)
    assert len(env.hotspots.road_entries) == 0
    assert (env.split_observation(obs["uav_0"])["compass"][1] == 0).all()
