"""The family of observation wrappers (``sb3_emmarl.common.appended.wrapping``): one base appends at reset, at each step and to
terminal observations; ``ensure_wrapped`` wraps once and refuses a wrapper that does not do what is asked."""

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3.common.env_util import make_vec_env as sb3_make_vec_env

from sb3_emmarl.common.appended.wrapping import AppendingVecEnvWrapper, ensure_wrapped, find_wrapper


class StepCount(AppendingVecEnvWrapper):
    """Appends each entry's step count in its episode (and the finished episode's length to its terminal one)."""

    def __init__(self, venv, scale=1.0):
        super().__init__(venv, np.zeros(1, np.float32), np.full(1, np.inf, np.float32))
        self.scale, self.steps = scale, np.zeros(venv.num_envs, np.float32)

    def _reset_extra(self, observations):
        self.steps[:] = 0
        return self.steps[:, None] * self.scale

    def _step_extra(self, observations, dones, infos):
        self.steps += 1
        terminal = {int(i): self.steps[i:i + 1] * self.scale for i in np.flatnonzero(dones)}
        self.steps[dones] = 0
        return self.steps[:, None] * self.scale, terminal


def test_the_base_widens_the_space_and_appends_everywhere():
    venv = StepCount(sb3_make_vec_env("CartPole-v1", n_envs=2, seed=0))
    assert venv.observation_space.shape == (5,) and venv.observation_space.high[-1] == np.inf
    observations = venv.reset()
    assert observations.shape == (2, 5) and np.all(observations[:, -1] == 0)
    ended = None
    for step in range(1, 200):
        observations, _, dones, infos = venv.step(np.zeros(2, dtype=np.int64))
        if dones.any():
            ended = int(np.flatnonzero(dones)[0])
            assert infos[ended]["terminal_observation"].shape == (5,)
            assert infos[ended]["terminal_observation"][-1] == step and observations[ended, -1] == 0
            break
        assert np.all(observations[:, -1] == step)
    assert ended is not None


def test_a_space_that_is_not_a_flat_box_is_refused():
    def square():
        return gym.wrappers.TransformObservation(gym.make("CartPole-v1"), lambda o: o.reshape(2, 2),
                                                 gym.spaces.Box(-np.inf, np.inf, (2, 2)))

    venv = sb3_make_vec_env(square, n_envs=1)
    with pytest.raises(ValueError, match="StepCount needs flat Box observations"):
        StepCount(venv)


def test_ensure_wrapped_wraps_once_and_refuses_a_wrapper_that_differs():
    def mismatch(wrapper):
        return None if wrapper.scale == 1.0 else f"scale {wrapper.scale}, asked 1.0"

    venv = ensure_wrapped(sb3_make_vec_env("CartPole-v1", n_envs=1), StepCount, StepCount, mismatch)
    assert isinstance(venv, StepCount) and ensure_wrapped(venv, StepCount, StepCount, mismatch) is venv
    assert ensure_wrapped(gym.make("CartPole-v1"), StepCount, StepCount, mismatch).num_envs == 1  # (SB3's wrapping)
    with pytest.raises(ValueError, match=r"scale 2\.0, asked 1\.0"):
        ensure_wrapped(StepCount(sb3_make_vec_env("CartPole-v1", n_envs=1), scale=2.0), StepCount, StepCount, mismatch)
    assert find_wrapper(venv, StepCount) is venv and find_wrapper("CartPole-v1", StepCount) is None
