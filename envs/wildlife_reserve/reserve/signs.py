"""Signs of poacher activity: tracks, snares, camps, vehicles and carcasses that outlast the poachers.

Rangers read how poachers operate from what they leave behind; so can the UAVs. Each episode starts
with the signs of the nights before, laid out by the episode's poacher strategy (the hidden mode),
and active poachers add tracks as they walk. A sign is a ground target: the UAVs detect it through
the sensor model (:func:`~wildlife_reserve.reserve.sensing.sign_detection_table`) and learn nothing
from one sign but that someone was there: the strategy shows only in where the signs lie.

================== ==================================================================================
strategy           signs laid before the episode (besides the in-episode tracks of every strategy)
================== ==================================================================================
hotspot_raid       ``SNARES_PER_DEN`` snares around every den; a track from the nearest edge to each den
edge_infiltration  ``EDGE_ROUTES`` vehicles along the infiltrators' side, each with a track inward
coordinated_group  one camp of ``CAMP_SIGNS`` signs on the way to the target den, a vehicle at the group's
                   entry point, a track from it to the camp and tracks from the camp to every den
dispersed_evasion  ``SCATTERED_SIGNS`` isolated signs anywhere in the reserve, half tracks, half snares
================== ==================================================================================

Everything is vectorised over signs; one live sign per cell (a new sign on a live one's cell keeps the
later expiry).
"""

from __future__ import annotations

import numpy as np

from wildlife_reserve.reserve.kernels import SignRecords, place_signs
from wildlife_reserve.reserve.modes import PoacherStrategy
from wildlife_reserve.reserve.terrain import edge_points, nearest_edge

SIGN_KINDS = ("track", "snare", "camp", "vehicle", "carcass", "decoy", "false_reading")
TRACK, SNARE, CAMP, VEHICLE, CARCASS, DECOY, FALSE_READING = range(len(SIGN_KINDS))
#: Steps each kind of sign stays visible after it is made (``inf``: until the episode ends).
#: A false reading is a sensor artefact: it exists only in the memory of the UAV that made it.
LIFETIME = np.array([100, np.inf, np.inf, np.inf, np.inf, np.inf, 0], dtype=np.float64)
#: Which kinds are real signs of poachers (what the ``sign`` reward counts): not decoys, not false readings.
REAL = np.array([kind not in ("decoy", "false_reading") for kind in SIGN_KINDS])
#: Pre-episode tracks were made up to this many steps before the episode started.
TRACK_AGE = 40
#: Chance per step that an active poacher that moved leaves a track on its new cell.
TRACK_PROB = 0.5
#: Spacing in cells of the signs along a pre-episode track.
TRACK_SPACING = 2
SNARES_PER_DEN = 12
#: Snares lie at Chebyshev distance in ``[2, SNARE_RADIUS]`` of their den.
SNARE_RADIUS = 8
EDGE_ROUTES = 12
#: Depth in cells (low, high) of an infiltration track from the edge inward.
EDGE_DEPTH = (5, 20)
CAMP_SIGNS = 24
#: The camp lies at this fraction (low, high) of the way from the group's entry point to its den.
CAMP_POSITION = (0.4, 0.6)
SCATTERED_SIGNS = 100
#: Fake signs planted around each decoy (adversarial condition).
DECOY_SIGNS = 4


