"""
# Wildlife Reserve

| Import             | `from wildlife_reserve import reserve_v1`                  |
|--------------------|------------------------------------------------------------|
| Actions            | Discrete (default) or continuous                           |
| Parallel API       | Yes                                                        |
| Manual control     | No                                                         |
| Agents             | `agents= ['uav_0', 'uav_1', ..., 'uav_9']` (default)       |
| Agents             | `n_uavs` (default 10, 1 to 1000; see the bounds in env.md) |
| Action shape       | `Discrete(15)` or `Box(-1, 1, (3,))`                       |
| Observation shape  | `(7 * (2r + 1)^2 + 6 + 3 * max_neighbors + 3 * belief_size^2,)`; 553 by default |
| With `compass`     | 4 more floats (offsets to the nearest den and road entry)  |
| With `agent_ids`   | `n_uavs` more floats (a one-hot of the UAV's index)        |
| Observation values | [-1, 1]                                                    |
| State shape        | `(4 n_uavs + 4 n_poachers + 3 n_leopards + 2 belief_size^2 + 1,)` |

A team of UAVs patrols a wildlife reserve against poachers who hunt its leopards. Each
episode has a hidden scenario mode `z*` (poacher strategy x weather) that decides where and
when poachers enter, how they move, where their signs (tracks, snares, camps, vehicles) lie and
how well the sensors see; the UAVs never observe it (it is in `infos[agent]["mode"]` for
evaluation only). The full card, with every argument and its range, is `docs/env.md`.

### Observations
Per UAV, a flat float32 vector: an egocentric `(2r + 1) x (2r + 1)` window of seven channels
(visual occlusion, risk, time since the team last saw the cell as far as this UAV knows,
poacher signals, leopard signals, other UAVs, signs of poacher activity), then own position,
velocity, battery, episode progress, the relative positions of up to `max_neighbors` UAVs within
`R_c` (padded, with a presence flag), and three `belief_size x belief_size` maps built from what
this UAV knows (its own history and what was shared with it): time since each block was flown
over, poacher activity, and the signs of poacher activity found there; with `compass=True`, the
offsets from the UAV to the nearest den and the nearest road entry; with `agent_ids=True`, a
one-hot of the UAV's index last.
`env.split_observation(obs)` names the parts.

### Actions
Discrete: `move + 5 * comm`, with move in {stay, up, down, left, right} and comm in {none,
broadcast, query the nearest neighbour}. Continuous: `(d_row, d_col, comm)` in [-1, 1]; the
first two scale `uav_speed`, comm > 1/3 broadcasts and comm < -1/3 queries.

### Rewards
One shared team reward per step: `detection` per poacher detected, `coverage` per high-risk
cell seen for the first time, `sign` per sign of poacher activity the team finds for the first
time, minus `poaching` per poaching event, `collision` per pair of UAVs in one cell and `energy`
per unit of battery spent. `shaping > 0` mixes in each UAV's own share. With `coverage_sectors=True` (a diagnostic),
`coverage` pays only for the high-risk cells in the sector of the episode's poacher strategy.

### Infos
`infos[agent]["mode"]` (the hidden mode, for evaluation), `infos[agent]["heard_from"]` (the
indices of the teammates whose messages reached this UAV this step) and, on the last step,
`infos[agent]["metrics"]`.

### Version History
* v1: the current version (`reserve_v1`, zoo id `WildlifeReserve-v1`): the name it took when the rule that the version
  rises whenever an episode can change was applied; what each sb3-emmarl release changed in it is in CHANGELOG.md
* v0: the name it kept from its first release while its observation and dynamics changed many times; `reserve_v0` and
  `WildlifeReserve-v0` still give v1, with a warning
"""

from __future__ import annotations

import dataclasses
import functools
import threading
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from pettingzoo import ParallelEnv
from pettingzoo.utils import wrappers
from pettingzoo.utils.conversions import parallel_to_aec_wrapper

from wildlife_reserve.reserve import actors, kernels, sensing
from wildlife_reserve.reserve import signs as signs_lib
from wildlife_reserve.reserve import terrain as terrain_lib
from wildlife_reserve.reserve.compilation import announce_compilation
from wildlife_reserve.reserve.config import ENERGY_COSTS, ReserveConfig
from wildlife_reserve.reserve.kernels import (
    Coverage,
    Flight,
    Ground,
    Jammer,
    Leopards,
    Looks,
    Poachers,
    Rewards,
    Sensing,
    Step,
    Talk,
    World,
    plain,
)
from wildlife_reserve.reserve.kernels.constants import (
    COMM_BROADCAST,
    COMM_NONE,
    COMM_QUERY,
    N_COMMS,
    N_MOVES,
    POACHER_WAITING,
)
from wildlife_reserve.reserve.knowledge import TeamKnowledge
from wildlife_reserve.reserve.modes import N_MODES, STRATEGIES, Weather, decode_mode
from wildlife_reserve.reserve.observation import (
    finish_observations,
    global_state,
    observation_layout,
    observation_record,
    observation_size,
    state_size,
)
from wildlife_reserve.reserve.stream import Stream
from wildlife_reserve.utils.checks import check_action_dict, check_agent, check_int, check_options, check_seed, discrete_action

if TYPE_CHECKING:
    from wildlife_reserve.reserve.rendering import ReserveRenderer

#: The keys ``reset(options=...)`` takes.
RESET_OPTIONS = ("mode", "uav_positions")
_NO_CHOICES = np.zeros(0, dtype=np.int64)  # continuous actions: decoded before the step's compiled call
_NO_JAMMER = np.zeros(2)  # what the step's compiled call gets for the jammer's cell without one (never written)


