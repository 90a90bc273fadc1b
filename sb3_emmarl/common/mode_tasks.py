"""Small tasks with a hidden mode, for testing latent-variable methods (as SB3 ships ``IdentityEnv``).

In each, each episode draws one of ``n_modes`` modes that no single observation reveals and acting on
which pays; ``info["mode"]`` holds it (for evaluation only), and ``told=True`` appends a one-hot of it to
the observation: the upper bound a method that infers the mode is measured against.

- :class:`ModeCueEnv`: the mode shows only through a weak cue at every step.
- :class:`ModeDynamicsEnv`: the mode changes only what the actions do.
- :class:`ModeReachEnv`: the mode changes what the actions do, and an episode ends when the goal is reached.
- :class:`ModeGoalEnv`: the mode decides where the reward lies, shown only by a weak cue at every step.
- :class:`ModeCorridorEnv`: the mode decides which action moves forward; an episode ends on success, and
  ``info["success"]`` tells which modes a policy solves.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces


class _ModeEnv(gym.Env):
    """What the tasks share: the mode drawn at reset, ``info["mode"]``, the ``told`` variant."""

    def __init__(self, n_modes: int, length: int, told: bool, own_dim: int) -> None:
        if isinstance(n_modes, bool) or not isinstance(n_modes, int) or n_modes < 2:
            raise ValueError(f"n_modes must be an int >= 2, got {n_modes!r}")
        if isinstance(length, bool) or not isinstance(length, int) or length < 1:
            raise ValueError(f"length must be an int >= 1, got {length!r}")
        self.n_modes, self.length, self.told = n_modes, length, bool(told)
        size = own_dim + (n_modes if told else 0)
        self.observation_space = spaces.Box(-1.0, 1.0, (size,), np.float32)  # every part lies in [-1, 1]
        self.mode, self.t = 0, 0

    def _observe(self, own: np.ndarray) -> np.ndarray:
        if self.told:
            own = np.concatenate([own, np.eye(self.n_modes)[self.mode]])
        return own.astype(np.float32)

    def _start(self, seed: int | None) -> None:
        super().reset(seed=seed)
        self.mode, self.t = int(self.np_random.integers(self.n_modes)), 0

    def _info(self) -> dict[str, Any]:
        return {"mode": self.mode}


class ModeCueEnv(_ModeEnv):
    """Guess the hidden mode, from a cue that is right ``cue_accuracy`` of the time (else uniform).

    Observation: the cue's one-hot (``n_modes``). Action: ``Discrete(n_modes)``; reward 1 when it is the mode.
    Reacting to the cue earns ``cue_accuracy + (1 - cue_accuracy) / n_modes`` a step (0.55 by default); a
    belief over the episode's cues approaches 1.

    :param n_modes: modes (and actions)
    :param cue_accuracy: chance that the cue is the mode rather than a uniform draw
    :param length: steps per episode
    :param told: append the mode's one-hot to the observation
    """

    def __init__(self, n_modes: int = 4, cue_accuracy: float = 0.4, length: int = 32, told: bool = False) -> None:
        if not 0 <= cue_accuracy <= 1:
            raise ValueError(f"cue_accuracy must be in [0, 1], got {cue_accuracy!r}")
        super().__init__(n_modes, length, told, n_modes)
        self.cue_accuracy = float(cue_accuracy)
        self.action_space = spaces.Discrete(n_modes)

    def _cue(self) -> np.ndarray:
        right = self.np_random.random() < self.cue_accuracy
        return np.eye(self.n_modes)[self.mode if right else int(self.np_random.integers(self.n_modes))]

    def reset(self, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        self._start(seed)
        return self._observe(self._cue()), self._info()

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict]:
        reward = float(int(action) == self.mode)
        self.t += 1
        return self._observe(self._cue()), reward, False, self.t >= self.length, self._info()


class ModeDynamicsEnv(_ModeEnv):
    """Steer a point to the origin when the mode decides which way each action moves it.

    Observation: the position ``(x, y)`` in ``[-1, 1]^2``, drawn uniformly at reset. Action:
    ``Discrete(4)``; action ``a`` moves the point by ``step`` along direction ``(a + mode) % 4`` (right, up,
    left, down) plus Gaussian noise. Reward ``1 - |position| / sqrt(2)`` after each step. Every mode leaves
    the observations alike until an action is taken; one transition then tells it.

    :param step: distance of one move
    :param noise: standard deviation of the position noise per step
    :param length: steps per episode
    :param told: append the mode's one-hot to the observation
    """

    #: Unit moves of the four directions: right, up, left, down.
    DIRECTIONS = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]])

    def __init__(self, step: float = 0.15, noise: float = 0.01, length: int = 25, told: bool = False) -> None:
        if not step > 0 or not noise >= 0:
            raise ValueError(f"need step > 0 and noise >= 0, got {step!r} and {noise!r}")
        super().__init__(4, length, told, 2)
        self.step_size, self.noise = float(step), float(noise)
        self.action_space = spaces.Discrete(4)
        self.position = np.zeros(2)

    def reset(self, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        self._start(seed)
        self.position = self.np_random.uniform(-1, 1, 2)
        return self._observe(self.position), self._info()

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict]:
        move = self.DIRECTIONS[(int(action) + self.mode) % 4] * self.step_size
        self.position = np.clip(self.position + move + self.np_random.normal(0, self.noise, 2), -1, 1)
        self.t += 1
        reward = float(1 - np.linalg.norm(self.position) / np.sqrt(2))
        return self._observe(self.position), reward, False, self.t >= self.length, self._info()


class ModeReachEnv(ModeDynamicsEnv):
    """Reach the origin when the mode decides which way each action moves the point; the episode ends on arrival.

    As :class:`ModeDynamicsEnv` (action ``a`` moves the point along direction ``(a + mode) % 4``), but the point
    starts at least ``2 * radius`` from the origin, each step pays the distance it gained towards the origin (it
    costs what it lost), the step that brings the point within ``radius`` of the origin pays 1 more and ends the
    episode (``terminated``), and an episode that never arrives is truncated after ``length`` steps. A policy that
    steers by the wrong mode drifts away and pays for it: one transition tells the mode, a memoryless policy
    cannot keep it.

    :param step: distance of one move
    :param noise: standard deviation of the position noise per step
    :param radius: distance to the origin that counts as arrival
    :param length: steps per episode at most
    :param told: append the mode's one-hot to the observation
    """

    def __init__(self, step: float = 0.15, noise: float = 0.01, radius: float = 0.2, length: int = 50,
                 told: bool = False) -> None:
        if not 0 < radius < 0.5:
            raise ValueError(f"radius must be in (0, 0.5), got {radius!r}")
        super().__init__(step=step, noise=noise, length=length, told=told)
        self.radius = float(radius)

    def reset(self, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        self._start(seed)
        self.position = self.np_random.uniform(-1, 1, 2)
        while np.linalg.norm(self.position) < 2 * self.radius:
            self.position = self.np_random.uniform(-1, 1, 2)
        return self._observe(self.position), self._info()

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict]:
        before = np.linalg.norm(self.position)
        move = self.DIRECTIONS[(int(action) + self.mode) % 4] * self.step_size
        self.position = np.clip(self.position + move + self.np_random.normal(0, self.noise, 2), -1, 1)
        self.t += 1
        distance = np.linalg.norm(self.position)
        arrived = bool(distance < self.radius)
        reward = float(before - distance) + float(arrived)
        return self._observe(self.position), reward, arrived, self.t >= self.length and not arrived, self._info()


class ModeGoalEnv(_ModeEnv):
    """Go to the corner the mode names and stay there; a weak cue at every step is the only sign of which.

    Observation: the position ``(x, y)`` (starting in ``[-0.3, 0.3]^2``) and a cue's one-hot over the ``4`` corners
    ``(+-corner, +-corner)``, naming the mode's corner ``cue_accuracy`` of the time, else a uniform draw. Action:
    ``Discrete(5)``: stay, or move by ``step`` right, up, left or down (the same in every mode), plus Gaussian noise.
    Reward 1 on each step that ends within ``radius`` of the mode's corner. The mode decides where the reward lies,
    not what the actions do: a policy that follows each step's cue wanders between corners, one that accumulates
    the cues goes to one corner and stays. With the defaults the Bayes-optimal player (the exact posterior of the
    cues so far, heading for its most likely corner) earns 0.92 of what a player told the mode earns (31.0 against
    33.9 over 300 episodes); at ``cue_accuracy=0.25`` it would earn 0.70.

    :param cue_accuracy: chance that the cue names the mode's corner rather than a uniform draw
    :param corner: the corners' distance from the origin along each axis
    :param step: distance of one move
    :param noise: standard deviation of the position noise per step
    :param radius: distance to the corner within which a step pays
    :param length: steps per episode
    :param told: append the mode's one-hot to the observation
    """

    #: Unit moves of the five actions: stay, right, up, left, down.
    MOVES = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]])
    #: Signs of the four corners (mode k's corner is ``SIGNS[k] * corner``).
    SIGNS = np.array([[1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0], [1.0, -1.0]])

    def __init__(self, cue_accuracy: float = 0.5, corner: float = 0.7, step: float = 0.15, noise: float = 0.01,
                 radius: float = 0.3, length: int = 40, told: bool = False) -> None:
        if not 0 <= cue_accuracy <= 1:
            raise ValueError(f"cue_accuracy must be in [0, 1], got {cue_accuracy!r}")
        if not 0 < corner <= 1 or not step > 0 or not noise >= 0 or not radius > 0:
            raise ValueError(f"need 0 < corner <= 1, step > 0, noise >= 0 and radius > 0, got corner={corner!r}, "
                             f"step={step!r}, noise={noise!r} and radius={radius!r}")
        super().__init__(4, length, told, 6)
        self.cue_accuracy, self.corner, self.step_size = float(cue_accuracy), float(corner), float(step)
        self.noise, self.radius = float(noise), float(radius)
        self.action_space = spaces.Discrete(5)
        self.position = np.zeros(2)

    def _observation(self) -> np.ndarray:
        right = self.np_random.random() < self.cue_accuracy
        cue = np.eye(4)[self.mode if right else int(self.np_random.integers(4))]
        return self._observe(np.concatenate([self.position, cue]))

    def reset(self, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        self._start(seed)
        self.position = self.np_random.uniform(-0.3, 0.3, 2)
        return self._observation(), self._info()

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict]:
        move = self.MOVES[int(action)] * self.step_size
        self.position = np.clip(self.position + move + self.np_random.normal(0, self.noise, 2), -1, 1)
        self.t += 1
        goal = self.SIGNS[self.mode] * self.corner
        reward = float(np.linalg.norm(self.position - goal) < self.radius)
        return self._observation(), reward, False, self.t >= self.length, self._info()


class ModeCorridorEnv(_ModeEnv):
    """Walk to the end of a corridor when the mode decides which action moves forward; the episode ends on arrival.

    Observation: the position ``cell / cells`` (starting at cell 1 of ``0 .. cells``). Action: ``Discrete(4)``; in mode
    ``m`` action ``m`` moves one cell forward, action ``(m + 2) % 4`` one cell back (not below cell 0), the other two
    leave the position as it is. Each step costs ``step_cost``; arriving at cell ``cells`` pays 1 and ends the episode
    (``terminated``, ``info["success"]`` True); an episode that never arrives is truncated after ``length`` steps
    (``info["success"]`` False). A policy that keeps pressing one action solves one mode of four, and counting
    successes per mode (:meth:`solved_modes`) shows which modes a learner solves. At most two actions tell the mode
    (one that moves does), and a memoryless policy cannot keep it. With the defaults a policy told the mode earns
    ``1 - 6 * 0.01 = 0.94``; the best policy not told (the exact posterior: one action, a second if it did not move)
    takes 7.5 steps on average and earns 0.925, 0.98 of it: the task asks for every mode solved, at a small cost of
    identification.

    :param cells: the corridor's last cell, the goal (at least 2)
    :param length: steps per episode at most (at least ``cells``)
    :param step_cost: the cost of a step, in [0, 1 / length] (an episode that fails costs at most 1)
    :param told: append the mode's one-hot to the observation
    """

    def __init__(self, cells: int = 7, length: int = 30, step_cost: float = 0.01, told: bool = False) -> None:
        if isinstance(cells, bool) or not isinstance(cells, int) or cells < 2:
            raise ValueError(f"cells must be an int >= 2, got {cells!r}")
        if isinstance(length, int) and not isinstance(length, bool) and length < cells:
            raise ValueError(f"length must be at least cells ({cells}), got {length!r}")
        super().__init__(4, length, told, 1)
        if not 0 <= step_cost <= 1 / length:
            raise ValueError(f"step_cost must be in [0, 1 / length = {1 / length:.4g}], got {step_cost!r}")
        self.cells, self.step_cost = cells, float(step_cost)
        self.action_space = spaces.Discrete(4)
        self.cell = 1

    def reset(self, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        self._start(seed)
        self.cell = 1
        return self._observe(np.array([self.cell / self.cells])), self._info()

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict]:
        effect = (int(action) - self.mode) % 4
        self.cell = max(0, self.cell + (1 if effect == 0 else -1 if effect == 2 else 0))
        self.t += 1
        arrived = self.cell >= self.cells
        reward = float(arrived) - self.step_cost
        truncated = self.t >= self.length and not arrived
        info = {**self._info(), "success": arrived} if arrived or truncated else self._info()
        return self._observe(np.array([self.cell / self.cells])), reward, arrived, truncated, info

    @staticmethod
    def solved_modes(modes: list[int] | np.ndarray, successes: list[bool] | np.ndarray, n_modes: int = 4,
                     share: float = 0.9) -> np.ndarray:
        """Which modes a learner solves: per mode, whether at least ``share`` of its episodes ended in success.

        :param modes: each finished episode's mode (``info["mode"]`` at its end)
        :param successes: whether it succeeded (``info["success"]``)
        :param n_modes: modes
        :param share: the share of successes that counts as solved
        :return: ``(n_modes,)`` flags (a mode without episodes is not solved)
        """
        modes, successes = np.asarray(modes, dtype=int), np.asarray(successes, dtype=bool)
        if modes.shape != successes.shape:
            raise ValueError(f"modes and successes must have one entry per episode, got {modes.shape} and "
                             f"{successes.shape}")
        return np.array([(modes == m).any() and successes[modes == m].mean() >= share for m in range(n_modes)])
