"""The reserve's compiled kernels against the plain numpy they replace, on random and hand-built inputs."""

import numpy as np
import pytest

from wildlife_reserve import reserve_v1
from wildlife_reserve.reserve import actors, kernels
from wildlife_reserve.reserve.kernels.constants import CH_STALENESS, COMM_NONE, N_COMMS, N_MOVES, NEVER
from wildlife_reserve.reserve.knowledge import (
    SIGN_MAP_SCALE,
    SIGN_VALUES,
    STAMP_LAYOUT,
    TeamKnowledge,
    pack_stamps,
    sign_values,
    stamp_dtype,
    unpack_stamps,
)


def test_discrete_actions_decode_as_divmod_and_out_of_range_ones_are_flagged():
    choices = np.arange(N_MOVES * N_COMMS, dtype=np.int64)
    move, comm, valid = kernels.decode_actions(choices, actors.STEPS.astype(np.float64), N_MOVES, N_COMMS)
    expected_comm, expected_move = np.divmod(choices, N_MOVES)
    assert valid
    np.testing.assert_array_equal(comm, expected_comm)
    np.testing.assert_array_equal(move, actors.STEPS[expected_move])
    for bad in (-1, N_MOVES * N_COMMS):
        assert not kernels.decode_actions(np.array([0, bad]), actors.STEPS.astype(np.float64), N_MOVES, N_COMMS)[2]


def reference_ages(last, first, knowledge, cells, t, scale):
    """The staleness as numpy computes it: sources' stamps known to each receiver, newest first."""
    seen_last, seen_first = last[cells].transpose(0, 2, 1), first[cells].transpose(0, 2, 1)  # (r, s, c)
    known = knowledge[:, :, None]
    seen = np.where(seen_last <= known, seen_last, np.where(seen_first <= known, seen_first, NEVER))
    return np.minimum((np.float32(t) - seen.max(axis=1)) * np.float32(scale), np.float32(1.0))


def random_stamps(rng, rows, n, t):
    """Visit stamps ``(rows, n)`` before step ``t`` with never-seen entries, and knowledge with never-heard sources."""
    last = rng.integers(0, t, (rows, n)).astype(np.float32)
    first = np.minimum(last, rng.integers(0, t, (rows, n))).astype(np.float32)
    never = rng.random((rows, n)) < 0.3
    last[never], first[never] = NEVER, -NEVER
    knowledge = rng.integers(0, t, (n, n)).astype(np.float32)
    knowledge[rng.random((n, n)) < 0.3] = NEVER
    return last, first, knowledge


@pytest.mark.parametrize("dtype", [np.int16, np.int32])
@pytest.mark.parametrize("seed", range(4))
def test_staleness_is_the_newest_visit_each_uav_knows_of(seed, dtype):
    """Random stamps with never-seen cells and never-heard sources (whose stamps must not count), packed as the step
    keeps them, in both stamp types."""
    rng = np.random.default_rng(seed)
    n, m, c, t = 6, 40, 9, 50
    last, first, knowledge = random_stamps(rng, m, n, t)
    cells = rng.integers(0, m, (n, c))
    stamps = pack_stamps(last, first, dtype)
    ages = kernels.known_ages(stamps, knowledge, cells, np.float32(t), np.float32(1 / 80), np.float32(t - 1))
    np.testing.assert_array_equal(ages, reference_ages(last, first, knowledge, cells, t, 1 / 80))


def test_packed_stamps_unpack_to_the_float_ones_and_take_int16_only_below_its_range():
    last, first, _ = random_stamps(np.random.default_rng(3), 30, 4, 40)
    for dtype in (np.int16, np.int32):
        stamps = pack_stamps(last, first, dtype)
        assert stamps.dtype == dtype and stamps.shape == (30, 2, 4)
        np.testing.assert_array_equal(unpack_stamps(stamps, 0), last)
        np.testing.assert_array_equal(unpack_stamps(stamps, 1), first)
    assert stamp_dtype(200) is np.int16 and stamp_dtype(32_766) is np.int16
    assert stamp_dtype(32_767) is np.int32 and stamp_dtype(100_000) is np.int32


