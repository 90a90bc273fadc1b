"""Ground actors: leopards on a random walk around their dens, and scripted poachers.

Poachers enter over the episode as their strategy (the hidden mode) dictates (planned here, at reset),
walk toward their target with stochastic mobility, and evade the UAVs they notice by fleeing or by
hiding in cover. The step of both is compiled: ``kernels.move_ground_actors`` with the constants below.
"""

from __future__ import annotations

import numpy as np

from wildlife_reserve.reserve.modes import PoacherStrategy
from wildlife_reserve.reserve.terrain import edge_points, nearest_edge

#: Unit steps: stay, up, down, left, right (row, col). Index 0 is "stay".
STEPS = np.array([[0, 0], [-1, 0], [1, 0], [0, -1], [0, 1]], dtype=np.int64)
#: Chance per step that a leopard moves.
LEOPARD_MOVE_PROB = 0.4
#: Poachers within this many cells of a leopard go for it instead of their strategic target.
POACHER_SIGHT = 8
#: Nominal radius (clear weather) within which a poacher notices a UAV.
NOTICE_RADIUS = 5
#: With strategy zones, how far along the side nearest to its zone each strategy's poachers spread their entries (a
#: fraction of the side, either way): a group comes in at one point, a hotspot raid straight in, infiltrators and
#: dispersed poachers along more of the side.
ZONE_ENTRY_SPREAD: dict[str, float] = {"group": 0.015, "near_den": 0.05, "one_side": 0.15, "perimeter": 0.25}


def plan_poachers(
    rng: np.random.Generator,
    strategy: PoacherStrategy,
    n_poachers: int,
    max_cycles: int,
    shape: tuple[int, int],
    dens: np.ndarray,
    road_entries: np.ndarray | None = None,
    zone: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Draw when and where each poacher enters and which den it heads for.

    Infiltrators and groups come by road: an edge infiltration enters along the side where one of the
    reserve's roads enters it, a coordinated group at a road's entry point (one road drawn per episode;
    with no roads, any side and any point). With a ``zone`` (the reserve's ``strategy_zones``), every poacher heads
    for that den and enters from the side nearest to it, spread along the side as :data:`ZONE_ENTRY_SPREAD` says,
    at the strategy's times (a group all at once).

    :param rng: random generator
    :param strategy: the episode's poacher strategy
    :param n_poachers: number of poachers
    :param max_cycles: episode length (entry times are fractions of it, never step 0)
    :param shape: ``(height, width)``
    :param dens: ``(k, 2)`` den cells
    :param road_entries: ``(r, 2)`` edge cells where the roads enter the reserve
    :param zone: the den ``(2,)`` of the strategy's zone, or None
    :return: entry times ``(P,)``, entry cells ``(P, 2)``, target cells ``(P, 2)``
    """
    lo = max(1, int(strategy.entry_window[0] * max_cycles))
    hi = max(lo + 1, int(strategy.entry_window[1] * max_cycles))
    n = n_poachers
    jitter = rng.uniform(-0.05, 0.05, size=n)
    roads = np.zeros((0, 2), dtype=np.int64) if road_entries is None else np.asarray(road_entries).reshape(-1, 2)

    def by_road() -> tuple[int, float]:
        """The side and the place along it of a road's entry drawn at random (a random point without roads)."""
        if not len(roads):
            return int(rng.integers(4)), float(rng.uniform())
        road_side, road_frac = nearest_edge(roads[rng.integers(len(roads))][None], shape)
        return int(road_side[0]), float(road_frac[0])

    if zone is not None:
        zone_side, zone_frac = nearest_edge(np.asarray(zone, dtype=np.int64)[None], shape)
        if strategy.entry == "group":
            times = np.full(n, rng.integers(lo, hi))
        else:
            times = rng.integers(lo, hi, size=n)
        spread = rng.uniform(-1.0, 1.0, size=n) * ZONE_ENTRY_SPREAD[strategy.entry]
        entry = edge_points(np.full(n, zone_side[0]), np.clip(zone_frac[0] + spread, 0.0, 1.0), shape)
        return times.astype(np.int64), entry, np.repeat(np.asarray(zone, dtype=np.int64)[None], n, axis=0)
    if strategy.entry == "group":
        times = np.full(n, rng.integers(lo, hi))
        group_side, group_frac = by_road()
        side = np.full(n, group_side)
        frac = np.clip(group_frac + 0.3 * jitter, 0.0, 1.0)
        target = np.repeat(dens[rng.integers(len(dens))][None], n, axis=0)
    elif strategy.entry == "near_den":
        times = rng.integers(lo, hi, size=n)
        target = dens[rng.integers(len(dens), size=n)]
        side, frac = nearest_edge(target, shape)
        frac = np.clip(frac + jitter, 0.0, 1.0)
    elif strategy.entry == "one_side":
        times = rng.integers(lo, hi, size=n)
        side = np.full(n, by_road()[0])
        frac = rng.uniform(size=n)
        target = None
    else:  # "perimeter"
        times = rng.integers(lo, hi, size=n)
        side = rng.integers(4, size=n)
        frac = rng.uniform(size=n)
        target = dens[rng.integers(len(dens), size=n)]
    entry = edge_points(np.broadcast_to(side, (n,)), np.broadcast_to(frac, (n,)), shape)
    if target is None:  # each infiltrator heads for the den closest to where it came in
        d = np.abs(entry[:, None, :] - dens[None, :, :]).sum(-1)
        target = dens[d.argmin(axis=1)]
    return times.astype(np.int64), entry, np.asarray(target, dtype=np.int64)
