"""The records a step of the reserve reads and updates, by phase: numba compiles them as tuples, and the step
takes them as plain tuples (:func:`~wildlife_reserve.reserve.kernels.world.named`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


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
    """Everything a step reads and updates but the :class:`Step` itself, by phase (``ReserveParallelEnv._build_world``
    builds it; it crosses into ``world.advance_world`` as plain tuples, named again inside)."""

    flight: Flight
    ground: Ground
    signs: SignRecords
    sensing: Sensing
    team: Team
    coverage: Coverage
    observe: Observe
    rewards: Rewards


class StepOutcome(NamedTuple):
    """What :func:`~wildlife_reserve.reserve.kernels.world.advance_world` returns, by name (the compiled call returns
    the plain tuple; ``StepOutcome._make`` names it on the Python side)."""

    entered: int  # poachers that entered play
    rewards: np.ndarray  # (n,) each UAV's reward
    team_reward: float
    spent: float  # energy spent
    terminated: bool  # every UAV grounded
    collisions: int  # pairs
    readings: np.ndarray  # (k, 3) poacher readings (uav, row, col)
    caught: int  # poachers caught
    false_alarms: int  # false poacher readings
    signs_found: int  # real signs found for the first time
    poaching_events: int
    sign_count: int  # the sign records in use
    jammer_on: bool
    events: np.ndarray  # the team's record of readings
    new_cells: int  # the team's new high-risk cells
    masks: np.ndarray  # the senders' masks
