"""The sensing phase of a step: detections, false alarms, decoys, sign sightings and false sign readings from
the step's uniform draws, and the noise on the signal channels.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from wildlife_reserve.reserve.kernels.constants import POACHER_ACTIVE
from wildlife_reserve.reserve.kernels.draws import standard_normal
from wildlife_reserve.reserve.kernels.records import Candidates, Ground, Sensing, SignRecords, Spots, Team


@njit(cache=True)
def detection_probabilities(targets: np.ndarray, cells: np.ndarray, table: np.ndarray, terrain: np.ndarray,
                            moved: np.ndarray, present: np.ndarray, airborne: np.ndarray,
                            radius: int) -> np.ndarray:  # pragma: no cover - compiled
    """``p[u, i] = table[min(chebyshev(target i - cell u), radius + 1), terrain at target i, moved[i]]``, and 0 for
    targets not present or UAVs not airborne (which then never detect, whatever their draw)."""
    n, m = len(cells), len(targets)
    p = np.zeros((n, m))
    for u in range(n):
        if not airborne[u]:
            continue
        for i in range(m):
            if present[i]:
                d = min(max(abs(targets[i, 0] - cells[u, 0]), abs(targets[i, 1] - cells[u, 1])), radius + 1)
                p[u, i] = table[d, terrain[targets[i, 0], targets[i, 1]], moved[i]]
    return p

@njit(cache=True)
def false_reading_cells(alarm_draw: np.ndarray, spot_draw: np.ndarray, probability: float, airborne: np.ndarray,
                        reach_offsets: np.ndarray, cells: np.ndarray, height: int,
                        width: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """Spurious readings: UAV ``u`` reads one if airborne and ``alarm_draw[u] < probability``, at offset
    ``reach_offsets[int(spot_draw[u] * len(reach_offsets))]``; readings off the map are dropped.

    :return: reading UAVs ``(k,)``, offsets ``(k, 2)`` and cells ``(k, 2)``
    """
    n = len(cells)
    uav = np.empty(n, dtype=np.int64)
    offsets = np.empty((n, 2), dtype=np.int64)
    where = np.empty((n, 2), dtype=np.int64)
    k = 0
    for u in range(n):
        if alarm_draw[u] < probability and airborne[u]:
            offset = reach_offsets[np.int64(spot_draw[u] * len(reach_offsets))]
            row, col = cells[u, 0] + offset[0], cells[u, 1] + offset[1]
            if 0 <= row < height and 0 <= col < width:
                uav[k], offsets[k, 0], offsets[k, 1], where[k, 0], where[k, 1] = u, offset[0], offset[1], row, col
                k += 1
    return uav[:k], offsets[:k], where[:k]

@njit(cache=True)
def decoy_reading_cells(draws: np.ndarray, table: np.ndarray, decoys: np.ndarray, cells: np.ndarray,
                        airborne: np.ndarray, height: int,
                        width: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """Decoys read as poachers: UAV ``u`` reads decoy ``i`` if airborne and ``draws[u, i] < table[min(chebyshev
    distance, len(table) - 1)]``; readings off the map are dropped.

    :return: reading UAVs ``(k,)``, offsets from them ``(k, 2)`` and cells ``(k, 2)``, in (UAV, decoy) order
    """
    n, d = draws.shape
    far = len(table) - 1
    uav = np.empty(n * d, dtype=np.int64)
    offsets = np.empty((n * d, 2), dtype=np.int64)
    where = np.empty((n * d, 2), dtype=np.int64)
    k = 0
    for u in range(n):
        for i in range(d):
            d_row, d_col = decoys[i, 0] - cells[u, 0], decoys[i, 1] - cells[u, 1]
            if draws[u, i] < table[min(max(abs(d_row), abs(d_col)), far)] and airborne[u]:
                row, col = cells[u, 0] + d_row, cells[u, 1] + d_col
                if 0 <= row < height and 0 <= col < width:
                    uav[k], offsets[k, 0], offsets[k, 1], where[k, 0], where[k, 1] = u, d_row, d_col, row, col
                    k += 1
    return uav[:k], offsets[:k], where[:k]

@njit(cache=True)
def record_readings(hit: np.ndarray, poachers: np.ndarray, leopards: np.ndarray, cells: np.ndarray, radius: int,
                    spots: Spots, signals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """Mark this step's detections ``hit`` ``(n, P + L)`` (poachers, then leopards) and the false poacher readings
    ``spots`` in ``signals`` (channels 0 and 1), and list the poacher readings.

    :return: who detected which poacher ``(n, P)``, and the poacher readings ``(k, 3)`` ``(uav, row, col)``: the true
        ones in (UAV, poacher) order, then the false ones
    """
    false_uav, false_offsets, false_cells = spots.uav, spots.offsets, spots.cells
    n = len(cells)
    n_poachers = len(poachers)
    seen = np.zeros((n, n_poachers), dtype=np.bool_)
    readings = np.empty((int(hit[:, :n_poachers].sum()) + len(false_uav), 3), dtype=np.int64)
    k = 0
    for u in range(n):
        for i in range(hit.shape[1]):
            if hit[u, i]:
                if i < n_poachers:
                    row, col = poachers[i, 0], poachers[i, 1]
                    seen[u, i] = True
                    readings[k, 0], readings[k, 1], readings[k, 2] = u, row, col
                    k += 1
                    signals[u, 0, row - cells[u, 0] + radius, col - cells[u, 1] + radius] = 1.0
                else:
                    row, col = leopards[i - n_poachers, 0], leopards[i - n_poachers, 1]
                    signals[u, 1, row - cells[u, 0] + radius, col - cells[u, 1] + radius] = 1.0
    for a in range(len(false_uav)):
        signals[false_uav[a], 0, false_offsets[a, 0] + radius, false_offsets[a, 1] + radius] = 1.0
        readings[k, 0], readings[k, 1], readings[k, 2] = false_uav[a], false_cells[a, 0], false_cells[a, 1]
        k += 1
    return seen, readings

@njit(cache=True)
def see_signs(hit: np.ndarray, candidates: Candidates, signals: np.ndarray, team: Team,
              signs: SignRecords) -> int:  # pragma: no cover - compiled
    """The ``candidates`` sightings that ``hit``: mark the sign channel ``signals[uav, 2]`` at the window cell (flat),
    the UAV learns of the sign (counted once per UAV in the team's ``counts`` by block), and the team finds it
    (``found``) if its kind is ``real``.

    :return: how many real signs the team found for the first time
    """
    uav, cell, sign = candidates.uav, candidates.cell, candidates.sign
    known, counts, found = team.known, team.counts, signs.found
    w = signals.shape[-1]
    fresh = 0
    for a in range(len(hit)):
        if hit[a]:
            u, i = uav[a], sign[a]
            signals[u, 2, cell[a] // w, cell[a] % w] = 1.0
            if not known[u, i]:
                known[u, i] = True
                counts[u, signs.block[i]] += 1.0
            if signs.real[signs.kind[i]] and not found[i]:
                found[i] = True
                fresh += 1
    return fresh

@njit(cache=True)
def sense(draws: np.ndarray, ground: Ground, cells: np.ndarray, airborne: np.ndarray, sensing: Sensing,
          candidates: Candidates, team: Team, signs: SignRecords) -> tuple:  # pragma: no cover - compiled
    """One step of sensing in one call, from the step's uniform ``draws`` taken in this order: detection of every
    active poacher and live leopard by every airborne UAV ``(n, P + L)`` (``detection_probabilities``), spurious
    poacher readings ``(2, n)`` (``false_reading_cells``), decoys ``(n, D)`` (``decoy_reading_cells``), the sign
    sightings ``(k,)`` (the ``candidates`` of ``sign_candidates``; ``see_signs``), false sign readings ``(2, n)``.
    Marks ``signals`` ``(n, 3, w, w)``; updates the team's ``known`` and ``counts`` and the signs' ``found`` in place.

    :return: who detected which poacher ``(n, P)``, the poachers detected by anyone ``(P,)`` and how many, the poacher
        readings ``(k, 3)`` (``record_readings``), the number of false poacher readings (decoys included), the real
        signs the team found for the first time, and the false sign readings' UAVs ``(f,)`` and cells ``(f, 2)``
    """
    poachers, leopards = ground.poachers.pos, ground.leopards.pos
    signals, radius, decoys = sensing.signals, sensing.radius, sensing.decoys
    alarm_probability, reach_offsets = sensing.false_alarm, sensing.reach_offsets
    height, width = sensing.terrain.shape
    n, m = len(cells), len(poachers) + len(leopards)
    p = detection_probabilities(np.concatenate((poachers, leopards)), cells, sensing.detection, sensing.terrain,
                                np.concatenate((ground.poachers.moved, ground.leopards.moved)).astype(np.int64),
                                np.concatenate((ground.poachers.status == POACHER_ACTIVE, ground.leopards.alive)),
                                airborne, radius)
    hit = draws[:n * m].reshape((n, m)) < p
    start = n * m
    uav, offsets, where = false_reading_cells(draws[start:start + n], draws[start + n:start + 2 * n], alarm_probability,
                                              airborne, reach_offsets, cells, height, width)
    start += 2 * n
    if len(decoys):
        d_uav, d_offsets, d_where = decoy_reading_cells(draws[start:start + n * len(decoys)].reshape((n, len(decoys))),
                                                        sensing.decoy, decoys, cells, airborne, height, width)
        start += n * len(decoys)
        uav, offsets, where = (np.concatenate((uav, d_uav)), np.concatenate((offsets, d_offsets)),
                               np.concatenate((where, d_where)))
    seen, readings = record_readings(hit, poachers, leopards, cells, radius, Spots(uav, offsets, where), signals)
    k = len(candidates.p)
    sighted = draws[start:start + k] < candidates.p
    start += k
    fresh = see_signs(sighted, candidates, signals, team, signs)
    f_uav, f_offsets, f_where = false_reading_cells(draws[start:start + n], draws[start + n:start + 2 * n],
                                                    alarm_probability, airborne, reach_offsets, cells, height, width)
    for a in range(len(f_uav)):
        signals[f_uav[a], 2, f_offsets[a, 0] + radius, f_offsets[a, 1] + radius] = 1.0
    caught = np.zeros(len(poachers), dtype=np.bool_)
    for u in range(n):
        for i in range(len(poachers)):
            caught[i] |= seen[u, i]
    return seen, caught, caught.sum(), readings, len(uav), fresh, f_uav, f_where

@njit(cache=True)
def noisy_signals(addresses: np.ndarray, signals: np.ndarray, scale: float) -> None:  # pragma: no cover - compiled
    """The signal channels as the UAVs read them (``sensing.SIGNAL_NOISE_STD``): in place, ``signals[:, :2] =
    np.clip(signals[:, :2] + rng.normal(0.0, scale, (n, 2, w, w)), 0, 1)``, then the same for ``signals[:, 2]``, with
    ``rng`` the generator of ``addresses`` (``stream.handle``)."""
    n, _, w, _ = signals.shape
    for first, last in ((0, 2), (2, 3)):
        draws = standard_normal(addresses, n * (last - first) * w * w)
        i = 0
        for u in range(n):
            for ch in range(first, last):
                for a in range(w):
                    for b in range(w):
                        noisy = np.float64(signals[u, ch, a, b]) + (0.0 + scale * draws[i])
                        signals[u, ch, a, b] = min(max(noisy, 0.0), 1.0)
                        i += 1