def route(start: np.ndarray, end: np.ndarray, spacing: int = TRACK_SPACING) -> np.ndarray:
    """Cells every ``spacing`` cells along the straight line from ``start`` to ``end`` (both included)."""
    n = max(int(np.abs(end - start).max()) // spacing, 1) + 1
    return np.rint(np.linspace(start, end, n)).astype(np.int64)


def around(rng: np.random.Generator, centre: np.ndarray, count: int, low: int, high: int) -> np.ndarray:
    """``count`` cells at Chebyshev distance in ``[low, high]`` of ``centre`` (uniform over that ring)."""
    offsets = np.argwhere(np.ones((2 * high + 1, 2 * high + 1), dtype=bool)) - high
    ring = offsets[np.abs(offsets).max(-1) >= low]
    pick = rng.choice(len(ring), size=min(count, len(ring)), replace=False)
    return centre + ring[pick]


def plan_signs(
    rng: np.random.Generator,
    strategy: PoacherStrategy,
    entry: np.ndarray,
    target: np.ndarray,
    dens: np.ndarray,
    shape: tuple[int, int],
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The signs left before the episode by poachers of ``strategy`` (see the module's table).

    :param rng: random generator
    :param strategy: the episode's poacher strategy
    :param entry: ``(P, 2)`` this episode's entry cells (they fix the side or point the strategy uses)
    :param target: ``(P, 2)`` this episode's target dens
    :param dens: ``(k, 2)`` den cells
    :param shape: ``(height, width)``
    :return: cells ``(S, 2)``, times made ``(S,)`` (<= 0) and kinds ``(S,)``; nothing when there are no poachers
    """
    height, width = shape
    if not len(entry):
        return np.zeros((0, 2), dtype=np.int64), np.zeros(0), np.zeros(0, dtype=np.int64)
    cells, kinds = [], []

    def add(new: np.ndarray, kind: int) -> None:
        cells.append(np.asarray(new, dtype=np.int64).reshape(-1, 2))
        kinds.append(np.full(len(cells[-1]), kind))

    if strategy.entry == "near_den":
        for den in dens:
            add(around(rng, den, SNARES_PER_DEN, 2, SNARE_RADIUS), SNARE)
            side, frac = nearest_edge(den[None], shape)
            start = edge_points(side, frac, shape)[0]
            add(route(start, den)[:-1], TRACK)
    elif strategy.entry == "one_side":
        side = nearest_edge(entry[:1], shape)[0]
        starts = edge_points(np.repeat(side, EDGE_ROUTES), rng.uniform(size=EDGE_ROUTES), shape)
        inward = np.array([[1, 0], [-1, 0], [0, 1], [0, -1]])[side[0]]
        for start in starts:
            add(start, VEHICLE)
            add(route(start, start + inward * rng.integers(EDGE_DEPTH[0], EDGE_DEPTH[1] + 1))[1:], TRACK)
    elif strategy.entry == "group":
        camp = np.rint(entry[0] + rng.uniform(*CAMP_POSITION) * (target[0] - entry[0])).astype(np.int64)
        add(np.vstack([camp, around(rng, camp, CAMP_SIGNS - 1, 1, 3)]), CAMP)
        add(entry[0], VEHICLE)
        add(route(entry[0], camp)[1:-1], TRACK)
        for den in dens:  # the group's trails radiate from its camp to every den
            add(route(camp, den)[1:-1], TRACK)
    else:  # "perimeter": dispersed traces anywhere
        spots = np.stack([rng.integers(0, height, SCATTERED_SIGNS), rng.integers(0, width, SCATTERED_SIGNS)], axis=-1)
        add(spots, TRACK)
        kinds[-1][SCATTERED_SIGNS // 2:] = SNARE
    pos = np.clip(np.concatenate(cells), 0, [height - 1, width - 1])
    kind = np.concatenate(kinds).astype(np.int64)
    born = np.where(kind == TRACK, -rng.integers(0, TRACK_AGE + 1, len(kind)), -TRACK_AGE).astype(np.float64)
    return pos, born, kind


class Signs:
    """The signs of one episode: a growing table of records and a grid that points at each cell's sign.

    Records are public for tests and tools: ``pos`` ``(S, 2)``, ``born``, ``expires`` and ``kind`` ``(S,)``,
    ``block`` (the coarse-map block of each sign), ``found`` (the team has found it), ``count`` (records in use).
    ``grid`` is padded by the sensor radius and holds a record index or -1 per cell. ``record`` holds them all, with
    the constants the compiled step reads, as a ``kernels.SignRecords`` (remade when the records grow).

    :param padded_shape: shape of the padded grids
    :param pad: the padding (the sensor radius)
    :param block: ``(height, width)`` block index of each cell
    """

    def __init__(self, padded_shape: tuple[int, int], pad: int, block: np.ndarray) -> None:
        self.pad = pad
        self.width = padded_shape[1]
        self._block_of = block
        self.grid = np.full(padded_shape, -1, dtype=np.int64)
        self._flat = self.grid.reshape(-1)
        self.count = 0
        self.pos, self.born, self.expires = np.zeros((0, 2), np.int64), np.zeros(0), np.zeros(0)
        self.kind, self.block, self.found = np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, bool)
        self._grow(64)

    def __getstate__(self) -> dict:
        """Pickle without :attr:`record`, which unpickling remakes."""
        return {name: value for name, value in self.__dict__.items() if name != "record"}

    def __setstate__(self, state: dict) -> None:
        """Unpickle (checkpoints); a state from before the signs kept ``found`` gets it all False (the reserve, which
        kept it then, fills it in)."""
        self.__dict__.update(state)
        if "found" not in state:
            self.found = np.zeros(self.capacity, dtype=bool)
        self._refresh_record()

    def _grow(self, capacity: int) -> None:
        old = self.count
        pos, born, expires = np.zeros((capacity, 2), np.int64), np.zeros(capacity), np.zeros(capacity)
        kind, block, found = np.zeros(capacity, np.int64), np.zeros(capacity, np.int64), np.zeros(capacity, bool)
        if old:
            pos[:old], born[:old], expires[:old] = self.pos[:old], self.born[:old], self.expires[:old]
            kind[:old], block[:old] = self.kind[:old], self.block[:old]
        found[:len(self.found)] = self.found
        self.pos, self.born, self.expires, self.kind, self.block, self.found = pos, born, expires, kind, block, found
        self._refresh_record()

    def _refresh_record(self) -> None:
        """:attr:`record` of the records as they are now."""
        self.record = SignRecords(grid=self._flat, pad=self.pad, width=self.width, block_of=self._block_of,
                                  lifetime=LIFETIME, pos=self.pos, born=self.born, expires=self.expires, kind=self.kind,
                                  block=self.block, found=self.found, real=REAL, track_kind=TRACK,
                                  carcass_kind=CARCASS, false_kind=FALSE_READING)

    def make_room(self, k: int) -> None:
        """Room for ``k`` more records (the capacity at least doubles when it grows)."""
        if self.count + k > self.capacity:
            self._grow(max(2 * self.capacity, self.count + k))

    @property
    def capacity(self) -> int:
        return len(self.born)

    def add(self, pos: np.ndarray, born: np.ndarray | float, kind: np.ndarray | int, t: float,
            on_grid: bool = True) -> np.ndarray:
        """Make signs at cells ``pos`` (``(k, 2)``, inside the map) at times ``born``.

        A cell that holds a live sign keeps it (its expiry becomes the later of the two); a cell whose
        sign has expired gets the new one.

        :param t: the current step (decides which signs are live)
        :param on_grid: ``False`` for false readings, which no other UAV can find
        :return: the record index of each new sign (-1 where a live sign was kept)
        """
        pos = np.asarray(pos, dtype=np.int64).reshape(-1, 2)
        k = len(pos)
        # A scalar is filled (the common case: cheap); an array must broadcast to (k,), as before (checked here:
        # the compiled place_signs does not check bounds).
        born = np.full(k, born, dtype=np.float64) if np.ndim(born) == 0 else np.broadcast_to(
            np.asarray(born, dtype=np.float64), (k,))
        kind = np.full(k, kind, dtype=np.int64) if np.ndim(kind) == 0 else np.broadcast_to(
            np.asarray(kind, dtype=np.int64), (k,))
        self.make_room(k)
        if on_grid:
            index, self.count = place_signs(self.record, pos, born, kind, t, self.count)
            return index
        start = self.count
        ids = np.arange(start, start + k)
        self.pos[ids], self.born[ids], self.expires[ids], self.kind[ids] = pos, born, born + LIFETIME[kind], kind
        self.block[ids] = self._block_of[pos[:, 0], pos[:, 1]]
        self.count = start + k
        return ids

    def live(self, t: float) -> np.ndarray:
        """Record indices of the signs on the ground at step ``t``."""
        n = self.count
        return np.flatnonzero((self.born[:n] <= t) & (self.expires[:n] > t) & (self.kind[:n] != FALSE_READING))
