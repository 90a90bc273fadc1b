"""Signs of poacher activity and the links in infos: hand-built cases and the strategies' layouts."""

import numpy as np
import pytest
from scipy import stats

from wildlife_reserve import reserve_v1
from wildlife_reserve.reserve import sensing
from wildlife_reserve.reserve import signs as signs_lib
from wildlife_reserve.reserve.kernels.constants import CH_SIGN, COMM_BROADCAST, N_MOVES, POACHER_ACTIVE, STAY
from wildlife_reserve.reserve.modes import STRATEGIES, WEATHERS
from wildlife_reserve.reserve.terrain import FOREST, OPEN

CLEAR, FOG = 0, 1  # hotspot raid in clear weather and in fog
BROADCAST = STAY + N_MOVES * COMM_BROADCAST


def make(size=15, ground=OPEN, **kwargs):
    """A small uniform reserve with no poachers (so no signs but the ones a test lays)."""
    kwargs.setdefault("n_uavs", 1)
    kwargs.setdefault("n_leopards", 0)
    kwargs.setdefault("n_poachers", 0)
    kwargs.setdefault("mode", CLEAR)
    return reserve_v1.parallel_env(grid_size=size, terrain=np.full((size, size), ground), **kwargs)


def lay(env, cell, kind=signs_lib.SNARE, born=0):
    return int(env.signs.add(np.array([cell]), born, kind, env.t)[0])


# ---------------------------------------------------------------------------------------------------- detection
def test_a_sign_in_the_open_under_a_noiseless_uav_is_detected_and_rewarded():
    env = make()
    for seed in range(30):
        env.reset(seed=seed, options={"uav_positions": [[7, 7]]})
        lay(env, [7, 7])
        obs, rewards, *_ = env.step({"uav_0": STAY})
        parts = env.split_observation(obs["uav_0"])
        assert parts["window"][CH_SIGN, env.r, env.r] == 1.0
        assert parts["window"][CH_SIGN].sum() == 1.0
        assert parts["signs"].max() > 0 and env.metrics["signs_found"] == 1
        assert rewards["uav_0"] == pytest.approx(env.config.reward_weights["sign"] - env.metrics["energy"])
        _, rewards, *_ = env.step({"uav_0": STAY})  # found again: no second reward
        assert env.metrics["signs_found"] == 1 and rewards["uav_0"] < 0


def sign_detection_rate(ground, mode, trials=400):
    env = make(ground=ground, mode=mode)
    hits = 0
    for seed in range(trials):
        env.reset(seed=seed, options={"uav_positions": [[7, 7]]})
        lay(env, [7, 8])
        env.step({"uav_0": STAY})
        hits += env.metrics["signs_found"]
    return hits / trials


def test_forest_and_fog_lower_the_sign_detection_rate():
    clear_open = sign_detection_rate(OPEN, CLEAR)
    forest, fog = sign_detection_rate(FOREST, CLEAR), sign_detection_rate(OPEN, FOG)
    forest_fog = sign_detection_rate(FOREST, FOG)
    assert clear_open == 1.0
    assert forest < 0.6 and fog < 0.85 and forest_fog < min(forest, fog) - 0.1
    # Within a few standard errors of the documented model.
    for rate, terrain, weather in ((forest, FOREST, 0), (fog, OPEN, 1), (forest_fog, FOREST, 1)):
        p = sensing.sign_detection_table(3, WEATHERS[weather], 0.0)[1, terrain]
        assert abs(rate - p) < 4 * np.sqrt(p * (1 - p) / 400) + 1e-9, (rate, p)


def test_fog_hides_signs_in_the_outer_ring():
    env = make(mode=FOG)
    for seed in range(50):
        env.reset(seed=seed, options={"uav_positions": [[7, 7]]})
        lay(env, [7, 10])  # 3 cells away: beyond the fog's reach of 2
        env.step({"uav_0": STAY})
        assert env.metrics["signs_found"] == 0


def test_sensor_noise_adds_false_sign_readings_known_only_to_the_reader():
    env = make(n_uavs=2, sensor_noise=1.0, comm_radius=0.0)
    env.reset(seed=0, options={"uav_positions": [[3, 3], [11, 11]]})
    for _ in range(100):
        env.step(dict.fromkeys(env.agents, STAY))
    phantoms = np.flatnonzero(env.signs.kind[:env.signs.count] == signs_lib.FALSE_READING)
    assert len(phantoms) > 0 and env.metrics["signs_found"] == 0  # false readings earn nothing
    known = env.team.known_signs[:, phantoms]
    assert (known.sum(axis=0) == 1).all()  # each one known to the UAV that made it, and (no links) to nobody else
    assert not (env.signs.grid >= 0).any()  # and never on the ground, where another UAV could find it


