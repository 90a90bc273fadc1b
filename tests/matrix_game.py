"""QMIX's two-step cooperative matrix game (Rashid et al. 2018, section 5 and appendix B.1) as a PettingZoo env.

Two agents, two actions each (0 is the paper's A, 1 its B), two steps. In the first step nothing is paid and agent
``agent_0``'s action alone chooses the second state: 0 leads to state 2A, 1 to state 2B. In 2A every joint action
pays 7; in 2B the payoff is ``[[0, 1], [1, 8]][a_0][a_1]``; the episode then ends (terminated). The optimum is 8
(B then (B, B)); a value decomposition that cannot represent 2B's matrix (VDN) settles for 7 (A, then anything).

As in the paper each state is one-hot encoded and every agent observes it (observation and ``state()`` are the same
three floats: state 1, 2A, 2B); the agents tell each other apart by their index (``agent_id=True``).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

#: The second step's payoffs: state 2A (index 1) and 2B (index 2), by (agent_0's action, agent_1's action).
PAYOFFS = {1: np.full((2, 2), 7.0), 2: np.array([[0.0, 1.0], [1.0, 8.0]])}
#: The best joint policy's return and the return of the best joint policy of an additive decomposition.
OPTIMUM, ADDITIVE_OPTIMUM = 8.0, 7.0


class TwoStepGame(ParallelEnv):
    """The two-step game: ``possible_agents = ["agent_0", "agent_1"]``, ``Discrete(2)`` actions, one-hot states."""

    metadata = {"name": "two_step_game_v0", "render_modes": [], "is_parallelizable": True}

    def __init__(self, render_mode: str | None = None) -> None:
        self.possible_agents = ["agent_0", "agent_1"]
        self.agents: list[str] = []
        self.render_mode = render_mode
        self.state_space = spaces.Box(0.0, 1.0, (3,), dtype=np.float32)
        self._observation_space = spaces.Box(0.0, 1.0, (3,), dtype=np.float32)
        self._action_space = spaces.Discrete(2)
        self._state = 0  # 0: state 1, 1: state 2A, 2: state 2B

    def observation_space(self, agent: str) -> spaces.Box:
        return self._observation_space

    def action_space(self, agent: str) -> spaces.Discrete:
        return self._action_space

    def state(self) -> np.ndarray:
        one_hot = np.zeros(3, dtype=np.float32)
        one_hot[self._state] = 1.0
        return one_hot

    def _observations(self) -> dict[str, np.ndarray]:
        return {agent: self.state() for agent in self.agents}

    def reset(self, seed: int | None = None, options: dict[str, Any] | None = None):
        self.agents = list(self.possible_agents)
        self._state = 0
        return self._observations(), {agent: {} for agent in self.agents}

    def step(self, actions: dict[str, int]):
        a_0, a_1 = int(actions["agent_0"]), int(actions["agent_1"])
        if self._state == 0:
            self._state, reward, done = 1 + a_0, 0.0, False
        else:
            reward, done = float(PAYOFFS[self._state][a_0, a_1]), True
        observations = self._observations()
        rewards = {agent: reward for agent in self.agents}
        terminations = {agent: done for agent in self.agents}
        truncations = {agent: False for agent in self.agents}
        infos = {agent: {} for agent in self.agents}
        if done:
            self.agents = []
        return observations, rewards, terminations, truncations, infos

    def render(self) -> None:
        return None

    def close(self) -> None:
        pass


def greedy_return(model: Any) -> float:
    """The return of ``model``'s greedy joint policy (the game is deterministic: one episode)."""
    env = TwoStepGame()
    observations, _ = env.reset()
    total = 0.0
    while env.agents:
        obs = np.stack([observations[agent] for agent in env.possible_agents])
        actions, _ = model.predict(obs, deterministic=True)
        observations, rewards, *_ = env.step({agent: int(a) for agent, a in zip(env.possible_agents, actions)})
        total += rewards["agent_0"]
    return total
