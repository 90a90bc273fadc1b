"""The reserve's arguments under fuzzing (tests/fuzz_reserve.py), and the audit's defects one by one.

Every bad argument must fail at construction with a ValueError naming it, the value and what is allowed;
every valid one must build, reset and step with finite output, within the documented memory bounds.
"""

import time
import tracemalloc

import numpy as np
import pytest
from fuzz_reserve import FAILURES, Case, Entry, generate_cases, run_case, run_cases

from wildlife_reserve import reserve_v1
from wildlife_reserve.reserve.config import DEFAULT_REWARD_WEIGHTS, ReserveConfig


def test_fuzz_of_1000_argument_sets_has_no_failure():
    report = run_cases(generate_cases(1000, seed=0))
    print(report.format())
    counts = report.counts
    assert not report.failures, report.format()
    assert all(counts[kind] == 0 for kind in FAILURES)
    # The generator exercises both sides: valid sets that run and invalid ones that fail cleanly.
    assert counts["ran"] >= 200 and counts["clean_error"] >= 500, counts


def test_the_fuzz_is_seeded():
    first, again, other = generate_cases(100, seed=3), generate_cases(100, seed=3), generate_cases(100, seed=4)
    assert [c.describe() for c in first] == [c.describe() for c in again]
    assert [c.describe() for c in first] != [c.describe() for c in other]


def test_the_runner_sorts_every_outcome(monkeypatch):
    import fuzz_reserve

    def case(kwargs, valid):
        return Case(0, kwargs, (Entry(kwargs, valid),))

    tracemalloc.start()
    try:
        assert run_case(case({"n_uavs": 2}, True)).outcome == "ran"
        assert run_case(case({"n_uavs": 0}, False)).outcome == "clean_error"
        assert run_case(case({"n_uavs": 2}, False)).outcome == "silent_acceptance"  # labelled invalid, yet accepted
        assert run_case(case({"n_uavs": 0}, True)).outcome == "false_rejection"
        # A ValueError that does not name the argument labelled invalid is not clean.
        mislabelled = Case(0, {"n_uavs": 0, "shaping": 0.5}, (Entry({"n_uavs": 0}, True), Entry({"shaping": 0.5}, False)))
        assert run_case(mislabelled).outcome == "unclean_exception"

        class Stub:
            def __init__(self, behaviour):
                self.behaviour = behaviour

            def parallel_env(self, **kwargs):
                if self.behaviour == "sleep":
                    time.sleep(5)
                if self.behaviour == "allocate":
                    np.ones(8 * 2**20)  # 64 MiB
                raise ValueError("something went wrong")

        monkeypatch.setattr(fuzz_reserve, "reserve_v1", Stub("raise"))
        assert run_case(case({"n_uavs": 0}, False)).outcome == "unclean_exception"
        monkeypatch.setattr(fuzz_reserve, "reserve_v1", Stub("sleep"))
        start = time.perf_counter()
        assert run_case(case({"n_uavs": 0}, False), time_limit=0.2).outcome == "hang"
        assert time.perf_counter() - start < 2
        monkeypatch.setattr(fuzz_reserve, "reserve_v1", Stub("allocate"))
        assert run_case(case({"n_uavs": 0}, False), memory_limit=2**20).outcome == "memory"
    finally:
        tracemalloc.stop()


# ---------------------------------------------------------------------- the audit's defects
@pytest.mark.parametrize("name", ["adversarial", "continuous_actions"])
@pytest.mark.parametrize("value", ["false", "no", "0", "True", float("nan"), 0, 1, 1.0, None, [True], np.array([True])])
def test_booleans_must_be_booleans(name, value):
    with pytest.raises(ValueError, match=rf"{name} must be a bool \(True or False\), got "):
        reserve_v1.parallel_env(**{name: value})


