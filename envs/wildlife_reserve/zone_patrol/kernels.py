"""ZonePatrol's compiled loops: a step of every copy, and the observations (numba; the random numbers are drawn by
numpy beforehand, in :meth:`~wildlife_reserve.zone_patrol.world.ZonePatrolWorld.step`, so the episodes are those of
the generator alone). Twenty-odd numpy calls per step on arrays of a few dozen values cost several times the
arithmetic; one compiled pass over the copies does not."""

from __future__ import annotations

import numpy as np
from numba import njit

#: Moves of the five movement actions: stay, up, down, left, right (row, column).
MOVES = np.array([[0, 0], [-1, 0], [1, 0], [0, -1], [0, 1]], dtype=np.int64)


@njit(cache=True)
def _detect(c, actions, positions, sensors, intruders, alive, detections, detect_draws, radii, chances, weather,
            grid_size):  # pragma: no cover (compiled)
    """The UAVs of copy ``c`` move and set their sensors; each sensor detects each live intruder within its reach with
    its weather's chance. Returns which slots were detected."""
    n_uavs, n_slots = positions.shape[1], alive.shape[1]
    for u in range(n_uavs):
        move = actions[c, u] % 5
        sensors[c, u] = actions[c, u] // 5
        for k in range(2):
            positions[c, u, k] = min(max(positions[c, u, k] + MOVES[move, k], 0), grid_size - 1)
    hit = np.zeros(n_slots, dtype=np.bool_)
    for u in range(n_uavs):
        reach, chance = radii[sensors[c, u]], chances[sensors[c, u], weather]
        for m in range(n_slots):
            gap = max(abs(positions[c, u, 0] - intruders[c, m, 0]), abs(positions[c, u, 1] - intruders[c, m, 1]))
            seen = alive[c, m] and gap <= reach and detect_draws[c, u, m] < chance
            detections[c, u, m] = seen
            hit[m] |= seen
    return hit


@njit(cache=True)
def _wander_and_spawn(c, intruders, ages, alive, origin, wander_draws, direction_draws, spawn_draw, cell_draw,
                      zone_size, move_prob, spawn_prob):  # pragma: no cover (compiled)
    """Every slot of copy ``c`` wanders within the zone (a free one is overwritten when it is used); a new intruder may
    appear in the first free slot. Returns 1 if one did."""
    top, left = origin[0], origin[1]
    n_slots = alive.shape[1]
    for m in range(n_slots):
        if wander_draws[c, m] < move_prob:
            d = 1 + direction_draws[c, m]
            intruders[c, m, 0] += MOVES[d, 0]
            intruders[c, m, 1] += MOVES[d, 1]
        intruders[c, m, 0] = min(max(intruders[c, m, 0], top), top + zone_size - 1)
        intruders[c, m, 1] = min(max(intruders[c, m, 1], left), left + zone_size - 1)
    if spawn_draw < spawn_prob:
        for m in range(n_slots):
            if not alive[c, m]:
                intruders[c, m, 0], intruders[c, m, 1] = top + cell_draw[0], left + cell_draw[1]
                ages[c, m], alive[c, m] = 0, True
                return 1
    return 0


@njit(cache=True)
def advance(actions, positions, sensors, intruders, ages, alive, tracks, detections, detected_cells, origins, weathers,
            detect_draws, wander_draws, direction_draws, spawn_draws, cell_draws, radii, chances, grid_size, zone_size,
            intruder_life, move_prob, spawn_prob, track_life, found, escaped, spawned):  # pragma: no cover (compiled)
    """One step of every copy, in place, phase by phase (see ``ZonePatrolWorld.step``).

    :param radii: ``(2,)`` reach of the wide and the narrow sensor
    :param chances: ``(2, 2)`` detection chance by sensor and weather
    :param found: ``(c,)`` out: intruders detected this step; ``escaped`` likewise; ``spawned`` ``(c,)`` out: 0 or 1
    """
    for c in range(positions.shape[0]):
        hit = _detect(c, actions, positions, sensors, intruders, alive, detections, detect_draws, radii, chances,
                      weathers[c], grid_size)
        found[c], escaped[c] = 0, 0
        for m in range(alive.shape[1]):  # detected intruders leave; the others age, and escape at the end of their lives
            detected_cells[c, m, 0], detected_cells[c, m, 1] = intruders[c, m, 0], intruders[c, m, 1]
            if hit[m]:
                alive[c, m] = False
                found[c] += 1
            elif alive[c, m]:
                ages[c, m] += 1
                if ages[c, m] >= intruder_life:
                    alive[c, m] = False
                    escaped[c] += 1
        tracks[c] = np.maximum(tracks[c] - 1, 0)
        spawned[c] = _wander_and_spawn(c, intruders, ages, alive, origins[c], wander_draws, direction_draws,
                                       spawn_draws[c], cell_draws[c], zone_size, move_prob, spawn_prob)
        for m in range(alive.shape[1]):
            if alive[c, m]:
                tracks[c, intruders[c, m, 0], intruders[c, m, 1]] = track_life


@njit(cache=True)
def observe(positions, tracks, detections, detected_cells, visibility, progress, radius, track_life, told_modes, out):
    """Every UAV's observation into ``out`` ``(c, n, obs_dim)`` (see the card for the layout); ``told_modes`` ``(c,)``
    the modes to append as one-hots, or empty."""  # pragma: no cover (compiled)
    n_copies, n_uavs = positions.shape[0], positions.shape[1]
    grid_size = tracks.shape[1]
    side = 2 * radius + 1
    cells = side * side
    n_slots = detections.shape[2]
    span = max(grid_size - 1, 1)
    for c in range(n_copies):
        for u in range(n_uavs):
            row, col = positions[c, u, 0], positions[c, u, 1]
            for a in range(side):
                for b in range(side):
                    i, j = row + a - radius, col + b - radius
                    w = a * side + b
                    inside = 0 <= i < grid_size and 0 <= j < grid_size
                    out[c, u, w] = tracks[c, i, j] / track_life if inside else -1.0
                    out[c, u, cells + w] = 0.0
                    out[c, u, 2 * cells + w] = 0.0
            for m in range(n_slots):
                if detections[c, u, m]:
                    a, b = detected_cells[c, m, 0] - row + radius, detected_cells[c, m, 1] - col + radius
                    if 0 <= a < side and 0 <= b < side:
                        out[c, u, cells + a * side + b] = 1.0
            for v in range(n_uavs):
                if v != u:
                    a, b = positions[c, v, 0] - row + radius, positions[c, v, 1] - col + radius
                    if 0 <= a < side and 0 <= b < side:
                        out[c, u, 2 * cells + a * side + b] = 1.0
            at = 3 * cells
            out[c, u, at] = row / span * 2.0 - 1.0
            out[c, u, at + 1] = col / span * 2.0 - 1.0
            out[c, u, at + 2] = min(max(visibility[c, u], -3.0), 4.0) / 4.0
            out[c, u, at + 3] = progress
            if told_modes.shape[0]:
                for k in range(out.shape[2] - at - 4):
                    out[c, u, at + 4 + k] = 1.0 if k == told_modes[c] else 0.0
