"""The flight phase of a step: the actions decoded, the UAVs moved, their energy spent, their windows placed and
their collisions counted.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from wildlife_reserve.reserve.kernels.constants import COMM_NONE
from wildlife_reserve.reserve.kernels.records import Flight


@njit(cache=True)
def decode_actions(choices: np.ndarray, steps: np.ndarray, n_moves: int,
                   n_comms: int) -> tuple[np.ndarray, np.ndarray, bool]:  # pragma: no cover - compiled
    """Discrete actions ``move + n_moves * comm`` as ``(n, 2)`` unit moves (rows of ``steps``) and ``(n,)``
    communication choices, and whether every action was in ``[0, n_moves * n_comms)`` (the rest is then garbage)."""
    n = len(choices)
    move, comm = np.empty((n, 2)), np.empty(n, dtype=np.int64)
    valid = True
    for u in range(n):
        a = choices[u]
        if a < 0 or a >= n_moves * n_comms:
            valid = False
            a = 0
        comm[u] = a // n_moves
        move[u, 0], move[u, 1] = steps[a % n_moves, 0], steps[a % n_moves, 1]
    return move, comm, valid

@njit(cache=True)
def fly(flight: Flight, move: np.ndarray, comm: np.ndarray) -> tuple[np.ndarray, bool]:  # pragma: no cover - compiled
    """Move the UAVs by ``move`` ``(n, 2)`` (clamped to the map) and spend their energy, capped by what the battery
    holds, with communication choices ``comm`` ``(n,)``; a grounded UAV neither moves nor talks (``move`` and ``comm``
    are zeroed for it) nor hovers. Updates in place the positions, the velocities (displacement / speed), the
    batteries, which UAVs are grounded (battery <= 1e-12), their cells and their windows (:func:`place_windows`).

    :return: the energy each UAV spent, and whether every UAV is now grounded
    """
    pos, velocity, battery, grounded = flight.pos, flight.velocity, flight.battery, flight.grounded
    speed, upper, hover, move_cost, comm_costs = flight.speed, flight.upper, flight.hover, flight.move_cost, \
        flight.comm_costs
    n = len(pos)
    energy = np.empty(n)
    everyone = True
    for u in range(n):
        if grounded[u]:
            move[u, 0], move[u, 1], comm[u] = 0.0, 0.0, COMM_NONE
        for axis in range(2):
            new = min(max(pos[u, axis] + move[u, axis] * speed, 0.0), upper[axis])
            velocity[u, axis] = (new - pos[u, axis]) / speed
            pos[u, axis] = new
        e = (0.0 if grounded[u] else hover) + move_cost * np.sqrt(velocity[u, 0] ** 2 + velocity[u, 1] ** 2)
        e += comm_costs[comm[u]]
        energy[u] = min(e, battery[u])
        battery[u] = battery[u] - energy[u]
        grounded[u] = battery[u] <= 1e-12
        everyone = everyone and grounded[u]
    place_windows(pos, flight.cells, flight.window, flight.padded_width, flight.window_offsets)
    return energy, everyone

@njit(cache=True)
def fly_and_collide(flight: Flight, move: np.ndarray,
                    comm: np.ndarray) -> tuple[np.ndarray, bool, np.ndarray, int]:  # pragma: no cover - compiled
    """:func:`fly`, then :func:`collisions` among the UAVs that were airborne before the flight, in one call:
    the energy spent, whether every UAV is grounded, ``(n,)`` other UAVs in each one's cell and the pairs."""
    airborne = ~flight.grounded
    energy, everyone = fly(flight, move, comm)
    own, pairs = collisions(flight.cells, airborne)
    return energy, everyone, own, pairs

@njit(cache=True)
def place_windows(pos: np.ndarray, cells: np.ndarray, window: np.ndarray, padded_width: int,
                  window_offsets: np.ndarray) -> None:  # pragma: no cover - compiled
    """The UAVs' ``cells`` ``(n, 2)`` (their positions, floored) and their windows' padded flat cells ``window``
    ``(n, w, w)``, written in place.

    :param window_offsets: ``(w, w)`` flat offsets of a window's cells from its top-left corner in the padded grids
    """
    w = window_offsets.shape[0]
    for u in range(len(pos)):
        cells[u, 0], cells[u, 1] = np.int64(np.floor(pos[u, 0])), np.int64(np.floor(pos[u, 1]))
        corner = cells[u, 0] * padded_width + cells[u, 1]
        for a in range(w):
            for b in range(w):
                window[u, a, b] = corner + window_offsets[a, b]

@njit(cache=True)
def collisions(cells: np.ndarray, airborne: np.ndarray) -> tuple[np.ndarray, int]:  # pragma: no cover - compiled
    """``(n,)`` other airborne UAVs in each airborne UAV's cell, and the pairs of UAVs that share a cell."""
    n = len(cells)
    count = np.zeros(n, dtype=np.int64)
    for u in range(n):
        if airborne[u]:
            for v in range(n):
                if v != u and airborne[v] and cells[u, 0] == cells[v, 0] and cells[u, 1] == cells[v, 1]:
                    count[u] += 1
    return count, count.sum() // 2
