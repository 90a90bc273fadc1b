"""The reserve's keyword arguments: defaults, allowed ranges and validation, in one place."""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

from wildlife_reserve.reserve.modes import N_MODES
from wildlife_reserve.reserve.terrain import REGIONS, TERRAIN_NAMES

#: Default weights of the team reward terms (see the environment card).
DEFAULT_REWARD_WEIGHTS: dict[str, float] = {
    "detection": 10.0,  # per poacher detected for the first time
    "coverage": 0.05,  # per high-risk cell seen for the first time this episode
    "sign": 0.1,  # per sign of poacher activity (track, snare, camp, ...) the team finds for the first time
    "poaching": 20.0,  # penalty per poaching event
    "collision": 1.0,  # penalty per pair of UAVs in one cell
    "energy": 1.0,  # penalty per unit of battery spent (a full battery is 1)
}

#: Battery spent per step: hovering, flying a full ``uav_speed``, broadcasting, querying a neighbour.
ENERGY_COSTS: dict[str, float] = {"hover": 0.0005, "move": 0.002, "broadcast": 0.003, "query": 0.0015}


def check_int(name: str, value: Any, low: int, high: int | None = None) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"{name} must be an int, got {value!r}")
    if value < low or (high is not None and value > high):
        allowed = f">= {low}" if high is None else f"in [{low}, {high}]"
        raise ValueError(f"{name} must be {allowed}, got {value!r}")
    return int(value)


def check_float(name: str, value: Any, low: float, high: float | None = None) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) or not np.isfinite(value):
        raise ValueError(f"{name} must be a finite number, got {value!r}")
    if value < low or (high is not None and value > high):
        allowed = f">= {low}" if high is None else f"in [{low}, {high}]"
        raise ValueError(f"{name} must be {allowed}, got {value!r}")
    return float(value)


