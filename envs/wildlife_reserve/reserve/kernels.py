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
)
from wildlife_reserve.reserve.stream import standard_normal, uniform


class ActionError(ValueError):
    """A discrete action out of range, raised by :func:`advance_world` before it changes anything (the reserve
    re-raises it as a ``ValueError`` naming the actions)."""


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
def move_poachers(pos: np.ndarray, mobile: np.ndarray, target: np.ndarray, uav_cells: np.ndarray, notice_radius: float,
                  move_prob: float, wander_prob: float, evasion_prob: float, hide_in_cover: bool, cover: np.ndarray,
                  steps: np.ndarray, draw: np.ndarray, wander_draw: np.ndarray, pick: np.ndarray,
                  evade_draw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """Move the poachers one step: toward their target with ``move_prob``, a random step with ``wander_prob``, else
    wait; one that notices a UAV within ``notice_radius`` (Chebyshev) evades it with ``evasion_prob`` (hides when
    ``hide_in_cover`` and on cover, else flees); those not ``mobile`` stay.

    :param draw, wander_draw, pick, evade_draw: ``(P,)`` uniform draws each
    :return: new cells ``(P, 2)`` and who moved ``(P,)``
    """
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
            if best <= notice_radius and evade_draw[i] < evasion_prob:
                if hide_in_cover and cover[pos[i, 0], pos[i, 1]]:
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
def move_leopards(pos: np.ndarray, home: np.ndarray, home_range: float, height: int, width: int, move_prob: float,
                  steps: np.ndarray, move_draw: np.ndarray, step_draw: np.ndarray,
                  pick: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """Move the leopards one step: with ``move_prob``, a random step, or toward the den beyond ``home_range``
    (Chebyshev) of it.

    :param move_draw, step_draw, pick: ``(L,)`` uniform draws each
    """
    new = pos.copy()
    for i in range(len(pos)):
        step = steps[1 + np.int64(step_draw[i] * 4)]
        d_row, d_col = step[0], step[1]
        if max(abs(pos[i, 0] - home[i, 0]), abs(pos[i, 1] - home[i, 1])) > home_range:
            d_row, d_col = _toward_step(pos[i], home[i], pick[i])
        if not move_draw[i] < move_prob:
            d_row, d_col = np.int64(0), np.int64(0)
        new[i, 0] = min(max(pos[i, 0] + d_row, 0), height - 1)
        new[i, 1] = min(max(pos[i, 1] + d_col, 0), width - 1)
    return new


@njit(cache=True)
def move_ground_actors(draws: np.ndarray, leopards: np.ndarray, leopard_moved: np.ndarray, home: np.ndarray,
                       home_range: float, leopard_move_prob: float, poachers: np.ndarray, poacher_moved: np.ndarray,
                       active: np.ndarray, timer: np.ndarray, alive: np.ndarray, planned: np.ndarray, sight: float,
                       uav_cells: np.ndarray, notice_radius: float, move_prob: float, wander_prob: float,
                       evasion_prob: float, hide_in_cover: bool, cover: np.ndarray, steps: np.ndarray,
                       track_prob: float) -> np.ndarray:  # pragma: no cover - compiled
    """One step of the leopards and, if any poacher is active, of the poachers, in one call: :func:`move_leopards`,
    :func:`poacher_targets`, :func:`move_poachers` and the track draw, in that order. The cells ``leopards`` and
    ``poachers`` and which of them moved (``leopard_moved``, ``poacher_moved``) are updated in place.

    :param draws: the uniform draws those calls make, in their order: ``3 L`` for the leopards, then ``5 P`` (four
        rows for the poachers' moves, one for their tracks) when any poacher is active (one numpy call draws the
        same stream as their several)
    :param active: ``(P,)`` poachers in play; ``timer``: ``(P,)`` their poaching timers (poaching ones do not move)
    :return: the cells of the tracks the poachers left ``(k, 2)``
    """
    height, width = cover.shape
    n_leopards, n = len(leopards), len(poachers)
    walk = draws[:3 * n_leopards].reshape(3, n_leopards)
    new_leopards = move_leopards(leopards, home, home_range, height, width, leopard_move_prob, steps, walk[0], walk[1],
                                 walk[2])
    leopard_moved[:] = (new_leopards[:, 0] != leopards[:, 0]) | (new_leopards[:, 1] != leopards[:, 1])
    leopards[:] = new_leopards
    if len(draws) == 3 * n_leopards:  # no poacher active
        poacher_moved[:] = False
        return np.zeros((0, 2), dtype=np.int64)
    target = poacher_targets(poachers, new_leopards, alive, planned, sight)
    moves = draws[3 * n_leopards:].reshape(5, n)
    new_poachers, moved = move_poachers(poachers, active & (timer == 0), target, uav_cells, notice_radius, move_prob,
                                        wander_prob, evasion_prob, hide_in_cover, cover, steps, moves[0], moves[1],
                                        moves[2], moves[3])
    poachers[:] = new_poachers
    poacher_moved[:] = moved
    return new_poachers[moved & (moves[4] < track_prob)]


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
def look(uavs: np.ndarray, seen: np.ndarray, blocks: np.ndarray, high_risk: np.ndarray, visited: np.ndarray,
         stamps: np.ndarray, block_last: np.ndarray, block_first: np.ndarray, knowledge: np.ndarray,
         t: np.float32) -> tuple[np.ndarray, int]:  # pragma: no cover - compiled
    """The airborne ``uavs`` look at padded flat cells ``seen`` ``(k, c)`` from above ``blocks`` ``(k,)``: stamp each
    one's own visit history of cells and blocks (``stamps[cell, 0, u] = t``, ``stamps[cell, 1, u] = min(first, t)``:
    the cells' stamps are packed cell-major, see :func:`known_ages`, the blocks' source-major,
    ``block_last[u, block]``), set its knowledge of itself to ``t``, and mark the team's coverage ``visited``.

    :return: high-risk cells each UAV sees that nobody had seen before this step ``(k,)`` (cells two UAVs see at
        once count for both), and the number of high-risk cells the team sees for the first time
    """
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
        knowledge[u, u] = t
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
def look_and_talk(t: np.float32, scale: np.float32, window: np.ndarray, cell_blocks: np.ndarray,
                  airborne: np.ndarray, high_risk: np.ndarray, visited: np.ndarray, stamps: np.ndarray,
                  block_last: np.ndarray, block_first: np.ndarray, knowledge: np.ndarray, pos: np.ndarray, ok: np.ndarray,
                  radius: float, comm: np.ndarray, beacon_draws: np.ndarray, message_draws: np.ndarray, loss: float,
                  known: np.ndarray, counts: np.ndarray, sign_blocks: np.ndarray, stale_cells: np.ndarray,
                  stale_blocks: np.ndarray, dist: np.ndarray, beacons: np.ndarray,
                  delivered: np.ndarray) -> tuple[np.ndarray, int]:  # pragma: no cover - compiled
    """One step of the team's knowledge in one call (each part is the kernel named, in this order): the staleness
    of every window cell and block as each UAV knew it before this step (``known_ages``, ``known_block_ages``, into
    ``stale_cells`` ``(n, c)`` and ``stale_blocks`` ``(n, blocks)``), the airborne UAVs' look (``look``), the links in
    range and their distances (``links_in_range``, into ``dist``), the beacons heard (``beacon_draws >= loss``, into
    ``beacons``), the messages delivered (``deliver``, into ``delivered``) and what they carry (``merge_messages``;
    the signs learned go through ``learn_signs``, by ``sign_blocks``). Everything is updated
    in place: the stamps, ``visited``, ``knowledge``, ``known``, ``counts`` and the outputs named.

    :param window: ``(n, c)`` padded flat cells of each UAV's window
    :param cell_blocks: ``(n,)`` the block under each UAV
    :param ok: ``(n,)`` UAVs that can talk (airborne, unjammed)
    :return: the high-risk cells each UAV saw that nobody had seen before ``(n,)``, and the team's new ones
    """
    newest = t - np.float32(1.0)  # the stamps are of looks before this step's
    stale_cells[:] = known_ages(stamps, knowledge, window, t, scale, newest)
    stale_blocks[:] = known_block_ages(block_last, block_first, knowledge, t, scale)
    uavs = np.flatnonzero(airborne)
    fresh = np.zeros(len(window), dtype=np.int64)
    fresh[uavs], new = look(uavs, window[uavs], cell_blocks[uavs], high_risk, visited, stamps, block_last,
                            block_first, knowledge, t)
    distances, links = links_in_range(pos, ok, radius)
    dist[:] = distances
    beacons[:] = links & (beacon_draws >= loss)
    delivered[:] = deliver(links, comm, distances, message_draws, loss)
    merged, learned = merge_messages(delivered, knowledge, known)
    knowledge[:] = merged
    who, sign = np.nonzero(learned)
    learn_signs(known, counts, who, sign, sign_blocks[sign])
    return fresh, new


@njit(cache=True)
def fill_observations(obs: np.ndarray, occlusion: np.ndarray, risk: np.ndarray, window: np.ndarray,
                      staleness: np.ndarray, signals: np.ndarray, cells: np.ndarray, grounded: np.ndarray, radius: int,
                      pos: np.ndarray, inv_scale: np.ndarray, velocity: np.ndarray, battery: np.ndarray,
                      progress: float, heard: np.ndarray, dist: np.ndarray, neighbour_scale: float, max_neighbours: int,
                      block_staleness: np.ndarray, events: np.ndarray, knowledge: np.ndarray, belief_decay: float,
                      t: float, sign_counts: np.ndarray, sign_values: np.ndarray, own: int, neighbours: int,
                      maps: int) -> None:  # pragma: no cover - compiled
    """Every UAV's flat observation ``obs`` ``(n, obs_dim)``, in the order of ``observation_layout``:

    - ``window`` ``(7, w, w)``: occlusion, risk, staleness, the poacher, leopard and sign readings ``signals``
      ``(n, 3, w, w)`` in channels 3, 4 and 6, and the other airborne UAVs inside the window in channel 5; a grounded
      UAV's channels 3-6 are 0;
    - ``own`` (6): position scaled to [0, 1] (capped at 1), velocity, battery, episode progress;
    - ``neighbours`` ``(max_neighbours, 3)``: the UAVs it heard (``heard[s, r]``), nearest first (the lower index among
      equals), as ``(clip((pos_s - pos_r) * neighbour_scale, -1, 1), 1)``; unused slots are 0;
    - the coarse maps ``(n, blocks)``: ``block_staleness``; the poacher-activity belief from the readings ``events``
      each UAV knows of (:func:`beliefs`; 0 without readings); the signs each UAV knows of, ``sign_values[count]``
      (the last entry for larger counts).

    :param occlusion: flat padded visual occlusion; ``risk`` likewise
    :param window: ``(n, w, w)`` padded flat cells of each UAV's window; ``staleness`` ``(n, w, w)``
    :param own: where the own features start in a row; ``neighbours`` and ``maps`` likewise (the window starts at 0)
    """
    n = len(obs)
    w = 2 * radius + 1
    c = w * w
    blocks = block_staleness.shape[1]
    belief = beliefs(events, knowledge, blocks, belief_decay, t) if len(events) else np.zeros((n, blocks))
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
        row[own + 2], row[own + 3] = velocity[u, 0], velocity[u, 1]
        row[own + 4] = battery[u]
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
        for slot in range(min(m, max_neighbours)):
            s = order[slot]
            for axis in range(2):
                value = (pos[s, axis] - pos[u, axis]) * neighbour_scale
                row[neighbours + 3 * slot + axis] = min(max(value, -1.0), 1.0)
            row[neighbours + 3 * slot + 2] = 1.0
        for i in range(blocks):
            row[maps + i] = block_staleness[u, i]
            row[maps + blocks + i] = belief[u, i]
            row[maps + 2 * blocks + i] = sign_values[min(int(sign_counts[u, i]), last_value)]


@njit(cache=True)
def fly(pos: np.ndarray, velocity: np.ndarray, battery: np.ndarray, grounded: np.ndarray, cells: np.ndarray,
        window: np.ndarray, move: np.ndarray, comm: np.ndarray, speed: float, upper: np.ndarray, hover: float,
        move_cost: float, comm_costs: np.ndarray, padded_width: int,
        window_offsets: np.ndarray) -> tuple[np.ndarray, bool]:  # pragma: no cover - compiled
    """Move the UAVs (clamped to the map) and spend their energy, capped by what the battery holds; a grounded UAV
    neither moves nor talks (``move`` and ``comm`` are zeroed for it) nor hovers. Updates in place the positions
    ``pos``, the velocities (displacement / speed), the batteries, which UAVs are grounded (battery <= 1e-12), their
    ``cells`` and their windows (:func:`place_windows`).

    :param comm_costs: energy of each communication choice (none, broadcast, query)
    :return: the energy each UAV spent, and whether every UAV is now grounded
    """
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
    place_windows(pos, cells, window, padded_width, window_offsets)
    return energy, everyone


@njit(cache=True)
def fly_and_collide(pos: np.ndarray, velocity: np.ndarray, battery: np.ndarray, grounded: np.ndarray,
                    cells: np.ndarray, window: np.ndarray, move: np.ndarray, comm: np.ndarray, speed: float,
                    upper: np.ndarray, hover: float, move_cost: float, comm_costs: np.ndarray, padded_width: int,
                    window_offsets: np.ndarray) -> tuple[np.ndarray, bool, np.ndarray, int]:  # pragma: no cover
    """:func:`fly`, then :func:`collisions` among the UAVs that were airborne before the flight, in one call:
    the energy spent, whether every UAV is grounded, ``(n,)`` other UAVs in each one's cell and the pairs."""
    airborne = ~grounded
    energy, everyone = fly(pos, velocity, battery, grounded, cells, window, move, comm, speed, upper, hover,
                           move_cost, comm_costs, padded_width, window_offsets)
    own, pairs = collisions(cells, airborne)
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
def place_signs(grid: np.ndarray, pad: int, width: int, block_of: np.ndarray, pos: np.ndarray, born: np.ndarray,
                kind: np.ndarray, lifetime: np.ndarray, t: float, start: int, record_pos: np.ndarray,
                record_born: np.ndarray, record_expires: np.ndarray, record_kind: np.ndarray,
                record_block: np.ndarray) -> tuple[np.ndarray, int]:  # pragma: no cover - compiled
    """Signs made at cells ``pos`` at times ``born`` (the first of repeated cells counts), in ascending cell order: a
    cell whose sign is live keeps it, with the later expiry; any other gets a new record ``start, start + 1, ...``
    (the record arrays must have room for all of them).

    :param grid: flat padded grid of record indices (-1: none), updated in place
    :param block_of: ``(height, width)`` block of each cell
    :param lifetime: lifetime of each kind of sign
    :return: for each input sign its new record or -1, and the records in use after them
    """
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
            record_born[m], record_expires[m], record_kind[m] = born[i], expires, kind[i]
            record_block[m] = block_of[pos[i, 0], pos[i, 1]]
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
                    false_uav: np.ndarray, false_offsets: np.ndarray, false_cells: np.ndarray,
                    signals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """Mark this step's detections ``hit`` ``(n, P + L)`` (poachers, then leopards) and the false poacher readings in
    ``signals`` (channels 0 and 1), and list the poacher readings.

    :return: who detected which poacher ``(n, P)``, and the poacher readings ``(k, 3)`` ``(uav, row, col)``: the true
        ones in (UAV, poacher) order, then the false ones
    """
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
def see_signs(hit: np.ndarray, uav: np.ndarray, cell: np.ndarray, sign: np.ndarray, signals: np.ndarray,
              known: np.ndarray, counts: np.ndarray, blocks: np.ndarray, kind: np.ndarray, real: np.ndarray,
              found: np.ndarray) -> int:  # pragma: no cover - compiled
    """The candidate sightings that ``hit``: mark the sign channel ``signals[uav, 2]`` at window cell ``cell``
    (flat), the UAV learns of the sign (counted once per UAV in ``counts`` by block), and the team finds it
    (``found``) if its kind is ``real``.

    :return: how many real signs the team found for the first time
    """
    w = signals.shape[-1]
    fresh = 0
    for a in range(len(hit)):
        if hit[a]:
            u, i = uav[a], sign[a]
            signals[u, 2, cell[a] // w, cell[a] % w] = 1.0
            if not known[u, i]:
                known[u, i] = True
                counts[u, blocks[i]] += 1.0
            if real[kind[i]] and not found[i]:
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
def sense(draws: np.ndarray, poachers: np.ndarray, active: np.ndarray, poacher_moved: np.ndarray,
          leopards: np.ndarray, alive: np.ndarray, leopard_moved: np.ndarray, cells: np.ndarray, airborne: np.ndarray,
          table: np.ndarray, terrain: np.ndarray, radius: int, alarm_probability: float, reach_offsets: np.ndarray,
          height: int, width: int, decoys: np.ndarray, decoy_table: np.ndarray, candidate_uav: np.ndarray,
          candidate_cell: np.ndarray, candidate_sign: np.ndarray, candidate_p: np.ndarray, known: np.ndarray,
          counts: np.ndarray, sign_blocks: np.ndarray, sign_kinds: np.ndarray, real: np.ndarray, found: np.ndarray,
          signals: np.ndarray) -> tuple:  # pragma: no cover - compiled
    """One step of sensing in one call, from the step's uniform ``draws`` taken in this order: detection of every
    poacher and leopard by every UAV ``(n, P + L)`` (``detection_probabilities``), spurious poacher readings
    ``(2, n)`` (``false_reading_cells``), decoys ``(n, D)`` (``decoy_reading_cells``), the sign sightings ``(k,)``
    (the ``candidate_*`` of ``sign_candidates``; ``see_signs``), false sign readings ``(2, n)``. Marks ``signals``
    ``(n, 3, w, w)``; updates ``known``, ``counts`` and ``found`` in place.

    :return: who detected which poacher ``(n, P)``, the poachers detected by anyone ``(P,)`` and how many, the poacher
        readings ``(k, 3)`` (``record_readings``), the number of false poacher readings (decoys included), the real
        signs the team found for the first time, and the false sign readings' UAVs ``(f,)`` and cells ``(f, 2)``
    """
    n, m = len(cells), len(poachers) + len(leopards)
    p = detection_probabilities(np.concatenate((poachers, leopards)), cells, table, terrain,
                                np.concatenate((poacher_moved, leopard_moved)).astype(np.int64),
                                np.concatenate((active, alive)), airborne, radius)
    hit = draws[:n * m].reshape((n, m)) < p
    start = n * m
    uav, offsets, where = false_reading_cells(draws[start:start + n], draws[start + n:start + 2 * n], alarm_probability,
                                              airborne, reach_offsets, cells, height, width)
    start += 2 * n
    if len(decoys):
        d_uav, d_offsets, d_where = decoy_reading_cells(draws[start:start + n * len(decoys)].reshape((n, len(decoys))),
                                                        decoy_table, decoys, cells, airborne, height, width)
        start += n * len(decoys)
        uav, offsets, where = (np.concatenate((uav, d_uav)), np.concatenate((offsets, d_offsets)),
                               np.concatenate((where, d_where)))
    seen, readings = record_readings(hit, poachers, leopards, cells, radius, uav, offsets, where, signals)
    k = len(candidate_p)
    sighted = draws[start:start + k] < candidate_p
    start += k
    fresh = see_signs(sighted, candidate_uav, candidate_cell, candidate_sign, signals, known, counts, sign_blocks,
                      sign_kinds, real, found)
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
def add_signs_off_grid(pos: np.ndarray, t: float, kind: int, lifetime: np.ndarray, block_of: np.ndarray,
                       start: int, record_pos: np.ndarray, record_born: np.ndarray, record_expires: np.ndarray,
                       record_kind: np.ndarray, record_block: np.ndarray) -> np.ndarray:  # pragma: no cover
    """``Signs.add(pos, t, kind, t, on_grid=False)``: records ``start, start + 1, ...`` (which must have room) for
    signs no other UAV can find (false readings), born at ``t``; returns their indices."""
    k = len(pos)
    ids = np.arange(start, start + k)
    for a in range(k):
        m = start + a
        record_pos[m, 0], record_pos[m, 1] = pos[a, 0], pos[a, 1]
        record_born[m] = t
        record_expires[m] = t + lifetime[kind]
        record_kind[m] = kind
        record_block[m] = block_of[pos[a, 0], pos[a, 1]]
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
def step_rewards(weights: tuple, shaping: float, n_detected: int, new_cells: int, signs_found: int,
                 poaching_events: int, collisions: int, energy: np.ndarray, seen: np.ndarray, own_new: np.ndarray,
                 own_collisions: np.ndarray) -> tuple[np.ndarray, float, float]:  # pragma: no cover - compiled
    """Each UAV's reward ``(n,)``, the team reward and the energy spent ``energy.sum()``.

    The team's is ``detection * n_detected + coverage * new_cells + sign * signs_found - poaching * poaching_events -
    collision * collisions - energy * spent`` (``weights`` in that order); with ``shaping > 0`` each UAV gets
    ``(1 - shaping) * team + shaping * own``, ``own`` the same terms of its own (``seen`` ``(n, P)`` the poachers it
    detected, ``own_new`` its first looks, ``own_collisions``, its ``energy``).
    """
    detection, coverage, sign, poaching, collision, energy_weight = weights
    spent = pairwise_sum(energy)
    team = (detection * n_detected + coverage * new_cells + sign * signs_found - poaching * poaching_events
            - collision * collisions - energy_weight * spent)
    rewards = np.full(len(energy), team)
    if shaping > 0:
        for u in range(len(energy)):
            own = (detection * seen[u].sum() + coverage * own_new[u] - collision * own_collisions[u]
                   - energy_weight * energy[u])
            rewards[u] = (1.0 - shaping) * team + shaping * own
    return rewards, team, spent


@njit(cache=True)
def place_new_signs(signs: tuple, count: int, pos: np.ndarray, now: float,
                    kind: int) -> int:  # pragma: no cover - compiled
    """:func:`place_signs` of signs of ``kind`` born ``now`` at cells ``pos`` into the records of ``signs`` (the tuple
    :func:`advance_world` takes), ``count`` of them in use; returns the records in use after them."""
    (grid, pad, padded_width, block_of, lifetime, _, record_pos, record_born, record_expires, record_kind,
     record_block) = signs[:11]
    k = len(pos)
    if k == 0:
        return count
    return place_signs(grid, pad, padded_width, block_of, pos, np.full(k, now), np.full(k, kind), lifetime, now, count,
                       record_pos, record_born, record_expires, record_kind, record_block)[1]


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
def jam(jammed: np.ndarray, airborne: np.ndarray, pos: np.ndarray, jammer: np.ndarray, radius: float,
        jammer_on: bool) -> np.ndarray:  # pragma: no cover - compiled
    """Which UAVs the jammer silences (``jammed``, in place: within ``radius`` of it while it is on) and which can
    talk: the ``airborne`` ones not jammed."""
    ok = airborne.copy()
    for u in range(len(pos)):
        jammed[u] = False
        if jammer_on:
            d_row, d_col = pos[u, 0] - jammer[0], pos[u, 1] - jammer[1]
            jammed[u] = np.sqrt(d_row ** 2 + d_col ** 2) <= radius
            ok[u] &= not jammed[u]
    return ok


@njit(cache=True)
def poach(near: np.ndarray, done: np.ndarray, status: np.ndarray, timer: np.ndarray, alive: np.ndarray,
          gone_status: int) -> np.ndarray:  # pragma: no cover - compiled
    """The poachers whose timer ran out (``done``) kill the leopard they are next to (the first in ``near``'s row;
    one event per leopard) and leave (``status``, ``timer`` and ``alive`` in place); returns the leopards killed."""
    killed = np.zeros(len(alive), dtype=np.bool_)
    for i in range(len(done)):
        if done[i]:
            killed[np.argmax(near[i])] = True
            status[i] = gone_status
            timer[i] = 0
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


@njit(cache=True)
def advance_world(addresses: np.ndarray, t: int, choices: np.ndarray, fly: tuple, ground: tuple, signs: tuple,
                  sensing: tuple, team: tuple, observe: tuple, reward: tuple) -> tuple:  # pragma: no cover - compiled
    """A step in one compiled call, with its random draws taken from the generator of ``addresses``
    (``stream.handle``) in the order the phases make them:

    0. **Actions**: discrete ``choices`` (``(n,)`` ints; empty when the moves and communication choices in ``fly``
       are already decoded) are decoded into ``fly``'s ``move`` and ``comm`` (:func:`decode_actions`); one out of
       range raises :class:`ActionError` before anything changes. Then the poachers whose entry time ``t`` has come
       enter play.
    1. **Flight** (:func:`fly_and_collide` on ``fly``, its arguments): the UAVs move and spend energy; collisions
       among those airborne before it.

    2. **Ground** (:func:`move_ground_actors` on ``3 L`` uniform draws, then ``5 P`` if any poacher is active): the
       leopards and poachers move; the poachers' tracks become signs born now (:func:`place_signs`); the jammer, if
       any, moves to the active poachers' mean cell; the live signs in the airborne UAVs' windows
       (:func:`sign_candidates`).
    3. **Sensing** (:func:`sense` on ``n (P + L + 2 + D + 2) + k`` uniform draws): detections, false alarms, decoys,
       sign sightings, false sign readings (records only the reading UAV knows of: :func:`add_signs_off_grid`,
       :func:`learn_signs`); caught poachers leave play; the noise on the signal channels (:func:`noisy_signals`,
       normal draws) when ``noise_scale > 0``.
    4. **Poaching** (:func:`poaching_timers`): an undetected poacher next to a live leopard for ``poaching_time``
       steps kills it (one event per leopard) and leaves (a carcass sign where the leopard was).
    5. **Sharing** (:func:`look_and_talk` on ``2 n n`` uniform draws, then :func:`fill_observations` and
       :func:`sender_masks`): the UAVs not jammed talk; the poacher readings join the team's record ``events`` (rows
       ``(time, uav, block)``, those older than ``horizon`` dropped); every UAV's observation is written.
    6. **Rewards** (:func:`step_rewards` on ``reward``: the weights and the shaping).

    ``ground``, ``signs``, ``sensing`` and ``team`` are the state and constants each phase reads, ``observe`` the
    arguments of :func:`fill_observations` (whose ``signals`` this step's readings are written into; see
    ``ReserveParallelEnv._world_args``, which builds them all); every array in them is updated in place except the
    record of readings, which is returned. The sign records and ``known``/``found`` must have room for ``P`` tracks,
    ``n`` false readings and ``L`` carcasses more.

    :return: the poachers that entered, the rewards ``(n,)``, the team reward, the energy spent, whether every UAV
        is grounded, the collisions (pairs), the poacher readings ``(k, 3)`` ``(uav, row, col)``, poachers caught,
        false poacher readings, real signs found for the first time, poaching events, the sign records in use,
        whether the jammer is on, the readings record ``events``, the team's new high-risk cells and the senders'
        bit masks of ``heard_from`` (empty above 63 UAVs)
    """
    (leopards, leopard_moved, home, home_range, leopard_move_prob, poachers, poacher_moved, status, timer, alive,
     planned, sight, notice_radius, move_prob, wander_prob, evasion_prob, hide_in_cover, cover, steps, track_prob,
     poaching_time, entry_time, waiting_status, active_status, caught_status, gone_status, jammer, jammed, has_jammer,
     jam_radius) = ground
    (grid, _, _, block_of, lifetime, count, record_pos, record_born, record_expires, record_kind, record_block,
     track_kind, carcass_kind, false_kind, real) = signs
    (detect_table, terrain, radius, alarm_probability, reach_offsets, decoys, decoy_table, sign_table, terrain_pad,
     found, noise_scale) = sensing
    (scale, high_risk, visited, stamps, block_last, block_first, knowledge, uav_pos, comm_radius, comm, loss, known,
     counts, stale_cells, stale_blocks, dist, beacons, delivered, events, horizon) = team
    cells = fly[4]
    n, n_poachers, n_leopards = len(cells), len(poachers), len(leopards)
    height, width = terrain.shape
    window, signals = observe[3].reshape(n, -1), observe[5]
    now = np.float64(t)

    # 0. Actions, and the poachers due.
    if len(choices):
        move, comm_choices, valid = decode_actions(choices, steps.astype(np.float64), N_MOVES, N_COMMS)
        if not valid:
            raise ActionError("discrete action out of range")
        fly[6][:] = move
        fly[7][:] = comm_choices
    entered = 0
    for i in range(n_poachers):
        if status[i] == waiting_status and entry_time[i] <= t:
            status[i] = active_status
            entered += 1

    # 1. Flight.
    airborne = ~fly[3]
    energy, everyone, own_collisions, pairs = fly_and_collide(*fly)

    # 2. Ground.
    active = status == active_status
    any_active = active.any()
    draws = uniform(addresses, 3 * n_leopards + 5 * n_poachers * any_active)
    tracks = move_ground_actors(draws, leopards, leopard_moved, home, home_range, leopard_move_prob, poachers,
                                poacher_moved, active, timer, alive, planned, sight, cells[airborne], notice_radius,
                                move_prob, wander_prob, evasion_prob, hide_in_cover, cover, steps, track_prob)
    count = place_new_signs(signs, count, tracks, now, track_kind)
    jammer_on = has_jammer and any_active
    if jammer_on:
        move_jammer(jammer, poachers, active)
    c_uav, c_cell, c_sign, c_p = sign_candidates(grid, record_born, record_expires, window, now, airborne,
                                                 sign_table, terrain_pad)

    # 3. Sensing.
    signals[:] = 0.0
    draws = uniform(addresses, n * (n_poachers + n_leopards + 2 + len(decoys) + 2) + len(c_p))
    seen, caught, n_caught, readings, false_alarms, fresh_signs, f_uav, f_where = sense(
        draws, poachers, status == active_status, poacher_moved, leopards, alive, leopard_moved, cells, airborne,
        detect_table, terrain, radius, alarm_probability, reach_offsets, height, width, decoys, decoy_table, c_uav,
        c_cell, c_sign, c_p, known, counts, record_block, record_kind, real, found, signals)
    for i in range(n_poachers):
        if caught[i]:
            status[i] = caught_status
    near, new_timer, done, any_done = poaching_timers(poachers, status, leopards, alive, timer, poaching_time)
    if len(f_uav):  # false sign readings: phantom records that only the reading UAV knows of
        phantom = add_signs_off_grid(f_where, now, false_kind, lifetime, block_of, count, record_pos, record_born,
                                     record_expires, record_kind, record_block)
        count += len(phantom)
        learn_signs(known, counts, f_uav, phantom, record_block[phantom])
    if noise_scale > 0:
        noisy_signals(addresses, signals, noise_scale)

    # 4. Poaching.
    timer[:] = new_timer
    events_now = 0
    if any_done:
        victims = poach(near, done, status, timer, alive, gone_status)
        events_now = len(victims)
        count = place_new_signs(signs, count, leopards[victims], now, carcass_kind)

    # 5. Sharing.
    ok = jam(jammed, airborne, uav_pos, jammer, jam_radius, jammer_on)
    events = record_readings_seen(events, readings, now, block_of, horizon)
    cell_blocks = np.empty(n, dtype=np.int64)
    for u in range(n):
        cell_blocks[u] = block_of[cells[u, 0], cells[u, 1]]
    talk = uniform(addresses, 2 * n * n).reshape(2, n, n)
    fresh, new = look_and_talk(np.float32(t), scale, window, cell_blocks, airborne, high_risk, visited, stamps,
                               block_last, block_first, knowledge, uav_pos, ok, comm_radius, comm, talk[0], talk[1],
                               loss, known[:, :count], counts, record_block[:count], stale_cells, stale_blocks, dist,
                               beacons, delivered)
    fill_observations(*observe[:19], events, *observe[20:])  # type: ignore[call-arg]  # (the readings as they are now)
    masks = sender_masks(delivered) if n <= 63 else np.zeros(0, dtype=np.int64)

    # 6. Rewards.
    rewards, team_reward, spent = step_rewards(reward[0], reward[1], n_caught, new, fresh_signs, events_now, pairs,
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
