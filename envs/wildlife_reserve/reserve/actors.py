"""Ground actors: leopards on a random walk around their dens, and scripted poachers.

Poachers enter over the episode as their strategy (the hidden mode) dictates, walk toward their
target with stochastic mobility, and evade the UAVs they notice by fleeing or by hiding in cover.
Everything is vectorised over actors.
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


def plan_poachers(
    rng: np.random.Generator,
    strategy: PoacherStrategy,
    n_poachers: int,
    max_cycles: int,
    shape: tuple[int, int],
    dens: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Draw when and where each poacher enters and which den it heads for.

    :param rng: random generator
    :param strategy: the episode's poacher strategy
    :param n_poachers: number of poachers
    :param max_cycles: episode length (entry times are fractions of it, never step 0)
    :param shape: ``(height, width)``
    :param dens: ``(k, 2)`` den cells
    :return: entry times ``(P,)``, entry cells ``(P, 2)``, target cells ``(P, 2)``
    """
    lo = max(1, int(strategy.entry_window[0] * max_cycles))
    hi = max(lo + 1, int(strategy.entry_window[1] * max_cycles))
    n = n_poachers
    jitter = rng.uniform(-0.05, 0.05, size=n)
    if strategy.entry == "group":
        times = np.full(n, rng.integers(lo, hi))
        side = np.full(n, rng.integers(4))
        frac = np.clip(rng.uniform() + 0.3 * jitter, 0.0, 1.0)
        target = np.repeat(dens[rng.integers(len(dens))][None], n, axis=0)
    elif strategy.entry == "near_den":
        times = rng.integers(lo, hi, size=n)
        target = dens[rng.integers(len(dens), size=n)]
        side, frac = nearest_edge(target, shape)
        frac = np.clip(frac + jitter, 0.0, 1.0)
    elif strategy.entry == "one_side":
        times = rng.integers(lo, hi, size=n)
        side = np.full(n, rng.integers(4))
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


def _toward(rng: np.random.Generator, pos: np.ndarray, target: np.ndarray) -> np.ndarray:
    """One unit step along a random axis on which ``target`` differs from ``pos``."""
    delta = np.sign(target - pos)
    pick_row = rng.random(len(pos)) < 0.5
    use_row = np.where(delta[:, 0] == 0, False, np.where(delta[:, 1] == 0, True, pick_row))
    return np.where(use_row[:, None], delta * [1, 0], delta * [0, 1])


def step_poachers(
    rng: np.random.Generator,
    pos: np.ndarray,
    mobile: np.ndarray,
    target: np.ndarray,
    uav_cells: np.ndarray,
    notice_radius: float,
    strategy: PoacherStrategy,
    cover: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Move the poachers one step.

    :param rng: random generator
    :param pos: ``(P, 2)`` cells
    :param mobile: ``(P,)`` which poachers may move (active and not busy poaching)
    :param target: ``(P, 2)`` where each heads
    :param uav_cells: ``(n, 2)`` cells of the airborne UAVs
    :param notice_radius: Chebyshev radius within which a poacher notices a UAV
    :param strategy: the episode's poacher strategy
    :param cover: ``(H, W)`` bool, forest or mountain (where hiding works)
    :return: new cells and a ``(P,)`` bool of who moved
    """
    n = len(pos)
    draw = rng.random(n)
    wander = STEPS[1 + (rng.random(n) * 4).astype(np.int64)]
    step = np.where(
        (draw < strategy.move_prob)[:, None],
        _toward(rng, pos, target),
        np.where((draw < strategy.move_prob + strategy.wander_prob)[:, None], wander, 0),
    )
    evade_draw = rng.random(n)
    if len(uav_cells):
        dist = np.abs(pos[:, None, :] - uav_cells[None, :, :]).max(-1)
        nearest = dist.argmin(axis=1)
        noticed = dist[np.arange(n), nearest] <= notice_radius
        evade = noticed & (evade_draw < strategy.evasion_prob)
        flee = np.sign(pos - uav_cells[nearest])
        flee = np.where((flee == 0).all(-1, keepdims=True), wander, flee)
        hide = evade & strategy.hide_in_cover & cover[pos[:, 0], pos[:, 1]]
        step = np.where((evade & ~hide)[:, None], flee, step)
        step = np.where(hide[:, None], 0, step)
    step = np.where(mobile[:, None], step, 0)
    new = np.minimum(np.maximum(pos + step, 0), np.array(cover.shape) - 1)
    return new, (new != pos).any(-1)


def step_leopards(
    rng: np.random.Generator, pos: np.ndarray, home: np.ndarray, home_range: float, shape: tuple[int, int]
) -> np.ndarray:
    """Random walk that turns back toward the den beyond ``home_range``.

    :param rng: random generator
    :param pos: ``(L, 2)`` cells
    :param home: ``(L, 2)`` den cells
    :param home_range: Chebyshev distance from the den beyond which a leopard heads home
    :param shape: ``(height, width)``
    """
    n = len(pos)
    moves = rng.random(n) < LEOPARD_MOVE_PROB
    step = STEPS[1 + (rng.random(n) * 4).astype(np.int64)]
    far = np.abs(pos - home).max(-1) > home_range
    step = np.where(far[:, None], _toward(rng, pos, home), step)
    step = np.where(moves[:, None], step, 0)
    return np.minimum(np.maximum(pos + step, 0), np.array(shape) - 1)