@pytest.mark.parametrize("value", [True, False, np.True_, np.False_])
def test_real_booleans_are_accepted(value):
    env = reserve_v1.parallel_env(adversarial=value, continuous_actions=value, n_uavs=2, grid_size=20)
    assert env.config.adversarial is bool(value) and env.config.continuous_actions is bool(value)


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"n_uavs": 10**9}, r"n_uavs must be in \[1, 1000\], got 1000000000"),
    ({"grid_size": 10000}, r"grid_size must be in \[1, 1000\], got 10000"),
    ({"grid_size": (50, 10000)}, r"grid_size\[1\] must be in \[1, 1000\], got 10000"),
    ({"max_neighbors": 10**9}, r"max_neighbors must be in \[0, 1000\], got 1000000000"),
    ({"max_cycles": 10**18}, r"max_cycles must be in \[1, 100000\]"),
    ({"n_poachers": 10**9}, r"n_poachers must be in \[0, 1000\]"),
    ({"n_leopards": 1001}, r"n_leopards must be in \[0, 1000\]"),
    ({"n_decoys": 10**9}, r"n_decoys must be in \[0, 1000\]"),
    ({"sensor_radius": 11}, r"sensor_radius must be in \[1, 10\]"),
    ({"belief_size": 17}, r"belief_size must be in \[1, 16\]"),
    ({"comm_radius": 1e308}, r"comm_radius must be in \[0.0, 10000.0\]"),
    ({"jam_radius": 10**9}, r"jam_radius must be in \[0.0, 10000.0\]"),
    ({"uav_speed": 1e9}, r"uav_speed must be in \[1e-06, 10000.0\]"),
    ({"leopard_range": 1e5}, r"leopard_range must be in \[0.0, 10000.0\]"),
    ({"poaching_time": 10**9}, r"poaching_time must be in \[1, 100000\]"),
    ({"terrain_seed": 2**63}, r"terrain_seed must be in \[0, 9223372036854775807\]"),
    ({"terrain": np.zeros((3000, 3000), dtype=np.int8)}, r"the terrain's height must be in \[1, 1000\], got 3000"),
    ({"n_uavs": 1000, "grid_size": 1000}, r"n_uavs \* \(height \+ 2 \* sensor_radius\) \* \(width \+ 2 \* sensor_radius\) "
                                          r"must be <= 25_000_000 .* at most 24 UAVs fit"),
])
def test_sizes_are_bounded_before_anything_is_allocated(kwargs, message):
    tracemalloc.start()
    try:
        with pytest.raises(ValueError, match=message):
            reserve_v1.parallel_env(**kwargs)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 2**20, f"{peak / 2**20:.1f} MiB allocated before the error"


def test_the_largest_grids_and_teams_still_build():
    # The joint bound: 24 UAVs fit a 1000 x 1000 grid with the default radius, 25 do not.
    env = reserve_v1.parallel_env(n_uavs=24, grid_size=1000, n_poachers=0)
    assert (env.height, env.width) == (1000, 1000)
    with pytest.raises(ValueError, match=r"n_uavs .* must be <= 25_000_000 .*got 25 \* 1_012_036"):
        reserve_v1.parallel_env(n_uavs=25, grid_size=1000)
    env = reserve_v1.parallel_env(n_uavs=1000, max_neighbors=1000, n_poachers=1000, n_leopards=1000, n_decoys=1000)
    assert len(env.possible_agents) == 1000


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"region": ["mixed"]}, r"region must be one of \['forest', 'mixed', 'mountain', 'steppe'\], got \['mixed'\] \(list\)"),
    ({"region": {"mixed": 1}}, r"region must be one of"),
    ({"terrain": "forest"}, r"terrain must be an int array \(height, width\) of terrain types 0, 1, 2, got 'forest'"),
    ({"terrain": np.ones((10, 10), dtype=bool)}, r"terrain must be an int array .* dtype bool"),
    ({"terrain": np.full((10, 10), np.inf)}, r"terrain must hold integer terrain types .* non-finite"),
    ({"terrain": [[0, 1], [2]]}, r"terrain must be an int array .*inhomogeneous"),
    ({"risk": np.full((10, 10), 0.5 + 0j), "grid_size": 10}, r"risk must be an int or float array .* dtype complex128"),
    ({"risk": np.full((10, 10), "0.5"), "grid_size": 10}, r"risk must be an int or float array"),
    ({"mode_prior": "abc"}, r"mode_prior must be 8 non-negative weights .* got 'abc'"),
    ({"mode_prior": [1] * 7 + [np.nan]}, r"mode_prior must be 8 non-negative weights"),
    ({"mode_prior": np.ones(8, dtype=object)}, r"mode_prior must be 8 non-negative weights .* dtype=object"),
    ({"reward_weights": [("coverage", 1.0)]}, r"reward_weights must be a dict \{term: weight\} or None, got .* \(list\)"),
    ({"reward_weights": {"coverage": "1"}}, r"reward_weights\['coverage'\] must be a finite number in \[0.0, 1000000.0\], "
                                            r"got '1' \(str\)"),
    ({"reward_weights": {1: 2.0}}, r"reward_weights keys must be among \['collision', .*\], got 1"),
    ({"n_uavs": "10"}, r"n_uavs must be an int in \[1, 1000\], got '10' \(str\)"),
    ({"n_uavs": [10]}, r"n_uavs must be an int in \[1, 1000\], got \[10\] \(list\)"),
    ({"n_uavs": 10.0}, r"n_uavs must be an int in \[1, 1000\], got 10.0 \(float\)"),
    ({"n_uavs": True}, r"n_uavs must be an int in \[1, 1000\], got True \(bool\)"),
    ({"comm_loss": 0.5 + 0j}, r"comm_loss must be a finite number in \[0.0, 1.0\], got \(0.5\+0j\) \(complex\)"),
    ({"comm_loss": float("inf")}, r"comm_loss must be a finite number in \[0.0, 1.0\], got inf"),
    ({"shaping": 10**5000}, r"shaping must be in \[0.0, 1.0\], got an int of about 5000 digits"),
    ({"grid_size": (20.0, 20)}, r"grid_size\[0\] must be an int in \[1, 1000\], got 20.0 \(float\)"),
    ({"grid_size": np.zeros((2, 2), dtype=int)}, r"grid_size must be an int or \(height, width\)"),
    ({"render_mode": np.array(["human", "rgb_array"])}, r"render_mode must be None, 'human' or 'rgb_array', got array"),
])
def test_unclear_failures_are_now_value_errors_naming_the_argument(kwargs, message):
    with pytest.raises(ValueError, match=message):
        reserve_v1.parallel_env(**kwargs)