# ---------------------------------------------------------------------------------------------------- lifetime
def test_signs_persist_for_their_stated_lifetime():
    lifetime = int(signs_lib.LIFETIME[signs_lib.TRACK])
    env = make(max_cycles=lifetime + 10)
    env.reset(seed=0, options={"uav_positions": [[2, 2]]})
    track, snare = lay(env, [7, 7], signs_lib.TRACK, born=0), lay(env, [7, 9], signs_lib.SNARE, born=0)
    for _ in range(lifetime - 1):
        env.step({"uav_0": STAY})
    assert set(env.signs.live(env.t)) == {track, snare}  # t = lifetime - 1: both on the ground
    env.step({"uav_0": STAY})
    assert set(env.signs.live(env.t)) == {snare}  # t = lifetime: the track is gone, the snare stays
    env.uav_pos[0] = [7.5, 7.5]  # fly over the old track: only the snare (2 cells away) can be seen
    seen = np.zeros((env.window, env.window))
    for _ in range(10):
        obs, *_ = env.step({"uav_0": STAY})
        seen += env.split_observation(obs["uav_0"])["window"][CH_SIGN]
    assert seen[env.r, env.r] == 0.0 and seen[env.r, env.r + 2] > 0 and seen.sum() == seen[env.r, env.r + 2]


def test_moving_poachers_leave_tracks():
    env = make(size=40, n_poachers=1)
    env.reset(seed=0, options={"uav_positions": [[0, 0]]})
    before = env.signs.count
    env.poacher_entry_time[0] = 10**6
    env.poacher_status[0] = POACHER_ACTIVE
    env.poacher_pos[0] = [30, 30]
    for _ in range(40):
        env.step({"uav_0": STAY})
    tracks = np.arange(before, env.signs.count)
    assert len(tracks) > 5 and (env.signs.kind[tracks] == signs_lib.TRACK).all()
    assert (env.signs.born[tracks] > 0).all()



