"""
# Wildlife Reserve

| Import             | `from wildlife_reserve import reserve_v0`                  |
|--------------------|------------------------------------------------------------|
| Actions            | Discrete (default) or continuous                           |
| Parallel API       | Yes                                                        |
| Manual control     | No                                                         |
| Agents             | `agents= ['uav_0', 'uav_1', ..., 'uav_9']` (default)       |
| Agents             | `n_uavs` (default 10, any n >= 1)                          |
| Action shape       | `Discrete(15)` or `Box(-1, 1, (3,))`                       |
| Observation shape  | `(6 * (2r + 1)^2 + 6 + 3 * max_neighbors + 2 * belief_size^2,)`; 440 by default |
| Observation values | [-1, 1]                                                    |
| State shape        | `(4 n_uavs + 4 n_poachers + 3 n_leopards + belief_size^2 + 1,)` |

A team of UAVs patrols a wildlife reserve against poachers who hunt its leopards. Each
episode has a hidden scenario mode `z*` (poacher strategy x weather) that decides where and
when poachers enter, how they move, and how well the sensors see; the UAVs never observe it
(it is in `infos[agent]["mode"]` for evaluation only). The full card, with every argument and
its range, is `docs/env.md`.

### Observations
Per UAV, a flat float32 vector: an egocentric `(2r + 1) x (2r + 1)` window of six channels
(visual occlusion, risk, time since the team last saw the cell as far as this UAV knows,
poacher signals, leopard signals, other UAVs), then own position, velocity, battery, episode
progress, the relative positions of up to `max_neighbors` UAVs within `R_c` (padded, with a
presence flag), and two `belief_size x belief_size` maps built from what this UAV knows (its own
history and what was shared with it): time since each block was flown over, and poacher activity.
`env.split_observation(obs)` names the parts.

### Actions
Discrete: `move + 5 * comm`, with move in {stay, up, down, left, right} and comm in {none,
broadcast, query the nearest neighbour}. Continuous: `(d_row, d_col, comm)` in [-1, 1]; the
first two scale `uav_speed`, comm > 1/3 broadcasts and comm < -1/3 queries.

### Rewards
One shared team reward per step: `detection` per poacher detected, `coverage` per high-risk
cell seen for the first time, minus `poaching` per poaching event, `collision` per pair of UAVs
in one cell and `energy` per unit of battery spent. `shaping > 0` mixes in each UAV's own share.

### Version History
* v0: initial release (sb3-emmarl 0.1.0)
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from pettingzoo import ParallelEnv
from pettingzoo.utils import wrappers
from pettingzoo.utils.conversions import parallel_to_aec_wrapper

from wildlife_reserve.reserve import actors, sensing, terrain as terrain_lib
from wildlife_reserve.reserve.config import ENERGY_COSTS, ReserveConfig, check_int
from wildlife_reserve.reserve.modes import N_MODES, decode_mode

N_CHANNELS = 6
CH_OCCLUSION, CH_RISK, CH_STALENESS, CH_POACHER, CH_LEOPARD, CH_UAV = range(N_CHANNELS)
N_MOVES, N_COMMS = 5, 3
COMM_NONE, COMM_BROADCAST, COMM_QUERY = range(N_COMMS)
POACHER_WAITING, POACHER_ACTIVE, POACHER_CAUGHT, POACHER_GONE = range(4)
#: Timestamp of a cell nobody has seen.
NEVER = np.float32(-1.0e6)
#: Standard deviation of the noise on the signal channels per unit of ``sensor_noise``.
SIGNAL_NOISE_STD = 0.3


def env(**kwargs: Any) -> wrappers.OrderEnforcingWrapper:
    """The AEC form of the reserve, with PettingZoo's standard wrappers.

    :param kwargs: see :class:`~wildlife_reserve.reserve.config.ReserveConfig`
    """
    aec = raw_env(**kwargs)
    if not aec.unwrapped.config.continuous_actions:
        aec = wrappers.AssertOutOfBoundsWrapper(aec)
    return wrappers.OrderEnforcingWrapper(aec)


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


class ReserveParallelEnv(ParallelEnv):
    """UAV patrol of a wildlife reserve against poachers (PettingZoo ``ParallelEnv``).

    State lives in numpy arrays over agents and cells; grids are padded by the sensor radius so
    that every observation window is one fancy-index away. Internal arrays are public for tests
    and tools: ``uav_pos`` (float rows/cols), ``battery``, ``grounded``, ``poacher_pos``,
    ``poacher_status``, ``leopard_pos``, ``leopard_alive``, ``terrain``, ``risk``.

    :param kwargs: see :class:`~wildlife_reserve.reserve.config.ReserveConfig`
    """

    metadata = {"name": "wildlife_reserve_v0", "render_modes": ["human", "rgb_array"], "is_parallelizable": True,
                "render_fps": 10}

    def __init__(self, **kwargs: Any) -> None:
        self.config = cfg = ReserveConfig(**kwargs)
        self.render_mode = cfg.render_mode
        self.max_cycles = cfg.max_cycles
        self.height, self.width = cfg.grid_size
        self.n = cfg.n_uavs
        self.r = cfg.sensor_radius
        self.window = 2 * self.r + 1
        self.possible_agents = [f"uav_{i}" for i in range(self.n)]
        self.agents = self.possible_agents[:]
        self.preset = terrain_lib.REGIONS[cfg.region]
        self.n_dens = max(self.preset.n_dens, 1)
        self._offsets = np.arange(-self.r, self.r + 1)
        self._ring = np.maximum(np.abs(self._offsets)[:, None], np.abs(self._offsets)[None, :])
        self._padded_shape = (self.height + 2 * self.r, self.width + 2 * self.r)
        self._cells_padded = self._padded_shape[0] * self._padded_shape[1]
        # Flat offsets of the window cells around a cell, in the padded grids (row-major).
        wp = self._padded_shape[1]
        self._win_offsets = (self._offsets[:, None] + self.r) * wp + self._offsets[None, :] + self.r
        self.obs_dim = N_CHANNELS * self.window**2 + 6 + 3 * cfg.max_neighbors + 2 * cfg.belief_size**2
        self.state_dim = 4 * self.n + 4 * cfg.n_poachers + 3 * cfg.n_leopards + cfg.belief_size**2 + 1
        # Map each cell to its block of the coarse belief map.
        rows = np.arange(self.height) * cfg.belief_size // self.height
        cols = np.arange(self.width) * cfg.belief_size // self.width
        self._block = (rows[:, None] * cfg.belief_size + cols[None, :]).astype(np.int64)
        self.np_random: np.random.Generator | None = None
        self._static_map = None
        if cfg.terrain_seed is not None:
            region_index = sorted(terrain_lib.REGIONS).index(cfg.region)
            self._static_map = self._build_map(np.random.default_rng([cfg.terrain_seed, region_index]))
        self._renderer = None
        self._upper = np.array([self.height, self.width]) - 1e-6
        self._inv_scale = 1.0 / np.array([max(self.height - 1, 1), max(self.width - 1, 1)])
        self.t = 0

    # ------------------------------------------------------------------ spaces
    @functools.cache  # noqa: B019 (one space object per agent, as PettingZoo requires)
    def observation_space(self, agent: str) -> spaces.Box:
        return spaces.Box(low=-1.0, high=1.0, shape=(self.obs_dim,), dtype=np.float32)

    @functools.cache  # noqa: B019
    def action_space(self, agent: str) -> spaces.Space:
        if self.config.continuous_actions:
            return spaces.Box(low=-1.0, high=1.0, shape=(3,), dtype=np.float32)
        return spaces.Discrete(N_MOVES * N_COMMS)

    @functools.cached_property
    def state_space(self) -> spaces.Box:
        return spaces.Box(low=-1.0, high=1.0, shape=(self.state_dim,), dtype=np.float32)

    # ------------------------------------------------------------------ map
    def _build_map(self, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, terrain_lib.Hotspots]:
        cfg = self.config
        shape = (self.height, self.width)
        ground = cfg.terrain if cfg.terrain is not None else terrain_lib.generate_terrain(rng, shape, self.preset)
        hotspots = terrain_lib.generate_hotspots(rng, ground, self.preset)
        if cfg.risk is not None:
            risk = cfg.risk
            empty = np.zeros((0, 2), dtype=np.int64)
            hotspots = terrain_lib.Hotspots(terrain_lib.dens_from_risk(rng, risk, self.n_dens), empty, empty)
        else:
            risk = terrain_lib.risk_map(shape, hotspots)
        return ground, risk, hotspots

    def _pad(self, grid: np.ndarray, value: float) -> np.ndarray:
        return np.pad(grid, self.r, constant_values=value)

    # ------------------------------------------------------------------ reset
    def reset(self, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        """Start an episode.

        :param seed: seeds every random draw of the episode (and of later unseeded resets)
        :param options: ``{"mode": int}`` fixes the hidden mode for this episode;
            ``{"uav_positions": array (n, 2)}`` sets the UAVs' start cells (row, col).
            Other keys are ignored.
        """
        if seed is not None or self.np_random is None:
            self.np_random, _ = seeding.np_random(seed)
        options = options or {}
        cfg = self.config
        world_seed, mode_seed, poacher_seed, step_seed = self.np_random.integers(0, 2**32, size=4)
        world_rng = np.random.default_rng(world_seed)
        self.rng = np.random.default_rng(step_seed)
        self.agents = self.possible_agents[:]
        self.t = 0
        shape = (self.height, self.width)

        # The map: fixed per region and terrain_seed, or drawn per episode.
        self.terrain, self.risk, self.hotspots = self._static_map or self._build_map(world_rng)
        self.high_risk = self.risk >= terrain_lib.HIGH_RISK_THRESHOLD
        self.n_high_risk = int(self.high_risk.sum())
        self.cover = self.terrain != terrain_lib.OPEN
        self._occ_pad = self._pad(terrain_lib.VISUAL_OCCLUSION[self.terrain], 1.0).ravel()
        self._risk_pad = self._pad(self.risk, 0.0).ravel()
        self._high_risk_pad = self._pad(self.high_risk, False).ravel()
        self._high_risk_flat = np.flatnonzero(self._high_risk_pad)
        self.visited = np.zeros(self._padded_shape, dtype=bool)

        # The hidden mode.
        mode = options.get("mode", cfg.mode)
        if mode is not None:
            mode = check_int("mode", mode, 0, N_MODES - 1)
        else:
            mode = int(np.random.default_rng(mode_seed).choice(N_MODES, p=cfg.mode_prior))
        self.strategy, self.weather = decode_mode(mode)
        self.mode = int(mode)
        self.reach = sensing.effective_radius(self.r, self.weather)
        # Readings (true or false) come from within the weather's reach; the whole window counts as flown over.
        self._reach_offsets = np.argwhere(self._ring <= self.reach) - self.r
        self._detect_table = sensing.detection_table(self.r, self.weather, cfg.sensor_noise)

        # UAVs.
        if "uav_positions" in options:
            start = np.asarray(options["uav_positions"], dtype=np.float64)
            if start.shape != (self.n, 2) or not np.isfinite(start).all() or (start < 0).any() or (start >= shape).any():
                raise ValueError(f"options['uav_positions'] must be {self.n} (row, col) cells inside {shape}, got {start!r}")
            start = np.floor(start)
        else:
            cells = world_rng.choice(self.height * self.width, size=self.n, replace=self.n > self.height * self.width)
            start = np.stack(np.divmod(cells, self.width), axis=-1).astype(np.float64)
        self.uav_pos = start + 0.5
        self.velocity = np.zeros((self.n, 2))
        self.battery = np.ones(self.n)
        self.grounded = np.zeros(self.n, dtype=bool)
        # Each UAV's own visit history: last and first time it saw each (padded) cell.
        self._stamps = np.empty((2, self.n, *self._padded_shape), dtype=np.float32)
        self._stamps[0], self._stamps[1] = NEVER, -NEVER
        self.own_last, self.own_first = self._stamps
        # The same per block of the coarse maps (the block under the UAV).
        self._block_stamps = np.empty((2, self.n, cfg.belief_size**2), dtype=np.float32)
        self._block_stamps[0], self._block_stamps[1] = NEVER, -NEVER
        # knowledge[r, s]: r knows s's visits and readings up to this time
        self.knowledge = np.full((self.n, self.n), NEVER, dtype=np.float32)
        self.beacons = np.zeros((self.n, self.n), dtype=bool)  # beacons[s, r]: r heard s's position this step
        self.comm_links = np.zeros((self.n, self.n), dtype=bool)  # comm_links[s, r]: s's knowledge reached r
        self._events = np.zeros((0, 3))  # (time, detecting UAV, belief block) of known poacher readings

        # Leopards at their dens.
        dens = self.hotspots.dens
        self.leopard_home = dens[np.arange(cfg.n_leopards) % len(dens)]
        self.leopard_pos = self.leopard_home.copy()
        self.leopard_alive = np.ones(cfg.n_leopards, dtype=bool)
        self.leopard_moved = np.zeros(cfg.n_leopards, dtype=bool)

        # Poachers, planned from the mode's strategy.
        poacher_rng = np.random.default_rng(poacher_seed)
        self.poacher_entry_time, self.poacher_entry, self.poacher_target = actors.plan_poachers(
            poacher_rng, self.strategy, cfg.n_poachers, self.max_cycles, shape, dens)
        self.poacher_pos = self.poacher_entry.copy()
        self.poacher_status = np.full(cfg.n_poachers, POACHER_WAITING, dtype=np.int8)
        self.poacher_moved = np.zeros(cfg.n_poachers, dtype=bool)
        self.poaching_timer = np.zeros(cfg.n_poachers, dtype=np.int64)

        # Adversarial condition: decoys at random cells, a jammer that travels with the poachers.
        if cfg.adversarial:
            self.decoy_pos = np.stack([poacher_rng.integers(0, self.height, cfg.n_decoys),
                                       poacher_rng.integers(0, self.width, cfg.n_decoys)], axis=-1)
            self.jammer_pos = self.poacher_entry[0].astype(np.float64) if cfg.n_poachers else np.array(shape) / 2
        else:
            self.decoy_pos = np.zeros((0, 2), dtype=np.int64)
            self.jammer_pos = None
        self.jammed = np.zeros(self.n, dtype=bool)
        self.jammer_on = False

        self.metrics = {"team_reward": 0.0, "false_alarms": 0, "poaching_events": 0, "collisions": 0, "energy": 0.0,
                        "poachers_entered": 0, "poachers_detected": 0}
        self.first_entry_time: int | None = None
        self.first_detection_time: int | None = None
        self.detections = np.zeros((0, 3), dtype=np.int64)  # this step's poacher readings: (uav, row, col)
        self._set_window(self._uav_cells())
        self._stale_window, self._stale_blocks = self._staleness()
        self._mark_own_visits(np.ones(self.n, dtype=bool))
        self._update_beacons(np.ones(self.n, dtype=bool))
        signals = np.zeros((self.n, 2, self.window, self.window), dtype=np.float32)
        obs = self._observations(signals)
        infos = {a: {"mode": self.mode} for a in self.agents}
        if self.render_mode == "human":
            self.render()
        return {a: obs[i] for i, a in enumerate(self.agents)}, infos

    # ------------------------------------------------------------------ step
    def step(self, actions: dict[str, Any]) -> tuple[dict, dict, dict, dict, dict]:
        """Advance every UAV, poacher and leopard one step.

        :param actions: one action per live agent
        """
        if not self.agents:
            raise RuntimeError("step() called on a finished episode: call reset() first")
        cfg = self.config
        weights = cfg.reward_weights
        move, comm = self._decode_actions(actions)
        airborne = ~self.grounded
        move[~airborne] = 0.0
        comm[~airborne] = COMM_NONE
        self.t += 1

        # UAV motion and energy.
        old = self.uav_pos
        self.uav_pos = np.minimum(np.maximum(old + move * cfg.uav_speed, 0.0), self._upper)
        self.velocity = (self.uav_pos - old) / cfg.uav_speed
        energy = airborne * ENERGY_COSTS["hover"] + ENERGY_COSTS["move"] * np.sqrt((self.velocity**2).sum(-1))
        energy += np.where(comm == COMM_BROADCAST, ENERGY_COSTS["broadcast"],
                           np.where(comm == COMM_QUERY, ENERGY_COSTS["query"], 0.0))
        energy = np.minimum(energy, self.battery)
        self.battery = self.battery - energy
        self.grounded = self.battery <= 1e-12
        cells = self._uav_cells()
        self._set_window(cells)

        # Collisions: pairs of airborne UAVs in one cell.
        flat = np.where(airborne, cells[:, 0] * self.width + cells[:, 1], -1 - np.arange(self.n))
        own_collisions = (flat[:, None] == flat[None, :]).sum(axis=1) - 1
        collisions = int(own_collisions.sum()) // 2

        # Leopards and poachers.
        old_leopards = self.leopard_pos
        self.leopard_pos = actors.step_leopards(self.rng, self.leopard_pos, self.leopard_home, cfg.leopard_range,
                                                (self.height, self.width))
        self.leopard_moved = (self.leopard_pos != old_leopards).any(-1)
        entering = (self.poacher_status == POACHER_WAITING) & (self.poacher_entry_time <= self.t)
        self.poacher_status[entering] = POACHER_ACTIVE
        if entering.any():
            self.metrics["poachers_entered"] += int(entering.sum())
            if self.first_entry_time is None:
                self.first_entry_time = self.t
        active = self.poacher_status == POACHER_ACTIVE
        if active.any():
            self.poacher_pos, self.poacher_moved = actors.step_poachers(
                self.rng, self.poacher_pos, active & (self.poaching_timer == 0), self._poacher_targets(), cells[airborne],
                actors.NOTICE_RADIUS * self.weather.notice_factor, self.strategy, self.cover)
        else:
            self.poacher_moved[:] = False
        self.jammer_on = self.jammer_pos is not None and bool(active.any())  # the jammer works while poachers are in
        if self.jammer_on:
            self.jammer_pos = self.poacher_pos[active].mean(axis=0)

        # Sensing: true detections, leopard sightings, false alarms and decoys.
        signals = np.zeros((self.n, 2, self.window, self.window), dtype=np.float32)
        seen = self._sense(cells, airborne, active, signals)
        caught = seen.any(axis=0)
        own_detections = seen.sum(axis=1)
        n_detected = int(caught.sum())
        self.poacher_status[caught] = POACHER_CAUGHT
        if n_detected and self.first_detection_time is None:
            self.first_detection_time = self.t
        pairs = np.argwhere(seen)  # (uav, poacher) pairs become (uav, row, col) readings
        readings = [np.column_stack([pairs[:, 0], self.poacher_pos[pairs[:, 1]]]),
                    self._false_alarms(cells, airborne, signals[:, 0])]

        # Poaching: an undetected poacher next to a live leopard for poaching_time steps.
        active = self.poacher_status == POACHER_ACTIVE
        poaching_events = 0
        if len(self.leopard_pos):
            near = (np.abs(self.poacher_pos[:, None] - self.leopard_pos[None]).max(-1) <= 1) & self.leopard_alive[None]
            near &= active[:, None]
            self.poaching_timer = np.where(near.any(axis=1), self.poaching_timer + 1, 0)
            done = self.poaching_timer >= cfg.poaching_time
            if done.any():  # one event per leopard killed; every poacher in on it leaves
                victims = np.unique(near[done].argmax(axis=1))
                self.leopard_alive[victims] = False
                self.poacher_status[done] = POACHER_GONE
                self.poaching_timer[done] = 0
                poaching_events = len(victims)

        # Coverage of high-risk cells, own visits and communication.
        before = self._covered()
        self._stale_window, self._stale_blocks = self._staleness()  # as known on arrival, before this step's look
        own_new = self._mark_own_visits(airborne)
        new_cells = self._covered() - before
        self._communicate(comm, airborne)
        self.detections = np.concatenate(readings).astype(np.int64)
        if len(self.detections):
            blocks = self._block[self.detections[:, 1], self.detections[:, 2]]
            fresh = np.column_stack([np.full(len(blocks), self.t), self.detections[:, 0], blocks])
            self._events = np.concatenate([self._events, fresh])
        horizon = np.log(1e-3) / np.log(cfg.belief_decay) if cfg.belief_decay < 1 else self.max_cycles
        self._events = self._events[self._events[:, 0] > self.t - horizon]

        # Rewards.
        team = (weights["detection"] * n_detected + weights["coverage"] * new_cells - weights["poaching"] * poaching_events
                - weights["collision"] * collisions - weights["energy"] * energy.sum())
        rewards_arr = np.full(self.n, team)
        if cfg.shaping > 0:
            own = (weights["detection"] * own_detections + weights["coverage"] * own_new
                   - weights["collision"] * own_collisions - weights["energy"] * energy)
            rewards_arr = (1.0 - cfg.shaping) * team + cfg.shaping * own

        m = self.metrics
        m["team_reward"] += float(team)
        m["poaching_events"] += poaching_events
        m["collisions"] += collisions
        m["energy"] += float(energy.sum())
        m["poachers_detected"] += n_detected

        obs = self._observations(signals)
        truncated = self.t >= self.max_cycles
        terminated = bool(self.grounded.all())
        info = {"mode": self.mode}
        if truncated or terminated:
            info = {"mode": self.mode, "metrics": self.episode_metrics()}
        agents = self.agents
        observations = {a: obs[i] for i, a in enumerate(agents)}
        rewards = {a: float(rewards_arr[i]) for i, a in enumerate(agents)}
        terminations = dict.fromkeys(agents, terminated)
        truncations = dict.fromkeys(agents, truncated and not terminated)
        infos = {a: dict(info) for a in agents}
        if truncated or terminated:
            self.agents = []
        if self.render_mode == "human":
            self.render()
        return observations, rewards, terminations, truncations, infos

    # ------------------------------------------------------------------ helpers
    def _decode_actions(self, actions: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
        """Turn the action dict into ``(n, 2)`` unit moves and ``(n,)`` communication choices."""
        if self.config.continuous_actions:
            act = np.zeros((self.n, 3))
            for i, agent in enumerate(self.agents):
                if actions.get(agent) is not None:
                    act[i] = actions[agent]
            if not np.all(np.isfinite(act)):
                raise ValueError(f"continuous actions must be finite, got {act}")
            act = np.clip(act, -1.0, 1.0)
            comm = np.select([act[:, 2] > 1 / 3, act[:, 2] < -1 / 3], [COMM_BROADCAST, COMM_QUERY], COMM_NONE)
            return act[:, :2], comm
        try:
            act = np.array([actions[agent] for agent in self.agents], dtype=np.int64).reshape(-1)
        except (KeyError, TypeError):  # a missing or None action means "stay, no message"
            act = np.array([actions.get(agent) or 0 for agent in self.agents], dtype=np.int64).reshape(-1)
        if act.size != self.n or act.min() < 0 or act.max() >= N_MOVES * N_COMMS:
            raise ValueError(f"discrete actions must be {self.n} ints in [0, {N_MOVES * N_COMMS - 1}], got {act}")
        return actors.STEPS[act % N_MOVES].astype(np.float64), act // N_MOVES

    def _uav_cells(self) -> np.ndarray:
        return np.floor(self.uav_pos).astype(np.int64)

    def _set_window(self, cells: np.ndarray) -> None:
        """Flat indices ``(n, w, w)`` of each UAV's observation window in the padded grids."""
        self._window = (cells[:, 0] * self._padded_shape[1] + cells[:, 1])[:, None, None] + self._win_offsets

    def _poacher_targets(self) -> np.ndarray:
        """Each poacher heads for a live leopard within sight, else for its planned den."""
        target = self.poacher_target
        if self.leopard_alive.any() and len(self.poacher_pos):
            d = np.abs(self.poacher_pos[:, None] - self.leopard_pos[None]).max(-1).astype(np.float64)
            d[:, ~self.leopard_alive] = np.inf
            nearest = d.argmin(axis=1)
            in_sight = d[np.arange(len(d)), nearest] <= actors.POACHER_SIGHT
            target = np.where(in_sight[:, None], self.leopard_pos[nearest], target)
        return target

    def _sense(self, cells: np.ndarray, airborne: np.ndarray, active: np.ndarray, signals: np.ndarray) -> np.ndarray:
        """Draw detections of poachers and leopards by every airborne UAV and mark them in ``signals`` (n, 2, w, w).

        :return: ``(n, n_poachers)`` bool of which UAV detected which poacher
        """
        n_poachers = len(self.poacher_pos)
        targets = np.concatenate([self.poacher_pos, self.leopard_pos])
        if not len(targets):
            return np.zeros((self.n, 0), dtype=bool)
        present = np.concatenate([active, self.leopard_alive])
        moved = np.concatenate([self.poacher_moved, self.leopard_moved])
        delta = targets[None, :, :] - cells[:, None, :]
        dist = np.minimum(np.abs(delta).max(-1), self.r + 1)
        p = self._detect_table[dist, self.terrain[targets[:, 0], targets[:, 1]][None], moved.astype(np.int64)[None]]
        seen = (self.rng.random(p.shape) < p) & present[None] & airborne[:, None]
        uav, tgt = np.nonzero(seen)
        signals[uav, (tgt >= n_poachers).astype(np.int64), delta[uav, tgt, 0] + self.r, delta[uav, tgt, 1] + self.r] = 1.0
        return seen[:, :n_poachers]

    def _false_alarms(self, cells: np.ndarray, airborne: np.ndarray, channel: np.ndarray) -> np.ndarray:
        """Spurious poacher readings (sensor noise, adversarial decoys), marked in ``channel``.

        :return: ``(k, 3)`` readings ``(uav, row, col)``
        """
        cfg = self.config
        alarm = (self.rng.random(self.n) < sensing.false_alarm_probability(cfg.sensor_noise)) & airborne
        spot = (self.rng.random(self.n) * len(self._reach_offsets)).astype(np.int64)
        uav = np.flatnonzero(alarm)
        offsets = self._reach_offsets[spot[uav]]
        if len(self.decoy_pos):
            delta = self.decoy_pos[None, :, :] - cells[:, None, :]
            dist = np.abs(delta).max(-1)
            p = sensing.DECOY_PEAK * sensing.range_falloff(dist, self.r, self.reach) * (1 - 0.5 * cfg.sensor_noise)
            d_uav, d_idx = np.nonzero((self.rng.random(p.shape) < p) & airborne[:, None])
            uav = np.concatenate([uav, d_uav])
            offsets = np.concatenate([offsets, delta[d_uav, d_idx]])
        where = cells[uav] + offsets
        keep = (where >= 0).all(-1) & (where < [self.height, self.width]).all(-1)  # no readings off the map
        uav, offsets = uav[keep], offsets[keep]
        channel[uav, offsets[:, 0] + self.r, offsets[:, 1] + self.r] = 1.0
        self.metrics["false_alarms"] += len(uav)
        return np.column_stack([uav, where[keep]])

    def _covered(self) -> int:
        """High-risk cells seen so far this episode."""
        return int(np.count_nonzero(self.visited.ravel()[self._high_risk_flat]))

    def _mark_own_visits(self, airborne: np.ndarray) -> np.ndarray:
        """Record what each airborne UAV sees now: the team's coverage and each UAV's own visit history.

        :return: ``(n,)`` high-risk cells each UAV saw for the first time in the episode
        """
        idx = np.flatnonzero(airborne)
        seen = self._window.reshape(self.n, -1)[idx]
        visited = self.visited.ravel()
        fresh = np.zeros(self.n, dtype=np.int64)
        fresh[idx] = (self._high_risk_pad[seen] & ~visited[seen]).sum(axis=1)
        visited[seen] = True
        own = (idx[:, None] * self._cells_padded + seen).ravel()
        self.own_last.ravel()[own] = self.t
        first = self.own_first.ravel()
        first[own] = np.minimum(first[own], self.t)
        blocks = self._block.ravel()[(cells := self._uav_cells()[idx])[:, 0] * self.width + cells[:, 1]]
        self._block_stamps[0, idx, blocks] = self.t
        self._block_stamps[1, idx, blocks] = np.minimum(self._block_stamps[1, idx, blocks], self.t)
        self.knowledge[idx, idx] = self.t
        return fresh

    def _in_range(self, airborne: np.ndarray) -> np.ndarray:
        """``(n, n)`` bool: s and r (s != r) are airborne, unjammed and within ``R_c`` of each other."""
        diff = self.uav_pos[:, None, :] - self.uav_pos[None, :, :]
        self._dist = np.sqrt((diff**2).sum(-1))
        ok = airborne.copy()
        if self.jammer_on:
            self.jammed = np.sqrt(((self.uav_pos - self.jammer_pos) ** 2).sum(-1)) <= self.config.jam_radius
            ok &= ~self.jammed
        else:
            self.jammed[:] = False
        links = (self._dist <= self.config.comm_radius) & ok[:, None] & ok[None, :]
        np.fill_diagonal(links, False)
        return links

    def _update_beacons(self, airborne: np.ndarray) -> np.ndarray:
        """Position beacons heard this step (lost with probability ``comm_loss``); returns the link matrix."""
        links = self._in_range(airborne)
        self.beacons = links & (self.rng.random(links.shape) >= self.config.comm_loss)
        return links

    def _communicate(self, comm: np.ndarray, airborne: np.ndarray) -> None:
        """Broadcasts push and queries pull each UAV's knowledge; each message is lost with ``comm_loss``."""
        links = self._update_beacons(airborne)
        sent = links & (comm == COMM_BROADCAST)[:, None]
        asking = np.flatnonzero(comm == COMM_QUERY)
        if len(asking):
            dist = np.where(links[:, asking], self._dist[:, asking], np.inf)
            source = dist.argmin(axis=0)
            reachable = np.isfinite(dist[source, np.arange(len(asking))])
            sent[source[reachable], asking[reachable]] = True
        delivered = sent & (self.rng.random(sent.shape) >= self.config.comm_loss)
        self.comm_links = delivered
        if delivered.any():
            # knowledge[r] = max(knowledge[r], knowledge[s] for every s whose message reached r)
            incoming = np.where(delivered.T[:, :, None], self.knowledge[None, :, :], NEVER).max(axis=1)
            self.knowledge = np.maximum(self.knowledge, incoming)

    def _known_age(self, last: np.ndarray, first: np.ndarray) -> np.ndarray:
        """Age in [0, 1] (1 = never) of the newest visit each receiver knows of, from per-source stamps.

        UAV r knows UAV s's visits up to ``knowledge[r, s]``: s's last visit if it is that old, else
        s's first visit if that one is, else nothing.

        :param last: ``(source, receiver, ...)`` last-visit times
        :param first: ``(source, receiver, ...)`` first-visit times
        :return: ``(receiver, ...)`` ages scaled by ``max_cycles``
        """
        known_to = self.knowledge.T.reshape(self.n, self.n, *([1] * (last.ndim - 2)))  # knowledge[receiver, source]
        seen = np.where(last <= known_to, last, np.where(first <= known_to, first, NEVER)).max(axis=0)
        return np.minimum((np.float32(self.t) - seen) * np.float32(1.0 / self.max_cycles), np.float32(1.0))

    def _staleness(self) -> tuple[np.ndarray, np.ndarray]:
        """Time since each window cell ``(n, w, w)`` and each coarse block ``(n, belief_size^2)`` was seen,
        as far as each UAV knows (before it looks this step)."""
        src = np.arange(self.n)[:, None, None] * self._cells_padded
        cells = np.take(self._stamps.reshape(2, -1), src + self._window.reshape(1, self.n, -1), axis=1)
        blocks = np.broadcast_to(self._block_stamps[:, :, None, :], (2, self.n, self.n, self._block_stamps.shape[-1]))
        last, first = np.concatenate([cells, blocks], axis=-1)  # (source, receiver, w * w + blocks)
        ages = self._known_age(last, first)
        return ages[:, : self.window**2].reshape(self.n, self.window, self.window), ages[:, self.window**2:]

    def _belief(self) -> np.ndarray:
        """``(n, belief_size^2)`` poacher activity from the readings each UAV knows of, in [0, 1)."""
        size = self.config.belief_size**2
        if not len(self._events):
            return np.zeros((self.n, size), dtype=np.float32)
        times, who, block = self._events.T
        known = times[None, :] <= self.knowledge[:, who.astype(np.int64)]
        weight = known * self.config.belief_decay ** (self.t - times)[None, :]
        onehot = np.zeros((len(block), size))
        onehot[np.arange(len(block)), block.astype(np.int64)] = 1.0
        mass = weight @ onehot
        return 1.0 - np.exp(-mass)

    def _observations(self, signals: np.ndarray) -> np.ndarray:
        cfg = self.config
        cells = self._uav_cells()
        obs = np.empty((self.n, self.obs_dim), dtype=np.float32)
        n_win = N_CHANNELS * self.window**2
        win = obs[:, :n_win].reshape(self.n, N_CHANNELS, self.window, self.window)
        win[:, CH_OCCLUSION] = self._occ_pad[self._window]
        win[:, CH_RISK] = self._risk_pad[self._window]
        win[:, CH_STALENESS] = self._stale_window
        win[:, CH_POACHER:CH_LEOPARD + 1] = signals
        if cfg.sensor_noise > 0:
            noisy = signals + self.rng.normal(0.0, SIGNAL_NOISE_STD * cfg.sensor_noise, signals.shape)
            win[:, CH_POACHER:CH_LEOPARD + 1] = np.clip(noisy, 0.0, 1.0)
        # Other airborne UAVs inside the window (seen, not communicated).
        delta = cells[None, :, :] - cells[:, None, :]  # delta[i, j] = cell_j - cell_i
        visible = (np.abs(delta).max(-1) <= self.r) & ~self.grounded[None, :]
        np.fill_diagonal(visible, False)
        i, j = np.nonzero(visible)
        win[:, CH_UAV] = 0.0
        win[i, CH_UAV, delta[i, j, 0] + self.r, delta[i, j, 1] + self.r] = 1.0
        if self.grounded.any():
            win[self.grounded, CH_POACHER:] = 0.0

        # Own position, velocity, battery and episode progress.
        own = obs[:, n_win:n_win + 6]
        own[:, :2] = np.minimum(self.uav_pos * self._inv_scale, 1.0)
        own[:, 2:4] = self.velocity
        own[:, 4] = self.battery
        own[:, 5] = min(self.t / self.max_cycles, 1.0)
        # Neighbours heard through beacons, nearest first.
        k = cfg.max_neighbors
        neighbours = obs[:, n_win + 6:n_win + 6 + 3 * k].reshape(self.n, k, 3)
        neighbours[:] = 0.0
        if k and self.n > 1:
            diff = self.uav_pos[None, :, :] - self.uav_pos[:, None, :]  # diff[r, s] = pos_s - pos_r
            dist = np.where(self.beacons.T, np.sqrt((diff**2).sum(-1)), np.inf)
            order = np.argsort(dist, axis=1, kind="stable")[:, :k]
            rows = np.arange(self.n)[:, None]
            present = dist[rows, order] < np.inf
            rel = diff[rows, order] * (1.0 / max(cfg.comm_radius, 1.0))
            m = order.shape[1]
            neighbours[:, :m, :2] = np.minimum(np.maximum(rel, -1.0), 1.0) * present[:, :, None]
            neighbours[:, :m, 2] = present
        size = cfg.belief_size**2
        obs[:, n_win + 6 + 3 * k:n_win + 6 + 3 * k + size] = self._stale_blocks
        obs[:, n_win + 6 + 3 * k + size:] = self._belief()
        return obs

    # ------------------------------------------------------------------ public extras
    @functools.cached_property
    def observation_layout(self) -> dict[str, tuple[slice, tuple[int, ...]]]:
        """Where each part of the flat observation lives: name -> (slice, shape).

        ``window`` (6, w, w) channels (occlusion, risk, staleness, poacher, leopard, UAVs); ``own``
        (row, col, d_row, d_col, battery, progress); ``neighbours`` (max_neighbors, 3) as (d_row, d_col,
        present) / ``R_c``; ``block_staleness`` (time since each block was flown over, as far as the UAV
        knows) and ``belief`` (poacher activity) maps, both (belief_size, belief_size).
        """
        k, b = self.config.max_neighbors, self.config.belief_size
        shapes = {"window": (N_CHANNELS, self.window, self.window), "own": (6,), "neighbours": (k, 3),
                  "block_staleness": (b, b), "belief": (b, b)}
        layout, start = {}, 0
        for name, shape in shapes.items():
            size = int(np.prod(shape))
            layout[name] = (slice(start, start + size), shape)
            start += size
        return layout

    def split_observation(self, obs: np.ndarray) -> dict[str, np.ndarray]:
        """Split flat observations ``(..., obs_dim)`` into their named parts (see :attr:`observation_layout`)."""
        obs = np.asarray(obs)
        layout = self.observation_layout
        return {name: obs[..., part].reshape(*obs.shape[:-1], *shape) for name, (part, shape) in layout.items()}

    def episode_metrics(self) -> dict[str, float]:
        """The episode's metrics so far (what ``infos[agent]["metrics"]`` holds at the end).

        ``coverage_efficiency`` is the share of high-risk cells seen; ``detection_rate`` the share of
        entered poachers detected (0 if none entered); ``time_to_first_detection`` counts steps from
        the first entry to the first true detection, and runs to the current step when none happened.
        """
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
            "episode_length": int(self.t),
            "mode": int(self.mode),
        }

    def state(self) -> np.ndarray:
        """The global state (positions, batteries, poachers, leopards, coverage by block, progress), in [-1, 1]."""
        scale = np.array([max(self.height - 1, 1), max(self.width - 1, 1)])
        uavs = np.column_stack([self.uav_pos / scale, self.battery, self.grounded])
        poachers = np.column_stack([self.poacher_pos / scale, self.poacher_status == POACHER_ACTIVE,
                                    self.poacher_status / POACHER_GONE])
        leopards = np.column_stack([self.leopard_pos / scale, self.leopard_alive])
        size = self.config.belief_size**2
        inner = self.visited[self.r:self.r + self.height, self.r:self.r + self.width] & self.high_risk
        seen = np.bincount(self._block.ravel(), weights=inner.ravel(), minlength=size)
        total = np.bincount(self._block.ravel(), weights=self.high_risk.ravel(), minlength=size)
        coverage = np.divide(seen, total, out=np.zeros(size), where=total > 0)
        parts = [uavs.ravel(), poachers.ravel(), leopards.ravel(), coverage, [min(self.t / self.max_cycles, 1.0)]]
        return np.clip(np.concatenate(parts), -1.0, 1.0).astype(np.float32)

    def render(self) -> np.ndarray | None:
        """Draw the reserve with pygame: an RGB array in ``"rgb_array"`` mode, a window in ``"human"`` mode."""
        if self.render_mode is None:
            import gymnasium

            gymnasium.logger.warn("render() called without a render_mode; pass render_mode='rgb_array' or 'human'.")
            return None
        from wildlife_reserve.reserve.rendering import ReserveRenderer

        if self._renderer is None:
            self._renderer = ReserveRenderer(self, self.render_mode)
        return self._renderer.draw()

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
