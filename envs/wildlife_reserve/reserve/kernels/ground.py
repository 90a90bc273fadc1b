"""The ground phase of a step: the leopards and poachers move (the poachers notice and evade the UAVs), enter
play and poach; the jammer travels with them.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from wildlife_reserve.reserve.kernels.constants import POACHER_ACTIVE, POACHER_GONE, POACHER_WAITING
from wildlife_reserve.reserve.kernels.records import Ground, Leopards, Poachers


@njit(cache=True)
def _sign(x: np.int64) -> np.int64:  # pragma: no cover - compiled
    return np.int64(x > 0) - np.int64(x < 0)

@njit(cache=True)
def _toward_step(pos: np.ndarray, target: np.ndarray, pick: float) -> tuple[np.int64, np.int64]:  # pragma: no cover
    """One unit step along an axis on which ``target`` differs from ``pos``: the row axis if only it differs, the
    column axis if only it does, else the row axis when ``pick < 0.5`` (how poachers and leopards head for a target)."""
    d_row, d_col = _sign(target[0] - pos[0]), _sign(target[1] - pos[1])
    use_row = False if d_row == 0 else (True if d_col == 0 else pick < 0.5)
    return (d_row, np.int64(0)) if use_row else (np.int64(0), d_col)

@njit(cache=True)
def poacher_targets(poachers: np.ndarray, leopards: np.ndarray, alive: np.ndarray, planned: np.ndarray,
                    sight: float) -> np.ndarray:  # pragma: no cover - compiled
    """Each poacher heads for the nearest live leopard within ``sight`` (Chebyshev; the first of equals), else for
    its planned den."""
    target = planned.copy()
    for i in range(len(poachers)):
        nearest, best = -1, np.inf
        for j in range(len(leopards)):
            if alive[j]:
                d = max(abs(poachers[i, 0] - leopards[j, 0]), abs(poachers[i, 1] - leopards[j, 1]))
                if d < best:
                    nearest, best = j, d
        if nearest >= 0 and best <= sight:
            target[i, 0], target[i, 1] = leopards[nearest, 0], leopards[nearest, 1]
    return target

@njit(cache=True)
def move_poachers(poachers: Poachers, mobile: np.ndarray, target: np.ndarray, uav_cells: np.ndarray, cover: np.ndarray,
                  steps: np.ndarray, draws: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """Move the poachers one step: toward their target with ``move_prob``, a random step with ``wander_prob``, else
    wait; one that notices a UAV within ``notice_radius`` (Chebyshev) evades it with ``evasion_prob`` (hides when
    ``hide_in_cover`` and on cover, else flees); those not ``mobile`` stay.

    :param draws: ``(4, P)`` uniform draws: whether to move, the wandering step, the axis toward the target, evasion
    :return: new cells ``(P, 2)`` and who moved ``(P,)``
    """
    pos = poachers.pos
    draw, wander_draw, pick, evade_draw = draws[0], draws[1], draws[2], draws[3]
    move_prob, wander_prob = poachers.move_prob, poachers.wander_prob
    n = len(pos)
    new = pos.copy()
    moved = np.zeros(n, dtype=np.bool_)
    height, width = cover.shape
    for i in range(n):
        wander = steps[1 + np.int64(wander_draw[i] * 4)]
        if draw[i] < move_prob:
            d_row, d_col = _toward_step(pos[i], target[i], pick[i])
        elif draw[i] < move_prob + wander_prob:
            d_row, d_col = wander[0], wander[1]
        else:
            d_row, d_col = np.int64(0), np.int64(0)
        if len(uav_cells):
            nearest, best = 0, np.int64(-1)
            for u in range(len(uav_cells)):
                d = max(abs(pos[i, 0] - uav_cells[u, 0]), abs(pos[i, 1] - uav_cells[u, 1]))
                if best < 0 or d < best:
                    nearest, best = u, d
            if best <= poachers.notice_radius and evade_draw[i] < poachers.evasion_prob:
                if poachers.hide_in_cover and cover[pos[i, 0], pos[i, 1]]:
                    d_row, d_col = np.int64(0), np.int64(0)
                else:
                    f_row, f_col = _sign(pos[i, 0] - uav_cells[nearest, 0]), _sign(pos[i, 1] - uav_cells[nearest, 1])
                    if f_row == 0 and f_col == 0:
                        f_row, f_col = wander[0], wander[1]
                    d_row, d_col = f_row, f_col
        if not mobile[i]:
            d_row, d_col = np.int64(0), np.int64(0)
        new[i, 0] = min(max(pos[i, 0] + d_row, 0), height - 1)
        new[i, 1] = min(max(pos[i, 1] + d_col, 0), width - 1)
        moved[i] = new[i, 0] != pos[i, 0] or new[i, 1] != pos[i, 1]
    return new, moved

@njit(cache=True)
def move_leopards(leopards: Leopards, height: int, width: int, steps: np.ndarray,
                  draws: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """Move the leopards one step: with ``move_prob``, a random step, or toward the den beyond ``home_range``
    (Chebyshev) of it; returns their new cells.

    :param draws: ``(3, L)`` uniform draws: whether to move, the random step, the axis toward the den
    """
    pos, home = leopards.pos, leopards.home
    move_draw, step_draw, pick = draws[0], draws[1], draws[2]
    new = pos.copy()
    for i in range(len(pos)):
        step = steps[1 + np.int64(step_draw[i] * 4)]
        d_row, d_col = step[0], step[1]
        if max(abs(pos[i, 0] - home[i, 0]), abs(pos[i, 1] - home[i, 1])) > leopards.home_range:
            d_row, d_col = _toward_step(pos[i], home[i], pick[i])
        if not move_draw[i] < leopards.move_prob:
            d_row, d_col = np.int64(0), np.int64(0)
        new[i, 0] = min(max(pos[i, 0] + d_row, 0), height - 1)
        new[i, 1] = min(max(pos[i, 1] + d_col, 0), width - 1)
    return new

@njit(cache=True)
def move_ground_actors(draws: np.ndarray, ground: Ground, active: np.ndarray,
                       uav_cells: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """One step of the leopards and, if any poacher is active, of the poachers, in one call: :func:`move_leopards`,
    :func:`poacher_targets`, :func:`move_poachers` and the track draw, in that order. The cells of the leopards and the
    poachers and which of them moved are updated in place.

    :param draws: the uniform draws those calls make, in their order: ``3 L`` for the leopards, then ``5 P`` (four
        rows for the poachers' moves, one for their tracks) when any poacher is active (one numpy call draws the
        same stream as their several)
    :param active: ``(P,)`` poachers in play (poaching ones, with a running timer, do not move)
    :param uav_cells: the airborne UAVs' cells ``(k, 2)`` (what the poachers notice)
    :return: the cells of the tracks the poachers left ``(k, 2)``
    """
    leopards, poachers = ground.leopards, ground.poachers
    height, width = ground.cover.shape
    n_leopards, n = len(leopards.pos), len(poachers.pos)
    walk = draws[:3 * n_leopards].reshape(3, n_leopards)
    new_leopards = move_leopards(leopards, height, width, ground.steps, walk)
    leopards.moved[:] = (new_leopards[:, 0] != leopards.pos[:, 0]) | (new_leopards[:, 1] != leopards.pos[:, 1])
    leopards.pos[:] = new_leopards
    if len(draws) == 3 * n_leopards:  # no poacher active
        poachers.moved[:] = False
        return np.zeros((0, 2), dtype=np.int64)
    target = poacher_targets(poachers.pos, new_leopards, leopards.alive, poachers.planned, poachers.sight)
    moves = draws[3 * n_leopards:].reshape(5, n)
    new_poachers, moved = move_poachers(poachers, active & (poachers.timer == 0), target, uav_cells, ground.cover,
                                        ground.steps, moves[:4])
    poachers.pos[:] = new_poachers
    poachers.moved[:] = moved
    return new_poachers[moved & (moves[4] < poachers.track_prob)]

@njit(cache=True)
def enter_poachers(poachers: Poachers, t: int) -> int:  # pragma: no cover - compiled
    """The waiting poachers whose entry time ``t`` has come enter play; returns how many did."""
    entered = 0
    for i in range(len(poachers.status)):
        if poachers.status[i] == POACHER_WAITING and poachers.entry_time[i] <= t:
            poachers.status[i] = POACHER_ACTIVE
            entered += 1
    return entered

@njit(cache=True)
def move_jammer(jammer: np.ndarray, poachers: np.ndarray, active: np.ndarray) -> None:  # pragma: no cover - compiled
    """``jammer[:] = poachers[active].mean(axis=0)`` (the cells are whole numbers: any order sums them exactly)."""
    total_row, total_col = 0.0, 0.0
    for i in range(len(poachers)):
        if active[i]:
            total_row += poachers[i, 0]
            total_col += poachers[i, 1]
    jammer[0], jammer[1] = total_row / active.sum(), total_col / active.sum()

@njit(cache=True)
def poaching_timers(poachers: np.ndarray, status: np.ndarray, leopards: np.ndarray, alive: np.ndarray,
                    timer: np.ndarray, poaching_time: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.bool_]:
    # pragma: no cover - compiled
    """Which active poacher (``status == POACHER_ACTIVE``) is next to (Chebyshev distance <= 1) which live leopard
    ``(P, L)``, each poacher's timer (one more step if it is next to one, else 0), which timers reached
    ``poaching_time`` and whether any did."""
    near = np.zeros((len(poachers), len(leopards)), dtype=np.bool_)
    timer = timer.copy()
    done = np.zeros(len(poachers), dtype=np.bool_)
    for i in range(len(poachers)):
        any_near = False
        if status[i] == POACHER_ACTIVE:
            for j in range(len(leopards)):
                if alive[j] and max(abs(poachers[i, 0] - leopards[j, 0]), abs(poachers[i, 1] - leopards[j, 1])) <= 1:
                    near[i, j] = True
                    any_near = True
        timer[i] = timer[i] + 1 if any_near else 0
        done[i] = timer[i] >= poaching_time
    return near, timer, done, done.any()

@njit(cache=True)
def poach(near: np.ndarray, done: np.ndarray, poachers: Poachers, alive: np.ndarray) -> np.ndarray:  # pragma: no cover
    """The poachers whose timer ran out (``done``) kill the leopard they are next to (the first in ``near``'s row;
    one event per leopard) and leave (their status, timer and the leopards' ``alive`` in place); returns the leopards
    killed."""
    killed = np.zeros(len(alive), dtype=np.bool_)
    for i in range(len(done)):
        if done[i]:
            killed[np.argmax(near[i])] = True
            poachers.status[i] = POACHER_GONE
            poachers.timer[i] = 0
    victims = np.flatnonzero(killed)
    for j in victims:
        alive[j] = False
    return victims
