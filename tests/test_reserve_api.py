"""PettingZoo's own checks on the reserve, over the argument combinations that matter (as MPE2's tests do)."""

import numpy as np
import pytest
from pettingzoo.test import api_test, parallel_api_test, parallel_seed_test, render_test, seed_test
from pettingzoo.utils import parallel_to_aec

from wildlife_reserve import reserve_v0
from wildlife_reserve.reserve.terrain import REGIONS

COMBINATIONS = {
    "default": {},
    "one_uav": {"n_uavs": 1},
    "fifty_uavs_200": {"n_uavs": 50, "grid_size": 200},
    "continuous": {"continuous_actions": True},
    "agent_ids_continuous": {"agent_ids": True, "continuous_actions": True},
    "compass_agent_ids": {"compass": True, "agent_ids": True},
    "coverage_sectors_new_maps": {"coverage_sectors": True, "terrain_seed": None},
    "sensor_noise": {"sensor_noise": 0.5},
    "comm_loss": {"comm_loss": 0.5},
    "adversarial": {"adversarial": True},
    **{f"region_{name}": {"region": name} for name in REGIONS},
}
# Long enough to cross an episode end at the default max_cycles (200); shorter for the big reserve.
CYCLES = {"fifty_uavs_200": 60}


@pytest.mark.parametrize("name", COMBINATIONS)
def test_parallel_api(name):
    kwargs = COMBINATIONS[name]
    parallel_api_test(reserve_v0.parallel_env(**kwargs), num_cycles=CYCLES.get(name, 250))


@pytest.mark.parametrize("name", COMBINATIONS)
def test_aec_api(name):
    kwargs = COMBINATIONS[name]
    api_test(parallel_to_aec(reserve_v0.parallel_env(**kwargs)), num_cycles=CYCLES.get(name, 250))
    api_test(reserve_v0.env(**kwargs), num_cycles=20)


@pytest.mark.parametrize("name", COMBINATIONS)
def test_seed(name):
    kwargs = COMBINATIONS[name]

    def par(**more):
        return reserve_v0.parallel_env(**kwargs, **more)

    def aec(**more):
        return reserve_v0.env(**kwargs, **more)

    parallel_seed_test(par)
    seed_test(aec, num_cycles=CYCLES.get(name, 100))


@pytest.mark.parametrize("name", COMBINATIONS)
def test_render_rgb_array(name):
    kwargs = COMBINATIONS[name]
    render_test(lambda render_mode=None: reserve_v0.env(**kwargs, render_mode=render_mode))


def test_rgb_frame_shows_the_reserve():
    env = reserve_v0.parallel_env(render_mode="rgb_array", grid_size=50)
    env.reset(seed=1)
    frame = env.render()
    assert frame.shape == (600, 600, 3) and frame.dtype == np.uint8
    # Terrain colours and at least one UAV are drawn: many distinct colours, some UAV blue.
    assert len(np.unique(frame.reshape(-1, 3), axis=0)) > 10
    assert np.any(np.all(frame == (40, 90, 230), axis=-1))
    env.close()


def test_state_matches_state_space():
    env = reserve_v0.parallel_env(n_uavs=3)
    env.reset(seed=0)
    for _ in range(5):
        env.step({a: env.action_space(a).sample() for a in env.agents})
        state = env.state()
        assert env.state_space.contains(state)
