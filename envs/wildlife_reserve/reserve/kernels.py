"""The reserve's hot loops, compiled with numba.

At 10 UAVs a step of the reserve is dominated by fixed numpy call overhead on small arrays, not by
arithmetic; these loops replace chains of small array operations with compiled code, and a step after
the actions' decoding is one compiled call (:func:`advance_world`). Each kernel computes exactly what
the numpy expression in its docstring computes (same float32/float64 arithmetic, same random draws:
numpy's own generator, called from compiled code through ``stream.handle``), so results are bit-identical.
Compiled code is cached beside this file (``cache=True``): the first import on a machine compiles
for a few seconds, later ones load the cache.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from wildlife_reserve.reserve.constants import (
    CH_LEOPARD,
    CH_OCCLUSION,
    CH_POACHER,
    CH_RISK,
    CH_SIGN,
    CH_STALENESS,
    CH_UAV,
    COMM_NONE,
    N_COMMS,
    N_MOVES,
    NEVER,
    POACHER_ACTIVE,
    POACHER_CAUGHT,
    POACHER_GONE,
    POACHER_WAITING,
)
from wildlife_reserve.reserve.stream import standard_normal, uniform


class ActionError(ValueError):
    """A discrete action out of range, raised by :func:`advance_world` before it changes anything (the reserve
    re-raises it as a ``ValueError`` naming the actions)."""


class Step(NamedTuple):
    """What changes at every step: the addresses of the step's random stream (``stream.handle``), the step ``t`` (after
    its increment), the actions (``choices``: ``(n,)`` discrete ones to decode into ``move`` ``(n, 2)`` and ``comm``
    ``(n,)``, or none and those two already decoded), the observations to write ``obs`` ``(n, obs_dim)``, the sign
    records in use ``sign_count`` and the team's record of poacher readings ``events`` (rows ``(time, uav, block)``)."""

    addresses: np.ndarray
    t: int
    choices: np.ndarray
    move: np.ndarray
    comm: np.ndarray
    obs: np.ndarray
    sign_count: int
    events: np.ndarray


class Flight(NamedTuple):
    """The UAVs as their flight moves them (updated in place): positions ``pos`` and ``velocity`` ``(n, 2)``,
    ``battery`` and ``grounded`` ``(n,)``, their ``cells`` ``(n, 2)`` and the padded flat cells of their windows
    ``window`` ``(n, w, w)``; and the flight's constants: ``speed``, the positions' ``upper`` bounds ``(2,)``, the energy
    of hovering, of moving one unit and of each communication choice ``comm_costs`` (none, broadcast, query), the padded
    grids' width and the flat offsets of a window's cells ``window_offsets`` ``(w, w)``."""

    pos: np.ndarray
    velocity: np.ndarray
    battery: np.ndarray
    grounded: np.ndarray
    cells: np.ndarray
    window: np.ndarray
    speed: float
    upper: np.ndarray
    hover: float
    move_cost: float
    comm_costs: np.ndarray
    padded_width: int
    window_offsets: np.ndarray


class Leopards(NamedTuple):
    """The leopards: cells ``pos`` ``(L, 2)``, which moved this step ``moved``, their dens ``home`` ``(L, 2)``, which are
    ``alive`` (updated in place), how far from the den they roam (``home_range``, Chebyshev) and their chance to move
    each step."""

    pos: np.ndarray
    moved: np.ndarray
    home: np.ndarray
    alive: np.ndarray
    home_range: float
    move_prob: float


class Poachers(NamedTuple):
    """The poachers: cells ``pos`` ``(P, 2)``, which moved this step ``moved``, their ``status`` (``POACHER_*``),
    poaching ``timer``, ``planned`` target dens ``(P, 2)`` and ``entry_time`` (updated in place); how far they see a
    leopard (``sight``) and notice a UAV (``notice_radius``), the strategy's chances to move, wander and evade and
    whether they hide in cover, the chance that a move leaves a track and the steps of poaching that kill a leopard."""

    pos: np.ndarray
    moved: np.ndarray
    status: np.ndarray
    timer: np.ndarray
    planned: np.ndarray
    entry_time: np.ndarray
    sight: float
    notice_radius: float
    move_prob: float
    wander_prob: float
    evasion_prob: float
    hide_in_cover: bool
    track_prob: float
    poaching_time: int


class Jammer(NamedTuple):
    """The jammer of the adversarial condition: its position ``pos`` ``(2,)`` (moved in place), which UAVs it silences
    ``jammed`` ``(n,)`` (written), whether the episode has one (``present``) and its ``radius``."""

    pos: np.ndarray
    jammed: np.ndarray
    present: bool
    radius: float