def test_int32_stamps_give_the_observations_of_int16_ones_and_long_episodes_take_them(monkeypatch):
    """The stamp type does not change what the UAVs observe (the same reserve stamping in int16 and in int32); an
    episode longer than int16's range stamps in int32, and a cell nobody has seen reads as stale as can be (1)."""
    from wildlife_reserve.reserve import knowledge

    def run(**kwargs):
        env = reserve_v1.parallel_env(n_uavs=4, grid_size=20, comm_radius=30.0, **kwargs)
        env.reset(seed=4)
        rng = np.random.default_rng(4)
        return env, np.array([env.step_arrays(rng.integers(0, N_MOVES * N_COMMS, 4))[0] for _ in range(150)])

    narrow, narrow_obs = run()
    monkeypatch.setattr(knowledge, "stamp_dtype", lambda max_cycles: np.int32)
    wide, wide_obs = run()
    assert narrow.team._stamps.dtype == np.int16 and wide.team._stamps.dtype == np.int32
    np.testing.assert_array_equal(wide_obs, narrow_obs)
    np.testing.assert_array_equal(wide.team.own_last, narrow.team.own_last)
    monkeypatch.undo()
    long = reserve_v1.parallel_env(n_uavs=4, grid_size=20, max_cycles=40_000)
    long.reset(seed=4)
    assert long.team._stamps.dtype == np.int32
    obs = long.step_arrays(np.full(4, 3))[0]  # one step east: the windows' east column is new
    staleness = long.split_observation(obs)["window"][:, CH_STALENESS]
    assert set(np.unique(staleness).tolist()) == {np.float32(1 / 40_000), 1.0}


def test_flight_updates_in_place_and_a_grounded_uav_neither_moves_talks_nor_hovers():
    pos = np.array([[2.5, 2.5], [5.5, 5.5]])
    velocity, battery, grounded = np.zeros((2, 2)), np.array([1.0, 0.0]), np.array([False, True])
    cells, window = np.zeros((2, 2), dtype=np.int64), np.zeros((2, 3, 3), dtype=np.int64)
    move, comm = np.array([[0.0, 1.0], [1.0, 0.0]]), np.array([1, 1])
    offsets = np.arange(9, dtype=np.int64).reshape(3, 3)
    flight = kernels.Flight(pos, velocity, battery, grounded, cells, window, 2.0, np.array([9.99, 9.99]), 0.5, 0.25,
                            np.array([0.0, 0.1, 0.05]), 12, offsets)
    energy, everyone = kernels.fly(flight, move, comm)
    np.testing.assert_array_equal(pos, [[2.5, 4.5], [5.5, 5.5]])
    np.testing.assert_array_equal(velocity, [[0.0, 1.0], [0.0, 0.0]])
    assert comm.tolist() == [1, COMM_NONE] and move[1].tolist() == [0.0, 0.0]
    np.testing.assert_allclose(energy, [0.5 + 0.25 + 0.1, 0.0])
    assert grounded.tolist() == [False, True] and bool(everyone) is False
    np.testing.assert_array_equal(cells, [[2, 4], [5, 5]])
    np.testing.assert_array_equal(window, (cells[:, 0] * 12 + cells[:, 1])[:, None, None] + offsets)


def test_flight_and_collisions_in_one_call_count_the_uavs_airborne_before_the_flight():
    """Three UAVs end in one cell; the one that was grounded before the flight (and stays, at 0 battery) is not
    counted, and the last one's flight empties its battery: it still counts (it was airborne when it moved)."""
    def team():
        pos = np.array([[2.5, 0.5], [2.5, 4.5], [2.5, 2.5], [2.5, 0.5]])
        return (pos, np.zeros((4, 2)), np.array([1.0, 1.0, 0.0, 0.0001]), np.array([False, False, True, False]),
                np.zeros((4, 2), dtype=np.int64), np.zeros((4, 3, 3), dtype=np.int64),
                np.array([[0.0, 1.0], [0.0, -1.0], [0.0, 0.0], [0.0, 1.0]]), np.array([0, 0, 0, 0]))
    constants = (2.0, np.array([9.99, 9.99]), 0.0005, 0.002, np.array([0.0, 0.003, 0.0015]), 12,
                 np.arange(9, dtype=np.int64).reshape(3, 3))
    together = team()
    energy, everyone, own, pairs = kernels.fly_and_collide(kernels.Flight(*together[:6], *constants), *together[6:])
    apart = team()
    airborne = ~apart[3]
    expected_energy, expected_everyone = kernels.fly(kernels.Flight(*apart[:6], *constants), *apart[6:])
    expected_own, expected_pairs = kernels.collisions(apart[4], airborne)
    np.testing.assert_array_equal(energy, expected_energy)
    assert bool(everyone) == bool(expected_everyone)
    assert own.tolist() == expected_own.tolist() == [2, 2, 0, 2] and pairs == expected_pairs == 3
    assert together[3].tolist() == [False, False, True, True]  # the last one grounded by its flight


