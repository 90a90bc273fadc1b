"""Every environment of the package (the reserve, its zone raids, ZonePatrol) refuses what Gymnasium and PettingZoo
would not take, before anything changes, and goes on as before (issue 65, item 4): action dicts naming agents that
are not in the episode, actions of another shape or type, unknown reset options, unknown agent names, seeds that are
not an int >= 0 or None."""

import numpy as np
import pytest

from wildlife_reserve import reserve_v1, zone_patrol_v1

ENVS = {
    "reserve": lambda: reserve_v1.parallel_env(n_uavs=2, grid_size=20, max_cycles=10),
    "zone_raids": lambda: reserve_v1.parallel_env(scenario="zone_raids", n_uavs=2, grid_size=20, max_cycles=10),
    "zone_patrol": lambda: zone_patrol_v1.parallel_env(max_cycles=10),
}


def snapshot(env):
    return env.state().copy()


@pytest.fixture(params=sorted(ENVS))
def env(request):
    env = ENVS[request.param]()
    env.reset(seed=3)
    return env


@pytest.mark.parametrize(("actions", "message"), [
    ({"uav_9": 0}, r"actions for agents that are not in the episode: \['uav_9'\]"),
    ({"uav_0 ": 0}, "not in the episode"),
    ([0, 0], "actions must be a dict of agent -> action, got list"),
    ({"uav_0": [1]}, r"the action of uav_0 must be an int in \[0, \d+\]( or None)?, got \[1\]"),
    ({"uav_0": [[1]]}, "the action of uav_0 must be an int"),
    ({"uav_0": np.array([[1]])}, "the action of uav_0 must be an int"),
    ({"uav_0": 1.0}, "the action of uav_0 must be an int"),
    ({"uav_0": True}, "the action of uav_0 must be an int"),
    ({"uav_0": "1"}, "the action of uav_0 must be an int"),
    ({"uav_0": -1}, "the action of uav_0 must be an int"),
    ({"uav_0": 10 ** 6}, "the action of uav_0 must be an int"),
])
def test_bad_actions_are_refused_and_the_episode_goes_on(env, actions, message):
    before, t = snapshot(env), env.world.t if hasattr(env, "world") else env.t
    with pytest.raises(ValueError, match=message):
        env.step(actions)
    np.testing.assert_array_equal(snapshot(env), before)
    assert (env.world.t if hasattr(env, "world") else env.t) == t
    env.step({agent: np.int64(1) for agent in env.agents})  # numpy integers, as SB3 and PettingZoo's tests give


@pytest.mark.parametrize(("seed", "options", "message"), [
    (None, {"mod": 1}, r"unknown reset option 'mod': did you mean 'mode'\?"),
    (None, {"mode": 0, "Mode": 1}, r"unknown reset option 'Mode': did you mean 'mode'\?"),
    (None, "mode 3", "options must be a dict or None, got str"),
    (-1, None, "seed must be an int >= 0 or None, got -1"),
    (1.5, None, "seed must be an int >= 0 or None"),
    ("7", None, "seed must be an int >= 0 or None"),
    (True, None, "seed must be an int >= 0 or None"),
])
def test_bad_resets_are_refused_and_the_episode_goes_on(env, seed, options, message):
    before = snapshot(env)
    with pytest.raises(ValueError, match=message):
        env.reset(seed=seed, options=options)
    np.testing.assert_array_equal(snapshot(env), before)
    env.step({agent: 0 for agent in env.agents})


def test_other_unknown_options_are_named_in_a_warning(env):
    """PettingZoo's API test resets with options={"options": 1}: an environment must take it; it says so."""
    with pytest.warns(UserWarning, match=r"reset ignores the options \['options'\]"):
        env.reset(seed=0, options={"options": 1})


def test_unknown_agents_have_no_spaces(env):
    for method in (env.observation_space, env.action_space):
        with pytest.raises(ValueError, match=r"no agent 'no_such_uav': the agents are \['uav_0'"):
            method("no_such_uav")
        assert method("uav_0") is method("uav_0")  # (one space object per agent, as PettingZoo asks)


def test_zone_patrol_refuses_an_output_array_of_another_shape_before_stepping():
    env = zone_patrol_v1.parallel_env(max_cycles=10)
    env.reset(seed=0)
    before = snapshot(env)
    with pytest.raises(ValueError, match="out must be a float32 array of shape"):
        env.step_arrays(np.zeros(4, dtype=np.int64), out=np.zeros((4, 3), dtype=np.float32))
    np.testing.assert_array_equal(snapshot(env), before)
    obs = env.step_arrays(np.zeros(4, dtype=np.int64), out=np.zeros((4, env.obs_dim), dtype=np.float32))[0]
    assert obs.shape == (4, env.obs_dim)