class Ground(NamedTuple):
    """The ground actors (:class:`Leopards`, :class:`Poachers`, the :class:`Jammer`), the cells that give ``cover``
    ``(height, width)`` and the unit ``steps`` ``(5, 2)`` (stay, up, down, left, right)."""

    leopards: Leopards
    poachers: Poachers
    jammer: Jammer
    cover: np.ndarray
    steps: np.ndarray


class SignRecords(NamedTuple):
    """The signs' records (``signs.Signs.record``; updated in place, with room for a step's new signs): the flat padded
    ``grid`` of record indices (-1: none), its ``pad`` and ``width``, the ``block_of`` each cell ``(height, width)``,
    the ``lifetime`` of each kind; each record's cell ``pos`` ``(S, 2)``, ``born``, ``expires``, ``kind``, ``block`` and
    whether the team ``found`` it (``(S,)``); which kinds are ``real`` signs of poachers, and the kinds a step makes
    (tracks, carcasses, false readings)."""

    grid: np.ndarray
    pad: int
    width: int
    block_of: np.ndarray
    lifetime: np.ndarray
    pos: np.ndarray
    born: np.ndarray
    expires: np.ndarray
    kind: np.ndarray
    block: np.ndarray
    found: np.ndarray
    real: np.ndarray
    track_kind: int
    carcass_kind: int
    false_kind: int


class Sensing(NamedTuple):
    """What the sensors read: the ``detection`` table ``[distance, terrain, moved]``, the ``terrain`` ``(height,
    width)``, the nominal ``radius``, the ``false_alarm`` chance per UAV-step, the window offsets within the weather's
    reach ``reach_offsets`` ``(k, 2)``, the ``decoys`` ``(D, 2)`` and their ``decoy`` table ``[distance]``, the ``sign``
    table ``(w * w, terrain types)``, the flat padded ``terrain_pad``, the standard deviation of the noise on the signal
    channels ``signal_noise`` (``sensing.SIGNAL_NOISE_STD * sensor_noise``) and the readings ``signals`` ``(n, 3, w, w)``
    (written)."""

    detection: np.ndarray
    terrain: np.ndarray
    radius: int
    false_alarm: float
    reach_offsets: np.ndarray
    decoys: np.ndarray
    decoy: np.ndarray
    sign: np.ndarray
    terrain_pad: np.ndarray
    signal_noise: float
    signals: np.ndarray


class Team(NamedTuple):
    """The team's knowledge (``knowledge.TeamKnowledge.record``; updated in place): ``knowledge`` ``(n, n)``, the
    cells' visit ``stamps`` ``(cells, 2, n)``, the blocks' ``block_last`` and ``block_first`` ``(n, blocks)``, which sign
    records each UAV knows of ``known`` ``(n, capacity)`` and their ``counts`` by block, the distances ``dist``, the
    ``beacons`` heard and the messages delivered ``comm_links`` ``(n, n)``; the staleness scale ``time_scale``
    (``1 / max_cycles``), ``comm_radius``, ``comm_loss``, the readings' ``horizon`` and the belief's ``belief_decay``."""

    knowledge: np.ndarray
    stamps: np.ndarray
    block_last: np.ndarray
    block_first: np.ndarray
    known: np.ndarray
    counts: np.ndarray
    dist: np.ndarray
    beacons: np.ndarray
    comm_links: np.ndarray
    time_scale: np.float32
    comm_radius: float
    comm_loss: float
    horizon: float
    belief_decay: float


class Coverage(NamedTuple):
    """What the UAVs' looks mark: the flat padded ``high_risk`` cells (those the coverage term pays for), those the
    team has seen ``visited`` (updated in place), and the staleness each UAV knew before this step's look, of its window
    cells ``stale_cells`` ``(n, w * w)`` and of the blocks ``stale_blocks`` ``(n, blocks)`` (written)."""

    high_risk: np.ndarray
    visited: np.ndarray
    stale_cells: np.ndarray
    stale_blocks: np.ndarray


class Observe(NamedTuple):
    """What the observations show besides the flight and the team: the flat padded ``occlusion`` and ``risk``, the
    window staleness ``staleness`` ``(n, w, w)``, the readings ``signals`` ``(n, 3, w, w)``, the block staleness
    ``block_staleness`` ``(n, blocks)``, the sensor ``radius``, ``inv_scale`` ``(2,)`` (``1 / (side - 1)``), the
    neighbours' ``neighbour_scale`` (``1 / R_c``) and how many are shown, the sign map's values by count, where the own,
    neighbour and map parts start in a row, and ``max_cycles`` (the progress)."""

    occlusion: np.ndarray
    risk: np.ndarray
    staleness: np.ndarray
    signals: np.ndarray
    block_staleness: np.ndarray
    radius: int
    inv_scale: np.ndarray
    neighbour_scale: float
    max_neighbours: int
    sign_values: np.ndarray
    own: int
    neighbours: int
    maps: int
    max_cycles: int


