"""The reserve's reset and step are strict and atomic: bad input is refused before anything changes, with a message
naming the agent or option; nothing runs before the first reset; the dict path takes exactly what step_arrays takes."""

import numpy as np
import pytest

from wildlife_reserve import reserve_v1

TINY = {"n_uavs": 2, "grid_size": 20, "max_cycles": 10}


def test_every_method_before_the_first_reset_says_to_call_reset():
    env = reserve_v1.parallel_env(**TINY, render_mode="rgb_array")
    for call in (lambda: env.step({"uav_0": 0, "uav_1": 0}), lambda: env.step_arrays(np.zeros(2, dtype=np.int64)),
                 env.state, env.render, env.episode_metrics):
        with pytest.raises(RuntimeError, match=r"needs an episode: call reset\(\) first"):
            call()


@pytest.mark.parametrize(("options", "message"), [
    ({"mode": 99}, "mode"),
    ({"mode": 2.5}, "mode"),
    ({"uav_positions": [[0, 0]]}, r"options\['uav_positions'\] must be 2 \(row, col\) cells"),
    ({"uav_positions": "corner"}, r"options\['uav_positions'\]"),
    ("mode 3", "options must be a dict or None"),
])
def test_a_failed_reset_leaves_the_episode_as_it_was(options, message):
    env = reserve_v1.parallel_env(**TINY)
    env.reset(seed=1)
    env.step({"uav_0": 1, "uav_1": 2})
    before = (env.t, env.uav_pos.copy(), env.battery.copy(), env.mode, env.state().copy(), env.episode_metrics())
    with pytest.raises(ValueError, match=message):
        env.reset(seed=2, options=options)
    assert env.t == before[0] and env.mode == before[3] and env.episode_metrics() == before[5]
    np.testing.assert_array_equal(env.uav_pos, before[1])
    np.testing.assert_array_equal(env.battery, before[2])
    np.testing.assert_array_equal(env.state(), before[4])
    env.step({"uav_0": 0, "uav_1": 0})
    assert env.t == 2


def test_a_failed_first_reset_leaves_nothing_to_step():
    env = reserve_v1.parallel_env(**TINY)
    with pytest.raises(ValueError, match="mode"):
        env.reset(options={"mode": -1})
    with pytest.raises(RuntimeError, match="call reset"):
        env.step({"uav_0": 0, "uav_1": 0})


@pytest.mark.parametrize("seed", [np.int64(5), np.uint32(5), 5])
def test_numpy_integer_seeds_are_taken(seed):
    first = reserve_v1.parallel_env(**TINY).reset(seed=seed)[0]
    again = reserve_v1.parallel_env(**TINY).reset(seed=5)[0]
    np.testing.assert_array_equal(first["uav_0"], again["uav_0"])


@pytest.mark.parametrize("seed", [True, -1, 1.5, "7"])
def test_bad_seeds_are_refused(seed):
    with pytest.raises(ValueError, match="seed must be an int >= 0 or None"):
        reserve_v1.parallel_env(**TINY).reset(seed=seed)


@pytest.mark.parametrize("action", [3.7, "14", b"3", True, -0.5, float("inf"), 2**70, -1, 15, np.nan, [1, 2]])
def test_the_dict_path_refuses_what_step_arrays_refuses(action):
    env = reserve_v1.parallel_env(**TINY)
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"the action of uav_1 must be an int in \[0, 14\] or None"):
        env.step({"uav_0": 0, "uav_1": action})
    assert env.t == 0  # nothing stepped
    with pytest.raises(ValueError, match="discrete actions must be 2 ints"):
        env.step_arrays(np.array([action, action]))  # every UAV given it: the same refusal


def test_the_dict_path_takes_ints_numpy_ints_and_none_as_stay():
    """As Gymnasium's ``Discrete.contains``: a whole float or a one-element array is refused (since 0.22.1)."""
    def play(actions):
        env = reserve_v1.parallel_env(**TINY)
        env.reset(seed=3)
        return env.step(actions)[0]["uav_0"]

    reference = play({"uav_0": 0, "uav_1": 7})
    for actions in ({"uav_0": None, "uav_1": np.int64(7)}, {"uav_1": np.array(7)}, {"uav_0": np.uint8(0), "uav_1": 7}):
        np.testing.assert_array_equal(play(actions), reference)
    for actions in ({"uav_1": 7.0}, {"uav_0": np.array([0]), "uav_1": 7}):
        with pytest.raises(ValueError, match="must be an int"):
            play(actions)


def test_a_list_of_actions_is_refused():
    env = reserve_v1.parallel_env(**TINY)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="actions must be a dict of agent -> action, got list"):
        env.step([0, 0])


@pytest.mark.parametrize("action", [3, "0.5", [0.1, 0.2], [0.0, np.inf, 0.0], np.zeros((3, 1))])
def test_continuous_actions_must_be_three_finite_floats(action):
    env = reserve_v1.parallel_env(**TINY, continuous_actions=True)
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"the action of uav_0 must be 3 finite floats \(d_row, d_col, comm\) or None"):
        env.step({"uav_0": action, "uav_1": None})


def test_the_aec_form_takes_none_as_stay():
    aec = reserve_v1.env(**TINY)
    aec.reset(seed=0)
    aec.step(None)
    aec.step(3)
    assert aec.unwrapped.t == 1
    with pytest.raises(AssertionError):
        aec.step(99)  # PettingZoo's own check of the action space stays
