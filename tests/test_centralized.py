"""The centralised (single-agent) view of the reserve used by Centralized PPO."""

import warnings

import gymnasium
import numpy as np
import pytest
from gymnasium import spaces
from gymnasium.utils.env_checker import check_env as gymnasium_check_env
from stable_baselines3 import PPO
from stable_baselines3.common.env_checker import check_env

from sb3_emmarl.common.centralized import ENV_ID, CentralizedReserveEnv, register_envs
from wildlife_reserve import reserve_v1
from wildlife_reserve.reserve.kernels.constants import N_MOVES
from wildlife_reserve.reserve.reserve import ReserveParallelEnv

STAY, UP, DOWN, LEFT, RIGHT = range(N_MOVES)
SMALL = {"n_uavs": 3, "grid_size": 20, "max_cycles": 30}
START = np.array([[4, 4], [10, 10], [15, 3]])


def make(**kwargs) -> CentralizedReserveEnv:
    return CentralizedReserveEnv(**{**SMALL, **kwargs})


@pytest.mark.parametrize("continuous_actions", [False, True])
def test_sb3_check_env(continuous_actions):
    env = make(continuous_actions=continuous_actions)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env)
    env.close()


@pytest.mark.parametrize("continuous_actions", [False, True])
def test_gymnasium_check_env(continuous_actions):
    # Gymnasium's checker also checks that reset(seed=...) is deterministic.
    env = make(continuous_actions=continuous_actions)
    gymnasium_check_env(env, skip_render_check=True)
    env.close()


@pytest.mark.parametrize("n_uavs, n_poachers, n_leopards, belief_size", [(3, 4, 3, 8), (1, 0, 0, 4), (5, 2, 1, 3)])
def test_observation_is_the_global_state(n_uavs, n_poachers, n_leopards, belief_size):
    env = make(n_uavs=n_uavs, n_poachers=n_poachers, n_leopards=n_leopards, belief_size=belief_size)
    dim = 4 * n_uavs + 4 * n_poachers + 3 * n_leopards + 2 * belief_size**2 + 1
    assert env.observation_space == spaces.Box(-1.0, 1.0, (dim,), np.float32)
    assert env.observation_space == env.parallel_env.state_space
    obs, info = env.reset(seed=0)
    assert obs.shape == (dim,) and obs.dtype == np.float32
    np.testing.assert_array_equal(obs, env.parallel_env.state())
    assert info["mode"] == env.parallel_env.mode
    for _ in range(3):
        obs, *_ = env.step(env.action_space.sample())
        assert obs in env.observation_space
        np.testing.assert_array_equal(obs, env.parallel_env.state())


@pytest.mark.parametrize("n_uavs", [1, 3, 7])
def test_action_spaces(n_uavs):
    assert make(n_uavs=n_uavs).action_space == spaces.MultiDiscrete([15] * n_uavs)
    assert make(n_uavs=n_uavs, continuous_actions=True).action_space == spaces.Box(-1.0, 1.0, (3 * n_uavs,), np.float32)


@pytest.mark.parametrize("mover", range(3))
def test_discrete_joint_action_drives_each_uav(mover):
    env = make(uav_speed=2.0)
    env.reset(seed=0, options={"uav_positions": START})
    before = env.parallel_env.uav_pos.copy()
    action = np.full(3, STAY)
    action[mover] = RIGHT
    env.step(action)
    expected = before.copy()
    expected[mover, 1] += 2.0
    np.testing.assert_allclose(env.parallel_env.uav_pos, expected)


@pytest.mark.parametrize("mover", range(3))
def test_continuous_joint_action_drives_each_uav(mover):
    env = make(uav_speed=2.0, continuous_actions=True)
    env.reset(seed=0, options={"uav_positions": START})
    before = env.parallel_env.uav_pos.copy()
    action = np.zeros((3, 3), dtype=np.float32)
    action[mover] = [1.0, -0.5, 0.0]  # (d_row, d_col, comm) of UAV `mover`
    env.step(action.ravel())
    expected = before.copy()
    expected[mover] += [2.0, -1.0]
    np.testing.assert_allclose(env.parallel_env.uav_pos, expected)


@pytest.mark.parametrize("kwargs", [{}, {"shaping": 0.5}, {"continuous_actions": True}])
def test_reward_is_the_team_reward_of_the_parallel_env(kwargs):
    env = make(**kwargs)
    reference = reserve_v1.parallel_env(**SMALL, **kwargs)
    env.reset(seed=3, options={"uav_positions": START})
    reference.reset(seed=3, options={"uav_positions": START})
    env.action_space.seed(3)
    total = 0.0
    for _ in range(SMALL["max_cycles"]):
        action = env.action_space.sample()
        obs, reward, terminated, truncated, info = env.step(action)
        per_uav = action.reshape(3, -1) if env.continuous_actions else action
        _, rewards, _, _, infos = reference.step({agent: per_uav[i] for i, agent in enumerate(reference.possible_agents)})
        assert isinstance(reward, float)
        assert reward == pytest.approx(np.mean(list(rewards.values())))
        if not kwargs.get("shaping"):
            assert all(r == reward for r in rewards.values())  # every UAV gets the identical team reward
        np.testing.assert_array_equal(obs, reference.state())
        assert info == infos["uav_0"]
        total += reward
    assert truncated and not terminated
    if not kwargs.get("shaping"):
        assert total == pytest.approx(info["metrics"]["team_reward"])


