"""ZonePatrol's compiled loops: a step of every copy, and the observations (numba; the random numbers are drawn by
numpy beforehand, in :meth:`~wildlife_reserve.zone_patrol.world.ZonePatrolWorld.step`, so the episodes are those of
the generator alone). Twenty-odd numpy calls per step on arrays of a few dozen values cost several times the
arithmetic; one compiled pass over the copies does not. The kernels take the world's arrays as named records
(:class:`Team`, :class:`Intruders`, :class:`Draws`, :class:`Rules`, :class:`Counts`, :class:`Readings`,
:class:`Layout`), which numba compiles as tuples."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

#: Moves of the five movement actions: stay, up, down, left, right (row, column).
MOVES = np.array([[0, 0], [-1, 0], [1, 0], [0, -1], [0, 1]], dtype=np.int64)


class Team(NamedTuple):
    """The UAVs of every copy: cells ``(c, n, 2)``, sensors ``(c, n)`` (0 wide, 1 narrow) and this step's detections
    ``(c, n, slots)``."""

    positions: np.ndarray
    sensors: np.ndarray
    detections: np.ndarray


class Intruders(NamedTuple):
    """The intruders' slots of every copy: cells ``(c, slots, 2)``, ages and liveness ``(c, slots)``, where the slots
    were this step ``(c, slots, 2)`` (what a detection shows), and the tracks on the grid ``(c, g, g)``."""

    cells: np.ndarray
    ages: np.ndarray
    alive: np.ndarray
    detected_cells: np.ndarray
    tracks: np.ndarray


class Draws(NamedTuple):
    """A step's random numbers, drawn by numpy: detection ``(c, n, slots)``, wandering and its direction
    ``(c, slots)``, spawning ``(c,)`` and the new intruder's cell in the zone ``(c, 2)``."""

    detect: np.ndarray
    wander: np.ndarray
    direction: np.ndarray
    spawn: np.ndarray
    cell: np.ndarray


class Rules(NamedTuple):
    """The constants a step reads: the sensors' reach ``(2,)`` and chance by sensor and weather ``(2, 2)``, and the
    configuration's sizes, lives and probabilities."""

    radii: np.ndarray
    chances: np.ndarray
    grid_size: int
    zone_size: int
    intruder_life: int
    move_prob: float
    spawn_prob: float
    track_life: int


class Readings(NamedTuple):
    """What the UAVs read beside their windows at a step: the visibility readings ``(c, n)``, the zone readings
    ``cues`` ``(c, n, 4)`` (``(c, n, 0)`` without them), the modes to append as one-hots ``told_modes`` ``(c,)`` (empty:
    none) and the episode's ``progress`` (``t / max_cycles``)."""

    visibility: np.ndarray
    cues: np.ndarray
    told_modes: np.ndarray
    progress: float


class Layout(NamedTuple):
    """How an observation is laid out: the windows' ``radius``, the tracks' life ``track_life`` (their scale) and
    whether each UAV's one-hot index follows its zone readings (``ids``)."""

    radius: int
    track_life: int
    ids: bool


class Counts(NamedTuple):
    """What a step counts per copy ``(c,)``: intruders detected, escaped, spawned (0 or 1)."""

    found: np.ndarray
    escaped: np.ndarray
    spawned: np.ndarray


@njit(cache=True)
def _detect(c, actions, team, intruders, detect_draws, rules, weather):  # pragma: no cover (compiled)
    """The UAVs of copy ``c`` move and set their sensors; each sensor detects each live intruder within its reach with
    its weather's chance. Returns which slots were detected."""
    positions, sensors, detections = team.positions, team.sensors, team.detections
    cells, alive = intruders.cells, intruders.alive
    n_uavs, n_slots = positions.shape[1], alive.shape[1]
    for u in range(n_uavs):
        move = actions[c, u] % 5
        sensors[c, u] = actions[c, u] // 5
        for k in range(2):
            positions[c, u, k] = min(max(positions[c, u, k] + MOVES[move, k], 0), rules.grid_size - 1)
    hit = np.zeros(n_slots, dtype=np.bool_)
    for u in range(n_uavs):
        reach, chance = rules.radii[sensors[c, u]], rules.chances[sensors[c, u], weather]
        for m in range(n_slots):
            gap = max(abs(positions[c, u, 0] - cells[c, m, 0]), abs(positions[c, u, 1] - cells[c, m, 1]))
            seen = alive[c, m] and gap <= reach and detect_draws[c, u, m] < chance
            detections[c, u, m] = seen
            hit[m] |= seen
    return hit


