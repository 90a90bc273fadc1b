"""Scripted patrols: reference behaviours that need no training.

The first two act on observations only (execution stays decentralised); the third is told the hidden
mode. All return PettingZoo action dicts for the discrete action mode.

- :class:`RandomPatrol`: uniform random actions.
- :class:`StalestBlockPatrol`: each UAV flies toward the coarse block it believes was flown over
  longest ago (ties to the nearest, leaving blocks to closer neighbours), heads for fresh poacher
  activity in its belief map when there is any, and broadcasts every ``broadcast_every`` steps.
- :class:`ToldModePatrol`: the stalest-block patrol told the episode's poacher strategy (an oracle,
  not a deployable team): it shows whether knowing the mode *can* pay, whatever a learner makes of it.
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


class ToldModePatrol(StalestBlockPatrol):
    """The stalest-block patrol, told the episode's poacher strategy (read from the environment).

    Until the strategy's entry window closes, each UAV holds a station near where that strategy's
    poachers come from: the dens for a hotspot raid, the roads' entry points for an edge infiltration or a
    coordinated group. The UAVs of one spot hold stations on a ring of radius ``spread`` around it (moved
    inside the map when the spot is on its edge), and UAVs
    of even and odd index fly row-first and column-first, so that the team neither piles up nor flies in
    lockstep. After that, and throughout a dispersed evasion, it sweeps as :class:`StalestBlockPatrol` does;
    it communicates as that patrol does all along.

    :param env: the (parallel) reserve, discrete actions
    :param spread: radius in cells of the ring of stations around each spot
    :param kwargs: see :class:`StalestBlockPatrol`
    """

    def __init__(self, env: ReserveParallelEnv, spread: int = 6, **kwargs) -> None:
        super().__init__(env, **kwargs)
        self.spread = spread

    def __call__(self, observations: dict[str, np.ndarray]) -> dict[str, int]:
        env = self.env
        actions = super().__call__(observations)
        strategy = env.strategy
        if strategy.entry == "near_den":
            spots = env.hotspots.dens
        elif strategy.entry in ("one_side", "group"):
            spots = env.hotspots.road_entries
        else:
            return actions
        if not len(spots) or env.t >= strategy.entry_window[1] * env.max_cycles:
            return actions
        index = np.array([env.possible_agents.index(agent) for agent in observations])
        spot, place = index % len(spots), index // len(spots)
        around = -(-env.n // len(spots))  # UAVs per spot
        angle = 2 * np.pi * (place + 0.5 * (spot % 2)) / around
        ring = self.spread * np.stack([np.cos(angle), np.sin(angle)], axis=-1)
        centre = np.clip(spots[spot], self.spread, [env.height - 1 - self.spread, env.width - 1 - self.spread])
        stations = np.clip(np.rint(centre + ring), 0, [env.height - 1, env.width - 1])  # the ring inside the map
        heading = stations + 0.5 - env.uav_pos[index]
        near = max(env.config.uav_speed / 2, 0.5)  # an axis is done once a move would overshoot its station
        axis = np.where(index % 2 == 0, np.abs(heading[:, 0]) <= near, np.abs(heading[:, 1]) > near).astype(int)
        step = np.sign(heading[np.arange(len(index)), axis])
        move = np.where(axis == 0, np.where(step < 0, 1, 2), np.where(step < 0, 3, 4))  # up, down, left, right
        move = np.where(np.abs(heading).max(-1) <= near, 0, move)
        comm = np.array([actions[agent] for agent in observations]) // N_MOVES
        return dict(zip(observations, (move + N_MOVES * comm).tolist()))


SCRIPTED_PATROLS = {"random": RandomPatrol, "stalest_block": StalestBlockPatrol, "told_mode": ToldModePatrol}


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
