"""The sharing phase of a step: the staleness each UAV knows, the looks, the links, beacons and messages (what
they carry), the jammer's silence and the team's record of poacher readings.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from wildlife_reserve.reserve.kernels.constants import NEVER
from wildlife_reserve.reserve.kernels.records import Coverage, Jammer, Looks, Talk, Team
from wildlife_reserve.reserve.kernels.signs import learn_signs


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
    of maxima over the blocks, a loop the compiler vectorises (faster than the per-block maximum over the sources)."""
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