class Rewards(NamedTuple):
    """The reward's ``weights`` (detection, coverage, sign, poaching, collision, energy) and its ``shaping``."""

    weights: tuple
    shaping: float


class Tally(NamedTuple):
    """What a step counts for the team's reward: poachers detected, new high-risk cells seen, real signs found, poaching
    events and collisions (pairs)."""

    detected: int
    new_cells: int
    signs_found: int
    poaching_events: int
    collisions: int


class Candidates(NamedTuple):
    """Sign sightings a step may make (:func:`sign_candidates`): the UAV, the window cell (flat), the sign record and
    the chance, each ``(k,)``."""

    uav: np.ndarray
    cell: np.ndarray
    sign: np.ndarray
    p: np.ndarray


class Spots(NamedTuple):
    """Spurious readings (:func:`false_reading_cells`, :func:`decoy_reading_cells`): the reading UAVs ``(k,)``, the
    offsets from them ``(k, 2)`` and the cells ``(k, 2)``."""

    uav: np.ndarray
    offsets: np.ndarray
    cells: np.ndarray


class Looks(NamedTuple):
    """A step's looks: the step ``t`` (float32), the padded flat cells of each UAV's window ``window`` ``(n, w * w)``,
    the block under each UAV ``cell_blocks`` ``(n,)`` and which UAVs are ``airborne``."""

    t: np.float32
    window: np.ndarray
    cell_blocks: np.ndarray
    airborne: np.ndarray


class Talk(NamedTuple):
    """A step's talk: the UAVs' positions ``pos`` ``(n, 2)``, which can talk ``ok`` (airborne, unjammed), their
    communication choices ``comm`` (0 none, 1 broadcast, 2 query) and the uniform draws of the beacons and of the
    messages ``(n, n)`` each."""

    pos: np.ndarray
    ok: np.ndarray
    comm: np.ndarray
    beacon_draws: np.ndarray
    message_draws: np.ndarray


class World(NamedTuple):
    """Everything a step reads and updates but the :class:`Step` itself, by phase (``ReserveParallelEnv._world``
    builds it; it crosses into :func:`advance_world` as plain tuples, named again inside)."""

    flight: Flight
    ground: Ground
    signs: SignRecords
    sensing: Sensing
    team: Team
    coverage: Coverage
    observe: Observe
    rewards: Rewards


@njit(cache=True, inline="always")
def _known_stamp(newer: np.float32, older: np.float32, known: np.float32) -> np.float32:  # pragma: no cover
    """A source's stamp as a receiver that knows it up to ``known`` sees it: its last visit ``newer`` if that is
    known, else its first visit ``older`` if that is, else ``NEVER``."""
    return newer if newer <= known else (older if older <= known else NEVER)


@njit(cache=True)
def known_ages(stamps: np.ndarray, knowledge: np.ndarray, cells: np.ndarray, t: np.float32, scale: np.float32,
               newest: np.float32) -> np.ndarray:  # pragma: no cover - compiled
    """Age in [0, 1] of the newest visit each receiver knows of, at its own cells.

    ``ages[r, c] = min((t - max_s seen[s, r, c]) * scale, 1)`` with ``seen = last[cells[r, c], s]`` if that
    is ``<= knowledge[r, s]``, else ``first[cells[r, c], s]`` if that is, else ``NEVER``, where ``last`` and
    ``first`` are ``stamps[:, 0]`` and ``stamps[:, 1]``.

    The maximum is taken over the sources the receiver knows anything of (``knowledge > NEVER``: the others add
    ``NEVER``), the receiver's own stamps first, and stops at a stamp equal to ``newest``, which no stamp may exceed
    (the step of the latest look): for most cells of a UAV's window its own look of the step before decides.

    :param stamps: ``(m, 2, n)`` integer last- and first-visit times at each cell of each source, never-seen cells at
        the dtype's least and greatest value (``knowledge.pack_stamps``; cell-major: a cell's stamps of every source
        in one run of memory, 40 bytes at 10 UAVs in int16; the least value reads as an age of 1, as ``NEVER`` does,
        since the stamps are int16 only in episodes shorter than int16's greatest value)
    :param knowledge: ``(n, n)`` float32, ``knowledge[r, s]``
    :param cells: ``(n, c)`` cell indices (into the first axis of ``stamps``) per receiver
    """
    n, c = cells.shape
    ages = np.empty((n, c), dtype=np.float32)
    one = np.float32(1.0)
    sources = np.empty(n, dtype=np.int64)
    for r in range(n):
        m = 0
        if knowledge[r, r] > NEVER:
            sources[0] = r
            m = 1
        for s in range(n):
            if s != r and knowledge[r, s] > NEVER:
                sources[m] = s
                m += 1
        for j in range(c):
            cell = cells[r, j]
            best = NEVER
            for q in range(m):
                s = sources[q]
                best = max(best, _known_stamp(np.float32(stamps[cell, 0, s]), np.float32(stamps[cell, 1, s]),
                                              knowledge[r, s]))
                if best >= newest:
                    break
            age = (t - best) * scale
            ages[r, j] = age if age < one else one
    return ages