def test_collision_penalty_on_a_hand_built_step():
    # Two UAVs in one cell, no poachers or leopards: the team reward is -collision - energy.
    env = make(n_uavs=2, n_poachers=0, n_leopards=0, reward_weights={"coverage": 0.0, "energy": 0.0, "collision": 3.0})
    env.reset(seed=0, options={"uav_positions": [[5, 5], [5, 5]]})
    _, reward, *_ = env.step(np.array([STAY, STAY]))
    assert reward == pytest.approx(-3.0)
    _, reward, *_ = env.step(np.array([STAY, RIGHT]))
    assert reward == pytest.approx(0.0)


def run_episode(env: CentralizedReserveEnv, seed: int) -> list:
    env.action_space.seed(seed)
    obs, info = env.reset(seed=seed)
    trajectory = [(obs, info)]
    done = False
    while not done:
        obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
        trajectory.append((obs, reward, terminated, truncated, info))
        done = terminated or truncated
    return trajectory


def assert_same(a, b) -> None:
    assert len(a) == len(b)
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x[0], y[0])
        assert x[1:] == y[1:]


@pytest.mark.parametrize("continuous_actions", [False, True])
def test_same_seed_same_actions_same_episode(continuous_actions):
    first = run_episode(make(continuous_actions=continuous_actions), seed=7)
    second = run_episode(make(continuous_actions=continuous_actions), seed=7)
    assert_same(first, second)
    # The episode is truncated at max_cycles and the last info holds the metrics.
    assert len(first) == SMALL["max_cycles"] + 1
    _, _, terminated, truncated, info = first[-1]
    assert truncated and not terminated
    assert info["metrics"]["episode_length"] == SMALL["max_cycles"]
    assert info["metrics"]["mode"] == info["mode"]
    assert all("metrics" not in step[-1] for step in first[:-1])


def test_unseeded_reset_continues_the_seeded_stream():
    env, other = make(), make()
    env.reset(seed=5)
    other.reset(seed=5)
    np.testing.assert_array_equal(env.reset()[0], other.reset()[0])


def test_options_reach_the_parallel_env():
    env = make()
    _, info = env.reset(seed=0, options={"mode": 5, "uav_positions": START})
    assert info["mode"] == 5 == env.parallel_env.mode
    np.testing.assert_array_equal(env.parallel_env.uav_pos, START + 0.5)


def test_terminated_when_every_uav_is_grounded():
    env = make()
    env.reset(seed=0)
    env.parallel_env.battery[:] = 1e-4
    _, _, terminated, truncated, info = env.step(np.full(3, RIGHT))
    assert terminated and not truncated
    assert "metrics" in info


def test_register_envs_and_make():
    register_envs()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # re-registering would warn "Overriding environment"
        register_envs()
    spec = gymnasium.spec(ENV_ID)
    assert ENV_ID == "WildlifeReserve-v1"
    assert spec.entry_point == "sb3_emmarl.common.centralized:CentralizedReserveEnv"
    assert spec.max_episode_steps is None and not spec.disable_env_checker
    env = gymnasium.make(ENV_ID, n_uavs=2, grid_size=20)
    assert isinstance(env.unwrapped, CentralizedReserveEnv)
    assert env.action_space == spaces.MultiDiscrete([15, 15])
    obs, info = env.reset(seed=0)
    assert obs in env.observation_space and "mode" in info
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
    assert obs in env.observation_space and isinstance(reward, float)
    assert not terminated and not truncated and info["mode"] == env.unwrapped.parallel_env.mode
    env.close()


def test_render_rgb_array():
    assert set(CentralizedReserveEnv.metadata["render_modes"]) == {"human", "rgb_array"}
    assert CentralizedReserveEnv.metadata["render_fps"] == ReserveParallelEnv.metadata["render_fps"]
    register_envs()
    env = gymnasium.make(ENV_ID, n_uavs=2, grid_size=20, render_mode="rgb_array")
    env.reset(seed=0)
    frame = env.render()
    assert frame.ndim == 3 and frame.shape[-1] == 3 and frame.dtype == np.uint8
    env.close()


@pytest.mark.parametrize("continuous_actions", [False, True])
def test_ppo_learns_and_predicts(continuous_actions):
    env = make(continuous_actions=continuous_actions)
    model = PPO("MlpPolicy", env, n_steps=64, batch_size=32, n_epochs=2, seed=0).learn(128)
    obs, _ = env.reset(seed=0)
    action, _ = model.predict(obs, deterministic=True)
    assert action in env.action_space
    env.step(action)


@pytest.mark.parametrize(
    "continuous_actions, action, expected",
    [
        (False, np.zeros(4, dtype=np.int64), r"shape \(3,\)"),
        (False, np.zeros((1, 3), dtype=np.int64), r"shape \(3,\)"),
        (False, 0, r"shape \(3,\)"),
        (True, np.zeros((3, 3), dtype=np.float32), r"shape \(9,\)"),
        (True, np.zeros(3, dtype=np.float32), r"shape \(9,\)"),
    ],
)
def test_wrong_action_shape_raises(continuous_actions, action, expected):
    env = make(continuous_actions=continuous_actions)
    env.reset(seed=0)
    with pytest.raises(ValueError, match=expected):
        env.step(action)


@pytest.mark.parametrize("action", [np.array([0, 1, 15]), np.array([-1, 0, 0]), np.array([0.5, 0.0, 0.0])])
def test_invalid_discrete_actions_raise(action):
    env = make()
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"integers|ints|an int in"):
        env.step(action)


def test_integral_float_actions_are_accepted():
    env, other = make(), make()
    env.reset(seed=0, options={"uav_positions": START})
    other.reset(seed=0, options={"uav_positions": START})
    np.testing.assert_array_equal(env.step(np.array([4.0, 0.0, 1.0]))[0], other.step([RIGHT, STAY, UP])[0])
