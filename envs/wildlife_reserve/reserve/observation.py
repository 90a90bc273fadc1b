"""Observation building: the layout of the flat per-UAV vector, the vector itself and the global state."""

from __future__ import annotations

import numpy as np

from wildlife_reserve.reserve.config import ReserveConfig
from wildlife_reserve.reserve.kernels import Observe
from wildlife_reserve.reserve.kernels.constants import N_CHANNELS, POACHER_ACTIVE, POACHER_GONE
from wildlife_reserve.reserve.knowledge import SIGN_VALUES, sign_values
from wildlife_reserve.reserve.modes import STRATEGIES
from wildlife_reserve.reserve.view import ReserveView

#: Number of own features: row, col, d_row, d_col, battery, progress.
N_OWN = 6
#: Coarse maps at the end of the observation, in order.
MAP_NAMES = ("block_staleness", "belief", "signs")
#: What the compass points at, in order (its rows): the nearest den and the nearest road entry.
COMPASS_TARGETS = ("den", "road_entry")


def observation_layout(config: ReserveConfig) -> dict[str, tuple[slice, tuple[int, ...]]]:
    """Where each part of the flat observation lives: name -> (slice, shape).

    ``window`` (7, w, w) channels (occlusion, risk, staleness, poacher, leopard, UAVs, signs); ``own``
    (row, col, d_row, d_col, battery, progress); ``neighbours`` (max_neighbors, 3) as (d_row, d_col,
    present) / ``R_c``; ``block_staleness`` (time since each block was flown over, as far as the UAV
    knows), ``belief`` (poacher activity) and ``signs`` (signs of poacher activity the UAV knows of)
    maps, each (belief_size, belief_size); with ``compass``, ``compass`` (2, 2), the offset ``(d_row, d_col) /
    (side - 1)`` from the UAV's cell to the nearest den and to the nearest road entry (rows in
    :data:`COMPASS_TARGETS`; zeros where the map has none); with ``compass`` and ``strategy_zones``, ``zones``
    (n_strategies, 2), the offset from the UAV's cell to each strategy zone's centre, in the strategies' order; with
    ``agent_ids``, ``agent_id`` (n_uavs,), a one-hot of
    the UAV's index.
    """
    w, k, b = 2 * config.sensor_radius + 1, config.max_neighbors, config.belief_size
    shapes = {"window": (N_CHANNELS, w, w), "own": (N_OWN,), "neighbours": (k, 3)} | dict.fromkeys(MAP_NAMES, (b, b))
    if config.compass:
        shapes["compass"] = (len(COMPASS_TARGETS), 2)
    if config.compass and config.strategy_zones:
        shapes["zones"] = (len(STRATEGIES), 2)
    if config.agent_ids:
        shapes["agent_id"] = (config.n_uavs,)
    layout, start = {}, 0
    for name, shape in shapes.items():
        size = int(np.prod(shape))
        layout[name] = (slice(start, start + size), shape)
        start += size
    return layout


def observation_size(config: ReserveConfig) -> int:
    """Length of the flat observation."""
    return max(part.stop for part, _ in observation_layout(config).values())


def state_size(config: ReserveConfig) -> int:
    """Length of the global state (see :func:`global_state`)."""
    return 4 * config.n_uavs + 4 * config.n_poachers + 3 * config.n_leopards + 2 * config.belief_size**2 + 1