@njit(cache=True)
def known_block_ages(last: np.ndarray, first: np.ndarray, knowledge: np.ndarray, t: np.float32,
                     scale: np.float32) -> np.ndarray:  # pragma: no cover - compiled
    """:func:`known_ages` of every block for every receiver, ``(n, blocks)``, from block stamps ``last`` and
    ``first`` ``(n, blocks)`` (source-major, unlike the cells': every block of a source is read at once). For each
    receiver the sources it knows anything of (``knowledge > NEVER``: the others add ``NEVER``) are folded into a row
    of maxima over the blocks, a loop the compiler vectorises (about 2.4x faster than the per-block maximum over the
    sources at 10 UAVs)."""
    n, blocks = knowledge.shape[0], last.shape[1]
    ages = np.empty((n, blocks), dtype=np.float32)
    best = np.empty(blocks, dtype=np.float32)
    one = np.float32(1.0)
    for r in range(n):
        best[:] = NEVER
        for s in range(n):
            known = knowledge[r, s]
            if known == NEVER:
                continue
            for b in range(blocks):
                best[b] = max(best[b], _known_stamp(last[s, b], first[s, b], known))
        for b in range(blocks):
            age = (t - best[b]) * scale
            ages[r, b] = age if age < one else one
    return ages


@njit(cache=True)
def merge_messages(delivered: np.ndarray, knowledge: np.ndarray, known: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """What each receiver knows after this step's messages (one hop: what the senders knew before them).

    ``knowledge[r] = max(knowledge[r], knowledge[s] for every s with delivered[s, r])``, and ``learned[r, i]``:
    some sender of ``r`` knew of sign ``i`` and ``r`` did not.

    :param delivered: ``(n, n)`` bool, ``delivered[s, r]``
    :param knowledge: ``(n, n)`` float32
    :param known: ``(n, k)`` bool, which signs each UAV knows of
    :return: the new knowledge ``(n, n)`` and ``learned`` ``(n, k)``
    """
    n, k = known.shape
    merged = knowledge.copy()
    learned = np.zeros((n, k), dtype=np.bool_)
    for r in range(n):
        for s in range(n):
            if delivered[s, r]:
                for j in range(n):
                    if knowledge[s, j] > merged[r, j]:
                        merged[r, j] = knowledge[s, j]
                for i in range(k):
                    if known[s, i] and not known[r, i]:
                        learned[r, i] = True
    return merged, learned


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


@njit(cache=True)
def look(team: Team, coverage: Coverage, uavs: np.ndarray, seen: np.ndarray, blocks: np.ndarray,
         t: np.float32) -> tuple[np.ndarray, int]:  # pragma: no cover - compiled
    """The airborne ``uavs`` look at padded flat cells ``seen`` ``(k, c)`` from above ``blocks`` ``(k,)``: stamp each
    one's own visit history of cells and blocks (``stamps[cell, 0, u] = t``, ``stamps[cell, 1, u] = min(first, t)``:
    the cells' stamps are packed cell-major, see :func:`known_ages`, the blocks' source-major,
    ``block_last[u, block]``), set its knowledge of itself to ``t``, and mark the team's coverage ``visited``.

    :return: high-risk cells each UAV sees that nobody had seen before this step ``(k,)`` (cells two UAVs see at
        once count for both), and the number of high-risk cells the team sees for the first time
    """
    high_risk, visited, stamps = coverage.high_risk, coverage.visited, team.stamps
    block_last, block_first = team.block_last, team.block_first
    k, c = seen.shape
    fresh = np.zeros(k, dtype=np.int64)
    for a in range(k):
        for j in range(c):
            cell = seen[a, j]
            if high_risk[cell] and not visited[cell]:
                fresh[a] += 1
    new = 0
    for a in range(k):
        u = uavs[a]
        for j in range(c):
            cell = seen[a, j]
            if not visited[cell]:
                visited[cell] = True
                if high_risk[cell]:
                    new += 1
            stamps[cell, 0, u] = t
            if t < stamps[cell, 1, u]:
                stamps[cell, 1, u] = t
        block_last[u, blocks[a]] = t
        if t < block_first[u, blocks[a]]:
            block_first[u, blocks[a]] = t
        team.knowledge[u, u] = t
    return fresh, new


@njit(cache=True)
def links_in_range(pos: np.ndarray, ok: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover
    """Euclidean distances ``(n, n)`` between the UAVs and the links: both ``ok`` and within ``radius``, not self."""
    n = len(pos)
    dist = np.empty((n, n))
    links = np.zeros((n, n), dtype=np.bool_)
    for s in range(n):
        for r in range(n):
            d_row, d_col = pos[s, 0] - pos[r, 0], pos[s, 1] - pos[r, 1]
            dist[s, r] = np.sqrt(d_row * d_row + d_col * d_col)
            links[s, r] = s != r and dist[s, r] <= radius and ok[s] and ok[r]
    return dist, links


@njit(cache=True)
def deliver(links: np.ndarray, comm: np.ndarray, dist: np.ndarray, draws: np.ndarray,
            loss: float) -> np.ndarray:  # pragma: no cover - compiled
    """``delivered[s, r]``: a message of ``s`` reached ``r``. A broadcasting UAV sends to every UAV it is linked with;
    the nearest linked UAV of a querying one (the first of equals) answers it; each message is lost when its
    ``draws[s, r] < loss``.

    :param comm: ``(n,)`` communication choices (0 none, 1 broadcast, 2 query)
    """
    n = len(links)
    sent = np.zeros((n, n), dtype=np.bool_)
    for s in range(n):
        if comm[s] == 1:
            for r in range(n):
                sent[s, r] = links[s, r]
    for asker in range(n):
        if comm[asker] == 2:
            source, best = -1, np.inf
            for s in range(n):
                if links[s, asker] and dist[s, asker] < best:
                    source, best = s, dist[s, asker]
            if source >= 0:
                sent[source, asker] = True
    for s in range(n):
        for r in range(n):
            sent[s, r] = sent[s, r] and draws[s, r] >= loss
    return sent


@njit(cache=True)
def look_and_talk(team: Team, coverage: Coverage, looks: Looks, talk: Talk,
                  sign_blocks: np.ndarray) -> tuple[np.ndarray, int]:  # pragma: no cover - compiled
    """One step of the team's knowledge in one call (each part is the kernel named, in this order): the staleness
    of every window cell and block as each UAV knew it before this step (``known_ages``, ``known_block_ages``, into
    the coverage's ``stale_cells`` and ``stale_blocks``), the airborne UAVs' look (``look``), the links in range and
    their distances (``links_in_range``, into ``dist``), the beacons heard (``beacon_draws >= comm_loss``, into
    ``beacons``), the messages delivered (``deliver``, into ``comm_links``) and what they carry (``merge_messages``;
    the signs learned go through ``learn_signs``, by ``sign_blocks``, the block of each sign record in use).
    Everything is updated in place: the stamps, ``visited``, ``knowledge``, ``known``, ``counts`` and the outputs
    named.

    :return: the high-risk cells each UAV saw that nobody had seen before ``(n,)``, and the team's new ones
    """
    t, window, cell_blocks = looks.t, looks.window, looks.cell_blocks
    known = team.known[:, :len(sign_blocks)]
    newest = t - np.float32(1.0)  # the stamps are of looks before this step's
    coverage.stale_cells[:] = known_ages(team.stamps, team.knowledge, window, t, team.time_scale, newest)
    coverage.stale_blocks[:] = known_block_ages(team.block_last, team.block_first, team.knowledge, t, team.time_scale)
    uavs = np.flatnonzero(looks.airborne)
    fresh = np.zeros(len(window), dtype=np.int64)
    fresh[uavs], new = look(team, coverage, uavs, window[uavs], cell_blocks[uavs], t)
    distances, links = links_in_range(talk.pos, talk.ok, team.comm_radius)
    team.dist[:] = distances
    team.beacons[:] = links & (talk.beacon_draws >= team.comm_loss)
    team.comm_links[:] = deliver(links, talk.comm, distances, talk.message_draws, team.comm_loss)
    merged, learned = merge_messages(team.comm_links, team.knowledge, known)
    team.knowledge[:] = merged
    who, sign = np.nonzero(learned)
    learn_signs(known, team.counts, who, sign, sign_blocks[sign])
    return fresh, new


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
def learn_signs(known: np.ndarray, counts: np.ndarray, uavs: np.ndarray, signs: np.ndarray,
                blocks: np.ndarray) -> None:  # pragma: no cover - compiled
    """UAV ``uavs[a]`` learns of sign ``signs[a]`` (in block ``blocks[a]``): counted once per UAV."""
    for a in range(len(uavs)):
        if not known[uavs[a], signs[a]]:
            known[uavs[a], signs[a]] = True
            counts[uavs[a], blocks[a]] += 1.0


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
def pairwise_sum(values: np.ndarray) -> float:  # pragma: no cover - compiled
    """``np.add.reduce(values)`` of a contiguous float64 vector, bit for bit: numpy's pairwise summation (eight
    accumulators in blocks of up to 128, halves above that; numba's ``sum`` adds in order, which rounds
    differently)."""
    n = len(values)
    if n < 8:
        total = 0.0
        for i in range(n):
            total += values[i]
        return total
    if n <= 128:
        r = values[:8].copy()
        i = 8
        while i < n - n % 8:
            for j in range(8):
                r[j] += values[i + j]
            i += 8
        total = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]))
        while i < n:
            total += values[i]
            i += 1
        return total
    half = n // 2
    half -= half % 8
    return pairwise_sum(values[:half]) + pairwise_sum(values[half:])