@dataclass
class ReserveConfig:
    """Every argument of ``reserve_v0.env`` / ``parallel_env``, validated on construction.

    :param n_uavs: number of UAVs (agents ``uav_0`` ... ``uav_{n-1}``), >= 1
    :param grid_size: reserve side in cells (int, square) or ``(height, width)``; defaults to the
        terrain array's shape if one is given, else 100; each side >= ``2 * sensor_radius + 1``
    :param max_cycles: steps per episode (truncation), >= 1
    :param n_leopards: leopards, >= 0
    :param n_poachers: poachers entering over an episode, >= 0
    :param sensor_radius: Chebyshev sensing radius in cells, >= 1 (the observation window is ``2r + 1`` wide)
    :param comm_radius: communication radius ``R_c`` in cells, >= 0
    :param continuous_actions: ``Box`` actions (velocity + communication intent) instead of ``Discrete(15)``
    :param region: terrain preset, one of :data:`~wildlife_reserve.reserve.terrain.REGIONS`
    :param terrain: int array ``(height, width)`` with values 0 (open), 1 (forest), 2 (mountain);
        overrides the generated terrain
    :param risk: float array ``(height, width)`` in [0, 1]; overrides the generated risk map
    :param terrain_seed: seed of the region's map (terrain and hotspots), fixed across episodes;
        ``None`` draws a new map every episode from the reset seed
    :param mode: ``None`` draws the hidden mode from ``mode_prior`` each episode; an int in
        ``[0, N_MODES)`` fixes it (for evaluation)
    :param mode_prior: probabilities of the ``N_MODES`` modes; ``None`` is uniform
    :param sensor_noise: sensor corruption level in [0, 1]
    :param comm_loss: chance in [0, 1] that any one message (or position beacon) is lost
    :param adversarial: poachers deploy decoys (spoofed signals) and carry a jammer
    :param n_decoys: decoys in the adversarial condition, >= 0
    :param jam_radius: radius of the jammer in cells, >= 0
    :param uav_speed: cells per step at full speed, > 0
    :param max_neighbors: neighbours within ``R_c`` listed in the observation, >= 0
    :param belief_size: side of the coarse poacher-activity belief map, in [1, min(height, width)]
    :param belief_decay: per-step decay in (0, 1] of old detections in the belief map
    :param poaching_time: steps an undetected poacher must stay next to a leopard to poach it, >= 1
    :param leopard_range: home range of a leopard around its den in cells, >= 0
    :param reward_weights: overrides of :data:`DEFAULT_REWARD_WEIGHTS` (each >= 0)
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
    belief_size: int = 8
    belief_decay: float = 0.98
    poaching_time: int = 5
    leopard_range: float = 8.0
    reward_weights: dict[str, float] = field(default_factory=dict)
    shaping: float = 0.0
    render_mode: str | None = None

    def __post_init__(self) -> None:  # noqa: C901
        self.n_uavs = check_int("n_uavs", self.n_uavs, 1)
        self.sensor_radius = check_int("sensor_radius", self.sensor_radius, 1)
        window = 2 * self.sensor_radius + 1
        if self.terrain is not None:
            self.terrain = np.asarray(self.terrain)
            if self.terrain.ndim != 2:
                raise ValueError(f"terrain must be a 2-D array (height, width), got shape {self.terrain.shape}")
        if self.grid_size is None:
            self.grid_size = tuple(self.terrain.shape) if self.terrain is not None else 100
        size = (self.grid_size, self.grid_size) if np.ndim(self.grid_size) == 0 else tuple(self.grid_size)  # type: ignore[arg-type]
        if len(size) != 2:
            raise ValueError(f"grid_size must be an int or (height, width), got {self.grid_size!r}")
        name = "grid_size" if np.ndim(self.grid_size) == 0 else "grid_size[{}]"
        grid = (check_int(name.format(0), size[0], 1), check_int(name.format(1), size[1], 1))
        self.grid_size = grid
        if min(grid) < window:
            raise ValueError(f"grid_size must be at least the sensing window 2 * sensor_radius + 1 = {window} on each side, "
                             f"got {self.grid_size}")
        if self.terrain is not None:
            if self.terrain.shape != self.grid_size:
                raise ValueError(f"terrain must have shape grid_size={self.grid_size}, got {self.terrain.shape}")
            if not np.issubdtype(self.terrain.dtype, np.integer) and not np.all(np.mod(self.terrain, 1) == 0):
                raise ValueError("terrain must hold integer terrain types 0 (open), 1 (forest), 2 (mountain)")
            if self.terrain.min() < 0 or self.terrain.max() >= len(TERRAIN_NAMES):
                raise ValueError(f"terrain values must be in [0, {len(TERRAIN_NAMES) - 1}] ({', '.join(TERRAIN_NAMES)}), "
                                 f"got values in [{self.terrain.min()}, {self.terrain.max()}]")
            self.terrain = self.terrain.astype(np.int8)
        if self.risk is not None:
            self.risk = np.asarray(self.risk, dtype=np.float64)
            if self.risk.shape != self.grid_size:
                raise ValueError(f"risk must have shape grid_size={self.grid_size}, got {self.risk.shape}")
            if not np.all(np.isfinite(self.risk)) or self.risk.min() < 0 or self.risk.max() > 1:
                raise ValueError("risk values must be finite and in [0, 1]")
            self.risk = self.risk.astype(np.float32)
        self.max_cycles = check_int("max_cycles", self.max_cycles, 1)
        self.n_leopards = check_int("n_leopards", self.n_leopards, 0)
        self.n_poachers = check_int("n_poachers", self.n_poachers, 0)
        self.comm_radius = check_float("comm_radius", self.comm_radius, 0.0)
        self.continuous_actions = bool(self.continuous_actions)
        if self.region not in REGIONS:
            raise ValueError(f"region must be one of {sorted(REGIONS)}, got {self.region!r}")
        if self.terrain_seed is not None:
            self.terrain_seed = check_int("terrain_seed", self.terrain_seed, 0)
        if self.mode is not None:
            self.mode = check_int("mode", self.mode, 0, N_MODES - 1)
        if self.mode_prior is not None:
            prior = np.asarray(self.mode_prior, dtype=np.float64)
            if prior.shape != (N_MODES,) or not np.all(np.isfinite(prior)) or prior.min() < 0 or prior.sum() <= 0:
                raise ValueError(f"mode_prior must be {N_MODES} non-negative weights with a positive sum, "
                                 f"got {self.mode_prior!r}")
            self.mode_prior = prior / prior.sum()
        self.sensor_noise = check_float("sensor_noise", self.sensor_noise, 0.0, 1.0)
        self.comm_loss = check_float("comm_loss", self.comm_loss, 0.0, 1.0)
        self.adversarial = bool(self.adversarial)
        self.n_decoys = check_int("n_decoys", self.n_decoys, 0)
        self.jam_radius = check_float("jam_radius", self.jam_radius, 0.0)
        self.uav_speed = check_float("uav_speed", self.uav_speed, 1e-6)
        self.max_neighbors = check_int("max_neighbors", self.max_neighbors, 0)
        self.belief_size = check_int("belief_size", self.belief_size, 1, min(grid))
        self.belief_decay = check_float("belief_decay", self.belief_decay, 1e-6, 1.0)
        self.poaching_time = check_int("poaching_time", self.poaching_time, 1)
        self.leopard_range = check_float("leopard_range", self.leopard_range, 0.0)
        unknown = set(self.reward_weights) - set(DEFAULT_REWARD_WEIGHTS)
        if unknown:
            raise ValueError(f"reward_weights keys must be among {sorted(DEFAULT_REWARD_WEIGHTS)}, got {sorted(unknown)}")
        weights = dict(DEFAULT_REWARD_WEIGHTS)
        for key, value in self.reward_weights.items():
            weights[key] = check_float(f"reward_weights[{key!r}]", value, 0.0)
        self.reward_weights = weights
        self.shaping = check_float("shaping", self.shaping, 0.0, 1.0)
        if self.render_mode not in (None, "human", "rgb_array"):
            raise ValueError(f"render_mode must be None, 'human' or 'rgb_array', got {self.render_mode!r}")

    @classmethod
    def argument_names(cls) -> list[str]:
        """Names of every keyword argument the reserve accepts."""
        return [f.name for f in fields(cls)]
