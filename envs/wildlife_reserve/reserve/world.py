"""The reserve's world: its state, the episode's start and the step's bookkeeping, without PettingZoo.

:class:`ReserveWorld` holds the reserve as numpy arrays over UAVs and cells (grids padded by the sensor radius, so
that every observation window is one fancy-index away), builds the map (drawn per episode or fixed per region and
``terrain_seed``), starts an episode in named phases (:meth:`ReserveWorld.start_episode`: the map, the hidden mode,
the UAVs, the ground actors, the tallies, the first look) and advances it by one compiled call
(:meth:`ReserveWorld.advance`, ``kernels.advance_world`` on the records of :meth:`ReserveWorld._build_world`). The
PettingZoo face, :class:`~wildlife_reserve.reserve.reserve.ReserveParallelEnv`, adds the agents, the spaces, the
seeding, the checks of what it is given and the per-agent dictionaries, as MPE2's ``SimpleEnv`` adds them to its
``World``; it subclasses the world (where ``SimpleEnv`` holds one), so that the arrays, public for tests and tools,
stay ``env.uav_pos``, ``env.battery``, ... (see the face's docstring).
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import numpy as np

from wildlife_reserve.reserve import actors, kernels, sensing
from wildlife_reserve.reserve import signs as signs_lib
from wildlife_reserve.reserve import terrain as terrain_lib
from wildlife_reserve.reserve.config import ENERGY_COSTS, ReserveConfig
from wildlife_reserve.reserve.kernels.constants import POACHER_WAITING
from wildlife_reserve.reserve.knowledge import TeamKnowledge
from wildlife_reserve.reserve.modes import N_MODES, STRATEGIES, Weather, decode_mode
from wildlife_reserve.reserve.observation import (
    finish_observations,
    observation_layout,
    observation_record,
    observation_size,
    state_size,
)
from wildlife_reserve.reserve.stream import Stream

_NO_JAMMER = np.zeros(2)  # what the step's compiled call gets for the jammer's cell without one (never written)


class ReserveMap(NamedTuple):
    """A map and what the steps read from it (:meth:`ReserveWorld._make_map`): the ``terrain``, ``risk`` and
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