@njit(cache=True)
def step_rewards(rewards: Rewards, tally: Tally, energy: np.ndarray, seen: np.ndarray, own_new: np.ndarray,
                 own_collisions: np.ndarray) -> tuple[np.ndarray, float, float]:  # pragma: no cover - compiled
    """Each UAV's reward ``(n,)``, the team reward and the energy spent ``energy.sum()``.

    The team's is ``detection * detected + coverage * new_cells + sign * signs_found - poaching * poaching_events -
    collision * collisions - energy * spent`` (the ``tally``; ``weights`` in that order); with ``shaping > 0`` each UAV
    gets ``(1 - shaping) * team + shaping * own``, ``own`` the same terms of its own (``seen`` ``(n, P)`` the poachers
    it detected, ``own_new`` its first looks, ``own_collisions``, its ``energy``).
    """
    detection, coverage, sign, poaching, collision, energy_weight = rewards.weights
    shaping = rewards.shaping
    spent = pairwise_sum(energy)
    team = (detection * tally.detected + coverage * tally.new_cells + sign * tally.signs_found
            - poaching * tally.poaching_events - collision * tally.collisions - energy_weight * spent)
    out = np.full(len(energy), team)
    if shaping > 0:
        for u in range(len(energy)):
            own = (detection * seen[u].sum() + coverage * own_new[u] - collision * own_collisions[u]
                   - energy_weight * energy[u])
            out[u] = (1.0 - shaping) * team + shaping * own
    return out, team, spent


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
def move_jammer(jammer: np.ndarray, poachers: np.ndarray, active: np.ndarray) -> None:  # pragma: no cover - compiled
    """``jammer[:] = poachers[active].mean(axis=0)`` (the cells are whole numbers: any order sums them exactly)."""
    total_row, total_col = 0.0, 0.0
    for i in range(len(poachers)):
        if active[i]:
            total_row += poachers[i, 0]
            total_col += poachers[i, 1]
    jammer[0], jammer[1] = total_row / active.sum(), total_col / active.sum()


