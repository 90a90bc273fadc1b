"""ZonePatrol's world: the state of ``n_copies`` independent copies as arrays, stepped together.

The PettingZoo face (:mod:`~wildlife_reserve.zone_patrol.zone_patrol`) is one copy of this world; a vector
environment can step many copies in one call (every array has the copies first). The random numbers of a step are
drawn by numpy in one go (one generator serves the batch); the step and the observations are compiled loops
(:mod:`~wildlife_reserve.zone_patrol.kernels`).
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from wildlife_reserve.utils.checks import check_bool, check_float, check_int
from wildlife_reserve.zone_patrol import kernels

#: Sensors: the action is ``move + N_MOVES * sensor``.
WIDE, NARROW = 0, 1
N_MOVES, N_SENSORS = 5, 2
CLEAR, FOG = 0, 1
N_WEATHERS = 2
#: The four corner zones (mode = N_WEATHERS * zone + weather).
N_ZONES = 4
#: Window channels: tracks (remaining life / track_life; -1 off the grid), this UAV's detections this step, teammates.
N_CHANNELS = 3


@dataclass(frozen=True)
class ZonePatrolConfig:
    """Every argument of ZonePatrol, validated once (each error names the argument and what is allowed).

    :param grid_size: side of the square grid
    :param n_uavs: UAVs in the team
    :param max_cycles: steps per episode
    :param zone_size: side of each of the four corner zones
    :param spawn_prob: chance per step that an intruder appears in the mode's zone
    :param intruder_life: steps an intruder stays before it escapes (undetected: ``escape_cost``)
    :param intruder_move_prob: chance per step that an intruder steps to a neighbouring cell of its zone
    :param track_life: steps a track lasts (an intruder leaves one on its cell every step)
    :param initial_tracks: tracks lying in the mode's zone at the episode's start (of random ages)
    :param wide_radius: Chebyshev reach of the wide sensor
    :param narrow_radius: Chebyshev reach of the narrow sensor
    :param wide_detect: ``(clear, fog)`` chance per step that the wide sensor detects an intruder within reach
    :param narrow_detect: the same for the narrow sensor
    :param visibility_noise: standard deviation of the visibility reading (1 in clear weather, 0 in fog, plus noise)
    :param zone_cue: strength of a faint reading of the zone that reaches every UAV wherever it is (radio chatter):
        each step, per zone, ``zone_cue`` if it is the mode's zone, plus standard normal noise; 0: no such reading,
        episodes and observations as without the option (``zone_patrol_v0``'s default). Its evidence builds up as
        ``zone_cue * sqrt(steps)``: a team can infer the zone without searching, if it integrates the readings over
        time. The default was chosen on the gate (``benchmarks/zone_patrol_gate.py``; docs/zone_patrol.md): told
        scripted teams must still earn far more than blind ones, while the whole team's readings tell the zone by
        mid-episode
    :param comm_range: Chebyshev distance within which teammates hear each other (``infos["heard_from"]``); None (the
        default): half the grid, which keeps a team that splits over the four zones linked through relays, so that
        its evidence reaches every UAV within a few steps (``zone_patrol_v0``: 4; ``benchmarks/zone_patrol_reach.py``)
    :param escape_cost: team reward lost per intruder that escapes
    :param window_radius: radius of the observed window (``(2r + 1)^2`` cells per channel)
    :param agent_ids: append the one-hot of the UAV's index in the team to its observation (EPyMARL's
        ``obs_agent_id``): with parameter sharing, what lets UAVs that see alike act apart, as a blind team that splits
        over the zones must
    :param told: append the one-hot of the hidden mode to every observation (the told oracle)
    """

    grid_size: int = 28
    n_uavs: int = 4
    max_cycles: int = 60
    zone_size: int = 6
    spawn_prob: float = 0.5
    intruder_life: int = 3
    intruder_move_prob: float = 0.5
    track_life: int = 12
    initial_tracks: int = 4
    wide_radius: int = 2
    narrow_radius: int = 1
    wide_detect: tuple[float, float] = (0.4, 0.03)
    narrow_detect: tuple[float, float] = (0.3, 0.3)
    visibility_noise: float = 1.0
    zone_cue: float = 0.24
    comm_range: int | None = None
    escape_cost: float = 0.25
    window_radius: int = 2
    agent_ids: bool = False
    told: bool = False

    def __post_init__(self) -> None:
        check_int("grid_size", self.grid_size, 6, 256)
        check_int("n_uavs", self.n_uavs, 1, 64)
        check_int("max_cycles", self.max_cycles, 1, 100_000)
        check_int("zone_size", self.zone_size, 1, self.grid_size // 2)
        check_float("spawn_prob", self.spawn_prob, 0.0, 1.0)
        check_int("intruder_life", self.intruder_life, 1, 10_000)
        check_float("intruder_move_prob", self.intruder_move_prob, 0.0, 1.0)
        check_int("track_life", self.track_life, 1, 10_000)
        check_int("initial_tracks", self.initial_tracks, 0, self.zone_size ** 2)
        check_int("wide_radius", self.wide_radius, 0, self.grid_size)
        check_int("narrow_radius", self.narrow_radius, 0, self.grid_size)
        for name in ("wide_detect", "narrow_detect"):
            value = getattr(self, name)
            if isinstance(value, (str, bytes)) or not hasattr(value, "__len__") or len(value) != N_WEATHERS:
                raise ValueError(f"{name} must be a pair (clear, fog) of chances in [0, 1], got {value!r}")
            object.__setattr__(self, name, tuple(check_float(f"{name}[{i}]", v, 0.0, 1.0) for i, v in enumerate(value)))
        check_float("visibility_noise", self.visibility_noise, 0.0, 100.0)
        check_float("zone_cue", self.zone_cue, 0.0, 100.0)
        if self.comm_range is None:
            object.__setattr__(self, "comm_range", self.grid_size // 2)
        check_int("comm_range", self.comm_range, 0, self.grid_size)
        check_float("escape_cost", self.escape_cost, 0.0, 1000.0)
        check_int("window_radius", self.window_radius, 0, self.grid_size)
        for name in ("agent_ids", "told"):
            check_bool(name, getattr(self, name))

    @classmethod
    def from_kwargs(cls, **kwargs) -> ZonePatrolConfig:
        names = {f.name for f in fields(cls)}
        unknown = sorted(set(kwargs) - names)
        if unknown:
            raise ValueError(f"unknown ZonePatrol argument(s) {unknown}; allowed: {sorted(names)}")
        return cls(**kwargs)

    @property
    def n_modes(self) -> int:
        """Hidden modes: 4 zones x 2 weathers (mode = 2 * zone + weather)."""
        return N_ZONES * N_WEATHERS

    @property
    def window_cells(self) -> int:
        return (2 * self.window_radius + 1) ** 2

    @property
    def obs_dim(self) -> int:
        """Window channels, own position (2), the visibility reading, the episode's progress, [the zone readings (4)],
        [the UAV's index as a one-hot], [the told one-hot]."""
        return (N_CHANNELS * self.window_cells + 4 + (N_ZONES if self.zone_cue else 0) + (self.n_uavs if self.agent_ids else 0)
                + (self.n_modes if self.told else 0))

    @property
    def state_dim(self) -> int:
        """UAV positions, the intruders' map, the tracks' map and the episode's progress."""
        return 2 * self.n_uavs + 2 * self.grid_size ** 2 + 1

    def zone_origins(self) -> np.ndarray:
        """``(4, 2)`` top-left cells of the four corner zones."""
        far = self.grid_size - self.zone_size
        return np.array([[0, 0], [0, far], [far, 0], [far, far]], dtype=np.int64)


def max_intruders(config: ZonePatrolConfig) -> int:
    """Most intruders a copy holds at once (``intruder_life`` steps of at most one spawn per step, and a margin)."""
    return config.intruder_life + 1


class ZonePatrolWorld:
    """``n_copies`` copies of ZonePatrol as arrays (copies first), stepped together.

    :param config: the arguments
    :param n_copies: copies
    """

    def __init__(self, config: ZonePatrolConfig, n_copies: int = 1) -> None:
        self.config = config
        self.n_copies = check_int("n_copies", n_copies, 1, 1_000_000)
        c, n, g, m = n_copies, config.n_uavs, config.grid_size, max_intruders(config)
        self.positions = np.zeros((c, n, 2), dtype=np.int64)
        self.intruders = np.zeros((c, m, 2), dtype=np.int64)
        self.ages = np.zeros((c, m), dtype=np.int64)
        self.alive = np.zeros((c, m), dtype=bool)
        self.tracks = np.zeros((c, g, g), dtype=np.int64)
        self.modes = np.zeros(c, dtype=np.int64)
        self.t = 0
        self.detections = np.zeros((c, n, m), dtype=bool)  # which UAV detected which intruder this step
        self.detected_cells = np.zeros((c, m, 2), dtype=np.int64)  # and where
        self.caught = np.zeros(c, dtype=np.int64)
        self.escaped = np.zeros(c, dtype=np.int64)
        self.spawned = np.zeros(c, dtype=np.int64)
        self.team_reward = np.zeros(c)
        self.visibility = np.zeros((c, n))
        self.cues = np.zeros((c, n, N_ZONES if config.zone_cue else 0))  # the zone readings (zone_cue > 0)
        self.sensors = np.zeros((c, n), dtype=np.int64)
        radii = np.array([config.wide_radius, config.narrow_radius], dtype=np.int64)
        chances = np.array([config.wide_detect, config.narrow_detect], dtype=np.float64)  # (sensor, weather)
        self._rules = kernels.Rules(radii, chances, int(config.grid_size), int(config.zone_size),
                                    int(config.intruder_life), float(config.intruder_move_prob),
                                    float(config.spawn_prob), int(config.track_life))
        self._layout = kernels.Layout(int(config.window_radius), int(config.track_life), bool(config.agent_ids))
        self._subsets: list[tuple[int, ...]] | None = None
        # Made once (each step reads them): the zones' corners, the link masks' bits, the not-itself mask, the counts.
        self._origins = config.zone_origins()
        self._bits = 1 << np.arange(config.n_uavs)
        self._others = ~np.eye(config.n_uavs, dtype=bool)[None]
        self._counts = kernels.Counts(*(np.zeros(c, dtype=np.int64) for _ in range(3)))
        self._track_values = (np.arange(config.track_life + 1) / config.track_life).astype(np.float32)  # by life left
        # The kernels' records of the arrays above, made once (the arrays are changed in place from here on).
        self._team = kernels.Team(self.positions, self.sensors, self.detections)
        self._intruders = kernels.Intruders(self.intruders, self.ages, self.alive, self.detected_cells, self.tracks)

    # ------------------------------------------------------------------ episode
    @property
    def zones(self) -> np.ndarray:
        return self.modes // N_WEATHERS

    @property
    def weathers(self) -> np.ndarray:
        return self.modes % N_WEATHERS

    def reset(self, rng: np.random.Generator, modes: np.ndarray | None = None) -> None:
        """New episodes in every copy: modes drawn uniformly (or given), UAVs near the centre, old tracks in the zone."""
        cfg, c = self.config, self.n_copies
        if modes is None:
            modes = rng.integers(cfg.n_modes, size=c)
        modes = np.asarray(modes, dtype=np.int64).reshape(c)
        if modes.min() < 0 or modes.max() >= cfg.n_modes:
            raise ValueError(f"mode must be an int in [0, {cfg.n_modes - 1}], got {modes.tolist()}")
        self.modes = modes
        # What each step reads of the modes, fixed for the episode: its zones' corners, weathers, clear skies, zone signal.
        self._origins_now, self._weathers_now = self._origins[self.zones], self.weathers
        self._clear_now = (self._weathers_now == CLEAR).astype(np.float64)[:, None]
        self._signal_now = cfg.zone_cue * (np.arange(N_ZONES)[None, :] == self.zones[:, None])  # (c, 4)
        centre = cfg.grid_size // 2
        self.positions[:] = centre - 2 + rng.integers(4, size=(c, cfg.n_uavs, 2))  # (in place: the records hold it)
        self.alive[:] = False
        self.ages[:] = 0
        self.tracks[:] = 0
        if cfg.initial_tracks:
            origin = cfg.zone_origins()[self.zones]  # (c, 2)
            cells = np.argsort(rng.random((c, cfg.zone_size ** 2)), axis=1)[:, :cfg.initial_tracks]
            rows = origin[:, :1] + cells // cfg.zone_size
            cols = origin[:, 1:] + cells % cfg.zone_size
            life = rng.integers(1, cfg.track_life + 1, size=rows.shape)
            self.tracks[np.arange(c)[:, None], rows, cols] = life
        self.t = 0
        self.detections[:] = False
        self.caught[:] = 0
        self.escaped[:] = 0
        self.spawned[:] = 0
        self.team_reward[:] = 0.0
        self.sensors[:] = WIDE
        self.visibility = self._read_visibility(rng)
        self.cues = self._read_cues(rng)

    def _read_visibility(self, rng: np.random.Generator) -> np.ndarray:
        return self._clear_now + self.config.visibility_noise * rng.standard_normal((self.n_copies, self.config.n_uavs))

    def _read_cues(self, rng: np.random.Generator) -> np.ndarray:
        """The zone readings ``(c, n, 4)`` (none without ``zone_cue``: nothing is drawn, the episodes stay as they were)."""
        if not self.config.zone_cue:
            return self.cues
        return self._signal_now[:, None, :] + rng.standard_normal((self.n_copies, self.config.n_uavs, N_ZONES))

    def step(self, actions: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """One step of every copy; ``actions`` ``(n_copies, n_uavs)`` ints in ``[0, 10)``. Returns the team rewards.

        In order: the UAVs move and set their sensors; each sensor detects each live intruder within its reach with
        its weather's chance (detected intruders leave); the others age and escape at the end of their lives; tracks
        fade; intruders wander within their zone; a new one may appear in the mode's zone; every live intruder leaves
        a track on its cell (:func:`~wildlife_reserve.zone_patrol.kernels.advance`, one compiled pass)."""
        cfg, c, m = self.config, self.n_copies, self.alive.shape[1]
        draws = kernels.Draws(rng.random((c, cfg.n_uavs, m)), rng.random((c, m)), rng.integers(4, size=(c, m)),
                              rng.random(c), rng.integers(cfg.zone_size, size=(c, 2)))
        counts = self._counts
        for count in counts:
            count[:] = 0
        kernels.advance(np.ascontiguousarray(actions, dtype=np.int64), self._team, self._intruders,
                        self._origins_now, self._weathers_now, draws, self._rules, counts)
        found, escaped, spawned = counts
        self.caught += found
        self.escaped += escaped
        self.spawned += spawned
        rewards = found - cfg.escape_cost * escaped
        self.team_reward += rewards
        self.visibility = self._read_visibility(rng)
        self.cues = self._read_cues(rng)
        self.t += 1
        return rewards.astype(np.float64)

    # ------------------------------------------------------------------ what the UAVs see
    def observations(self) -> np.ndarray:
        """``(n_copies, n_uavs, obs_dim)`` float32 observations (see the card;
        :func:`~wildlife_reserve.zone_patrol.kernels.observe`)."""
        cfg = self.config
        out = np.empty((self.n_copies, cfg.n_uavs, cfg.obs_dim), dtype=np.float32)
        readings = kernels.Readings(self.visibility, self.cues, self.modes if cfg.told else self.modes[:0],
                                    self.t / cfg.max_cycles)
        kernels.observe(self._team, self._intruders, readings, self._layout, out)
        return out

    def near(self) -> np.ndarray:
        """``(n_copies, n_uavs, n_uavs)``: whether teammate ``j`` is within ``comm_range`` of UAV ``i`` (never itself)."""
        gap = np.abs(self.positions[:, :, None, :] - self.positions[:, None, :, :]).max(-1)
        return (gap <= self.config.comm_range) & self._others

    def links(self) -> list[list[tuple[int, ...]]]:
        """``[copy][uav]``: the teammates within ``comm_range`` (the UAV's ``heard_from``), each a sorted tuple."""
        n = self.config.n_uavs
        if self._subsets is None:  # every set of teammates as a tuple, by its bit mask (n <= 16 here)
            self._subsets = [tuple(j for j in range(n) if mask >> j & 1) for mask in range(1 << n)] if n <= 16 else []
        near = self.near()
        if not self._subsets:
            return [[tuple(np.flatnonzero(row).tolist()) for row in copy] for copy in near]
        masks = near @ self._bits
        subsets = self._subsets
        return [[subsets[m] for m in row] for row in masks.tolist()]

    def states(self) -> np.ndarray:
        """``(n_copies, state_dim)`` float32 global states (for centralised critics): the UAVs' positions in [-1, 1],
        the intruders' map, the tracks' map (a track's life over ``track_life``) and the episode's progress. Written into
        one array (each value as the float64 expression rounded to float32, as when the parts were concatenated)."""
        cfg = self.config
        c, g, head = self.n_copies, cfg.grid_size, 2 * cfg.n_uavs
        out = np.zeros((c, cfg.state_dim), dtype=np.float32)
        out[:, :head] = (self.positions / max(g - 1, 1) * 2.0 - 1.0).reshape(c, -1)
        cc, mm = np.nonzero(self.alive)
        out[:, head:head + g * g].reshape(c, g, g)[cc, self.intruders[cc, mm, 0], self.intruders[cc, mm, 1]] = 1.0
        out[:, head + g * g:head + 2 * g * g] = self._track_values[self.tracks.reshape(c, -1)]
        out[:, -1] = self.t / cfg.max_cycles
        return out

    def metrics(self) -> list[dict[str, float]]:
        """Each copy's episode metrics so far."""
        out = []
        for i in range(self.n_copies):
            total = self.caught[i] + self.escaped[i]
            out.append({"team_reward": float(self.team_reward[i]), "detections": float(self.caught[i]),
                        "escapes": float(self.escaped[i]), "intruders": float(self.spawned[i]),
                        "detection_rate": float(self.caught[i] / total) if total else 0.0, "mode": int(self.modes[i])})
        return out
