"""What each UAV knows and how the team shares it: visit stamps, links, messages and the coarse maps.

``knowledge[r, s]`` is the time up to which UAV ``r`` knows UAV ``s``'s visit history and readings.
Each airborne UAV knows its own up to now; a delivered message ``s -> r`` sets
``knowledge[r] = max(knowledge[r], knowledge[s])``, so knowledge travels one hop per step. From it
come the staleness channel and map (time since a cell or block was seen, as far as the UAV knows),
the poacher-activity belief map and the map of the signs of poacher activity the UAV knows of.
"""

from __future__ import annotations

import numpy as np

from wildlife_reserve.reserve.kernels import Team, sender_masks, senders_by_receiver
from wildlife_reserve.reserve.kernels.constants import NEVER

#: A block's sign value is ``1 - exp(-signs known there / SIGN_MAP_SCALE)``.
SIGN_MAP_SCALE = 2.0
#: That value for 0, 1, ... signs (numpy's exp, as tabulated): from 75 signs on it is exactly 1.0 in float64, so a
#: larger count reads the last entry.
SIGN_VALUES = 1.0 - np.exp(-np.arange(128) * (1.0 / SIGN_MAP_SCALE))
#: Layout of the visit stamps in a pickled :class:`TeamKnowledge` (a checkpoint of the vector environment): 2 since
#: sb3-emmarl 0.18.0, whose cells' stamps are packed integers (:func:`pack_stamps`); 1 (0.15.0-0.17.0) held them as
#: two float32 arrays ``(cells, n)`` with :data:`NEVER`; a state without it (0.14.0) also holds its block stamps
#: block-major ``(blocks, n)``. Older states are turned on unpickling.
STAMP_LAYOUT = 2
#: Teams of up to this many UAVs get their ``heard_from`` tuples by bit mask from :data:`_SENDERS` (a step's links
#: repeat across steps and copies: one dict lookup per UAV instead of a new tuple); larger teams build them.
MASK_UAVS = 63
#: Sender tuples by bit mask, shared by every reserve of the process (and its threads: a miss builds the list without
#: re-reading the dict); emptied when it outgrows :data:`_SENDERS_MAX`.
_SENDERS: dict[int, tuple[int, ...]] = {0: ()}
_SENDERS_MAX = 1 << 14


def stamp_dtype(max_cycles: int) -> type:
    """The integer type of the cells' visit stamps: int16 for episodes shorter than its greatest value (the stamps of
    10 UAVs at a cell then fill 40 bytes, one cache line: the staleness reads a few hundred scattered cells a step),
    int32 for longer ones."""
    return np.int16 if max_cycles < np.iinfo(np.int16).max else np.int32


def pack_stamps(last: np.ndarray, first: np.ndarray, dtype: type) -> np.ndarray:
    """The cells' visit stamps as the compiled step keeps them: ``(cells, 2, n)`` of ``dtype``, ``[:, 0]`` the last
    look and ``[:, 1]`` the first, from float32 ``last`` and ``first`` ``(cells, n)`` whose never-seen cells are
    :data:`NEVER` and ``-NEVER``; those become the dtype's least and greatest value (which, below and above every
    step of an episode, compare as :data:`NEVER` and ``-NEVER`` do)."""
    info = np.iinfo(dtype)
    stamps = np.stack([last, first], axis=1)
    packed: np.ndarray = np.where(np.abs(stamps) >= -NEVER, 0, stamps).astype(dtype)  # (sentinels set apart, not cast)
    packed[:, 0][last == NEVER], packed[:, 1][first == -NEVER] = info.min, info.max
    return packed


def unpack_stamps(stamps: np.ndarray, which: int) -> np.ndarray:
    """The last (``which=0``) or first (``1``) looks of :func:`pack_stamps`' ``stamps`` as float32 ``(cells, n)``,
    never-seen cells at :data:`NEVER` (last) or ``-NEVER`` (first)."""
    info = np.iinfo(stamps.dtype)
    part = stamps[:, which]
    never, value = (info.min, NEVER) if which == 0 else (info.max, -NEVER)
    return np.where(part == never, value, part).astype(np.float32)


def sign_values(counts: np.ndarray) -> np.ndarray:
    """``1 - exp(-counts / SIGN_MAP_SCALE)`` of whole-number ``counts`` (from :data:`SIGN_VALUES`)."""
    return SIGN_VALUES[np.minimum(counts, len(SIGN_VALUES) - 1).astype(np.int64)]


