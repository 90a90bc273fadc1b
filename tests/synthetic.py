"""A small task whose hidden mode changes the dynamics, for the latent-model tests."""

import gymnasium as gym
import numpy as np
from gymnasium import spaces

#: Rotation angle per step of each hidden mode.
ANGLES = np.array([0.3, -0.3, 0.9, -0.9])


class ModeSpin(gym.Env):
    """A point circles the origin at its episode's hidden angular speed; actions nudge it.

    Every mode leaves the point's distribution rotation-invariant, so no single observation shows the
    mode; two consecutive ones do. Observation: the position (2,). Action: ``Discrete(3)`` (none, +x, +y)
    or ``Box(-1, 1, (2,))``. ``info["mode"]`` holds the mode, for evaluation only.
    """

    def __init__(self, continuous: bool = False, length: int = 20, noise: float = 0.03):
        self.observation_space = spaces.Box(-np.inf, np.inf, (2,), np.float32)
        self.action_space = spaces.Box(-1, 1, (2,), np.float32) if continuous else spaces.Discrete(3)
        self.length, self.noise = length, noise

    def reset(self, seed=None, options=None):
        super().reset(seed=seed)
        self.mode = int(self.np_random.integers(len(ANGLES)))
        angle, radius = self.np_random.uniform(0, 2 * np.pi), self.np_random.uniform(0.5, 1.5)
        self.t, self.x = 0, np.array([np.cos(angle), np.sin(angle)]) * radius
        return self.x.astype(np.float32), {"mode": self.mode}

    def step(self, action):
        if isinstance(self.action_space, spaces.Discrete):
            nudge = np.array([[0, 0], [0.02, 0], [0, 0.02]])[int(action)]
        else:
            nudge = 0.02 * np.clip(np.asarray(action, dtype=np.float64), -1, 1)
        c, s = np.cos(ANGLES[self.mode]), np.sin(ANGLES[self.mode])
        self.x = np.array([[c, -s], [s, c]]) @ self.x + nudge + self.np_random.normal(0, self.noise, 2)
        self.t += 1
        reward = float(-0.1 * abs(np.linalg.norm(self.x) - 1.0))
        return self.x.astype(np.float32), reward, False, self.t >= self.length, {"mode": self.mode}