def test_huge_values_are_abbreviated_in_messages():
    with pytest.raises(ValueError, match="mode_prior") as error:
        reserve_v1.parallel_env(mode_prior=[1] * 10**6)
    assert len(str(error.value)) < 300
    with pytest.raises(ValueError, match="risk") as error:
        reserve_v1.parallel_env(risk=np.full((100, 100), 0.5 + 0j))
    assert "an array of shape (100, 100) and dtype complex128" in str(error.value)


def test_unknown_argument_names_it_and_lists_the_allowed_ones():
    with pytest.raises(ValueError, match=r"unknown argument 'n_drones' of the reserve") as error:
        reserve_v1.parallel_env(n_drones=3)
    assert all(name in str(error.value) for name in ReserveConfig.argument_names())
    with pytest.raises(ValueError, match=r"unknown arguments 'seed', 'N_UAVS' \(did you mean 'n_uavs'\?\) of the reserve"):
        reserve_v1.parallel_env(seed=1, N_UAVS=2)


def test_reward_weights_none_means_no_overrides():
    assert reserve_v1.parallel_env(reward_weights=None).config.reward_weights == DEFAULT_REWARD_WEIGHTS
    assert reserve_v1.parallel_env(reward_weights={}).config.reward_weights == DEFAULT_REWARD_WEIGHTS


def test_mode_prior_normalises_even_near_the_float_limit():
    env = reserve_v1.parallel_env(mode_prior=[1e308] * 8, n_uavs=2, grid_size=20)
    np.testing.assert_allclose(env.config.mode_prior, np.full(8, 1 / 8))
    env.reset(seed=0)
    env = reserve_v1.parallel_env(mode_prior=[0] * 5 + [1e308] + [0] * 2, n_uavs=2, grid_size=20)
    assert {env.reset(seed=seed)[1]["uav_0"]["mode"] for seed in range(5)} == {5}


def test_the_documented_minimum_grid_builds_with_the_default_belief_size():
    env = reserve_v1.parallel_env(grid_size=7)  # the sensing window with the default sensor_radius
    assert env.config.belief_size == 7
    observations, _ = env.reset(seed=0)
    env.step({agent: 0 for agent in env.agents})
    assert observations["uav_0"].shape == (7 * 49 + 6 + 3 * 4 + 3 * 49,)
    env = reserve_v1.parallel_env(grid_size=3, sensor_radius=1)
    assert env.config.belief_size == 3
    env.reset(seed=0)


@pytest.mark.parametrize("kwargs", [{}, {"grid_size": 8}, {"grid_size": (8, 50)}, {"terrain": np.zeros((30, 40), int)},
                                    {"grid_size": 1000, "n_uavs": 2}])
def test_default_observation_spaces_are_unchanged(kwargs):
    env = reserve_v1.parallel_env(**kwargs)
    assert env.config.belief_size == 8
    assert env.observation_space("uav_0").shape == (553,)
    if not kwargs:
        assert env.state_space.shape == (194,)


def test_the_largest_reward_weights_give_finite_rewards():
    with pytest.raises(ValueError, match=r"reward_weights\['coverage'\] must be in \[0.0, 1000000.0\], got 1e\+308"):
        reserve_v1.parallel_env(reward_weights={"coverage": 1e308})
    weights = dict.fromkeys(DEFAULT_REWARD_WEIGHTS, 1e6)
    for shaping in (0.0, 0.5, 1.0):
        env = reserve_v1.parallel_env(reward_weights=weights, shaping=shaping, n_uavs=20, grid_size=30, n_poachers=20,
                                      mode=0, max_cycles=30)
        env.reset(seed=0)
        rng = np.random.default_rng(0)
        while env.agents:
            _, rewards, _, _, _ = env.step({agent: int(rng.integers(15)) for agent in env.agents})
            assert np.all(np.isfinite(list(rewards.values())))
