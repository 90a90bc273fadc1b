"""The reserve's zone raids (``scenario="zone_raids"``, ``strategy_zones``): the zones, the poachers' plans, the zone
compass, the scenario's arguments, and the scripted teams of its gate."""

import numpy as np
import pytest

from wildlife_reserve import reserve_v1
from wildlife_reserve.reserve.config import SCENARIOS, ReserveConfig
from wildlife_reserve.reserve.modes import STRATEGIES, encode_mode
from wildlife_reserve.reserve.scripted import ZoneRaidPatrol, run_patrol
from wildlife_reserve.reserve.terrain import nearest_edge, strategy_zones


def test_the_zones_are_the_quarters_centres_and_the_dens():
    assert strategy_zones((100, 100), 4).tolist() == [[25, 25], [25, 75], [75, 25], [75, 75]]
    assert strategy_zones((40, 60), 5).tolist() == [[10, 15], [10, 45], [30, 15], [30, 45], [10, 15]]
    env = reserve_v1.parallel_env(scenario="zone_raids")
    env.reset(seed=0)
    assert env.hotspots.dens.tolist() == strategy_zones((100, 100), 4).tolist()
    assert env.leopard_home.tolist() == np.tile(strategy_zones((100, 100), 4), (2, 1)).tolist()  # two per zone
    assert env.risk[25, 25] == pytest.approx(1.0)  # the risk map peaks at the zones


@pytest.mark.parametrize("strategy", range(len(STRATEGIES)))
def test_every_poacher_heads_for_its_strategys_zone_from_the_nearest_side(strategy):
    env = reserve_v1.parallel_env(scenario="zone_raids", n_poachers=30)
    zone = strategy_zones((100, 100), 4)[strategy]
    side = nearest_edge(zone[None], (100, 100))[0][0]
    entries = set()
    for weather in range(2):
        env.reset(seed=strategy, options={"mode": encode_mode(strategy, weather)})
        assert (env.poacher_target == zone).all()
        assert (nearest_edge(env.poacher_entry, (100, 100))[0] == side).all()
        lo, hi = STRATEGIES[strategy].entry_window
        assert env.poacher_entry_time.min() >= int(lo * 200) and env.poacher_entry_time.max() < int(hi * 200)
        entries |= set(map(tuple, env.poacher_entry.tolist()))
    if STRATEGIES[strategy].entry == "group":  # together, at one point (within a cell or two) and one time
        assert len(np.unique(env.poacher_entry_time)) == 1
        assert np.ptp(env.poacher_entry, axis=0).max() <= 3
    else:
        assert len(entries) > 5


def test_the_zone_compass_points_at_every_zone_in_the_strategies_order():
    env = reserve_v1.parallel_env(scenario="zone_raids", n_uavs=3)
    obs, _ = env.reset(seed=3, options={"uav_positions": [[0, 0], [50, 50], [99, 10]]})
    zones = env.split_observation(np.stack([obs[a] for a in env.agents]))["zones"]
    assert zones.shape == (3, 4, 2)
    expected = (strategy_zones((100, 100), 4)[None] - np.array([[0, 0], [50, 50], [99, 10]])[:, None]) / 99
    np.testing.assert_allclose(zones, expected, rtol=1e-6)
    assert env.obs_dim == reserve_v1.parallel_env(compass=True).obs_dim + 8


def test_the_scenario_is_its_arguments_and_explicit_ones_override_it():
    config = ReserveConfig.from_kwargs(scenario="zone_raids")
    assert (config.strategy_zones, config.compass, config.n_leopards, config.n_poachers) == (True, True, 8, 16)
    assert config.reward_weights["coverage"] == 0.0 and config.reward_weights["sign"] == 0.0
    assert config.reward_weights["detection"] == 10.0
    mine = ReserveConfig.from_kwargs(scenario="zone_raids", n_poachers=4, reward_weights={"detection": 5.0})
    assert mine.n_poachers == 4 and mine.reward_weights["detection"] == 5.0 and mine.reward_weights["coverage"] == 0.0
    assert set(SCENARIOS) == {"zone_raids"}


@pytest.mark.parametrize("kwargs, message", [
    ({"scenario": "zone_raid"}, "scenario must be None or one of ['zone_raids'], got 'zone_raid'"),
    ({"scenario": ["zone_raids"]}, "scenario must be None or one of ['zone_raids'], got ['zone_raids'] (list)"),
    ({"strategy_zones": True}, "n_leopards must be >= 4, got 3"),
    ({"scenario": "zone_raids", "n_leopards": 2}, "n_leopards must be >= 4, got 2"),
    ({"strategy_zones": "yes"}, "strategy_zones must be a bool"),
])
def test_bad_scenario_arguments_are_refused_naming_the_value(kwargs, message):
    with pytest.raises(ValueError) as error:
        reserve_v1.parallel_env(**kwargs)
    assert message in str(error.value)


def test_the_patrol_needs_the_zones_and_a_known_plan():
    with pytest.raises(ValueError, match="strategy_zones=True"):
        ZoneRaidPatrol(reserve_v1.parallel_env())
    with pytest.raises(ValueError, match="plan must be one of"):
        ZoneRaidPatrol(reserve_v1.parallel_env(scenario="zone_raids"), plan="zone9")


def test_the_told_team_gathers_at_the_zone_and_the_blind_team_converges_on_its_first_catch():
    env = reserve_v1.parallel_env(scenario="zone_raids")
    zones = strategy_zones((100, 100), 4)
    told, blind = ZoneRaidPatrol(env, told=True), ZoneRaidPatrol(env)
    assert (told.name, blind.name, ZoneRaidPatrol(env, plan="zone2", converge=False).name) == (
        "told", "split+converge", "zone2")
    for mode in (0, 3, 6):
        strategy = mode // 2
        obs, _ = env.reset(seed=mode, options={"mode": mode})
        for _ in range(80):
            obs, *_ = env.step(told(obs))
        distance = np.abs(env.uav_pos - zones[strategy]).max(axis=1)
        assert distance.max() <= told.spread + 2  # every UAV on the ring around the strategy's zone
        obs, _ = env.reset(seed=mode, options={"mode": mode})
        obs, *_ = env.step(blind(obs))  # (its first call of an episode forgets the last episode's zone)
        while env.agents and blind._zone is None:
            obs, *_ = env.step(blind(obs))
        if blind._zone is not None:  # its first catch was in the strategy's zone
            assert blind._zone == strategy


def test_told_earns_more_than_blind_on_the_same_episodes():
    env = reserve_v1.parallel_env(scenario="zone_raids")
    told = [r["team_reward"] for r in run_patrol(env, ZoneRaidPatrol(env, told=True), 8, seed=7)]
    blind = [r["team_reward"] for r in run_patrol(env, ZoneRaidPatrol(env), 8, seed=7)]
    assert np.mean(told) > np.mean(blind) + 10