def test_links_are_grouped_by_receiver_with_senders_ascending():
    links = np.zeros((4, 4), dtype=bool)
    links[[3, 0, 2, 1], [0, 2, 0, 2]] = True  # s -> r
    senders, ends = kernels.senders_by_receiver(links)
    assert senders.tolist() == [2, 3, 0, 1] and ends.tolist() == [2, 2, 4, 4]


def test_sign_values_are_numpys_exp_for_every_count():
    counts = np.arange(1000)
    expected = 1.0 - np.exp(-counts / SIGN_MAP_SCALE)
    np.testing.assert_array_equal(sign_values(counts), expected)
    np.testing.assert_array_equal(sign_values(counts.astype(np.float64)), expected)
    assert SIGN_VALUES[-1] == 1.0  # so a count beyond the table reads the exact value


def test_step_arrays_writes_into_out_and_rejects_a_wrong_one():
    env = reserve_v1.parallel_env(n_uavs=3, grid_size=20, max_cycles=5)
    env.reset(seed=0)
    out = np.full((3, env.obs_dim), np.nan, dtype=np.float32)
    obs = env.step_arrays(np.zeros(3, dtype=np.int64), out)[0]
    assert obs is out and np.isfinite(out).all()
    reference = reserve_v1.parallel_env(n_uavs=3, grid_size=20, max_cycles=5)
    reference.reset(seed=0)
    np.testing.assert_array_equal(reference.step_arrays(np.zeros(3, dtype=np.int64))[0], out)
    for bad in (np.zeros((3, env.obs_dim)), np.zeros((2, env.obs_dim), dtype=np.float32),
                np.zeros((env.obs_dim, 3), dtype=np.float32).T):
        with pytest.raises(ValueError, match="out must be a C-contiguous float32 array of shape"):
            env.step_arrays(np.zeros(3, dtype=np.int64), bad)


def test_block_staleness_is_the_per_cell_staleness_of_every_block():
    n, blocks, t = 5, 16, 30
    last, first, knowledge = random_stamps(np.random.default_rng(7), blocks, n, t)
    every = np.tile(np.arange(blocks), (n, 1))
    # The block stamps are source-major, (n, blocks): the transposes of the cell-major stamps.
    ages = kernels.known_block_ages(np.ascontiguousarray(last.T), np.ascontiguousarray(first.T), knowledge,
                                    np.float32(t), np.float32(1 / 40))
    np.testing.assert_array_equal(ages, reference_ages(last, first, knowledge, every, t, 1 / 40))


@pytest.mark.parametrize("n", [1, 10, 63, 64, 70])
def test_heard_from_lists_each_receivers_senders_by_mask_and_beyond_63_uavs(n):
    """Teams of up to 63 UAVs take their tuples from the bit-mask cache, larger ones build them: the same lists."""
    team = TeamKnowledge(n, (12, 12), 4, 50, 0.98, 5.0, 0.0)
    team.reset()
    rng = np.random.default_rng(n)
    for density in (0.0, 0.05, 0.5, 1.0):
        for _ in range(3):
            team.comm_links = rng.random((n, n)) < density
            np.fill_diagonal(team.comm_links, False)
            expected = [tuple(np.flatnonzero(team.comm_links[:, r]).tolist()) for r in range(n)]
            assert team.heard_from() == expected


def test_a_checkpointed_team_from_before_the_source_major_block_stamps_is_turned_on_unpickling():
    """0.14.0 pickled the block stamps as (blocks, n); unpickled now they read as the same stamps, source-major."""
    import pickle

    env = reserve_v1.parallel_env(n_uavs=3, grid_size=24, belief_size=4, max_cycles=50)
    env.reset(seed=2)
    for _ in range(20):
        env.step_arrays(np.random.default_rng(0).integers(0, N_MOVES * N_COMMS, 3))
    team = env.team
    old = pickle.loads(pickle.dumps(team))  # a 0.14.0 state: no layout mark, block stamps (blocks, n)
    del old.__dict__["_stamp_layout"]
    old._block_last, old._block_first = team._block_last.T.copy(), team._block_first.T.copy()
    restored = pickle.loads(pickle.dumps(old))
    np.testing.assert_array_equal(restored._block_last, team._block_last)
    np.testing.assert_array_equal(restored._block_first, team._block_first)
    assert restored._block_last.flags.c_contiguous and restored._stamp_layout == STAMP_LAYOUT
    again = pickle.loads(pickle.dumps(restored))  # a state of now is left as it is
    np.testing.assert_array_equal(again._block_last, team._block_last)