def observation_record(config: ReserveConfig, *, occlusion: np.ndarray, risk: np.ndarray, staleness: np.ndarray,
                       signals: np.ndarray, block_staleness: np.ndarray, inv_scale: np.ndarray) -> Observe:
    """What ``kernels.fill_observations`` reads of the reserve besides the flight and the team: the arrays the steps
    update in place (made at reset), and the configuration's constants and the layout's offsets. The reserve's world
    builds it once an episode.

    :param config: the reserve's configuration
    :param occlusion: the padded flat visual occlusion
    :param risk: the padded flat risk
    :param staleness: ``(n, w, w)``: the window staleness each step writes
    :param signals: ``(n, 3, w, w)``: the readings each step writes
    :param block_staleness: ``(n, blocks)``: the block staleness each step writes
    :param inv_scale: ``(2,)``: ``1 / (side - 1)``, the scale of offsets on the grid
    """
    layout = observation_layout(config)
    return Observe(occlusion=occlusion, risk=risk, staleness=staleness, signals=signals,
                   block_staleness=block_staleness, radius=config.sensor_radius, inv_scale=inv_scale,
                   neighbour_scale=1.0 / max(config.comm_radius, 1.0), max_neighbours=config.max_neighbors,
                   sign_values=SIGN_VALUES, own=layout["own"][0].start, neighbours=layout["neighbours"][0].start,
                   maps=layout[MAP_NAMES[0]][0].start, max_cycles=config.max_cycles)


def finish_observations(env: ReserveView, obs: np.ndarray) -> np.ndarray:
    """Write the optional parts at the end of ``obs`` (compass, agent id), which ``fill_observations`` leaves."""
    layout = env.observation_layout
    if "compass" in layout:  # the kernel writes the parts before it
        obs[:, layout["compass"][0]] = compass(env.cells, (env.hotspots.dens, env.hotspots.road_entries),
                                               env.inv_scale).reshape(env.n, -1)
    if "zones" in layout:  # the dens are the zones, in the strategies' order
        obs[:, layout["zones"][0]] = ((env.hotspots.dens[None] - env.cells[:, None]) * env.inv_scale).reshape(env.n, -1)
    if "agent_id" in layout:
        obs[:, layout["agent_id"][0]] = np.eye(env.n, dtype=np.float32)
    return obs


def compass(cells: np.ndarray, targets: tuple[np.ndarray, ...], inv_scale: np.ndarray) -> np.ndarray:
    """``(n, len(targets), 2)`` offsets from each of ``n`` cells to the nearest (Chebyshev) point of each target set.

    :param cells: ``(n, 2)`` int cells
    :param targets: ``(k, 2)`` int arrays of points; an empty one gives zeros
    :param inv_scale: ``(2,)`` factors of the offsets (``1 / (side - 1)``)
    """
    out = np.zeros((len(cells), len(targets), 2))
    for index, points in enumerate(targets):
        if len(points):
            offsets = points[None, :, :] - cells[:, None, :]  # (n, k, 2)
            nearest = np.abs(offsets).max(axis=2).argmin(axis=1)
            out[:, index] = offsets[np.arange(len(cells)), nearest] * inv_scale
    return out


def global_state(env: ReserveView) -> np.ndarray:
    """The global state (UAVs, poachers, leopards, coverage and live signs by block, progress), in [-1, 1]."""
    size = env.config.belief_size**2
    scale = np.array([max(env.height - 1, 1), max(env.width - 1, 1)])
    uavs = np.column_stack([env.uav_pos / scale, env.battery, env.grounded])
    poachers = np.column_stack([env.poacher_pos / scale, env.poacher_status == POACHER_ACTIVE,
                                env.poacher_status / POACHER_GONE])
    leopards = np.column_stack([env.leopard_pos / scale, env.leopard_alive])
    inner = env.visited[env.r:env.r + env.height, env.r:env.r + env.width] & env.high_risk
    blocks = env.blocks.ravel()
    seen = np.bincount(blocks, weights=inner.ravel(), minlength=size)
    total = np.bincount(blocks, weights=env.high_risk.ravel(), minlength=size)
    coverage = np.divide(seen, total, out=np.zeros(size), where=total > 0)
    live = env.signs.live(env.t)
    signs = sign_values(np.bincount(env.signs.block[live], minlength=size))
    progress = np.array([min(env.t / env.max_cycles, 1.0)])
    parts = [uavs.ravel(), poachers.ravel(), leopards.ravel(), coverage, signs, progress]
    return np.clip(np.concatenate(parts), -1.0, 1.0).astype(np.float32)