def test_tracks_fill_a_full_sign_table_after_it_grows():
    """The step places tracks in compiled code, which cannot grow the records: the table must make room first. A
    table filled to its last free record still takes a track per poacher (the records before it unchanged), and the
    tracks sit where the poachers moved."""
    env = make(size=40, n_poachers=4)
    env.reset(seed=3, options={"uav_positions": [[0, 0]]})
    signs = env.signs
    free = signs.capacity - signs.count - 1
    signs.add(np.column_stack([np.arange(free) % 40, np.arange(free) // 40]), -100.0, signs_lib.SNARE, t=0)
    assert signs.capacity - signs.count == 1
    kept = signs.pos[:signs.count].copy()
    env.poacher_entry_time[:] = 10**6
    env.poacher_status[:] = POACHER_ACTIVE
    env.poacher_pos[:] = [[30, 30], [30, 35], [35, 30], [35, 35]]
    before = signs.count
    for _ in range(10):
        env.step({"uav_0": STAY})
    tracks = np.arange(before, env.signs.count)
    assert len(tracks) > 4 and (env.signs.kind[tracks] == signs_lib.TRACK).all()
    np.testing.assert_array_equal(env.signs.pos[:before], kept)
    assert (np.abs(env.signs.pos[tracks] - 32).max(axis=1) <= 14).all()


# ---------------------------------------------------------------------------------------------------- sharing and links
def test_a_broadcast_shares_found_signs_inside_the_comm_radius_only():
    env = make(size=40, n_uavs=3, comm_radius=10.0)
    env.reset(seed=0, options={"uav_positions": [[20, 5], [20, 12], [20, 20]]})
    lay(env, [20, 5])
    obs, _, _, _, infos = env.step({"uav_0": BROADCAST, "uav_1": STAY, "uav_2": STAY})
    maps = {a: env.split_observation(obs[a])["signs"] for a in env.agents}
    assert maps["uav_0"].max() > 0 and np.array_equal(maps["uav_0"], maps["uav_1"])
    assert maps["uav_2"].max() == 0
    assert infos["uav_1"]["heard_from"] == (0,) and infos["uav_2"]["heard_from"] == ()
    assert infos["uav_0"]["heard_from"] == ()


def test_heard_from_lists_every_delivered_message():
    env = make(size=40, n_uavs=4, comm_radius=10.0)
    env.reset(seed=0, options={"uav_positions": [[20, 5], [20, 12], [20, 19], [5, 35]]})
    query = STAY + N_MOVES * 2
    _, _, _, _, infos = env.step({"uav_0": BROADCAST, "uav_1": BROADCAST, "uav_2": query, "uav_3": BROADCAST})
    assert infos["uav_0"]["heard_from"] == (1,)
    assert infos["uav_1"]["heard_from"] == (0,)
    assert infos["uav_2"]["heard_from"] == (1,)  # the broadcast of 1 and, once, its answer to the query
    assert infos["uav_3"]["heard_from"] == ()  # out of everybody's range
    for r, agent in enumerate(env.agents):
        assert infos[agent]["heard_from"] == tuple(np.flatnonzero(env.comm_links[:, r]).tolist())


def test_with_total_communication_loss_no_link_is_listed():
    env = reserve_v1.parallel_env(comm_loss=1.0, max_cycles=30)
    env.reset(seed=0)
    while env.agents:
        _, _, _, _, infos = env.step(dict.fromkeys(env.agents, BROADCAST))
        assert all(info["heard_from"] == () for info in infos.values())


def test_jamming_removes_the_links_inside_the_jammer():
    env = make(size=60, n_uavs=4, n_poachers=1, comm_radius=20.0, adversarial=True, n_decoys=0, jam_radius=10.0)
    env.reset(seed=0, options={"uav_positions": [[20, 26], [20, 14], [20, 35], [20, 44]]})
    env.poacher_entry_time[0] = 10**6
    env.poacher_status[0] = POACHER_ACTIVE
    env.poacher_pos[0] = [20, 20]  # the jammer travels with the active poachers
    _, _, _, _, infos = env.step(dict.fromkeys(env.agents, BROADCAST))
    assert env.jammed.tolist() == [True, True, False, False]
    assert infos["uav_0"]["heard_from"] == () and infos["uav_1"]["heard_from"] == ()
    assert infos["uav_2"]["heard_from"] == (3,) and infos["uav_3"]["heard_from"] == (2,)


def test_adversarial_decoys_come_with_fake_signs():
    env = reserve_v1.parallel_env(adversarial=True, n_decoys=3)
    env.reset(seed=0)
    fakes = np.flatnonzero(env.signs.kind[:env.signs.count] == signs_lib.DECOY)
    assert len(fakes) >= 3
    dist = np.abs(env.signs.pos[fakes][:, None, :] - env.decoy_pos[None]).max(-1).min(axis=1)
    assert dist.max() <= 2


# ---------------------------------------------------------------------------------------------------- layouts
def layouts(strategy, episodes=60):
    """Pre-episode signs of ``episodes`` episodes of one strategy (clear weather) on the default reserve."""
    env = reserve_v1.parallel_env()
    out = []
    for seed in range(episodes):
        env.reset(seed=seed, options={"mode": strategy * len(WEATHERS)})
        n = env.signs.count
        out.append((env.signs.pos[:n].copy(), env.signs.kind[:n].copy(), env))
    return out


def side_distances(env, cells):
    """``(4, k)`` distances of each cell to the north, south, west and east sides."""
    return np.stack([cells[:, 0], env.height - 1 - cells[:, 0], cells[:, 1], env.width - 1 - cells[:, 1]])


def edge_distance(env, cells):
    return side_distances(env, cells).min(axis=0)


def den_distance(env, cells):
    return np.abs(cells[:, None, :] - env.hotspots.dens[None]).max(-1).min(axis=1)


@pytest.fixture(scope="module")
def all_layouts():
    return {s.name: layouts(i) for i, s in enumerate(STRATEGIES)}


def test_hotspot_raids_leave_snares_around_every_den(all_layouts):
    for pos, kind, env in all_layouts["hotspot_raid"]:
        snares = pos[kind == signs_lib.SNARE]
        assert len(snares) >= 0.9 * signs_lib.SNARES_PER_DEN * len(env.hotspots.dens)
        assert ((den_distance(env, snares) >= 2) & (den_distance(env, snares) <= signs_lib.SNARE_RADIUS)).all()
        nearest = np.abs(snares[:, None] - env.hotspots.dens[None]).max(-1).argmin(axis=1)
        assert set(nearest.tolist()) == set(range(len(env.hotspots.dens)))
        assert not np.isin(kind, [signs_lib.CAMP, signs_lib.VEHICLE]).any()


def test_edge_infiltrations_leave_vehicles_and_tracks_along_one_side(all_layouts):
    sides = []
    for pos, kind, env in all_layouts["edge_infiltration"]:
        vehicles = pos[kind == signs_lib.VEHICLE]
        assert len(vehicles) >= signs_lib.EDGE_ROUTES - 2 and (edge_distance(env, vehicles) == 0).all()
        on_side = (side_distances(env, vehicles) == 0).all(axis=1)
        assert on_side.any()  # all on one side
        side = int(np.flatnonzero(on_side)[0])
        sides.append(side)
        assert (side_distances(env, pos)[side] <= signs_lib.EDGE_DEPTH[1]).all()
    env = all_layouts["edge_infiltration"][0][2]
    road_sides = set(np.flatnonzero((side_distances(env, env.hotspots.road_entries) == 0).any(axis=1)).tolist())
    assert set(sides) == road_sides  # they come in along the sides where the roads enter, each of them in turn


def test_a_coordinated_group_leaves_one_camp(all_layouts):
    for pos, kind, env in all_layouts["coordinated_group"]:
        camp = pos[kind == signs_lib.CAMP]
        assert len(camp) == signs_lib.CAMP_SIGNS
        assert np.abs(camp[:, None] - camp[None]).max(-1).max(axis=0).min() <= 3  # all within 3 of one of them
        vehicles = pos[kind == signs_lib.VEHICLE]
        assert len(vehicles) == 1 and edge_distance(env, vehicles)[0] == 0


def test_dispersed_evasion_scatters_signs_uniformly(all_layouts):
    cells = np.concatenate([pos for pos, _, _ in all_layouts["dispersed_evasion"]])
    env = all_layouts["dispersed_evasion"][0][2]
    assert len(cells) >= 0.95 * signs_lib.SCATTERED_SIGNS * 60
    for axis, side in ((0, env.height), (1, env.width)):
        assert stats.kstest((cells[:, axis] + 0.5) / side, "uniform").pvalue > 1e-3


def test_the_strategies_lay_signs_in_different_places(all_layouts):
    def pooled(name, measure):
        return np.concatenate([measure(env, pos) for pos, _, env in all_layouts[name]])

    to_den = {name: pooled(name, den_distance) for name in all_layouts}
    to_edge = {name: pooled(name, edge_distance) for name in all_layouts}
    for other in ("edge_infiltration", "coordinated_group", "dispersed_evasion"):
        assert stats.mannwhitneyu(to_den["hotspot_raid"], to_den[other], alternative="less").pvalue < 1e-6
    for other in ("hotspot_raid", "coordinated_group", "dispersed_evasion"):
        assert stats.mannwhitneyu(to_edge["edge_infiltration"], to_edge[other], alternative="less").pvalue < 1e-6


def test_the_observation_stays_under_600_floats_for_ten_uavs():
    env = reserve_v1.parallel_env()
    assert env.obs_dim == 553 < 600
    assert env.observation_layout["signs"][1] == (8, 8)


def test_the_card_states_the_sign_model_as_the_code_has_it():
    from pathlib import Path

    card = (Path(__file__).resolve().parents[1] / "docs" / "env.md").read_text()
    for phrase in (f"{signs_lib.SNARES_PER_DEN} snares around every den (Chebyshev distance 2-{signs_lib.SNARE_RADIUS}",
                   f"{signs_lib.EDGE_ROUTES} vehicles", f"{signs_lib.EDGE_DEPTH[0]}-{signs_lib.EDGE_DEPTH[1]} cells deep",
                   f"one camp of {signs_lib.CAMP_SIGNS} signs", f"{signs_lib.SCATTERED_SIGNS} isolated signs",
                   f"| track | {int(signs_lib.LIFETIME[signs_lib.TRACK])} steps |", f"{signs_lib.DECOY_SIGNS} fake signs",
                   f"with probability {signs_lib.TRACK_PROB:g}", f"`p = {sensing.SIGN_PEAK:.1f} * f(d)"):
        assert phrase in card, phrase
    # The second table with these rows is the sign table (the first is the poachers').
    sign_rows = [line for line in card.splitlines() if line.startswith(("| <= 1 |", "| 2 |", "| 3 |"))][3:6]
    for d, line in zip((1, 2, 3), sign_rows):
        for weather, cell in zip(WEATHERS, line.split("|")[2:4]):
            table = sensing.sign_detection_table(3, weather, 0.0)[d]
            expected = " / ".join("0" if p == 0 else f"{p:.3f}" for p in table)
            assert cell.strip() == expected, (d, weather.name, cell, expected)


def test_the_decoys_fake_signs_are_seen_but_earn_nothing():
    env = make(size=30, adversarial=True, n_decoys=1)
    for seed in range(10):
        env.reset(seed=seed)
        fakes = np.flatnonzero(env.signs.kind[:env.signs.count] == signs_lib.DECOY)
        env.uav_pos[0] = env.signs.pos[fakes[0]] + 0.5
        env._place_windows()
        obs, *_ = env.step({"uav_0": STAY})
        assert env.split_observation(obs["uav_0"])["window"][CH_SIGN, env.r, env.r] == 1.0
        assert env.team.known_signs[0, fakes[0]] and env.metrics["signs_found"] == 0