class TeamKnowledge:
    """The team's shared knowledge, as numpy arrays over UAVs.

    Public arrays: ``knowledge`` ``(n, n)``; ``beacons[s, r]`` (r heard s's position this step);
    ``comm_links[s, r]`` (a message of s reached r this step); ``own_last`` / ``own_first`` ``(n, *padded)``
    (each UAV's last and first look at each cell); ``known_signs`` ``(n, capacity)`` (which sign records
    each UAV knows of) and ``sign_counts`` ``(n, blocks)``. ``record`` holds them, with the constants the compiled step
    reads, as a ``kernels.Team`` (from the first reset on).

    :param n: number of UAVs
    :param padded_shape: shape of the padded grids
    :param n_blocks: blocks of the coarse maps
    :param max_cycles: episode length (scales the staleness)
    :param belief_decay: per-step decay of old poacher readings in the belief map
    :param comm_radius: communication radius (Euclidean, cells)
    :param comm_loss: chance that any one beacon or message is lost
    """

    def __init__(self, n: int, padded_shape: tuple[int, int], n_blocks: int, max_cycles: int, belief_decay: float,
                 comm_radius: float, comm_loss: float) -> None:
        self.n = n
        self.padded_shape = padded_shape
        self.cells_padded = padded_shape[0] * padded_shape[1]
        self.n_blocks = n_blocks
        self.max_cycles = max_cycles
        self.belief_decay = belief_decay
        self.comm_radius = comm_radius
        self.comm_loss = comm_loss
        # Readings older than this carry less than 1e-3 of their weight and are dropped.
        self.horizon = np.log(1e-3) / np.log(belief_decay) if belief_decay < 1 else max_cycles
        # Cell-major and packed, (cell, last/first, UAV): the staleness reads every UAV's stamps of a few cells.
        self._stamps: np.ndarray = np.empty((self.cells_padded, 2, n), dtype=stamp_dtype(max_cycles))
        # Source-major, (UAV, block): the block staleness folds every block of one source at a time.
        self._block_last, self._block_first = (np.empty((n, n_blocks), dtype=np.float32) for _ in range(2))
        self._time_scale = np.float32(1.0 / max_cycles)  # made once: every step's compiled call reads it
        self._stamp_layout = STAMP_LAYOUT

    def __getstate__(self) -> dict:
        """Pickle without :attr:`record`, which unpickling remakes."""
        return {name: value for name, value in self.__dict__.items() if name != "record"}

    def __setstate__(self, state: dict) -> None:
        """Unpickle (checkpoints), turning the stamps of a state from before :data:`STAMP_LAYOUT`."""
        self.__dict__.update(state)
        layout = state.get("_stamp_layout", 0)
        if layout < 1 and hasattr(self, "_block_last"):
            self._block_last = np.ascontiguousarray(self._block_last.T)
            self._block_first = np.ascontiguousarray(self._block_first.T)
        if layout < 2 and hasattr(self, "_last"):
            self._stamps = pack_stamps(self.__dict__.pop("_last"), self.__dict__.pop("_first"),
                                       stamp_dtype(self.max_cycles))
        self._stamp_layout = STAMP_LAYOUT
        if hasattr(self, "knowledge"):  # (a team that has had an episode)
            self._refresh_record()

    def reset(self) -> None:
        """Forget everything: a new episode."""
        n = self.n
        info = np.iinfo(self._stamps.dtype)
        self._stamps[:, 0], self._stamps[:, 1] = info.min, info.max
        self._block_last[:], self._block_first[:] = NEVER, -NEVER
        self.knowledge = np.full((n, n), NEVER, dtype=np.float32)
        self.beacons = np.zeros((n, n), dtype=bool)
        self.comm_links = np.zeros((n, n), dtype=bool)
        self.dist = np.zeros((n, n))
        self.events = np.zeros((0, 3))  # (time, reading UAV, block) of the poacher readings
        self.known_signs = np.zeros((n, 64), dtype=bool)
        self.sign_counts = np.zeros((n, self.n_blocks), dtype=np.float64)
        self._refresh_record()

    @property
    def own_last(self) -> np.ndarray:
        """``(n, *padded)`` float32 each UAV's last look at each cell, :data:`NEVER` where it never looked (a copy)."""
        return unpack_stamps(self._stamps, 0).T.reshape(self.n, *self.padded_shape)

    @property
    def own_first(self) -> np.ndarray:
        """``(n, *padded)`` float32 each UAV's first look at each cell, ``-NEVER`` where it never looked (a copy)."""
        return unpack_stamps(self._stamps, 1).T.reshape(self.n, *self.padded_shape)

    def _refresh_record(self) -> None:
        """:attr:`record` of the arrays as they are now (they are replaced at every reset and when ``known_signs``
        grows)."""
        self.record = Team(knowledge=self.knowledge, stamps=self._stamps, block_last=self._block_last,
                           block_first=self._block_first, known=self.known_signs, counts=self.sign_counts,
                           dist=self.dist, beacons=self.beacons, comm_links=self.comm_links,
                           time_scale=self._time_scale, comm_radius=self.comm_radius, comm_loss=self.comm_loss,
                           horizon=float(self.horizon), belief_decay=self.belief_decay)

    def fit_signs(self, size: int) -> None:
        """Make room in ``known_signs`` for ``size`` sign records."""
        if size > self.known_signs.shape[1]:
            grown = np.zeros((self.n, max(size, 2 * self.known_signs.shape[1])), dtype=bool)
            grown[:, :self.known_signs.shape[1]] = self.known_signs
            self.known_signs = grown
            self._refresh_record()

    def heard_from(self, masks: np.ndarray | None = None) -> list[tuple[int, ...]]:
        """For each UAV, the indices of the teammates whose message reached it this step (ascending).

        :param masks: ``kernels.sender_masks(comm_links)`` if already made (teams of up to :data:`MASK_UAVS`)
        """
        if self.n <= MASK_UAVS:
            masks = (sender_masks(self.comm_links) if masks is None else masks).tolist()
            try:
                return [_SENDERS[mask] for mask in masks]
            except KeyError:  # a new mask (or another thread emptied the cache): the list made without re-reading it
                if len(_SENDERS) > _SENDERS_MAX:
                    _SENDERS.clear()
                heard = []
                for mask in masks:
                    senders = _SENDERS.get(mask)
                    if senders is None:
                        senders = _SENDERS[mask] = tuple(s for s in range(mask.bit_length()) if mask >> s & 1)
                    heard.append(senders)
                return heard
        grouped, group_ends = senders_by_receiver(self.comm_links)
        if not len(grouped):
            return [()] * self.n
        flat, ends = grouped.tolist(), group_ends.tolist()
        return [tuple(flat[start:end]) for start, end in zip([0, *ends], ends)]
