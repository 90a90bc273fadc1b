"""The signs' records in a step: signs placed on the grid and off it (false readings), the live ones in the UAVs'
windows, and what each UAV learns of them.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from wildlife_reserve.reserve.kernels.records import SignRecords


@njit(cache=True)
def place_signs(signs: SignRecords, pos: np.ndarray, born: np.ndarray, kind: np.ndarray, t: float,
                start: int) -> tuple[np.ndarray, int]:  # pragma: no cover - compiled
    """Signs made at cells ``pos`` at times ``born`` (the first of repeated cells counts), in ascending cell order: a
    cell whose sign is live keeps it, with the later expiry; any other gets a new record ``start, start + 1, ...``
    (the records must have room for all of them). The grid and the records of ``signs`` are updated in place.

    :return: for each input sign its new record or -1, and the records in use after them
    """
    grid, pad, width, block_of, lifetime = signs.grid, signs.pad, signs.width, signs.block_of, signs.lifetime
    record_pos, record_born, record_expires = signs.pos, signs.born, signs.expires
    k = len(pos)
    flat = np.empty(k, dtype=np.int64)
    for i in range(k):
        flat[i] = (pos[i, 0] + pad) * width + pos[i, 1] + pad
    index = np.full(k, -1, dtype=np.int64)
    order = np.argsort(flat, kind="mergesort")
    m = start
    for a in range(k):
        i = order[a]
        if a > 0 and flat[i] == flat[order[a - 1]]:
            continue
        expires = born[i] + lifetime[kind[i]]
        current = grid[flat[i]]
        if current >= 0 and record_expires[current] > t:
            if expires > record_expires[current]:
                record_expires[current] = expires
        else:
            index[i] = m
            grid[flat[i]] = m
            record_pos[m, 0], record_pos[m, 1] = pos[i, 0], pos[i, 1]
            record_born[m], record_expires[m], signs.kind[m] = born[i], expires, kind[i]
            signs.block[m] = block_of[pos[i, 0], pos[i, 1]]
            m += 1
    return index, m

@njit(cache=True)
def place_new_signs(signs: SignRecords, count: int, pos: np.ndarray, now: float,
                    kind: int) -> int:  # pragma: no cover - compiled
    """:func:`place_signs` of signs of ``kind`` born ``now`` at cells ``pos`` into ``signs``, ``count`` of its records
    in use; returns the records in use after them."""
    k = len(pos)
    if k == 0:
        return count
    return place_signs(signs, pos, np.full(k, now), np.full(k, kind), now, count)[1]

@njit(cache=True)
def add_signs_off_grid(signs: SignRecords, pos: np.ndarray, t: float, kind: int,
                       start: int) -> np.ndarray:  # pragma: no cover - compiled
    """``Signs.add(pos, t, kind, t, on_grid=False)``: records ``start, start + 1, ...`` (which must have room) for
    signs no other UAV can find (false readings), born at ``t``; returns their indices."""
    k = len(pos)
    ids = np.arange(start, start + k)
    for a in range(k):
        m = start + a
        signs.pos[m, 0], signs.pos[m, 1] = pos[a, 0], pos[a, 1]
        signs.born[m] = t
        signs.expires[m] = t + signs.lifetime[kind]
        signs.kind[m] = kind
        signs.block[m] = signs.block_of[pos[a, 0], pos[a, 1]]
    return ids

@njit(cache=True)
def learn_signs(known: np.ndarray, counts: np.ndarray, uavs: np.ndarray, signs: np.ndarray,
                blocks: np.ndarray) -> None:  # pragma: no cover - compiled
    """UAV ``uavs[a]`` learns of sign ``signs[a]`` (in block ``blocks[a]``): counted once per UAV."""
    for a in range(len(uavs)):
        if not known[uavs[a], signs[a]]:
            known[uavs[a], signs[a]] = True
            counts[uavs[a], blocks[a]] += 1.0

@njit(cache=True)
def sign_candidates(grid: np.ndarray, born: np.ndarray, expires: np.ndarray, window: np.ndarray, t: float,
                    airborne: np.ndarray, table: np.ndarray,
                    terrain: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover
    """The live signs in each airborne UAV's window and the chance of seeing each, in (UAV, window cell) order.

    :param grid: flat padded grid of sign record indices (-1: none)
    :param window: ``(n, c)`` padded flat cells of each UAV's window
    :param table: ``(c, terrain types)`` chance of seeing a sign at each window cell on each terrain
    :param terrain: flat padded terrain types
    :return: UAVs, window cells, sign records and probabilities ``(k,)``
    """
    n, c = window.shape
    size = n * c
    uav = np.empty(size, dtype=np.int64)
    cell = np.empty(size, dtype=np.int64)
    sign = np.empty(size, dtype=np.int64)
    p = np.empty(size)
    k = 0
    for u in range(n):
        if not airborne[u]:
            continue
        for j in range(c):
            flat = window[u, j]
            i = grid[flat]
            if i >= 0 and born[i] <= t and expires[i] > t:
                uav[k], cell[k], sign[k], p[k] = u, j, i, table[j, terrain[flat]]
                k += 1
    return uav[:k], cell[:k], sign[:k], p[:k]
