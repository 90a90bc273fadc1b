"""The reserve's keyword arguments: defaults, allowed ranges and validation, in one place.

:meth:`ReserveConfig.from_kwargs` is the one gate of ``reserve_v1.parallel_env`` / ``env`` / ``raw_env``: it
rejects unknown argument names, and :class:`ReserveConfig` checks the type and range of every value
before the environment allocates anything. Every rejection is a :class:`ValueError` whose message
names the argument, shows the value (abbreviated if long) and says what is allowed.

The upper bounds (the ``MAX_*`` constants) keep the largest configuration within a few hundred MB and
a few seconds per reset and step: the environment's memory grows with ``n_uavs x cells`` (each UAV
keeps two time stamps per cell) and its time with ``n_uavs^2 x (window cells + belief blocks)`` (what
each UAV knows of each teammate's visits). The measurements behind them are in ``docs/env.md``
(Arguments).
"""

from __future__ import annotations

import difflib
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

from wildlife_reserve.reserve.modes import N_MODES, STRATEGIES
from wildlife_reserve.reserve.terrain import REGIONS, TERRAIN_NAMES, as_risk
from wildlife_reserve.utils.checks import check_array, check_bool, check_float, check_int, show

N_STRATEGIES = len(STRATEGIES)

#: Default weights of the team reward terms (see the environment card).
DEFAULT_REWARD_WEIGHTS: dict[str, float] = {
    "detection": 10.0,  # per poacher detected for the first time
    "coverage": 0.05,  # per high-risk cell seen for the first time this episode
    "sign": 0.1,  # per sign of poacher activity (track, snare, camp, ...) the team finds for the first time
    "poaching": 20.0,  # penalty per poaching event
    "collision": 1.0,  # penalty per pair of UAVs in one cell
    "energy": 1.0,  # penalty per unit of battery spent (a full battery is 1)
}

#: Named scenarios: each is a set of the arguments below, which explicit arguments override (``reward_weights`` merged
#: key by key). ``zone_raids``: each poacher strategy strikes its own zone (``strategy_zones``) with two leopards, 16
#: poachers an episode, the ranger's map of the zones (``compass``); detections and poaching weigh, coverage and signs
#: (which pay the same in every mode) nothing. See the environment card, "Zone raids".
SCENARIOS: dict[str, dict[str, Any]] = {
    "zone_raids": {"strategy_zones": True, "compass": True, "n_leopards": 8, "n_poachers": 16,
                   "reward_weights": {"coverage": 0.0, "sign": 0.0}},
}

#: Battery spent per step: hovering, flying a full ``uav_speed``, broadcasting, querying a neighbour.
ENERGY_COSTS: dict[str, float] = {"hover": 0.0005, "move": 0.002, "broadcast": 0.003, "query": 0.0015}

# ---------------------------------------------------------------------- upper bounds (see docs/env.md, Arguments)
#: Most UAVs (the paper runs up to 200).
MAX_UAVS = 1000
#: Longest side of the grid, in cells.
MAX_SIDE = 1000
#: Most ``n_uavs * (height + 2 * sensor_radius) * (width + 2 * sensor_radius)``: every UAV keeps two time stamps (its
#: first and last look) per cell of the padded grid, int16 (int32 from 32,767 steps), so this caps them at 100 MB
#: (200 MB).
MAX_UAV_CELLS = 25_000_000
#: Longest episode. What a UAV knows of a teammate is a float32 time with "never" at -1e6, so staleness needs
#: ``max_cycles`` well below 1e6.
MAX_CYCLES = 100_000
#: Most leopards, poachers and decoys (each).
MAX_ACTORS = 1000
#: Largest sensing radius (a 21 x 21 window): the per-step cost grows with ``n_uavs^2 * (2r + 1)^2``.
MAX_SENSOR_RADIUS = 10
#: Largest side of the coarse maps: the per-step cost grows with ``n_uavs^2 * belief_size^2``.
MAX_BELIEF_SIZE = 16
#: Side of the coarse maps when ``belief_size`` is ``None`` (on grids at least this large).
DEFAULT_BELIEF_SIZE = 8
#: Most neighbour slots in the observation (more than ``MAX_UAVS - 1`` could never be filled).
MAX_NEIGHBORS = MAX_UAVS
#: Largest distance or speed in cells (comm_radius, jam_radius, leopard_range, uav_speed). The diagonal of the
#: largest grid is 1415 cells, so larger values change nothing.
MAX_DISTANCE = 10_000.0
#: Slowest UAV, in cells per step.
MIN_SPEED = 1e-6
#: Largest ``poaching_time`` (a poacher that needs longer than the longest episode never poaches).
MAX_POACHING_TIME = MAX_CYCLES
#: Largest ``terrain_seed`` (the largest int64).
MAX_SEED = 2**63 - 1
#: Largest reward weight. With at most 1e6 cells, 1000 poachers and 1000 UAVs a step's reward stays below about
#: 1e13 in magnitude, and an episode's sum below 1e18: finite inputs always give finite rewards.
MAX_REWARD_WEIGHT = 1e6