class ReserveMap(NamedTuple):
    """A map and what the steps read from it (:meth:`ReserveParallelEnv._make_map`): the ``terrain``, ``risk`` and
    ``hotspots``, the ``high_risk`` cells and their number, the cells that give ``cover``, the padded flat grids of the
    visual occlusion, the terrain, the risk and the high-risk cells, and with ``coverage_sectors`` each strategy's
    padded flat high-risk cells and their number (else None)."""

    terrain: np.ndarray
    risk: np.ndarray
    hotspots: terrain_lib.Hotspots
    high_risk: np.ndarray
    n_high_risk: int
    cover: np.ndarray
    occlusion_pad: np.ndarray
    terrain_pad: np.ndarray
    risk_pad: np.ndarray
    high_risk_pad: np.ndarray
    sectors: tuple[tuple[np.ndarray, int], ...] | None


def env(**kwargs: Any) -> wrappers.OrderEnforcingWrapper:
    """The AEC form of the reserve, with PettingZoo's standard wrappers.

    :param kwargs: see :class:`~wildlife_reserve.reserve.config.ReserveConfig`
    """
    aec = raw_env(**kwargs)
    if not aec.unwrapped.config.continuous_actions:
        aec = _InBoundsOrStay(aec)
    return wrappers.OrderEnforcingWrapper(aec)


class _InBoundsOrStay(wrappers.AssertOutOfBoundsWrapper):
    """PettingZoo's check that a discrete action is in its space, taking ``None`` as "stay, no message" (as the
    parallel form does) rather than refusing it."""

    def step(self, action: Any) -> None:
        if action is None:
            wrappers.BaseWrapper.step(self, action)
        else:
            super().step(action)


def raw_env(**kwargs: Any) -> parallel_to_aec_wrapper:
    """The AEC form of the reserve without wrappers.

    :param kwargs: see :class:`~wildlife_reserve.reserve.config.ReserveConfig`
    """
    return parallel_to_aec_wrapper(parallel_env(**kwargs))


def parallel_env(**kwargs: Any) -> ReserveParallelEnv:
    """The parallel form of the reserve (what SuperSuit and the training code use).

    :param kwargs: see :class:`~wildlife_reserve.reserve.config.ReserveConfig`
    """
    return ReserveParallelEnv(**kwargs)


#: The arguments :func:`compile_kernels` has played an episode with in this process, and its lock.
_COMPILED: set[str] = set()
_COMPILING = threading.Lock()
#: The steps :func:`compile_kernels` plays at most.
COMPILE_STEPS = 1000


def compile_kernels(**kwargs: Any) -> None:
    """Compile the reserve's numba kernels for these arguments in this process (once per process and arguments).

    numba compiles a kernel at its first call with each set of argument types and caches the machine code beside
    the ``kernels`` modules: a process started after the cache is written loads it in well under a second, while processes
    started before compile again, each for tens of seconds and over a hundred MiB of peak memory. Tools that time runs
    in fresh processes (the paper's experiments, ``zoo/compare.py``, the benchmarks) call this in the parent first, so
    that no run's time or peak memory counts the compilation. It plays one episode (at most :data:`COMPILE_STEPS`
    steps) with actions drawn from seeded action spaces; nothing else's random state is touched.

    :param kwargs: the reserve's arguments (see :class:`~wildlife_reserve.reserve.config.ReserveConfig`); invalid
        ones raise ``ValueError`` as the environment does
    """
    key = repr(sorted(kwargs.items()))
    with _COMPILING:
        if key in _COMPILED:
            return
        reserve = parallel_env(**kwargs)
        reserve.reset(seed=0)
        for i, agent in enumerate(reserve.possible_agents):
            reserve.action_space(agent).seed(i)
        for _ in range(COMPILE_STEPS):
            if not reserve.agents:
                break
            reserve.step({agent: reserve.action_space(agent).sample() for agent in reserve.agents})
        reserve.close()
        _COMPILED.add(key)