def test_a_checkpointed_reserve_with_float_cell_stamps_is_packed_on_unpickling_and_steps_on_alike():
    """0.15.0-0.17.0 pickled the cells' stamps as float32 ``_last`` / ``_first`` ``(cells, n)``: unpickled now they
    are packed, read as the same stamps and the reserve steps on exactly as the one never pickled."""
    import pickle

    env = reserve_v1.parallel_env(n_uavs=3, grid_size=24, belief_size=4, max_cycles=80)
    env.reset(seed=5)
    rng = np.random.default_rng(5)
    for _ in range(30):
        env.step_arrays(rng.integers(0, N_MOVES * N_COMMS, 3))
    from sb3_emmarl.common.trust.pickling import dumps  # (keeps the reserve's views of its arrays views)

    old = pickle.loads(dumps(env))
    team = old.team
    team._last, team._first = unpack_stamps(team._stamps, 0), unpack_stamps(team._stamps, 1)
    del team.__dict__["_stamps"]
    team._stamp_layout = 1
    assert team._last.dtype == np.float32 and (team._last == NEVER).any()
    restored = pickle.loads(dumps(old))
    assert restored.team._stamp_layout == STAMP_LAYOUT and not hasattr(restored.team, "_last")
    np.testing.assert_array_equal(restored.team._stamps, env.team._stamps)
    for _ in range(30):
        action = rng.integers(0, N_MOVES * N_COMMS, 3)
        np.testing.assert_array_equal(restored.step_arrays(action)[0], env.step_arrays(action)[0])


def test_heard_from_stays_right_when_its_cache_is_emptied(monkeypatch):
    """The mask cache is emptied when it outgrows its bound (here 4 entries): the lists stay the plain ones."""
    from wildlife_reserve.reserve import knowledge

    monkeypatch.setattr(knowledge, "_SENDERS_MAX", 4)
    team = TeamKnowledge(12, (12, 12), 4, 50, 0.98, 5.0, 0.0)
    team.reset()
    rng = np.random.default_rng(5)
    for _ in range(30):
        team.comm_links = rng.random((12, 12)) < 0.3
        np.fill_diagonal(team.comm_links, False)
        assert team.heard_from() == [tuple(np.flatnonzero(team.comm_links[:, r]).tolist()) for r in range(12)]
        assert len(knowledge._SENDERS) <= 4 + 12


def test_compile_kernels_plays_once_per_arguments_and_touches_no_other_random_state(monkeypatch):
    from wildlife_reserve.reserve import reserve as reserve_module

    monkeypatch.setattr(reserve_module, "_COMPILED", set())
    built = []
    real = reserve_module.parallel_env

    def counting(**kwargs):
        built.append(kwargs)
        return real(**kwargs)

    monkeypatch.setattr(reserve_module, "parallel_env", counting)
    np.random.seed(3)
    before = np.random.get_state()[1].copy()
    reserve_module.compile_kernels(n_uavs=3, max_cycles=30)
    reserve_module.compile_kernels(max_cycles=30, n_uavs=3)  # the same arguments: nothing played
    reserve_module.compile_kernels(n_uavs=3, max_cycles=30, continuous_actions=True)
    assert built == [{"n_uavs": 3, "max_cycles": 30}, {"n_uavs": 3, "max_cycles": 30, "continuous_actions": True}]
    assert np.array_equal(np.random.get_state()[1], before)
    # The kernel a step calls has machine code now (the kernels it calls in turn, e.g. decode_actions, are compiled
    # into it: when it is loaded from numba's cache, written by another process, they get no signatures of their own).
    assert kernels.advance_world.signatures


def test_compile_kernels_rejects_bad_arguments_as_the_reserve_does_and_remembers_nothing(monkeypatch):
    from wildlife_reserve.reserve import reserve as reserve_module

    monkeypatch.setattr(reserve_module, "_COMPILED", set())
    with pytest.raises(ValueError, match="n_uavs"):
        reserve_module.compile_kernels(n_uavs=0)
    assert reserve_module._COMPILED == set()
