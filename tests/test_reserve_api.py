"""PettingZoo's own checks on the reserve, over the argument combinations that matter (as MPE2's tests do)."""

import numpy as np
import pytest
from pettingzoo.test import api_test, parallel_api_test, parallel_seed_test, render_test, seed_test
from pettingzoo.utils import parallel_to_aec

from wildlife_reserve import reserve_v1
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
    "zone_raids": {"scenario": "zone_raids"},
    "zone_raids_continuous_new_maps": {"scenario": "zone_raids", "continuous_actions": True, "terrain_seed": None,
                                       "agent_ids": True},
    **{f"region_{name}": {"region": name} for name in REGIONS},
}
# Long enough to cross an episode end at the default max_cycles (200); shorter for the big reserve.
CYCLES = {"fifty_uavs_200": 60}


@pytest.mark.parametrize("name", COMBINATIONS)
def test_parallel_api(name):
    kwargs = COMBINATIONS[name]
    parallel_api_test(reserve_v1.parallel_env(**kwargs), num_cycles=CYCLES.get(name, 250))


@pytest.mark.parametrize("name", COMBINATIONS)
def test_aec_api(name):
    kwargs = COMBINATIONS[name]
    api_test(parallel_to_aec(reserve_v1.parallel_env(**kwargs)), num_cycles=CYCLES.get(name, 250))
    api_test(reserve_v1.env(**kwargs), num_cycles=20)


@pytest.mark.parametrize("name", COMBINATIONS)
def test_seed(name):
    kwargs = COMBINATIONS[name]

    def par(**more):
        return reserve_v1.parallel_env(**kwargs, **more)

    def aec(**more):
        return reserve_v1.env(**kwargs, **more)

    parallel_seed_test(par)
    seed_test(aec, num_cycles=CYCLES.get(name, 100))


@pytest.mark.parametrize("name", COMBINATIONS)
def test_render_rgb_array(name):
    kwargs = COMBINATIONS[name]
    render_test(lambda render_mode=None: reserve_v1.env(**kwargs, render_mode=render_mode))


def test_rgb_frame_shows_the_reserve():
    env = reserve_v1.parallel_env(render_mode="rgb_array", grid_size=50)
    env.reset(seed=1)
    frame = env.render()
    assert frame.shape == (600, 600, 3) and frame.dtype == np.uint8
    # Terrain colours and at least one UAV are drawn: many distinct colours, some UAV blue.
    assert len(np.unique(frame.reshape(-1, 3), axis=0)) > 10
    assert np.any(np.all(frame == (40, 90, 230), axis=-1))
    env.close()


def test_state_matches_state_space():
    env = reserve_v1.parallel_env(n_uavs=3)
    env.reset(seed=0)
    for _ in range(5):
        env.step({a: env.action_space(a).sample() for a in env.agents})
        state = env.state()
        assert env.state_space.contains(state)


def test_the_former_name_reserve_v0_warns_once_and_gives_reserve_v1():
    import subprocess
    import sys

    code = ("import warnings; warnings.simplefilter('always')\n"
            "with warnings.catch_warnings(record=True) as caught:\n"
            "    from wildlife_reserve import reserve_v0\n"
            "    import importlib; importlib.import_module('wildlife_reserve.reserve_v0')\n"
            "from wildlife_reserve import reserve_v1\n"
            "assert reserve_v0.parallel_env is reserve_v1.parallel_env and reserve_v0.env is reserve_v1.env\n"
            "futures = [w for w in caught if issubclass(w.category, FutureWarning)]\n"
            "print(len(futures)); print(futures[0].message)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.splitlines()
    assert out[0] == "1", out
    assert "0.1.0" in out[1] and "import wildlife_reserve.reserve_v1" in out[1]


def test_the_former_zoo_id_warns_once_and_gives_the_current_one(monkeypatch):
    import warnings

    from sb3_emmarl.common import env_ids
    from sb3_emmarl.common.env_ids import ENV_ID, check_env_id, current_env_id

    assert ENV_ID == "WildlifeReserve-v1"
    monkeypatch.setattr(env_ids, "_warned", set())
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert current_env_id("WildlifeReserve-v0") == ENV_ID
        assert check_env_id("WildlifeReserve-v0") == ENV_ID
        assert current_env_id("ZonePatrol-v0") == "ZonePatrol-v0"
    (warning,) = [w for w in caught if issubclass(w.category, FutureWarning)]
    assert "--env WildlifeReserve-v1" in str(warning.message)
    with pytest.raises(ValueError, match="unknown environment id 'WildlifeReserve-v2'"):
        check_env_id("WildlifeReserve-v2")


def test_the_zoo_takes_the_former_id_as_the_current_one(monkeypatch):
    from sb3_emmarl.common import env_ids
    from sb3_emmarl.zoo.cli import enjoy_parser, train_parser

    monkeypatch.setattr(env_ids, "_warned", set())
    with pytest.warns(FutureWarning):
        assert train_parser().parse_args(["--algo", "ppo", "--env", "WildlifeReserve-v0"]).env == "WildlifeReserve-v1"
    assert enjoy_parser().parse_args(["--algo", "ppo"]).env == "WildlifeReserve-v1"