class ReserveParallelEnv(ParallelEnv):
    """UAV patrol of a wildlife reserve against poachers (PettingZoo ``ParallelEnv``).

    State lives in numpy arrays over agents and cells; grids are padded by the sensor radius so
    that every observation window is one fancy-index away. Internal arrays are public for tests
    and tools: ``uav_pos`` (float rows/cols), ``battery``, ``grounded``, ``poacher_pos``,
    ``poacher_status``, ``leopard_pos``, ``leopard_alive``, ``terrain``, ``risk``, ``signs``
    (:class:`~wildlife_reserve.reserve.signs.Signs`) and ``team``
    (:class:`~wildlife_reserve.reserve.knowledge.TeamKnowledge`: what each UAV knows, the links), ``sensors``
    (:class:`~wildlife_reserve.reserve.sensing.SensorTables` of the episode's weather).

    :param kwargs: see :class:`~wildlife_reserve.reserve.config.ReserveConfig`
    """

    metadata: dict[str, Any] = {"name": "wildlife_reserve_v1", "render_modes": ["human", "rgb_array"],
                                "is_parallelizable": True, "render_fps": 10}

    def __init__(self, **kwargs: Any) -> None:
        self.config = cfg = ReserveConfig.from_kwargs(**kwargs)  # validates everything before anything is allocated
        self.render_mode = cfg.render_mode
        self.max_cycles = cfg.max_cycles
        self.height, self.width = cfg.grid_size  # type: ignore[misc]  # a (height, width) tuple once validated
        self.n = cfg.n_uavs
        self.r = cfg.sensor_radius
        self.window = 2 * self.r + 1
        self.possible_agents = [f"uav_{i}" for i in range(self.n)]
        self.agents = self.possible_agents[:]
        self.preset = terrain_lib.REGIONS[cfg.region]
        self.n_dens = max(self.preset.n_dens, 1)
        offsets = np.arange(-self.r, self.r + 1)
        self._padded_shape = (self.height + 2 * self.r, self.width + 2 * self.r)
        # Flat offsets of the window cells around a cell, in the padded grids (row-major).
        wp = self._padded_shape[1]
        self._win_offsets = (offsets[:, None] + self.r) * wp + offsets[None, :] + self.r
        self.observation_layout = observation_layout(cfg)
        self.obs_dim = observation_size(cfg)
        self.state_dim = state_size(cfg)
        # Map each cell to its block of the coarse maps.
        rows = np.arange(self.height) * cfg.belief_size // self.height
        cols = np.arange(self.width) * cfg.belief_size // self.width
        self._block = (rows[:, None] * cfg.belief_size + cols[None, :]).astype(np.int64)
        self.team = TeamKnowledge(self.n, self._padded_shape, cfg.belief_size**2, cfg.max_cycles, cfg.belief_decay,
                                  cfg.comm_radius, cfg.comm_loss)
        self.np_random: np.random.Generator | None = None
        self._static_map = None
        self._fixed_map: ReserveMap | None = None  # what a fixed map's steps read, made at the first reset
        self._sensor_tables: dict[Weather, sensing.SensorTables] = {}  # what the sensors read, by weather
        if cfg.terrain_seed is not None:
            region_index = sorted(terrain_lib.REGIONS).index(cfg.region)
            self._static_map = self._build_map(np.random.default_rng([cfg.terrain_seed, region_index]))
        self._renderer: ReserveRenderer | None = None
        self._upper = np.array([self.height, self.width]) - 1e-6
        self._inv_scale = 1.0 / np.array([max(self.height - 1, 1), max(self.width - 1, 1)])
        self._comm_costs = np.array([0.0, ENERGY_COSTS["broadcast"], ENERGY_COSTS["query"]])  # by COMM_* choice
        self._move, self._comm = np.zeros((self.n, 2)), np.zeros(self.n, dtype=np.int64)  # discrete actions, decoded
        # The reward weights and the false-alarm chance as plain floats, read once here rather than at every step.
        self._weights = tuple(float(cfg.reward_weights[term]) for term in
                              ("detection", "coverage", "sign", "poaching", "collision", "energy"))  # step_rewards' order
        self._false_alarm = float(sensing.false_alarm_probability(cfg.sensor_noise))
        self.t = 0
        self._ready = False  # an episode to step: set by reset()

    # ------------------------------------------------------------------ spaces
    @functools.cache  # noqa: B019 (one space object per agent, as PettingZoo requires)
    def observation_space(self, agent: str) -> spaces.Box:
        check_agent(agent, self.possible_agents)
        return spaces.Box(low=-1.0, high=1.0, shape=(self.obs_dim,), dtype=np.float32)

    @functools.cache  # noqa: B019
    def action_space(self, agent: str) -> spaces.Space:
        check_agent(agent, self.possible_agents)
        if self.config.continuous_actions:
            return spaces.Box(low=-1.0, high=1.0, shape=(3,), dtype=np.float32)
        return spaces.Discrete(N_MOVES * N_COMMS)

    @functools.cached_property
    def state_space(self) -> spaces.Box:
        return spaces.Box(low=-1.0, high=1.0, shape=(self.state_dim,), dtype=np.float32)

    # ------------------------------------------------------------------ the team's knowledge (read-only views)
    @property
    def knowledge(self) -> np.ndarray:
        """``knowledge[r, s]``: the time up to which UAV r knows UAV s's visits and readings."""
        return self.team.knowledge

    @property
    def beacons(self) -> np.ndarray:
        """``beacons[s, r]``: r heard s's position beacon this step."""
        return self.team.beacons

    @property
    def comm_links(self) -> np.ndarray:
        """``comm_links[s, r]``: a message (broadcast or query answer) of s reached r this step."""
        return self.team.comm_links

    # ------------------------------------------------------------------ the grid (read-only views)
    @property
    def cells(self) -> np.ndarray:
        """``(n, 2)``: each UAV's cell (row, col)."""
        return self._cells

    @property
    def blocks(self) -> np.ndarray:
        """``(height, width)``: each cell's block of the coarse maps."""
        return self._block

    @property
    def inv_scale(self) -> np.ndarray:
        """``(2,)``: ``1 / (side - 1)`` per axis, the scale of offsets on the grid."""
        return self._inv_scale

    # ------------------------------------------------------------------ map
    def _build_map(self, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, terrain_lib.Hotspots]:
        cfg = self.config
        shape = (self.height, self.width)
        ground = cfg.terrain if cfg.terrain is not None else terrain_lib.generate_terrain(rng, shape, self.preset)
        hotspots = terrain_lib.generate_hotspots(rng, ground, self.preset)
        if cfg.risk is not None:
            empty = np.zeros((0, 2), dtype=np.int64)
            hotspots = terrain_lib.Hotspots(terrain_lib.dens_from_risk(rng, cfg.risk, self.n_dens), empty, empty)
        if cfg.strategy_zones:  # the dens are the strategy zones' centres
            hotspots = dataclasses.replace(hotspots, dens=terrain_lib.strategy_zones(shape, len(STRATEGIES)))
        risk = cfg.risk if cfg.risk is not None else terrain_lib.risk_map(shape, hotspots)
        return ground, risk, hotspots

    def _pad(self, grid: np.ndarray, value: float) -> np.ndarray:
        return np.pad(grid, self.r, constant_values=value)

    def _make_map(self, terrain: np.ndarray, risk: np.ndarray, hotspots: terrain_lib.Hotspots) -> ReserveMap:
        """A map and what the steps read from it (high-risk cells, cover, the padded flat grids)."""
        high_risk = risk >= terrain_lib.HIGH_RISK_THRESHOLD
        # With coverage_sectors, per strategy: the padded flat cells its coverage term pays for, and their count.
        sectors = None
        if self.config.coverage_sectors:
            sector = terrain_lib.sectors(high_risk, len(STRATEGIES))
            sectors = tuple((self._pad(sector == k, False).ravel(), int((sector == k).sum()))
                            for k in range(len(STRATEGIES)))
        return ReserveMap(terrain=terrain, risk=risk, hotspots=hotspots, high_risk=high_risk,
                          n_high_risk=int(high_risk.sum()), cover=terrain != terrain_lib.OPEN,
                          occlusion_pad=self._pad(terrain_lib.VISUAL_OCCLUSION[terrain], 1.0).ravel(),
                          terrain_pad=self._pad(terrain, terrain_lib.OPEN).ravel(), risk_pad=self._pad(risk, 0.0).ravel(),
                          high_risk_pad=self._pad(high_risk, False).ravel(), sectors=sectors)

    def _use_map(self, reserve_map: ReserveMap) -> None:
        """Take the map of this episode."""
        self.terrain, self.risk, self.hotspots = reserve_map.terrain, reserve_map.risk, reserve_map.hotspots
        self.high_risk, self.n_high_risk, self.cover = reserve_map.high_risk, reserve_map.n_high_risk, reserve_map.cover
        self._occ_pad, self._terrain_pad = reserve_map.occlusion_pad, reserve_map.terrain_pad
        self._risk_pad, self._high_risk_pad = reserve_map.risk_pad, reserve_map.high_risk_pad
        self._sectors = reserve_map.sectors

    @property
    def reach(self) -> int:
        """The radius within which the sensors read anything in the episode's weather."""
        return self.sensors.reach

    # ------------------------------------------------------------------ reset
    def reset(self, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        """Start an episode.

        :param seed: seeds every random draw of the episode (and of later unseeded resets)
        :param options: ``{"mode": int}`` fixes the hidden mode for this episode;
            ``{"uav_positions": array (n, 2)}`` sets the UAVs' start cells (row, col); a misspelling of these is
            refused, another key is named in a warning and ignored (:func:`~wildlife_reserve.utils.checks.check_options`).
        :raise ValueError: for a bad seed or option, before anything changes (the previous episode, if any, is left as
            it was)
        """
        seed, mode, start = self._check_reset(seed, options)
        announce_compilation()
        self._ready = False  # until this reset is through, step(), state() and the rest refuse
        world_rng, mode_seed, ground_seed = self._seed(seed)
        self._start_map(world_rng)
        self._start_mode(mode, mode_seed)
        self._start_uavs(world_rng, start)
        self._start_ground(ground_seed)
        self._start_tallies()
        self._world = self._build_world()
        obs = self._first_look()
        infos = {a: {"mode": self.mode, "heard_from": ()} for a in self.agents}
        self._ready = True
        if self.render_mode == "human":
            self.render()
        return {a: obs[i] for i, a in enumerate(self.agents)}, infos

    def _seed(self, seed: int | None) -> tuple[np.random.Generator, int, int]:
        """Seed the episode (every generator of an episode comes from ``np_random``, seeded by ``seed`` when given) and
        start its clock: sets the step's generator ``rng`` and its stream, the agents and ``t``.

        :return: the generator of the map and the UAVs' start cells, and the seeds of the mode and of the ground actors
        """
        if seed is not None or self.np_random is None:
            self.np_random, _ = seeding.np_random(seed)
        world_seed, mode_seed, ground_seed, step_seed = self.np_random.integers(0, 2**32, size=4).tolist()
        self.rng = np.random.default_rng(step_seed)
        self._stream = Stream(self.rng)  # what the step's compiled call draws from (the same generator)
        self.agents = self.possible_agents[:]
        self.t = 0
        return np.random.default_rng(world_seed), mode_seed, ground_seed

    def _start_map(self, world_rng: np.random.Generator) -> None:
        """The map, fixed per region and terrain_seed (its arrays made once, read-only for the episodes) or drawn per
        episode; nothing seen yet."""
        if self._static_map is None:
            self._use_map(self._make_map(*self._build_map(world_rng)))
        else:
            if self._fixed_map is None:
                self._fixed_map = self._make_map(*self._static_map)
            self._use_map(self._fixed_map)
        self.visited = np.zeros(self._padded_shape, dtype=bool)
        self._n_covered = 0

    def _start_mode(self, mode: int | None, mode_seed: int) -> None:
        """The hidden mode (``mode``, else drawn from the prior with ``mode_seed``): the poachers' strategy, the
        weather and what the sensors read in it (made once per weather, read-only for the episodes)."""
        if mode is None:
            mode = int(np.random.default_rng(mode_seed).choice(N_MODES, p=self.config.mode_prior))
        self.strategy, self.weather = decode_mode(mode)
        self.mode = int(mode)
        if self._sectors is not None:  # coverage pays in the strategy's sector only
            self._high_risk_pad, self.n_high_risk = self._sectors[STRATEGIES.index(self.strategy)]
        if self.weather not in self._sensor_tables:
            self._sensor_tables[self.weather] = sensing.sensor_tables(self.r, self.weather, self.config.sensor_noise)
        self.sensors = self._sensor_tables[self.weather]

    def _start_uavs(self, world_rng: np.random.Generator, start: np.ndarray | None) -> None:
        """The UAVs at their start cells (``start``, else drawn with ``world_rng``), full and airborne, their windows,
        the team knowing nothing, and the buffers of what they read."""
        n, w = self.n, self.window
        if start is None:
            cells = world_rng.choice(self.height * self.width, size=n, replace=n > self.height * self.width)
            start = np.stack(np.divmod(cells, self.width), axis=-1).astype(np.float64)
        self.uav_pos = start + 0.5
        self.velocity = np.zeros((n, 2))
        self.battery = np.ones(n)
        self.grounded = np.zeros(n, dtype=bool)
        self.team.reset()
        self._cells = np.empty((n, 2), dtype=np.int64)
        self._window = np.empty((n, w, w), dtype=np.int64)
        self._place_windows()
        self._stale_window = np.empty((n, w, w), dtype=np.float32)
        self._stale_blocks = np.empty((n, self.config.belief_size**2), dtype=np.float32)
        self._signals = np.zeros((n, 3, w, w), dtype=np.float32)  # each step's readings

    def _start_ground(self, ground_seed: int) -> None:
        """The leopards at their dens; the poachers planned from the mode's strategy and the signs their kind left
        before the episode; in the adversarial condition, decoys at random cells (with fake signs around) and a jammer
        that travels with the poachers."""
        cfg, shape = self.config, (self.height, self.width)
        dens = self.hotspots.dens
        self.leopard_home = dens[np.arange(cfg.n_leopards) % len(dens)]
        self.leopard_pos = self.leopard_home.copy()
        self.leopard_alive = np.ones(cfg.n_leopards, dtype=bool)
        self.leopard_moved = np.zeros(cfg.n_leopards, dtype=bool)
        poacher_rng, sign_rng = np.random.default_rng(ground_seed), np.random.default_rng([ground_seed, 1])
        self.poacher_entry_time, self.poacher_entry, self.poacher_target = actors.plan_poachers(
            poacher_rng, self.strategy, cfg.n_poachers, self.max_cycles, shape, dens, self.hotspots.road_entries,
            zone=dens[STRATEGIES.index(self.strategy)] if cfg.strategy_zones else None)
        self.poacher_pos = self.poacher_entry.copy()
        self.poacher_status = np.full(cfg.n_poachers, POACHER_WAITING, dtype=np.int8)
        self.poacher_moved = np.zeros(cfg.n_poachers, dtype=bool)
        self.poaching_timer = np.zeros(cfg.n_poachers, dtype=np.int64)
        self.signs = signs_lib.Signs(self._padded_shape, self.r, self._block)
        self.signs.add(*signs_lib.plan_signs(sign_rng, self.strategy, self.poacher_entry, self.poacher_target, dens,
                                             shape), t=0)
        if cfg.adversarial:
            self.decoy_pos = np.stack([poacher_rng.integers(0, self.height, cfg.n_decoys),
                                       poacher_rng.integers(0, self.width, cfg.n_decoys)], axis=-1)
            self.jammer_pos = self.poacher_entry[0].astype(np.float64) if cfg.n_poachers else np.array(shape) / 2
            for decoy in self.decoy_pos:
                fakes = np.clip(signs_lib.around(sign_rng, decoy, signs_lib.DECOY_SIGNS, 1, 2), 0, [self.height - 1,
                                                                                                    self.width - 1])
                self.signs.add(fakes, -signs_lib.TRACK_AGE, signs_lib.DECOY, t=0)
        else:
            self.decoy_pos = np.zeros((0, 2), dtype=np.int64)
            self.jammer_pos = None
        self.jammed = np.zeros(self.n, dtype=bool)
        self.jammer_on = False

    def _start_tallies(self) -> None:
        """The episode's metrics, first times and readings, none yet."""
        self.metrics = {"team_reward": 0.0, "false_alarms": 0, "poaching_events": 0, "collisions": 0, "energy": 0.0,
                        "poachers_entered": 0, "poachers_detected": 0, "signs_found": 0}
        self.first_entry_time: int | None = None
        self.first_detection_time: int | None = None
        self.detections = np.zeros((0, 3), dtype=np.int64)  # this step's poacher readings: (uav, row, col)

    def _first_look(self) -> np.ndarray:
        """The UAVs' look at the start (every one airborne and able to talk; nobody talks: the beacons draw, the
        messages do not) and their first observations ``(n, obs_dim)``."""
        n, world, cells = self.n, self._world, self._cells
        everyone = np.ones(n, dtype=bool)
        looks = Looks(t=np.float32(self.t), window=self._window.reshape(n, -1),
                      cell_blocks=self._block[cells[:, 0], cells[:, 1]], airborne=everyone)
        beacons = self.rng.random((1, n, n))[0]
        talk = Talk(pos=self.uav_pos, ok=everyone, comm=np.zeros(n, dtype=np.int64), beacon_draws=beacons,
                    message_draws=beacons)
        self._n_covered += kernels.look_and_talk(world.team, world.coverage, looks, talk,
                                                 self.signs.block[:self.signs.count])[1]
        obs = np.empty((n, self.obs_dim), dtype=np.float32)
        kernels.fill_observations(obs, world.observe, world.flight, world.team, self.team.events, float(self.t),
                                  min(self.t / self.max_cycles, 1.0))
        return finish_observations(self, obs)

    def _check_reset(self, seed: Any, options: dict | None) -> tuple[int | None, int | None, np.ndarray | None]:
        """``reset``'s arguments checked before anything changes: the seed (an int >= 0, numpy's included, or None),
        the mode (``options["mode"]``, else the configuration's) and the UAVs' start cells (floored), or None."""
        seed = check_seed(seed)
        given = check_options(options, RESET_OPTIONS)
        mode = given.get("mode", self.config.mode)
        if mode is not None:
            mode = check_int("mode", mode, 0, N_MODES - 1)
        start = None
        if "uav_positions" in given:
            shape = (self.height, self.width)
            try:
                start = np.asarray(given["uav_positions"], dtype=np.float64)
            except (TypeError, ValueError):
                start = np.full(0, np.nan)
            if start.shape != (self.n, 2) or not np.isfinite(start).all() or (start < 0).any() or (start >= shape).any():
                raise ValueError(f"options['uav_positions'] must be {self.n} (row, col) cells inside {shape}, "
                                 f"got {given['uav_positions']!r}")
            start = np.floor(start)
        return seed, mode, start

    def _require_episode(self, method: str) -> None:
        """Refuse ``method`` before the first reset (or after a reset that failed)."""
        if not self._ready:
            raise RuntimeError(f"{method}() needs an episode: call reset() first")

    # ------------------------------------------------------------------ step
    def step(self, actions: dict[str, Any]) -> tuple[dict, dict, dict, dict, dict]:
        """Advance every UAV, poacher and leopard one step.

        :param actions: one action per live agent
        """
        self._require_episode("step")
        if not self.agents:
            raise RuntimeError("step() called on a finished episode: call reset() first")
        agents = self.agents
        obs, rewards_arr, terminated, truncated, info, heard = self._advance(*self._decode_actions(actions))
        observations = dict(zip(agents, obs))
        rewards = dict(zip(agents, rewards_arr.tolist()))
        terminations = dict.fromkeys(agents, terminated)
        truncations = dict.fromkeys(agents, truncated)
        infos = {a: {**info, "heard_from": senders} for a, senders in zip(agents, heard)}
        return observations, rewards, terminations, truncations, infos

    def step_arrays(self, actions: np.ndarray, out: np.ndarray | None = None) -> tuple[
            np.ndarray, np.ndarray, bool, bool, dict[str, Any], list[tuple[int, ...]]]:
        """:meth:`step` on arrays, in agent order, without the per-agent dictionaries (the fast vector environment,
        ``sb3_emmarl.common.vec_env.ReserveVecEnv``, steps the reserve through it; ``step`` is this plus the dicts).

        :param actions: ``(n,)`` ints (discrete) or ``(n, 3)`` floats (continuous), one row per UAV
        :param out: a C-contiguous float32 ``(n, obs_dim)`` array to write the observations into (returned), or None
        :return: observations ``(n, obs_dim)``, rewards ``(n,)``, terminated, truncated (every UAV alike), the info
            every UAV shares (``mode``, and ``metrics`` on the last step) and each UAV's ``heard_from``
        """
        self._require_episode("step_arrays")
        if not self.agents:
            raise RuntimeError("step_arrays() called on a finished episode: call reset() first")
        if out is not None and (out.shape != (self.n, self.obs_dim) or out.dtype != np.float32
                                or not out.flags.c_contiguous):
            raise ValueError(f"out must be a C-contiguous float32 array of shape {(self.n, self.obs_dim)}, got "
                             f"{out.dtype} {out.shape}")
        return self._advance(*self._action_arrays(actions), out)

    def _advance(self, choices: np.ndarray, move: np.ndarray, comm: np.ndarray, out: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray, bool, bool, dict[str, Any], list[tuple[int, ...]]]:
        """The step itself, from :meth:`_action_arrays`' actions (see :meth:`step_arrays` for what it returns): the
        whole step runs in one compiled call (``kernels.advance_world``, on :meth:`_step_and_world`: the actions'
        decoding, the poachers' entry, the flight, ground, sensing, poaching, sharing and reward phases); the
        episode's metrics are counted here."""
        self.t += 1
        obs = np.empty((self.n, self.obs_dim), dtype=np.float32) if out is None else out
        try:
            outcome = kernels.StepOutcome._make(kernels.advance_world(*self._step_and_world(choices, move, comm, obs)))
        except kernels.ActionError:  # raised before anything changed
            self.t -= 1
            raise self._bad_actions(choices) from None
        self.signs.count, self.jammer_on, self.team.events = outcome.sign_count, outcome.jammer_on, outcome.events
        if outcome.entered:
            self.metrics["poachers_entered"] += outcome.entered
            if self.first_entry_time is None:
                self.first_entry_time = self.t
        self.detections = outcome.readings
        if outcome.caught and self.first_detection_time is None:
            self.first_detection_time = self.t
        self._n_covered += outcome.new_cells
        finish_observations(self, obs)
        m = self.metrics
        m["team_reward"] += outcome.team_reward
        m["poaching_events"] += outcome.poaching_events
        m["collisions"] += outcome.collisions
        m["energy"] += outcome.spent
        m["poachers_detected"] += outcome.caught
        m["false_alarms"] += outcome.false_alarms
        m["signs_found"] += outcome.signs_found
        truncated = self.t >= self.max_cycles
        info: dict[str, Any] = {"mode": self.mode}
        if truncated or outcome.terminated:
            info["metrics"] = self.episode_metrics()
            self.agents = []
        if self.render_mode == "human":
            self.render()
        terminated = outcome.terminated
        return obs, outcome.rewards, terminated, truncated and not terminated, info, self.team.heard_from(outcome.masks)

    def __getstate__(self) -> dict:
        """Pickle without the step's records (:meth:`_build_world`), which unpickling remakes."""
        return {name: value for name, value in self.__dict__.items() if name not in ("_world", "_world_tuple")}

    def __setstate__(self, state: dict) -> None:
        """Unpickle (checkpoints), adding what a reserve pickled by an older version lacks (the step's compiled call
        reads the generator through a :class:`Stream`, writes the readings and decoded actions into buffers and reads
        the episode's :class:`~wildlife_reserve.reserve.sensing.SensorTables`; the signs keep which the team found)
        and remaking the step's records."""
        self.__dict__.update(state)
        for name in ("_next_entry", "_map_arrays", "_sensing_tables", "_ring", "reach", "_reach_offsets",
                     "_detect_table", "_decoy_table", "_sign_table"):  # (what older versions kept, now remade)
            self.__dict__.pop(name, None)
        self.__dict__.setdefault("_fixed_map", None)
        self.__dict__.setdefault("_sensor_tables", {})
        if "_move" not in state:
            self._move, self._comm = np.zeros((self.n, 2)), np.zeros(self.n, dtype=np.int64)
        if "rng" not in state:  # (pickled before its first reset)
            return
        if "_stream" not in state:
            self._stream = Stream(self.rng)
        if "_signals" not in state:
            self._signals = np.zeros((self.n, 3, self.window, self.window), dtype=np.float32)
        if "sensors" not in state:
            self.sensors = sensing.sensor_tables(self.r, self.weather, self.config.sensor_noise)
        found = self.__dict__.pop("_found", None)
        if found is not None:  # (the reserve kept it before the signs did)
            self.signs.found[:len(found)] = found
        self._world = self._build_world()

    # ------------------------------------------------------------------ the step's records
    def _build_world(self) -> World:
        """The records of the step's phases (``kernels.World``), on this episode's arrays (which the steps update in
        place), and the same as plain tuples (what ``kernels.advance_world`` takes): made at reset; the signs' and the
        team's own records replace theirs when those grow (:meth:`_step_and_world`)."""
        cfg, strategy, n = self.config, self.strategy, self.n
        flight = Flight(pos=self.uav_pos, velocity=self.velocity, battery=self.battery, grounded=self.grounded,
                        cells=self._cells, window=self._window, speed=cfg.uav_speed, upper=self._upper,
                        hover=ENERGY_COSTS["hover"], move_cost=ENERGY_COSTS["move"], comm_costs=self._comm_costs,
                        padded_width=self._padded_shape[1], window_offsets=self._win_offsets)
        leopards = Leopards(pos=self.leopard_pos, moved=self.leopard_moved, home=self.leopard_home,
                            alive=self.leopard_alive, home_range=float(cfg.leopard_range),
                            move_prob=actors.LEOPARD_MOVE_PROB)
        poachers = Poachers(pos=self.poacher_pos, moved=self.poacher_moved, status=self.poacher_status,
                            timer=self.poaching_timer, planned=self.poacher_target, entry_time=self.poacher_entry_time,
                            sight=float(actors.POACHER_SIGHT),
                            notice_radius=actors.NOTICE_RADIUS * self.weather.notice_factor,
                            move_prob=strategy.move_prob, wander_prob=strategy.wander_prob,
                            evasion_prob=strategy.evasion_prob, hide_in_cover=strategy.hide_in_cover,
                            track_prob=signs_lib.TRACK_PROB, poaching_time=cfg.poaching_time)
        jammer = Jammer(pos=_NO_JAMMER if self.jammer_pos is None else self.jammer_pos, jammed=self.jammed,
                        present=self.jammer_pos is not None, radius=float(cfg.jam_radius))
        sensors = self.sensors
        readings = Sensing(detection=sensors.detection, terrain=self.terrain, radius=self.r,
                           false_alarm=self._false_alarm, reach_offsets=sensors.reach_offsets, decoys=self.decoy_pos,
                           decoy=sensors.decoy, sign=sensors.sign, terrain_pad=self._terrain_pad,
                           signal_noise=sensing.signal_noise(cfg.sensor_noise), signals=self._signals)
        coverage = Coverage(high_risk=self._high_risk_pad, visited=self.visited.reshape(-1),
                            stale_cells=self._stale_window.reshape(n, -1), stale_blocks=self._stale_blocks)
        world = World(flight=flight, ground=Ground(leopards=leopards, poachers=poachers, jammer=jammer,
                                                   cover=self.cover, steps=actors.STEPS),
                      signs=self.signs.record, sensing=readings, team=self.team.record, coverage=coverage,
                      observe=observation_record(cfg, occlusion=self._occ_pad, risk=self._risk_pad,
                                                 staleness=self._stale_window, signals=self._signals,
                                                 block_staleness=self._stale_blocks, inv_scale=self._inv_scale),
                      rewards=Rewards(weights=self._weights, shaping=float(cfg.shaping)))
        self._world_tuple = plain(world)
        return world

    def _step_and_world(self, choices: np.ndarray, move: np.ndarray, comm: np.ndarray,
                        obs: np.ndarray) -> tuple[tuple, tuple]:
        """``kernels.advance_world``'s arguments for this step's actions (:meth:`_action_arrays`' three arrays),
        writing the observations into ``obs``: the :class:`~wildlife_reserve.reserve.kernels.Step` and the world
        (:meth:`_build_world`), as plain tuples. First makes room for the signs the step may add (a track per poacher,
        a false reading per UAV, a carcass per leopard) in the records and in what the UAVs know."""
        signs, team = self.signs, self.team
        signs.make_room(len(self.poacher_pos) + self.n + len(self.leopard_pos))
        team.fit_signs(signs.capacity)
        if signs.record is not self._world.signs or team.record is not self._world.team:  # (grown)
            self._world = self._world._replace(signs=signs.record, team=team.record)
            self._world_tuple = plain(self._world)
        if self._stream.rng is not self.rng:  # (the reserve was handed another generator)
            self._stream = Stream(self.rng)
        step = Step(addresses=self._stream.handle, t=self.t, choices=choices, move=move, comm=comm, obs=obs,
                    sign_count=signs.count, events=team.events)
        return tuple(step), self._world_tuple

    # ------------------------------------------------------------------ helpers
    def _decode_actions(self, actions: dict[str, Any]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`_action_arrays` of the action dict (a missing or None action means "stay, no message"; a key that is
        no live agent is refused); each action is checked as :meth:`step_arrays` checks its rows, and a bad one is
        refused naming its agent."""
        check_action_dict(actions, self.agents)
        if self.config.continuous_actions:
            act = np.zeros((self.n, 3))
            for i, agent in enumerate(self.agents):
                value = actions.get(agent)
                if value is not None:
                    row = np.asarray(value)
                    if row.shape != (3,) or row.dtype.kind not in "iuf" or not np.all(np.isfinite(row)):
                        raise ValueError(f"the action of {agent} must be 3 finite floats (d_row, d_col, comm) or None, "
                                         f"got {value!r}")
                    act[i] = row
            return self._action_arrays(act)
        choices = np.zeros(self.n, dtype=np.int64)  # 0: stay, no message
        for i, agent in enumerate(self.agents):
            value = actions.get(agent)
            if value is not None:
                choices[i] = discrete_action(agent, value, N_MOVES * N_COMMS, none_too=True)
        return self._action_arrays(choices)

    def _action_arrays(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The step's actions from ``(n,)`` ints or ``(n, 3)`` floats, as ``kernels.advance_world`` takes them:
        ``(n,)`` int64 discrete choices that it decodes (and checks) into the ``(n, 2)`` unit moves and ``(n,)``
        communication choices that follow them, or no choices and the moves and choices decoded here."""
        if self.config.continuous_actions:
            act = np.asarray(actions, dtype=np.float64)
            if act.size != 3 * self.n:
                raise ValueError(f"continuous actions must be {self.n} rows of 3 floats, got shape {act.shape}")
            act = act.reshape(self.n, 3)
            if not np.all(np.isfinite(act)):
                raise ValueError(f"continuous actions must be finite, got {act}")
            act = np.clip(act, -1.0, 1.0)
            comm = np.select([act[:, 2] > 1 / 3, act[:, 2] < -1 / 3], [COMM_BROADCAST, COMM_QUERY], COMM_NONE)
            return _NO_CHOICES, np.ascontiguousarray(act[:, :2]), comm
        choices = np.asarray(actions).reshape(-1)
        if choices.dtype != np.int64 or choices.size != self.n:  # (SB3 and SuperSuit pass n int64s: checked compiled)
            whole = choices.dtype.kind in "iu" or (choices.dtype.kind == "f"
                                                   and np.array_equal(choices, np.floor(choices)))
            if not whole or choices.size != self.n or choices.min() < 0 or choices.max() >= N_MOVES * N_COMMS:
                raise self._bad_actions(choices)
            choices = choices.astype(np.int64)
        return choices, self._move, self._comm

    def _bad_actions(self, choices: np.ndarray) -> ValueError:
        return ValueError(f"discrete actions must be {self.n} ints in [0, {N_MOVES * N_COMMS - 1}], got {choices}")

    def _place_windows(self) -> None:
        """The UAVs' cells ``(n, 2)`` and the flat indices ``(n, w, w)`` of their observation windows in the padded
        grids, from their positions (in place; ``kernels.fly`` does the same after every flight)."""
        kernels.place_windows(self.uav_pos, self._cells, self._window, self._padded_shape[1], self._win_offsets)

    def _covered(self) -> int:
        """High-risk cells seen so far this episode."""
        return self._n_covered

    # ------------------------------------------------------------------ public extras
    def split_observation(self, obs: np.ndarray) -> dict[str, np.ndarray]:
        """Split flat observations ``(..., obs_dim)`` into their named parts (see ``observation_layout``)."""
        obs = np.asarray(obs)
        layout = self.observation_layout
        return {name: obs[..., part].reshape(*obs.shape[:-1], *shape) for name, (part, shape) in layout.items()}

    def episode_metrics(self) -> dict[str, float]:
        """The episode's metrics so far (what ``infos[agent]["metrics"]`` holds at the end).

        ``coverage_efficiency`` is the share of high-risk cells seen; ``detection_rate`` the share of
        entered poachers detected (0 if none entered); ``time_to_first_detection`` counts steps from
        the first entry to the first true detection, and runs to the current step when none happened;
        ``signs_found`` counts the distinct signs of poacher activity the team found.
        """
        self._require_episode("episode_metrics")
        m = self.metrics
        entered = m["poachers_entered"]
        if self.first_entry_time is None:
            ttfd = 0
        else:
            ttfd = (self.first_detection_time if self.first_detection_time is not None else self.t) - self.first_entry_time
        return {
            "team_reward": float(m["team_reward"]),
            "coverage_efficiency": float(self._covered() / max(self.n_high_risk, 1)),
            "detection_rate": float(m["poachers_detected"] / entered) if entered else 0.0,
            "false_alarms": int(m["false_alarms"]),
            "poaching_events": int(m["poaching_events"]),
            "collisions": int(m["collisions"]),
            "energy": float(m["energy"]),
            "time_to_first_detection": int(ttfd),
            "poachers_entered": int(entered),
            "poachers_detected": int(m["poachers_detected"]),
            "signs_found": int(m["signs_found"]),
            "episode_length": int(self.t),
            "mode": int(self.mode),
        }

    def state(self) -> np.ndarray:
        """The global state (positions, batteries, poachers, leopards, coverage and signs by block, progress), in [-1, 1]."""
        self._require_episode("state")
        return global_state(self)

    def render(self) -> np.ndarray | None:
        """Draw the reserve with pygame: an RGB array in ``"rgb_array"`` mode, a window in ``"human"`` mode."""
        if self.render_mode is None:
            import gymnasium

            gymnasium.logger.warn("render() called without a render_mode; pass render_mode='rgb_array' or 'human'.")
            return None
        self._require_episode("render")
        from wildlife_reserve.reserve.rendering import ReserveRenderer

        if self._renderer is None:
            self._renderer = ReserveRenderer(self, self.render_mode)
        return self._renderer.draw()

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
