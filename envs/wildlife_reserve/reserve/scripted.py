"""Scripted patrols: reference behaviours that need no training.

Both act on observations only (execution stays decentralised) and return PettingZoo action dicts
for the discrete action mode.

- :class:`RandomPatrol`: uniform random actions.
- :class:`StalestBlockPatrol`: each UAV flies toward the coarse block it believes was flown over
  longest ago (ties to the nearest, leaving blocks to closer neighbours), heads for fresh poacher
  activity in its belief map when there is any, and broadcasts every ``broadcast_every`` steps.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from wildlife_reserve.reserve.actors import STEPS
from wildlife_reserve.reserve.constants import COMM_BROADCAST, N_COMMS, N_MOVES

if TYPE_CHECKING:
    from wildlife_reserve.reserve.reserve import ReserveParallelEnv


class RandomPatrol:
    """Uniform random discrete actions.

    :param env: the (parallel) reserve
    :param seed: seed of the action draws
    """

    def __init__(self, env: ReserveParallelEnv, seed: int | None = None) -> None:
        self.env = env.unwrapped
        self.rng = np.random.default_rng(seed)

    def __call__(self, observations: dict[str, np.ndarray]) -> dict[str, int]:
        agents = list(observations)
        return dict(zip(agents, self.rng.integers(0, N_MOVES * N_COMMS, len(agents)).tolist()))


class StalestBlockPatrol:
    """Fly toward the stalest block of the coarse map (or fresh poacher activity), broadcasting periodically.

    :param env: the (parallel) reserve, discrete actions
    :param broadcast_every: steps between broadcasts of each UAV (0: never)
    :param belief_threshold: belief above which a block with poacher activity is chased instead
    """

    def __init__(self, env: ReserveParallelEnv, broadcast_every: int = 5, belief_threshold: float = 0.3) -> None:
        self.env = env.unwrapped
        if self.env.config.continuous_actions:
            raise ValueError("StalestBlockPatrol needs continuous_actions=False")
        self.broadcast_every = broadcast_every
        self.belief_threshold = belief_threshold
        # A fixed, per-UAV preference among equally good blocks, so that UAVs in one cell part ways.
        blocks = self.env.config.belief_size**2
        self._preference = {a: 0.05 * np.random.default_rng(i).random(blocks) for i, a in enumerate(self.env.possible_agents)}

    def __call__(self, observations: dict[str, np.ndarray]) -> dict[str, int]:
        env = self.env
        agents = list(observations)
        parts = env.split_observation(np.stack([observations[a] for a in agents]))
        size = env.config.belief_size
        position = parts["own"][:, :2] * [env.height - 1, env.width - 1]
        centres = (np.indices((size, size)).reshape(2, -1).T + 0.5) * [env.height / size, env.width / size]
        dist = np.abs(centres[None, :, :] - position[:, None, :]).sum(-1)
        staleness = parts["block_staleness"].reshape(len(agents), -1)
        belief = parts["belief"].reshape(len(agents), -1)
        # Leave a block to a neighbour (heard through beacons) that is closer to it.
        neighbours = parts["neighbours"]
        others = position[:, None, :] + neighbours[:, :, :2] * max(env.config.comm_radius, 1.0)
        other_dist = np.abs(centres[None, None, :, :] - others[:, :, None, :]).sum(-1)
        claimed = ((other_dist <= dist[:, None, :]) & (neighbours[:, :, 2:3] > 0)).any(axis=1)
        # Score: staleness first, distance as the tie-breaker; fresh poacher activity outranks both.
        preference = np.stack([self._preference[a] for a in agents])
        score = (staleness - 1e-3 * dist / (env.height + env.width) - 0.5 * claimed + preference
                 + 2.0 * (belief > self.belief_threshold) * belief)
        target = centres[score.argmax(axis=1)]
        heading = target - position
        move = (STEPS[None, 1:] * heading[:, None, :]).sum(-1).argmax(axis=1) + 1
        move = np.where(np.abs(heading).max(-1) < 1.0, 0, move)
        step = np.rint(parts["own"][:, 5] * env.max_cycles).astype(np.int64)  # episode progress -> step
        comm = np.where((self.broadcast_every > 0) & (step % max(self.broadcast_every, 1) == 0), COMM_BROADCAST, 0)
        return dict(zip(agents, (move + N_MOVES * comm).tolist()))


SCRIPTED_PATROLS = {"random": RandomPatrol, "stalest_block": StalestBlockPatrol}


def run_patrol(env: ReserveParallelEnv, policy, episodes: int, seed: int = 0) -> list[dict[str, float]]:
    """Play ``episodes`` episodes (seeds ``seed``, ``seed + 1``, ...) and return each one's metrics.

    :param env: the parallel reserve
    :param policy: callable from an observation dict to an action dict
    :param episodes: number of episodes
    :param seed: seed of the first episode
    """
    records = []
    for episode in range(episodes):
        observations, infos = env.reset(seed=seed + episode)
        while env.agents:
            observations, _, _, _, infos = env.step(policy(observations))
        records.append(next(iter(infos.values()))["metrics"])
    return records