class UnknownArgumentError(ValueError, TypeError):
    """An argument name that the reserve does not know.

    A :class:`ValueError` like every other argument error; also a :class:`TypeError`, what Python raises for an
    unexpected keyword, so that callers written against that still catch it.
    """


@dataclass
class ReserveConfig:
    """Every argument of ``reserve_v1.env`` / ``parallel_env``, validated on construction.

    Every bad value raises a :class:`ValueError` naming the argument, the value and what is allowed. Ints must be
    ints (``int`` or numpy integers: no floats, bools or strings), numbers ints or floats (no bools, strings or
    complex numbers, finite), booleans ``bool`` or ``np.bool_`` (``"false"``, ``0`` or ``None`` are rejected).
    The upper bounds are the ``MAX_*`` constants of this module.

    :param n_uavs: number of UAVs (agents ``uav_0`` ... ``uav_{n-1}``), int in [1, 1000]; also
        ``n_uavs * (height + 2 * sensor_radius) * (width + 2 * sensor_radius) <= 25_000_000`` (every UAV keeps two
        int16 time stamps per cell of the padded grid, int32 from 32,767 steps: at most 100 MB, 200 MB)
    :param grid_size: reserve side in cells (int, square) or ``(height, width)`` (a tuple, list or array of two
        ints); defaults to the terrain array's shape if one is given, else 100; each side in
        ``[2 * sensor_radius + 1, 1000]``
    :param max_cycles: steps per episode (truncation), int in [1, 100_000] (what a UAV knows of a teammate is a
        float32 time and "never" is -1e6)
    :param n_leopards: leopards, int in [0, 1000]
    :param n_poachers: poachers entering over an episode, int in [0, 1000]
    :param sensor_radius: Chebyshev sensing radius in cells, int in [1, 10] (the observation window is ``2r + 1``
        wide)
    :param comm_radius: communication radius ``R_c`` in cells, number in [0, 10_000]
    :param continuous_actions: ``Box`` actions (velocity + communication intent) instead of ``Discrete(15)``; a bool
    :param agent_ids: end every UAV's observation with a one-hot of its index (``n_uavs`` floats), so that a policy
        shared by the UAVs can tell them apart: a deterministic one otherwise gives two UAVs in one cell the same
        action, and they stay together; a bool
    :param compass: add each UAV's offset to the nearest den and to the nearest road entry (4 floats, the map a
        ranger carries): where each poacher strategy strikes, in the UAV's own frame, so that a policy that knows or
        infers the strategy can head there; a bool
    :param coverage_sectors: the coverage term pays, and ``coverage_efficiency`` counts, only the high-risk cells in
        the sector of the episode's poacher strategy (the high-risk cells split into one sector per strategy, of equal
        count, by angle around the map's centre: :func:`~wildlife_reserve.reserve.terrain.sectors`); nothing a UAV
        observes marks the sectors, so where that reward lies follows from the strategy alone: a diagnostic of whether
        a learner acts on the mode it is told or infers; a bool
    :param strategy_zones: each poacher strategy strikes its own zone: the dens are the centres of the map's quarters
        (:func:`~wildlife_reserve.reserve.terrain.strategy_zones`, zone ``k`` for strategy ``k`` of
        :data:`~wildlife_reserve.reserve.modes.STRATEGIES`), the leopards live around them in turn, and every poacher
        of the episode heads for its strategy's zone from the side nearest to it
        (:func:`~wildlife_reserve.reserve.actors.plan_poachers`), keeping the strategy's timing, evasion and use of
        cover; with ``compass``, every UAV also observes its offset to each zone's centre (``zones``, the same in
        every mode); needs at least one leopard per zone; a bool
    :param scenario: ``None`` or the name of a set of arguments in :data:`SCENARIOS` (``"zone_raids"``), which
        explicit arguments override
    :param region: terrain preset, one of :data:`~wildlife_reserve.reserve.terrain.REGIONS` (a str)
    :param terrain: int array ``(height, width)`` with values 0 (open), 1 (forest), 2 (mountain) (float arrays of
        whole numbers are accepted; bool, complex, str and object arrays are not); overrides the generated terrain
    :param risk: int or float array ``(height, width)`` with finite values in [0, 1]; overrides the generated
        risk map (kept as float32, values below ``terrain.RISK_FLOOR`` = 1e-6 as 0)
    :param terrain_seed: seed of the region's map (terrain and hotspots), fixed across episodes, int in
        [0, 2**63 - 1]; ``None`` draws a new map every episode from the reset seed
    :param mode: ``None`` draws the hidden mode from ``mode_prior`` each episode; an int in
        ``[0, N_MODES)`` fixes it (for evaluation)
    :param mode_prior: ``N_MODES`` finite non-negative weights (int or float) with a positive sum, normalised
        (scaled by their maximum first, so that even weights near the float limit normalise); ``None`` is uniform
    :param sensor_noise: sensor corruption level in [0, 1]
    :param comm_loss: chance in [0, 1] that any one message (or position beacon) is lost
    :param adversarial: poachers deploy decoys (spoofed signals) and carry a jammer; a bool
    :param n_decoys: decoys in the adversarial condition, int in [0, 1000]
    :param jam_radius: radius of the jammer in cells, number in [0, 10_000]
    :param uav_speed: cells per step at full speed, number in [1e-6, 10_000]
    :param max_neighbors: neighbours within ``R_c`` listed in the observation, int in [0, 1000]
    :param belief_size: side of the coarse poacher-activity belief map, int in [1, min(16, height, width)];
        ``None`` (the default) is ``min(8, height, width)``, which is 8 on every grid of side >= 8
    :param belief_decay: per-step decay in [1e-6, 1] of old detections in the belief map
    :param poaching_time: steps an undetected poacher must stay next to a leopard to poach it, int in
        [1, 100_000]
    :param leopard_range: home range of a leopard around its den in cells, number in [0, 10_000]
    :param reward_weights: overrides of :data:`DEFAULT_REWARD_WEIGHTS`, a dict ``{term: weight}`` with each weight a
        number in [0, 1e6] (so that finite inputs always give finite rewards); ``None`` means no overrides
    :param shaping: in [0, 1]; each UAV gets ``(1 - shaping) * team + shaping * own`` reward
    :param render_mode: ``None``, ``"human"`` or ``"rgb_array"``
    """

    n_uavs: int = 10
    grid_size: int | tuple[int, int] | None = None
    max_cycles: int = 200
    n_leopards: int = 3
    n_poachers: int = 4
    sensor_radius: int = 3
    comm_radius: float = 20.0
    continuous_actions: bool = False
    agent_ids: bool = False
    compass: bool = False
    coverage_sectors: bool = False
    strategy_zones: bool = False
    scenario: str | None = None
    region: str = "mixed"
    terrain: np.ndarray | None = None
    risk: np.ndarray | None = None
    terrain_seed: int | None = 0
    mode: int | None = None
    mode_prior: np.ndarray | None = None
    sensor_noise: float = 0.0
    comm_loss: float = 0.0
    adversarial: bool = False
    n_decoys: int = 3
    jam_radius: float = 10.0
    uav_speed: float = 2.0
    max_neighbors: int = 4
    belief_size: int = None  # type: ignore[assignment]  # None: min(8, height, width), resolved on validation
    belief_decay: float = 0.98
    poaching_time: int = 5
    leopard_range: float = 8.0
    reward_weights: dict[str, float] = field(default_factory=dict)  # None is accepted: no overrides
    shaping: float = 0.0
    render_mode: str | None = None

    @classmethod
    def from_kwargs(cls, **kwargs: Any) -> ReserveConfig:
        """The validated configuration of ``kwargs``; an unknown name raises :class:`UnknownArgumentError`."""
        allowed = cls.argument_names()
        unknown = [name for name in kwargs if name not in allowed]
        if unknown:
            lowered = {name.lower(): name for name in allowed}
            described = []
            for name in unknown:
                text = repr(name) if len(name) <= 100 else show(name)
                close = difflib.get_close_matches(name.lower(), list(lowered), n=1, cutoff=0.8)
                described.append(f"{text} (did you mean {lowered[close[0]]!r}?)" if close else text)
            raise UnknownArgumentError(f"unknown argument{'s' if len(unknown) > 1 else ''} {', '.join(described)} of the "
                                       f"reserve; the arguments are: {', '.join(allowed)}")
        scenario = kwargs.get("scenario")
        if scenario is not None:
            if not isinstance(scenario, str) or scenario not in SCENARIOS:
                raise ValueError(f"scenario must be None or one of {sorted(SCENARIOS)}, got "
                                 f"{show(scenario, with_type=True)}")
            preset = SCENARIOS[scenario]
            weights = kwargs.get("reward_weights")
            if "reward_weights" in preset and (weights is None or isinstance(weights, Mapping)):
                kwargs = {**kwargs, "reward_weights": {**preset["reward_weights"], **(weights or {})}}
            kwargs = {**preset, **kwargs}
        return cls(**kwargs)

    def __post_init__(self) -> None:  # noqa: C901
        # Sizes first, and nothing allocated before they are checked.
        self.n_uavs = check_int("n_uavs", self.n_uavs, 1, MAX_UAVS)
        self.sensor_radius = check_int("sensor_radius", self.sensor_radius, 1, MAX_SENSOR_RADIUS)
        window = 2 * self.sensor_radius + 1
        if self.terrain is not None:
            self.terrain = check_array("terrain", self.terrain, "iuf",
                                       "an int array (height, width) of terrain types 0, 1, 2")
            if self.terrain.ndim != 2:
                raise ValueError(f"terrain must be a 2-D array (height, width), got shape {self.terrain.shape}")
        self.grid_size = grid = self._grid(window)
        if self.n_uavs * (grid[0] + 2 * self.sensor_radius) * (grid[1] + 2 * self.sensor_radius) > MAX_UAV_CELLS:
            padded = (grid[0] + 2 * self.sensor_radius) * (grid[1] + 2 * self.sensor_radius)
            raise ValueError(
                f"n_uavs * (height + 2 * sensor_radius) * (width + 2 * sensor_radius) must be <= {MAX_UAV_CELLS:_} "
                f"(every UAV keeps two float32 time stamps per padded cell), got {self.n_uavs} * {padded:_} = "
                f"{self.n_uavs * padded:_} with grid_size={grid}: at most {MAX_UAV_CELLS // padded} UAVs fit this "
                f"grid_size and sensor_radius")
        if self.terrain is not None:
            if self.terrain.shape != grid:
                raise ValueError(f"terrain must have shape grid_size={grid}, got {self.terrain.shape}")
            if self.terrain.dtype.kind == "f" and not np.all(np.isfinite(self.terrain)):
                raise ValueError("terrain must hold integer terrain types 0 (open), 1 (forest), 2 (mountain), "
                                 "got non-finite values")
            if self.terrain.dtype.kind == "f" and not np.all(np.mod(self.terrain, 1) == 0):
                raise ValueError("terrain must hold integer terrain types 0 (open), 1 (forest), 2 (mountain), "
                                 f"got fractional values such as {self.terrain[np.mod(self.terrain, 1) != 0][0]}")
            if self.terrain.min() < 0 or self.terrain.max() >= len(TERRAIN_NAMES):
                raise ValueError(f"terrain values must be in [0, {len(TERRAIN_NAMES) - 1}] ({', '.join(TERRAIN_NAMES)}), "
                                 f"got values in [{self.terrain.min()}, {self.terrain.max()}]")
            self.terrain = self.terrain.astype(np.int8)
        if self.risk is not None:
            risk = check_array("risk", self.risk, "iuf", "an int or float array (height, width) with values in [0, 1]")
            if risk.shape != grid:
                raise ValueError(f"risk must have shape grid_size={grid}, got {risk.shape}")
            if not np.all(np.isfinite(risk)) or risk.min() < 0 or risk.max() > 1:
                bad = risk[~(np.isfinite(risk) & (risk >= 0) & (risk <= 1))][0]
                raise ValueError(f"risk values must be finite and in [0, 1], got {show(bad)}")
            self.risk = as_risk(risk)
        self.max_cycles = check_int("max_cycles", self.max_cycles, 1, MAX_CYCLES)
        self.n_leopards = check_int("n_leopards", self.n_leopards, 0, MAX_ACTORS)
        self.n_poachers = check_int("n_poachers", self.n_poachers, 0, MAX_ACTORS)
        self.comm_radius = check_float("comm_radius", self.comm_radius, 0.0, MAX_DISTANCE)
        self.continuous_actions = check_bool("continuous_actions", self.continuous_actions)
        self.agent_ids = check_bool("agent_ids", self.agent_ids)
        self.compass = check_bool("compass", self.compass)
        self.coverage_sectors = check_bool("coverage_sectors", self.coverage_sectors)
        self.strategy_zones = check_bool("strategy_zones", self.strategy_zones)
        if self.strategy_zones and self.n_leopards < N_STRATEGIES:
            raise ValueError(f"strategy_zones needs a leopard in each of the {N_STRATEGIES} zones: n_leopards must be "
                             f">= {N_STRATEGIES}, got {self.n_leopards}")
        if self.scenario is not None and (not isinstance(self.scenario, str) or self.scenario not in SCENARIOS):
            raise ValueError(f"scenario must be None or one of {sorted(SCENARIOS)}, got "
                             f"{show(self.scenario, with_type=True)}")
        if not isinstance(self.region, str) or self.region not in REGIONS:
            raise ValueError(f"region must be one of {sorted(REGIONS)}, got {show(self.region, with_type=True)}")
        self.region = str(self.region)
        if self.terrain_seed is not None:
            self.terrain_seed = check_int("terrain_seed", self.terrain_seed, 0, MAX_SEED)
        if self.mode is not None:
            self.mode = check_int("mode", self.mode, 0, N_MODES - 1)
        if self.mode_prior is not None:
            self.mode_prior = self._prior()
        self.sensor_noise = check_float("sensor_noise", self.sensor_noise, 0.0, 1.0)
        self.comm_loss = check_float("comm_loss", self.comm_loss, 0.0, 1.0)
        self.adversarial = check_bool("adversarial", self.adversarial)
        self.n_decoys = check_int("n_decoys", self.n_decoys, 0, MAX_ACTORS)
        self.jam_radius = check_float("jam_radius", self.jam_radius, 0.0, MAX_DISTANCE)
        self.uav_speed = check_float("uav_speed", self.uav_speed, MIN_SPEED, MAX_DISTANCE)
        self.max_neighbors = check_int("max_neighbors", self.max_neighbors, 0, MAX_NEIGHBORS)
        if self.belief_size is None:
            self.belief_size = min(DEFAULT_BELIEF_SIZE, *grid)
        else:
            try:
                self.belief_size = check_int("belief_size", self.belief_size, 1, min(MAX_BELIEF_SIZE, *grid))
            except ValueError as error:
                raise ValueError(f"{error} (belief_size is at most {MAX_BELIEF_SIZE} and at most the smaller side of "
                                 f"grid_size {grid})") from None
        self.belief_decay = check_float("belief_decay", self.belief_decay, 1e-6, 1.0)
        self.poaching_time = check_int("poaching_time", self.poaching_time, 1, MAX_POACHING_TIME)
        self.leopard_range = check_float("leopard_range", self.leopard_range, 0.0, MAX_DISTANCE)
        self.reward_weights = self._weights()
        self.shaping = check_float("shaping", self.shaping, 0.0, 1.0)
        if not (self.render_mode is None or (isinstance(self.render_mode, str)
                                             and self.render_mode in ("human", "rgb_array"))):
            raise ValueError(f"render_mode must be None, 'human' or 'rgb_array', got {show(self.render_mode)}")
        self.render_mode = None if self.render_mode is None else str(self.render_mode)

    def _grid(self, window: int) -> tuple[int, int]:
        """``(height, width)`` from ``grid_size`` (or the terrain's shape), each side in ``[window, MAX_SIDE]``."""
        value = self.grid_size
        if value is None and self.terrain is not None:
            names: tuple[str, str] = ("the terrain's height", "the terrain's width")
            sides: tuple[Any, Any] = tuple(self.terrain.shape)  # type: ignore[assignment]
        elif isinstance(value, (tuple, list, np.ndarray)):
            if (isinstance(value, np.ndarray) and value.ndim != 1) or len(value) != 2:
                raise ValueError(f"grid_size must be an int or (height, width), got {show(value)}")
            names, sides = ("grid_size[0]", "grid_size[1]"), (value[0], value[1])
        else:
            value = 100 if value is None else value
            names, sides = ("grid_size", "grid_size"), (value, value)
        grid = (check_int(names[0], sides[0], 1, MAX_SIDE), check_int(names[1], sides[1], 1, MAX_SIDE))
        if min(grid) < window:
            source = "grid_size" if self.grid_size is not None else "grid_size (the terrain's shape)"
            raise ValueError(f"{source} must be at least the sensing window 2 * sensor_radius + 1 = {window} on each "
                             f"side (and at most {MAX_SIDE}), got {grid}")
        return grid

    def _prior(self) -> np.ndarray:
        what = f"{N_MODES} non-negative weights (finite, with a positive sum; None is uniform)"
        prior = check_array("mode_prior", self.mode_prior, "iuf", what).astype(np.float64)
        if prior.shape != (N_MODES,) or not np.all(np.isfinite(prior)) or prior.min() < 0 or prior.max() <= 0:
            raise ValueError(f"mode_prior must be {what}, got {show(self.mode_prior)}")
        prior = prior / prior.max()  # first to 1 at most, so that the sum cannot overflow
        prior = prior / prior.sum()
        if not (np.all(np.isfinite(prior)) and abs(prior.sum() - 1.0) < 1e-9):  # a guard: cannot happen after the above
            raise ValueError(f"mode_prior must be {what}, got {show(self.mode_prior)}")
        return prior

    def _weights(self) -> dict[str, float]:
        overrides: Any = {} if self.reward_weights is None else self.reward_weights
        if not isinstance(overrides, Mapping):
            raise ValueError(f"reward_weights must be a dict {{term: weight}} or None, got "
                             f"{show(overrides, with_type=True)}")
        unknown = [key for key in overrides if not isinstance(key, str) or key not in DEFAULT_REWARD_WEIGHTS]
        if unknown:
            raise ValueError(f"reward_weights keys must be among {sorted(DEFAULT_REWARD_WEIGHTS)}, got "
                             f"{', '.join(show(key) for key in unknown)}")
        weights = dict(DEFAULT_REWARD_WEIGHTS)
        for key, value in overrides.items():
            weights[str(key)] = check_float(f"reward_weights['{key}']", value, 0.0, MAX_REWARD_WEIGHT)
        return weights

    @classmethod
    def argument_names(cls) -> list[str]:
        """Names of every keyword argument the reserve accepts."""
        return [f.name for f in fields(cls)]