@njit(cache=True)
def jam(jammer: Jammer, airborne: np.ndarray, pos: np.ndarray, jammer_on: bool) -> np.ndarray:  # pragma: no cover
    """Which UAVs the jammer silences (its ``jammed``, in place: within its radius while it is on) and which can
    talk: the ``airborne`` ones not jammed."""
    jammed = jammer.jammed
    ok = airborne.copy()
    for u in range(len(pos)):
        jammed[u] = False
        if jammer_on:
            d_row, d_col = pos[u, 0] - jammer.pos[0], pos[u, 1] - jammer.pos[1]
            jammed[u] = np.sqrt(d_row ** 2 + d_col ** 2) <= jammer.radius
            ok[u] &= not jammed[u]
    return ok


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


@njit(cache=True)
def record_readings_seen(events: np.ndarray, readings: np.ndarray, now: float, block_of: np.ndarray,
                         horizon: float) -> np.ndarray:  # pragma: no cover - compiled
    """The team's record of poacher readings ``events`` (rows ``(time, uav, block)``, in time order) with this step's
    ``readings`` ``(k, 3)`` ``(uav, row, col)`` added and those older than ``horizon`` dropped (a new array when
    either happens)."""
    if len(readings):
        fresh = np.empty((len(readings), 3))
        for a in range(len(readings)):
            fresh[a, 0], fresh[a, 1] = now, readings[a, 0]
            fresh[a, 2] = block_of[readings[a, 1], readings[a, 2]]
        events = np.concatenate((events, fresh))
    if len(events) and events[0, 0] <= now - horizon:
        events = events[events[:, 0] > now - horizon]
    return events


