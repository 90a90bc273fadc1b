"""The observations: every UAV's flat vector and its poacher-activity belief.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from wildlife_reserve.reserve.kernels.constants import (
    CH_LEOPARD,
    CH_OCCLUSION,
    CH_POACHER,
    CH_RISK,
    CH_SIGN,
    CH_STALENESS,
    CH_UAV,
)
from wildlife_reserve.reserve.kernels.records import Flight, Observe, Team


@njit(cache=True)
def beliefs(events: np.ndarray, knowledge: np.ndarray, n_blocks: int, decay: float, t: float) -> np.ndarray:
    # pragma: no cover - compiled
    """``(n, blocks)`` poacher activity ``1 - exp(-sum decay^(t - t_e))`` over the readings ``e`` (rows ``(time, uav,
    block)``) each UAV knows of (``time <= knowledge[r, uav]``), summed in event order."""
    n = len(knowledge)
    mass = np.zeros((n, n_blocks))
    for e in range(len(events)):
        time, who, block = events[e, 0], np.int64(events[e, 1]), np.int64(events[e, 2])
        weight = decay ** (t - time)
        for r in range(n):
            if time <= knowledge[r, who]:
                mass[r, block] += weight
    belief = np.zeros((n, n_blocks))
    for r in range(n):  # most blocks hold no reading: their 1 - exp(-0) = 0 needs no exp
        for b in range(n_blocks):
            if mass[r, b] > 0.0:
                belief[r, b] = 1.0 - np.exp(-mass[r, b])
    return belief

@njit(cache=True)
def fill_observations(obs: np.ndarray, view: Observe, flight: Flight, team: Team, events: np.ndarray, t: float,
                      progress: float) -> None:  # pragma: no cover - compiled
    """Every UAV's flat observation ``obs`` ``(n, obs_dim)``, in the order of ``observation_layout``:

    - ``window`` ``(7, w, w)``: occlusion, risk, staleness, the poacher, leopard and sign readings ``signals``
      ``(n, 3, w, w)`` in channels 3, 4 and 6, and the other airborne UAVs inside the window in channel 5; a grounded
      UAV's channels 3-6 are 0;
    - ``own`` (6): position scaled to [0, 1] (capped at 1), velocity, battery, episode ``progress``;
    - ``neighbours`` ``(max_neighbours, 3)``: the UAVs it heard (the team's ``beacons[s, r]``), nearest first (the
      lower index among equals), as ``(clip((pos_s - pos_r) * neighbour_scale, -1, 1), 1)``; unused slots are 0;
    - the coarse maps ``(n, blocks)``: ``block_staleness``; the poacher-activity belief at step ``t`` from the readings
      ``events`` each UAV knows of (:func:`beliefs`; 0 without readings); the signs each UAV knows of,
      ``sign_values[count]`` (the last entry for larger counts).
    """
    occlusion, risk, staleness, signals = view.occlusion, view.risk, view.staleness, view.signals
    window, cells, grounded, pos = flight.window, flight.cells, flight.grounded, flight.pos
    radius, inv_scale, own, neighbours, maps = view.radius, view.inv_scale, view.own, view.neighbours, view.maps
    heard, dist, sign_counts, sign_values = team.beacons, team.dist, team.counts, view.sign_values
    n = len(obs)
    w = 2 * radius + 1
    c = w * w
    blocks = view.block_staleness.shape[1]
    belief = beliefs(events, team.knowledge, blocks, team.belief_decay, t) if len(events) else np.zeros((n, blocks))
    last_value = len(sign_values) - 1
    order = np.empty(n, dtype=np.int64)
    for u in range(n):
        row = obs[u]
        blind = grounded[u]
        for a in range(w):
            for b in range(w):
                j, cell = a * w + b, window[u, a, b]
                row[CH_OCCLUSION * c + j] = occlusion[cell]
                row[CH_RISK * c + j] = risk[cell]
                row[CH_STALENESS * c + j] = staleness[u, a, b]
                row[CH_POACHER * c + j] = 0.0 if blind else signals[u, 0, a, b]
                row[CH_LEOPARD * c + j] = 0.0 if blind else signals[u, 1, a, b]
                row[CH_UAV * c + j] = 0.0
                row[CH_SIGN * c + j] = 0.0 if blind else signals[u, 2, a, b]
        if not blind:
            for v in range(n):
                d_row, d_col = cells[v, 0] - cells[u, 0], cells[v, 1] - cells[u, 1]
                if v != u and not grounded[v] and abs(d_row) <= radius and abs(d_col) <= radius:
                    row[CH_UAV * c + (d_row + radius) * w + d_col + radius] = 1.0
        row[own] = min(pos[u, 0] * inv_scale[0], 1.0)
        row[own + 1] = min(pos[u, 1] * inv_scale[1], 1.0)
        row[own + 2], row[own + 3] = flight.velocity[u, 0], flight.velocity[u, 1]
        row[own + 4] = flight.battery[u]
        row[own + 5] = progress
        row[neighbours:maps] = 0.0
        m = 0
        for s in range(n):  # insertion sort of the heard UAVs by (distance, index)
            if heard[s, u]:
                j = m
                while j > 0 and dist[u, order[j - 1]] > dist[u, s]:
                    order[j] = order[j - 1]
                    j -= 1
                order[j] = s
                m += 1
        for slot in range(min(m, view.max_neighbours)):
            s = order[slot]
            for axis in range(2):
                value = (pos[s, axis] - pos[u, axis]) * view.neighbour_scale
                row[neighbours + 3 * slot + axis] = min(max(value, -1.0), 1.0)
            row[neighbours + 3 * slot + 2] = 1.0
        for i in range(blocks):
            row[maps + i] = view.block_staleness[u, i]
            row[maps + blocks + i] = belief[u, i]
            row[maps + 2 * blocks + i] = sign_values[min(int(sign_counts[u, i]), last_value)]