@njit(cache=True)
def _wander_and_spawn(c, intruders, origin, draws, rules):  # pragma: no cover (compiled)
    """Every slot of copy ``c`` wanders within the zone (a free one is overwritten when it is used); a new intruder may
    appear in the first free slot. Returns 1 if one did."""
    cells, ages, alive = intruders.cells, intruders.ages, intruders.alive
    top, left, size = origin[0], origin[1], rules.zone_size
    n_slots = alive.shape[1]
    for m in range(n_slots):
        if draws.wander[c, m] < rules.move_prob:
            d = 1 + draws.direction[c, m]
            cells[c, m, 0] += MOVES[d, 0]
            cells[c, m, 1] += MOVES[d, 1]
        cells[c, m, 0] = min(max(cells[c, m, 0], top), top + size - 1)
        cells[c, m, 1] = min(max(cells[c, m, 1], left), left + size - 1)
    if draws.spawn[c] < rules.spawn_prob:
        for m in range(n_slots):
            if not alive[c, m]:
                cells[c, m, 0], cells[c, m, 1] = top + draws.cell[c, 0], left + draws.cell[c, 1]
                ages[c, m], alive[c, m] = 0, True
                return 1
    return 0


@njit(cache=True)
def advance(actions, team, intruders, origins, weathers, draws, rules, counts):  # pragma: no cover (compiled)
    """One step of every copy, in place, phase by phase (see ``ZonePatrolWorld.step``).

    :param actions: ``(c, n)`` ints in ``[0, 10)``
    :param team: :class:`Team`, updated
    :param intruders: :class:`Intruders`, updated
    :param origins: ``(c, 2)`` the top-left cell of each copy's zone
    :param weathers: ``(c,)`` each copy's weather
    :param draws: :class:`Draws`
    :param rules: :class:`Rules`
    :param counts: :class:`Counts`, written
    """
    alive, ages, tracks = intruders.alive, intruders.ages, intruders.tracks
    for c in range(team.positions.shape[0]):
        hit = _detect(c, actions, team, intruders, draws.detect, rules, weathers[c])
        counts.found[c], counts.escaped[c] = 0, 0
        for m in range(alive.shape[1]):  # detected intruders leave; the others age, and escape at the end of their lives
            intruders.detected_cells[c, m, 0] = intruders.cells[c, m, 0]
            intruders.detected_cells[c, m, 1] = intruders.cells[c, m, 1]
            if hit[m]:
                alive[c, m] = False
                counts.found[c] += 1
            elif alive[c, m]:
                ages[c, m] += 1
                if ages[c, m] >= rules.intruder_life:
                    alive[c, m] = False
                    counts.escaped[c] += 1
        tracks[c] = np.maximum(tracks[c] - 1, 0)
        counts.spawned[c] = _wander_and_spawn(c, intruders, origins[c], draws, rules)
        for m in range(alive.shape[1]):
            if alive[c, m]:
                tracks[c, intruders.cells[c, m, 0], intruders.cells[c, m, 1]] = rules.track_life


@njit(cache=True)
def observe(team, intruders, readings, layout, out):  # pragma: no cover (compiled)
    """Every UAV's observation into ``out`` ``(c, n, obs_dim)`` (see the card for the layout, and :class:`Readings`,
    :class:`Layout`): its window of the tracks, of this step's detections and of its teammates, its cell, its
    visibility reading and the episode's progress; its zone readings (clipped to [-4, 4], over 4; none when there are
    none); with ``layout.ids``, the one-hot of its index in the team; the told mode's one-hot, if any."""
    positions, detections = team.positions, team.detections
    tracks, detected_cells = intruders.tracks, intruders.detected_cells
    visibility, cues, told_modes, progress = readings.visibility, readings.cues, readings.told_modes, readings.progress
    radius, track_life, ids = layout.radius, layout.track_life, layout.ids
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
            _observe_tail(out[c, u], at + 4, cues[c, u], ids, u, n_uavs, told_modes[c] if told_modes.shape[0] else -1)


@njit(cache=True)
def _observe_tail(row, at, cues, ids, uav, n_uavs, told_mode):  # pragma: no cover (compiled)
    """The optional end of one UAV's observation ``row`` from index ``at``: its zone readings ``cues`` (clipped to
    [-4, 4], over 4; none when empty), with ``ids`` the one-hot of its index ``uav``, and the one-hot of ``told_mode``
    (-1: none) in the rest."""
    for k in range(cues.shape[0]):
        row[at + k] = min(max(cues[k], -4.0), 4.0) / 4.0
    at += cues.shape[0]
    if ids:
        for v in range(n_uavs):
            row[at + v] = 1.0 if v == uav else 0.0
        at += n_uavs
    if told_mode >= 0:
        for k in range(row.shape[0] - at):
            row[at + k] = 1.0 if k == told_mode else 0.0
