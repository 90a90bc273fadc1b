"""Bad arguments fail early with a ValueError naming the argument and what is allowed."""

import numpy as np
import pytest

from wildlife_reserve import reserve_v1
from wildlife_reserve.reserve.config import ReserveConfig

BAD = [
    ({"n_uavs": 0}, r"n_uavs must be in \[1, 1000\], got 0"),
    ({"n_uavs": 2.5}, r"n_uavs must be an int in \[1, 1000\], got 2.5 \(float\)"),
    ({"sensor_radius": 0}, r"sensor_radius must be in \[1, 10\]"),
    ({"comm_radius": -1.0}, r"comm_radius must be in \[0.0, 10000.0\], got -1.0"),
    ({"jam_radius": -3}, r"jam_radius must be in \[0.0, 10000.0\]"),
    ({"sensor_noise": 1.5}, r"sensor_noise must be in \[0.0, 1.0\], got 1.5"),
    ({"comm_loss": -0.1}, r"comm_loss must be in \[0.0, 1.0\]"),
    ({"comm_loss": float("nan")}, r"comm_loss must be a finite number"),
    ({"shaping": 2}, r"shaping must be in \[0.0, 1.0\]"),
    ({"region": "atlantis"}, r"region must be one of \['forest', 'mixed', 'mountain', 'steppe'\], got 'atlantis'"),
    ({"grid_size": 5}, r"grid_size must be at least the sensing window 2 \* sensor_radius \+ 1 = 7"),
    ({"grid_size": (40, 6)}, r"grid_size must be at least the sensing window"),
    ({"grid_size": (1, 2, 3)}, r"grid_size must be an int or \(height, width\)"),
    ({"sensor_radius": 10, "grid_size": 20}, r"sensing window 2 \* sensor_radius \+ 1 = 21"),
    ({"terrain": np.zeros((10, 12), int), "grid_size": 10}, r"terrain must have shape grid_size=\(10, 10\), got \(10, 12\)"),
    ({"terrain": np.full((10, 10), 3)}, r"terrain values must be in \[0, 2\] \(open, forest, mountain\)"),
    ({"terrain": np.full((10, 10), 0.5)}, r"terrain must hold integer terrain types"),
    ({"terrain": np.zeros(10)}, r"terrain must be a 2-D array"),
    ({"risk": np.full((10, 10), 1.5), "grid_size": 10}, r"risk values must be finite and in \[0, 1\]"),
    ({"mode": 8}, r"mode must be in \[0, 7\], got 8"),
    ({"mode_prior": [1, 2]}, r"mode_prior must be 8 non-negative weights"),
    ({"max_cycles": 0}, r"max_cycles must be in \[1, 100000\]"),
    ({"n_poachers": -1}, r"n_poachers must be in \[0, 1000\]"),
    ({"belief_size": 200, "grid_size": 50}, r"belief_size must be in \[1, 16\], got 200"),
    ({"belief_size": 12, "grid_size": 10}, r"belief_size must be in \[1, 10\], got 12"),
    ({"reward_weights": {"bananas": 1.0}}, r"reward_weights keys must be among"),
    ({"reward_weights": {"energy": -1.0}}, r"reward_weights\['energy'\] must be in \[0.0, 1000000.0\], got -1.0"),
    ({"render_mode": "ascii"}, r"render_mode must be None, 'human' or 'rgb_array', got 'ascii'"),
    ({"agent_ids": "yes"}, r"agent_ids must be a bool \(True or False\), got 'yes' \(str\)"),
    ({"compass": 1}, r"compass must be a bool \(True or False\), got 1 \(int\)"),
    ({"coverage_sectors": "true"}, r"coverage_sectors must be a bool \(True or False\), got 'true' \(str\)"),
]


@pytest.mark.parametrize(("kwargs", "message"), BAD, ids=[next(iter(k)) + str(i) for i, (k, _) in enumerate(BAD)])
def test_bad_argument_raises_value_error_naming_it(kwargs, message):
    with pytest.raises(ValueError, match=message):
        reserve_v1.parallel_env(**kwargs)
    with pytest.raises(ValueError, match=message):
        reserve_v1.env(**kwargs)


def test_unknown_keyword_is_rejected():
    # A ValueError like every argument error, naming it and listing the arguments; also a TypeError (what Python
    # raises for an unexpected keyword) for callers that catch that.
    for make in (reserve_v1.parallel_env, reserve_v1.env, reserve_v1.raw_env):
        with pytest.raises(ValueError, match=r"unknown argument 'n_drones' of the reserve; the arguments are: n_uavs, "):
            make(n_drones=3)
    with pytest.raises(TypeError, match="n_drones"):
        reserve_v1.parallel_env(n_drones=3)


def test_bad_reset_options_are_rejected():
    env = reserve_v1.parallel_env(n_uavs=2, grid_size=20)
    with pytest.raises(ValueError, match=r"options\['uav_positions'\] must be 2 \(row, col\) cells inside \(20, 20\)"):
        env.reset(seed=0, options={"uav_positions": [[0, 0], [25, 3]]})
    with pytest.raises(ValueError, match=r"mode must be in \[0, 7\], got 9"):
        env.reset(seed=0, options={"mode": 9})


def test_the_terrain_array_sets_the_grid_size():
    env = reserve_v1.parallel_env(terrain=np.ones((30, 40), dtype=int))
    env.reset(seed=0)
    assert (env.height, env.width) == (30, 40)
    assert (env.terrain == 1).all()


def test_every_argument_is_documented_in_the_card():
    from pathlib import Path

    card = (Path(__file__).resolve().parents[1] / "docs" / "env.md").read_text()
    missing = [name for name in ReserveConfig.argument_names() if f"`{name}`" not in card]
    assert not missing, f"arguments missing from docs/env.md: {missing}"