def plain(record: tuple) -> tuple:
    """``record`` (a record of this module, its fields records or not) as the plain tuples :func:`advance_world` takes
    (:func:`named` names them again inside)."""
    return tuple(plain(field) if hasattr(field, "_fields") else field for field in record)


@njit(cache=True)
def named(step: tuple, world: tuple) -> tuple[Step, World]:  # pragma: no cover - compiled
    """:func:`advance_world`'s plain tuples as the records they are (:class:`Step`, :class:`World`): numba types a plain
    tuple argument in its C fast path and a named one in Python at every call, so the records cross as plain tuples
    and are named here, at no cost."""
    flight, ground, signs, sensing, team, coverage, observe, rewards = world
    leopards, poachers, jammer, cover, steps = ground
    return Step(*step), World(Flight(*flight), Ground(Leopards(*leopards), Poachers(*poachers), Jammer(*jammer), cover,
                                                      steps), SignRecords(*signs), Sensing(*sensing), Team(*team),
                               Coverage(*coverage), Observe(*observe), Rewards(*rewards))


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
def advance_world(step: tuple, world: tuple) -> tuple:  # pragma: no cover - compiled
    """A step in one compiled call, with its random draws taken from the step's stream (``step.addresses``) in the
    order the phases make them. ``step`` is a :class:`Step` and ``world`` a :class:`World`, as plain tuples
    (:func:`named`):

    0. **Actions**: discrete ``choices`` (empty when ``move`` and ``comm`` are already decoded) are decoded into
       ``move`` and ``comm`` (:func:`decode_actions`); one out of range raises :class:`ActionError` before anything
       changes. Then the poachers whose entry time has come enter play (:func:`enter_poachers`).
    1. **Flight** (:func:`fly_and_collide`): the UAVs move and spend energy; collisions among those airborne before it.
    2. **Ground** (:func:`move_ground_actors` on ``3 L`` uniform draws, then ``5 P`` if any poacher is active): the
       leopards and poachers move; the poachers' tracks become signs born now (:func:`place_signs`); the jammer, if
       any, moves to the active poachers' mean cell; the live signs in the airborne UAVs' windows
       (:func:`sign_candidates`).
    3. **Sensing** (:func:`sense` on ``n (P + L + 2 + D + 2) + k`` uniform draws): detections, false alarms, decoys,
       sign sightings, false sign readings (records only the reading UAV knows of: :func:`add_signs_off_grid`,
       :func:`learn_signs`); caught poachers leave play; the noise on the signal channels (:func:`noisy_signals`,
       normal draws) when ``signal_noise > 0``.
    4. **Poaching** (:func:`poaching_timers`, :func:`poach`): an undetected poacher next to a live leopard for
       ``poaching_time`` steps kills it (one event per leopard) and leaves (a carcass sign where the leopard was).
    5. **Sharing** (:func:`look_and_talk` on ``2 n n`` uniform draws, then :func:`fill_observations` and
       :func:`sender_masks`): the UAVs not jammed talk; the poacher readings join the team's record ``events`` (those
       older than ``horizon`` dropped); every UAV's observation is written into ``obs``.
    6. **Rewards** (:func:`step_rewards`).

    Every array of ``world`` is updated in place; the record of readings is returned. The sign records and the team's
    ``known`` must have room for ``P`` tracks, ``n`` false readings and ``L`` carcasses more.

    :return: the poachers that entered, the rewards ``(n,)``, the team reward, the energy spent, whether every UAV
        is grounded, the collisions (pairs), the poacher readings ``(k, 3)`` ``(uav, row, col)``, poachers caught,
        false poacher readings, real signs found for the first time, poaching events, the sign records in use,
        whether the jammer is on, the readings record ``events``, the team's new high-risk cells and the senders'
        bit masks of ``heard_from`` (empty above 63 UAVs)
    """
    step, world = named(step, world)
    flight, ground, signs, sensing, team, coverage = (world.flight, world.ground, world.signs, world.sensing,
                                                      world.team, world.coverage)
    poachers, leopards, addresses, t = ground.poachers, ground.leopards, step.addresses, step.t
    n, n_poachers, n_leopards = len(flight.cells), len(poachers.pos), len(leopards.pos)
    window = flight.window.reshape(n, -1)
    now = np.float64(t)
    count = step.sign_count

    # 0. Actions, and the poachers due.
    if len(step.choices):
        move, comm, valid = decode_actions(step.choices, ground.steps.astype(np.float64), N_MOVES, N_COMMS)
        if not valid:
            raise ActionError("discrete action out of range")
        step.move[:] = move
        step.comm[:] = comm
    entered = enter_poachers(poachers, t)

    # 1. Flight.
    airborne = ~flight.grounded
    energy, everyone, own_collisions, pairs = fly_and_collide(flight, step.move, step.comm)

    # 2. Ground.
    active = poachers.status == POACHER_ACTIVE
    any_active = active.any()
    draws = uniform(addresses, 3 * n_leopards + 5 * n_poachers * any_active)
    tracks = move_ground_actors(draws, ground, active, flight.cells[airborne])
    count = place_new_signs(signs, count, tracks, now, signs.track_kind)
    jammer_on = ground.jammer.present and any_active
    if jammer_on:
        move_jammer(ground.jammer.pos, poachers.pos, active)
    candidates = Candidates(*sign_candidates(signs.grid, signs.born, signs.expires, window, now, airborne,
                                             sensing.sign, sensing.terrain_pad))

    # 3. Sensing.
    sensing.signals[:] = 0.0
    draws = uniform(addresses, n * (n_poachers + n_leopards + 2 + len(sensing.decoys) + 2) + len(candidates.p))
    seen, caught, n_caught, readings, false_alarms, fresh_signs, f_uav, f_where = sense(
        draws, ground, flight.cells, airborne, sensing, candidates, team, signs)
    for i in range(n_poachers):
        if caught[i]:
            poachers.status[i] = POACHER_CAUGHT
    near, new_timer, done, any_done = poaching_timers(poachers.pos, poachers.status, leopards.pos, leopards.alive,
                                                      poachers.timer, poachers.poaching_time)
    if len(f_uav):  # false sign readings: phantom records that only the reading UAV knows of
        phantom = add_signs_off_grid(signs, f_where, now, signs.false_kind, count)
        count += len(phantom)
        learn_signs(team.known, team.counts, f_uav, phantom, signs.block[phantom])
    if sensing.signal_noise > 0:
        noisy_signals(addresses, sensing.signals, sensing.signal_noise)

    # 4. Poaching.
    poachers.timer[:] = new_timer
    events_now = 0
    if any_done:
        victims = poach(near, done, poachers, leopards.alive)
        events_now = len(victims)
        count = place_new_signs(signs, count, leopards.pos[victims], now, signs.carcass_kind)

    # 5. Sharing.
    ok = jam(ground.jammer, airborne, flight.pos, jammer_on)
    events = record_readings_seen(step.events, readings, now, signs.block_of, team.horizon)
    cell_blocks = np.empty(n, dtype=np.int64)
    for u in range(n):
        cell_blocks[u] = signs.block_of[flight.cells[u, 0], flight.cells[u, 1]]
    talk = uniform(addresses, 2 * n * n).reshape(2, n, n)
    fresh, new = look_and_talk(team, coverage, Looks(np.float32(t), window, cell_blocks, airborne),
                               Talk(flight.pos, ok, step.comm, talk[0], talk[1]), signs.block[:count])
    fill_observations(step.obs, world.observe, flight, team, events, now, min(t / world.observe.max_cycles, 1.0))
    masks = sender_masks(team.comm_links) if n <= 63 else np.zeros(0, dtype=np.int64)

    # 6. Rewards.
    rewards, team_reward, spent = step_rewards(world.rewards, Tally(n_caught, new, fresh_signs, events_now, pairs),
                                               energy, seen, fresh, own_collisions)
    return (entered, rewards, team_reward, spent, everyone, pairs, readings, n_caught, false_alarms, fresh_signs, events_now,
            count, jammer_on, events, new, masks)


@njit(cache=True)
def sender_masks(links: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """Each receiver's senders as a bit mask ``(n,)``, bit ``s`` set when ``links[s, r]`` (teams of up to 63)."""
    n = len(links)
    masks = np.zeros(n, dtype=np.int64)
    for r in range(n):
        mask = np.int64(0)
        for s in range(n):
            if links[s, r]:
                mask |= np.int64(1) << s
        masks[r] = mask
    return masks


@njit(cache=True)
def senders_by_receiver(links: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """The senders of ``links[s, r]`` grouped by receiver, ascending within each, and where each receiver's group
    ends ``(n,)``."""
    n = len(links)
    senders, ends = np.empty(n * n, dtype=np.int64), np.empty(n, dtype=np.int64)
    k = 0
    for r in range(n):
        for s in range(n):
            if links[s, r]:
                senders[k] = s
                k += 1
        ends[r] = k
    return senders[:k], ends
