"""A step in one compiled call (:func:`advance_world`): the phases in order, on the records that cross into it as
plain tuples and are named inside; and the rewards.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from wildlife_reserve.reserve.kernels.constants import N_COMMS, N_MOVES, POACHER_ACTIVE, POACHER_CAUGHT
from wildlife_reserve.reserve.kernels.draws import uniform
from wildlife_reserve.reserve.kernels.flight import decode_actions, fly_and_collide
from wildlife_reserve.reserve.kernels.ground import enter_poachers, move_ground_actors, move_jammer, poach, poaching_timers
from wildlife_reserve.reserve.kernels.observe import fill_observations
from wildlife_reserve.reserve.kernels.records import (
    Candidates,
    Coverage,
    Flight,
    Ground,
    Jammer,
    Leopards,
    Looks,
    Observe,
    Poachers,
    Rewards,
    Sensing,
    SignRecords,
    Step,
    Talk,
    Tally,
    Team,
    World,
)
from wildlife_reserve.reserve.kernels.sensing import noisy_signals, sense
from wildlife_reserve.reserve.kernels.signs import (
    add_signs_off_grid,
    learn_signs,
    place_new_signs,
    sign_candidates,
)
from wildlife_reserve.reserve.kernels.team import jam, look_and_talk, record_readings_seen, sender_masks


class ActionError(ValueError):
    """A discrete action out of range, raised by :func:`advance_world` before it changes anything (the reserve
    re-raises it as a ``ValueError`` naming the actions)."""

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

def plain(record: tuple) -> tuple:
    """``record`` (a record of :mod:`.records`, its fields records or not) as the plain tuples :func:`advance_world` takes
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
