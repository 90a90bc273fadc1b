"""Scripted patrols: reference behaviours that need no training.

They act on observations only (execution stays decentralised), except a station patrol given a plan per
strategy, which is told the hidden mode. All return PettingZoo action dicts for the discrete action mode.

- :class:`RandomPatrol`: uniform random actions.
- :class:`StalestBlockPatrol`: each UAV flies toward the coarse block it believes was flown over
  longest ago (ties to the nearest, leaving blocks to closer neighbours), heads for fresh poacher
  activity in its belief map when there is any, and broadcasts every ``broadcast_every`` steps.
- :class:`StationPatrol`: the stalest-block patrol that first holds stations around the dens or the roads'
  entry points until a given point of the episode (a :class:`StationPlan`), the same plan in every episode or,
  told the mode, a plan per poacher strategy (an oracle, not a deployable team). The best plan per strategy
  against the best single plan measures what knowing the mode *can* pay, whatever a learner makes of it
  (``benchmarks/mode_value.py``).
- :class:`ToldModePatrol`: the station patrol told the strategy, guarding where its poachers come from until
  their entry window closes (:data:`TOLD_PLANS`).
- :class:`ZoneRaidPatrol`: for the strategy zones (``strategy_zones``), rings of stations around the zones; told the
  strategy, around its zone; blind, around every zone (or a guessed one) until the team's first catch,
  then around the zone of that catch.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wildlife_reserve.reserve.actors import STEPS
from wildlife_reserve.reserve.kernels.constants import COMM_BROADCAST, N_COMMS, N_MOVES, POACHER_CAUGHT
from wildlife_reserve.reserve.modes import STRATEGIES
from wildlife_reserve.reserve.reserve import ReserveParallelEnv, parallel_env


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


#: Where a station patrol can hold its stations: the reserve's dens or the roads' entry points.
STATION_SPOTS: tuple[str, ...] = ("dens", "roads")


@dataclass(frozen=True)
class StationPlan:
    """Hold stations around ``spots`` until ``until`` x ``max_cycles`` steps, then sweep (``spots=None``: sweep all along).

    :param spots: ``"dens"``, ``"roads"`` (the roads' entry points) or ``None``
    :param until: fraction of the episode in [0, 1] after which the team sweeps
    """

    spots: str | None
    until: float = 0.0

    def __post_init__(self) -> None:
        if self.spots is not None and self.spots not in STATION_SPOTS:
            raise ValueError(f"spots must be None or one of {STATION_SPOTS}, got {self.spots!r}")
        if not 0.0 <= self.until <= 1.0:
            raise ValueError(f"until must be a fraction of the episode in [0, 1], got {self.until!r}")

    @property
    def name(self) -> str:
        """Short label for tables: ``sweep`` or ``<spots><<until>``, e.g. ``dens<0.75``."""
        return "sweep" if self.spots is None else f"{self.spots}<{self.until:g}"


#: What the told patrol does under each strategy: guard where its poachers come from until its entry window
#: closes (a dispersed evasion, from anywhere on the perimeter, gives no place to guard).
TOLD_PLANS: dict[str, StationPlan] = {
    strategy.name: StationPlan({"near_den": "dens", "one_side": "roads", "group": "roads"}.get(strategy.entry),
                               strategy.entry_window[1])
    for strategy in STRATEGIES
}


class StationPatrol(StalestBlockPatrol):
    """The stalest-block patrol that first holds stations around the dens or the roads' entry points.

    Until ``plan.until`` of the episode, each UAV holds a station near one of the plan's spots: the UAVs of one spot
    hold stations on a ring of radius ``spread`` around it (moved inside the map when the spot is on its edge), and
    UAVs of even and odd index fly row-first and column-first, so that the team neither piles up nor flies in
    lockstep. After that it sweeps as :class:`StalestBlockPatrol` does; it communicates as that patrol does all
    along. With one plan it is a deployable team (it reads the map, not the mode); with a plan per poacher strategy it
    is told the episode's strategy (read from the environment), an oracle.

    :param env: the (parallel) reserve, discrete actions
    :param plan: one :class:`StationPlan` for every episode, or a plan per strategy name (``modes.STRATEGIES``)
    :param spread: radius in cells of the ring of stations around each spot
    :param kwargs: see :class:`StalestBlockPatrol`
    """

    def __init__(self, env: ReserveParallelEnv, plan: StationPlan | dict[str, StationPlan], spread: int = 6,
                 **kwargs) -> None:
        super().__init__(env, **kwargs)
        if isinstance(plan, dict) and set(plan) != {s.name for s in STRATEGIES}:
            raise ValueError(f"plan must be a StationPlan or a dict with one per strategy "
                             f"{[s.name for s in STRATEGIES]}, got keys {sorted(plan)}")
        self.plan = plan
        self.spread = spread

    def current_plan(self) -> StationPlan:
        """The plan of this episode (the strategy's, when told)."""
        return self.plan[self.env.strategy.name] if isinstance(self.plan, dict) else self.plan

    def __call__(self, observations: dict[str, np.ndarray]) -> dict[str, int]:
        env = self.env
        actions = super().__call__(observations)
        plan = self.current_plan()
        if plan.spots is None:
            return actions
        spots = env.hotspots.dens if plan.spots == "dens" else env.hotspots.road_entries
        if not len(spots) or env.t >= plan.until * env.max_cycles:
            return actions
        index = np.array([env.possible_agents.index(agent) for agent in observations])
        return self.hold_stations(observations, actions, spots[index % len(spots)], index // len(spots),
                                  -(-env.n // len(spots)), index % len(spots))

    def hold_stations(self, observations: dict[str, np.ndarray], actions: dict[str, int], centres: np.ndarray,
                      place: np.ndarray, around: int, spot: np.ndarray) -> dict[str, int]:
        """``actions`` with the moves replaced by the way to each UAV's station (its communication kept): UAV ``i``
        (of ``observations``' order) holds place ``place[i]`` of ``around`` on a ring of radius ``spread`` around
        ``centres[i]`` (rings of odd ``spot`` turned by half a place).

        :param observations: the UAVs' observations (their keys and order)
        :param actions: what the patrol would do otherwise
        :param centres: ``(k, 2)`` each UAV's ring centre
        :param place: ``(k,)`` each UAV's place on its ring
        :param around: places per ring
        :param spot: ``(k,)`` each UAV's ring's index
        """
        env = self.env
        index = np.array([env.possible_agents.index(agent) for agent in observations])
        angle = 2 * np.pi * (place + 0.5 * (spot % 2)) / around
        ring = self.spread * np.stack([np.cos(angle), np.sin(angle)], axis=-1)
        centre = np.clip(centres, self.spread, [env.height - 1 - self.spread, env.width - 1 - self.spread])
        stations = np.clip(np.rint(centre + ring), 0, [env.height - 1, env.width - 1])  # the ring inside the map
        heading = stations + 0.5 - env.uav_pos[index]
        near = max(env.config.uav_speed / 2, 0.5)  # an axis is done once a move would overshoot its station
        axis = np.where(index % 2 == 0, np.abs(heading[:, 0]) <= near, np.abs(heading[:, 1]) > near).astype(int)
        step = np.sign(heading[np.arange(len(index)), axis])
        move = np.where(axis == 0, np.where(step < 0, 1, 2), np.where(step < 0, 3, 4))  # up, down, left, right
        move = np.where(np.abs(heading).max(-1) <= near, 0, move)
        comm = np.array([actions[agent] for agent in observations]) // N_MOVES
        return dict(zip(observations, (move + N_MOVES * comm).tolist()))


class ToldModePatrol(StationPatrol):
    """The station patrol told the episode's poacher strategy, with :data:`TOLD_PLANS`: until the strategy's entry
    window closes it guards where that strategy's poachers come from (the dens for a hotspot raid, the roads' entry
    points for an edge infiltration or a coordinated group); throughout a dispersed evasion it sweeps.

    :param env: the (parallel) reserve, discrete actions
    :param spread: radius in cells of the ring of stations around each spot
    :param kwargs: see :class:`StalestBlockPatrol`
    """

    def __init__(self, env: ReserveParallelEnv, spread: int = 6, **kwargs) -> None:
        super().__init__(env, TOLD_PLANS, spread=spread, **kwargs)


#: Where a zone-raid patrol (:class:`ZoneRaidPatrol`) holds its rings before it knows the zone: one ring per zone
#: (``split``) or every UAV around one zone (``zone<k>``, a guess).
ZONE_RAID_PLANS: tuple[str, ...] = ("split",) + tuple(f"zone{k}" for k in range(len(STRATEGIES)))


class ZoneRaidPatrol(StationPatrol):
    """A team for the reserve's strategy zones (``strategy_zones``: each poacher strategy strikes its own zone): the UAVs
    hold rings of stations around the zones, the whole episode.

    Told the episode's strategy (an oracle, read from the environment), every UAV holds a station around its zone.
    Blind, the team holds the rings of ``plan`` (one per zone, or every UAV around one guessed zone) and, with
    ``converge``, once the team has caught a poacher, every UAV moves to the rings of the zone nearest to where it was
    caught. The blind team learns of every catch at once, wherever it happens (from the reserve's poachers, as the team
    reward's detection term would tell a team), which no decentralised team can: it is a strong blind team, and what
    the told one gains over it is what knowing the mode pays.

    :param env: the (parallel) reserve with ``strategy_zones``, discrete actions
    :param told: read the strategy and hold stations around its zone
    :param plan: the blind team's rings before its first catch, one of :data:`ZONE_RAID_PLANS`
    :param converge: after the team's first catch, every UAV holds a station around the zone of that catch
    :param spread: radius in cells of the rings of stations
    :param kwargs: see :class:`StalestBlockPatrol`
    """

    def __init__(self, env: ReserveParallelEnv, told: bool = False, plan: str = "split", converge: bool = True,
                 spread: int = 6, **kwargs) -> None:
        super().__init__(env, StationPlan("dens", 1.0), spread=spread, **kwargs)
        if not self.env.config.strategy_zones:
            raise ValueError("ZoneRaidPatrol needs the reserve's strategy_zones=True (for example scenario='zone_raids')")
        if plan not in ZONE_RAID_PLANS:
            raise ValueError(f"plan must be one of {ZONE_RAID_PLANS}, got {plan!r}")
        self.told, self.zone_plan, self.converge = bool(told), plan, bool(converge)
        self._zone: int | None = None  # the zone every UAV holds (told, or converged on a catch), this episode

    @property
    def name(self) -> str:
        """Short label for tables, for example ``told``, ``split+converge`` or ``zone2``."""
        return "told" if self.told else self.zone_plan + ("+converge" if self.converge else "")

    def __call__(self, observations: dict[str, np.ndarray]) -> dict[str, int]:
        env = self.env
        actions = StalestBlockPatrol.__call__(self, observations)
        zones = env.hotspots.dens  # the zones' centres, in the strategies' order
        if env.t == 0:  # a new episode
            self._zone = STRATEGIES.index(env.strategy) if self.told else None
        caught = env.poacher_status == POACHER_CAUGHT
        if self._zone is None and self.converge and caught.any():  # (a catch, not a false alarm: the reward says so)
            self._zone = int(np.abs(zones - env.poacher_pos[caught][0]).max(axis=1).argmin())
        index = np.array([env.possible_agents.index(agent) for agent in observations])
        if self._zone is not None or self.zone_plan != "split":
            zone = self._zone if self._zone is not None else int(self.zone_plan[len("zone"):])
            return self.hold_stations(observations, actions, np.repeat(zones[zone][None], len(index), axis=0), index,
                                      env.n, np.zeros_like(index))
        return self.hold_stations(observations, actions, zones[index % len(zones)], index // len(zones),
                                  -(-env.n // len(zones)), index % len(zones))


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


def play_station_plan(plan: StationPlan | dict[str, StationPlan], episodes: int, seed: int = 0,
                      env_kwargs: dict | None = None) -> list[dict[str, float]]:
    """The station patrol with ``plan`` on a new reserve: each episode's metrics and its ``seed`` (a module-level
    function, so that a process pool can run plans side by side).

    :param plan: see :class:`StationPatrol`
    :param episodes: number of episodes
    :param seed: seed of the first episode
    :param env_kwargs: arguments of ``reserve_v1.parallel_env``
    """
    env = parallel_env(**dict(env_kwargs or {}))
    records = run_patrol(env, StationPatrol(env, plan), episodes, seed=seed)
    env.close()
    return [{**record, "seed": seed + i} for i, record in enumerate(records)]