class ReserveWorld:
    """The reserve's state and what changes it: map, episode start, step (see the module's docstring).

    :param config: the reserve's validated settings
    """

    #: the episode's first poacher entry and first true detection (steps), None until they happen
    first_entry_time: int | None
    first_detection_time: int | None

    def __init__(self, config: ReserveConfig) -> None:
        self.config = cfg = config
        self.max_cycles = cfg.max_cycles
        self.height, self.width = cfg.grid_size  # type: ignore[misc]  # a (height, width) tuple once validated
        self.n = cfg.n_uavs
        self.r = cfg.sensor_radius
        self.window = 2 * self.r + 1
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
        self._static_map = None
        self._fixed_map: ReserveMap | None = None  # what a fixed map's steps read, made at the first reset
        self._sensor_tables: dict[Weather, sensing.SensorTables] = {}  # what the sensors read, by weather
        if cfg.terrain_seed is not None:
            region_index = sorted(terrain_lib.REGIONS).index(cfg.region)
            self._static_map = self._build_map(np.random.default_rng([cfg.terrain_seed, region_index]))
        self._upper = np.array([self.height, self.width]) - 1e-6
        self._inv_scale = 1.0 / np.array([max(self.height - 1, 1), max(self.width - 1, 1)])
        self._comm_costs = np.array([0.0, ENERGY_COSTS["broadcast"], ENERGY_COSTS["query"]])  # by COMM_* choice
        self._move, self._comm = np.zeros((self.n, 2)), np.zeros(self.n, dtype=np.int64)  # discrete actions, decoded
        # The reward weights and the false-alarm chance as plain floats, read once here rather than at every step.
        self._weights = tuple(float(cfg.reward_weights[term]) for term in
                              ("detection", "coverage", "sign", "poaching", "collision", "energy"))  # step_rewards' order
        self._false_alarm = float(sensing.false_alarm_probability(cfg.sensor_noise))
        self.t = 0

    # ------------------------------------------------------------------ the episode's start
    def start_episode(self, world_seed: int, mode_seed: int, ground_seed: int, step_seed: int, mode: int | None,
                      start: np.ndarray | None) -> np.ndarray:
        """Start an episode from its seeds, in named phases, and return the UAVs' first observations ``(n, obs_dim)``.

        :param world_seed: seeds the map (when drawn per episode) and the UAVs' start cells
        :param mode_seed: seeds the hidden mode's draw from the prior (when ``mode`` is None)
        :param ground_seed: seeds the poachers' plans and the signs they left
        :param step_seed: seeds the steps' draws (``rng``)
        :param mode: the hidden mode, or None (drawn)
        :param start: the UAVs' start cells ``(n, 2)``, or None (drawn)
        """
        self.rng = np.random.default_rng(step_seed)
        self._stream = Stream(self.rng)  # what the step's compiled call draws from (the same generator)
        self.t = 0
        world_rng = np.random.default_rng(world_seed)
        self._start_map(world_rng)
        self._start_mode(mode, mode_seed)
        self._start_uavs(world_rng, start)
        self._start_ground(ground_seed)
        self._start_tallies()
        self._world = self._build_world()
        return self._first_look()

    # ------------------------------------------------------------------ the step
    def advance(self, choices: np.ndarray, move: np.ndarray, comm: np.ndarray, obs: np.ndarray) -> kernels.StepOutcome:
        """One step: the whole step in one compiled call (``kernels.advance_world``, on :meth:`_step_and_world`: the
        actions' decoding, the poachers' entry, the flight, ground, sensing, poaching, sharing and reward phases), the
        observations written into ``obs``, and the episode's tallies counted.

        :param choices: ``(n,)`` int64 discrete choices, or none (continuous actions, decoded into ``move`` and ``comm``)
        :param move: ``(n, 2)`` unit moves
        :param comm: ``(n,)`` communication choices
        :param obs: a C-contiguous float32 ``(n, obs_dim)`` array
        :raise kernels.ActionError: a discrete choice out of range, before anything changed
        """
        self.t += 1
        try:
            outcome = kernels.StepOutcome._make(kernels.advance_world(*self._step_and_world(choices, move, comm, obs)))
        except kernels.ActionError:
            self.t -= 1
            raise
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
        return outcome

    # ------------------------------------------------------------------ the rest: views, map, phases, records
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
        self.first_entry_time = None
        self.first_detection_time = None
        self.detections = np.zeros((0, 3), dtype=np.int64)  # this step's poacher readings: (uav, row, col)

    def _first_look(self) -> np.ndarray:
        """The UAVs' look at the start (every one airborne and able to talk; nobody talks: the beacons draw, the
        messages do not) and their first observations ``(n, obs_dim)``."""
        n, world, cells = self.n, self._world, self._cells
        everyone = np.ones(n, dtype=bool)
        looks = kernels.Looks(t=np.float32(self.t), window=self._window.reshape(n, -1),
                      cell_blocks=self._block[cells[:, 0], cells[:, 1]], airborne=everyone)
        beacons = self.rng.random((1, n, n))[0]
        talk = kernels.Talk(pos=self.uav_pos, ok=everyone, comm=np.zeros(n, dtype=np.int64), beacon_draws=beacons,
                    message_draws=beacons)
        self._n_covered += kernels.look_and_talk(world.team, world.coverage, looks, talk,
                                                 self.signs.block[:self.signs.count])[1]
        obs = np.empty((n, self.obs_dim), dtype=np.float32)
        kernels.fill_observations(obs, world.observe, world.flight, world.team, self.team.events, float(self.t),
                                  min(self.t / self.max_cycles, 1.0))
        return finish_observations(self, obs)

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

    def _build_world(self) -> kernels.World:
        """The records of the step's phases (``kernels.World``), on this episode's arrays (which the steps update in
        place), and the same as plain tuples (what ``kernels.advance_world`` takes): made at reset; the signs' and the
        team's own records replace theirs when those grow (:meth:`_step_and_world`)."""
        cfg, strategy, n = self.config, self.strategy, self.n
        flight = kernels.Flight(pos=self.uav_pos, velocity=self.velocity, battery=self.battery, grounded=self.grounded,
                        cells=self._cells, window=self._window, speed=cfg.uav_speed, upper=self._upper,
                        hover=ENERGY_COSTS["hover"], move_cost=ENERGY_COSTS["move"], comm_costs=self._comm_costs,
                        padded_width=self._padded_shape[1], window_offsets=self._win_offsets)
        leopards = kernels.Leopards(pos=self.leopard_pos, moved=self.leopard_moved, home=self.leopard_home,
                            alive=self.leopard_alive, home_range=float(cfg.leopard_range),
                            move_prob=actors.LEOPARD_MOVE_PROB)
        poachers = kernels.Poachers(pos=self.poacher_pos, moved=self.poacher_moved, status=self.poacher_status,
                            timer=self.poaching_timer, planned=self.poacher_target, entry_time=self.poacher_entry_time,
                            sight=float(actors.POACHER_SIGHT),
                            notice_radius=actors.NOTICE_RADIUS * self.weather.notice_factor,
                            move_prob=strategy.move_prob, wander_prob=strategy.wander_prob,
                            evasion_prob=strategy.evasion_prob, hide_in_cover=strategy.hide_in_cover,
                            track_prob=signs_lib.TRACK_PROB, poaching_time=cfg.poaching_time)
        jammer = kernels.Jammer(pos=_NO_JAMMER if self.jammer_pos is None else self.jammer_pos, jammed=self.jammed,
                        present=self.jammer_pos is not None, radius=float(cfg.jam_radius))
        sensors = self.sensors
        readings = kernels.Sensing(detection=sensors.detection, terrain=self.terrain, radius=self.r,
                           false_alarm=self._false_alarm, reach_offsets=sensors.reach_offsets, decoys=self.decoy_pos,
                           decoy=sensors.decoy, sign=sensors.sign, terrain_pad=self._terrain_pad,
                           signal_noise=sensing.signal_noise(cfg.sensor_noise), signals=self._signals)
        coverage = kernels.Coverage(high_risk=self._high_risk_pad, visited=self.visited.reshape(-1),
                            stale_cells=self._stale_window.reshape(n, -1), stale_blocks=self._stale_blocks)
        world = kernels.World(flight=flight, ground=kernels.Ground(leopards=leopards, poachers=poachers, jammer=jammer,
                                                   cover=self.cover, steps=actors.STEPS),
                      signs=self.signs.record, sensing=readings, team=self.team.record, coverage=coverage,
                      observe=observation_record(cfg, occlusion=self._occ_pad, risk=self._risk_pad,
                                                 staleness=self._stale_window, signals=self._signals,
                                                 block_staleness=self._stale_blocks, inv_scale=self._inv_scale),
                      rewards=kernels.Rewards(weights=self._weights, shaping=float(cfg.shaping)))
        self._world_tuple = kernels.plain(world)
        return world

    def _step_and_world(self, choices: np.ndarray, move: np.ndarray, comm: np.ndarray,
                        obs: np.ndarray) -> tuple[tuple, tuple]:
        """``kernels.advance_world``'s arguments for this step's actions (the three arrays of the face's ``_action_arrays``),
        writing the observations into ``obs``: the :class:`~wildlife_reserve.reserve.kernels.Step` and the world
        (:meth:`_build_world`), as plain tuples. First makes room for the signs the step may add (a track per poacher,
        a false reading per UAV, a carcass per leopard) in the records and in what the UAVs know."""
        signs, team = self.signs, self.team
        signs.make_room(len(self.poacher_pos) + self.n + len(self.leopard_pos))
        team.fit_signs(signs.capacity)
        if signs.record is not self._world.signs or team.record is not self._world.team:  # (grown)
            self._world = self._world._replace(signs=signs.record, team=team.record)
            self._world_tuple = kernels.plain(self._world)
        if self._stream.rng is not self.rng:  # (the reserve was handed another generator)
            self._stream = Stream(self.rng)
        step = kernels.Step(addresses=self._stream.handle, t=self.t, choices=choices, move=move, comm=comm, obs=obs,
                    sign_count=signs.count, events=team.events)
        return tuple(step), self._world_tuple

    def _place_windows(self) -> None:
        """The UAVs' cells ``(n, 2)`` and the flat indices ``(n, w, w)`` of their observation windows in the padded
        grids, from their positions (in place; ``kernels.fly`` does the same after every flight)."""
        kernels.place_windows(self.uav_pos, self._cells, self._window, self._padded_shape[1], self._win_offsets)

    def _covered(self) -> int:
        """High-risk cells seen so far this episode."""
        return self._n_covered
