"""What each UAV knows and how the team shares it: visit stamps, links, messages and the coarse maps.

``knowledge[r, s]`` is the time up to which UAV ``r`` knows UAV ``s``'s visit history and readings.
Each airborne UAV knows its own up to now; a delivered message ``s -> r`` sets
``knowledge[r] = max(knowledge[r], knowledge[s])``, so knowledge travels one hop per step. From it
come the staleness channel and map (time since a cell or block was seen, as far as the UAV knows),
the poacher-activity belief map and the map of the signs of poacher activity the UAV knows of.
"""

from __future__ import annotations

import numpy as np

from wildlife_reserve.reserve.constants import NEVER
from wildlife_reserve.reserve.kernels import (
    beliefs,
    deliver,
    known_ages,
    learn_signs,
    links_in_range,
    look,
    merge_messages,
)

#: A block's sign value is ``1 - exp(-signs known there / SIGN_MAP_SCALE)``.
SIGN_MAP_SCALE = 2.0


class TeamKnowledge:
    """The team's shared knowledge, as numpy arrays over UAVs.

    Public arrays: ``knowledge`` ``(n, n)``; ``beacons[s, r]`` (r heard s's position this step);
    ``comm_links[s, r]`` (a message of s reached r this step); ``own_last`` / ``own_first`` ``(n, *padded)``
    (each UAV's last and first look at each cell); ``known_signs`` ``(n, capacity)`` (which sign records
    each UAV knows of) and ``sign_counts`` ``(n, blocks)``.

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
        self._stamps = np.empty((2, n, *padded_shape), dtype=np.float32)
        self._block_stamps = np.empty((2, n, n_blocks), dtype=np.float32)
        self._all_blocks = np.broadcast_to(np.arange(n_blocks), (n, n_blocks))

    def reset(self) -> None:
        """Forget everything: a new episode."""
        n = self.n
        self._stamps[0], self._stamps[1] = NEVER, -NEVER
        self.own_last, self.own_first = self._stamps
        self._block_stamps[0], self._block_stamps[1] = NEVER, -NEVER
        self.knowledge = np.full((n, n), NEVER, dtype=np.float32)
        self.beacons = np.zeros((n, n), dtype=bool)
        self.comm_links = np.zeros((n, n), dtype=bool)
        self.dist = np.zeros((n, n))
        self.events = np.zeros((0, 3))  # (time, reading UAV, block) of the poacher readings
        self.known_signs = np.zeros((n, 64), dtype=bool)
        self.sign_counts = np.zeros((n, self.n_blocks), dtype=np.float64)
        self._sign_map, self._sign_map_total = np.zeros((n, self.n_blocks)), 0.0

    # ------------------------------------------------------------------ own looks
    def record_visits(self, t: int, uavs: np.ndarray, cells: np.ndarray, blocks: np.ndarray, high_risk: np.ndarray,
                      visited: np.ndarray) -> tuple[np.ndarray, int]:
        """The airborne ``uavs`` looked at padded flat ``cells`` ``(k, w * w)`` and flew over ``blocks`` ``(k,)`` at ``t``;
        the team's coverage ``visited`` (flat padded bool, updated in place) counts ``high_risk`` cells.

        :return: high-risk cells each of ``uavs`` saw that nobody had seen before ``(k,)``, and the team's new ones
        """
        last, first = self._stamps.reshape(2, self.n, -1)
        return look(uavs, cells, blocks, high_risk, visited, last, first, self._block_stamps[0], self._block_stamps[1],
                    self.knowledge, np.float32(t))

    def add_readings(self, t: int, uavs: np.ndarray, blocks: np.ndarray) -> None:
        """Poacher readings (true or false) made at ``t`` by ``uavs`` in ``blocks``; old ones are dropped."""
        if len(uavs):
            fresh = np.column_stack([np.full(len(uavs), t), uavs, blocks])
            self.events = np.concatenate([self.events, fresh])
        if len(self.events) and self.events[0, 0] <= t - self.horizon:  # events are in time order
            self.events = self.events[self.events[:, 0] > t - self.horizon]

    def learn_signs(self, uavs: np.ndarray, signs: np.ndarray, sign_blocks: np.ndarray) -> None:
        """Each of ``uavs`` found sign record ``signs`` (lying in ``sign_blocks``)."""
        if not len(uavs):
            return
        self.fit_signs(int(signs.max()) + 1)
        learn_signs(self.known_signs, self.sign_counts, uavs, signs, sign_blocks)

    def fit_signs(self, size: int) -> None:
        """Make room in ``known_signs`` for ``size`` sign records."""
        if size > self.known_signs.shape[1]:
            grown = np.zeros((self.n, max(size, 2 * self.known_signs.shape[1])), dtype=bool)
            grown[:, :self.known_signs.shape[1]] = self.known_signs
            self.known_signs = grown

    # ------------------------------------------------------------------ links and messages
    def in_range(self, uav_pos: np.ndarray, ok: np.ndarray) -> np.ndarray:
        """``(n, n)`` bool: s and r (s != r) both ``ok`` (airborne, unjammed) and within ``R_c`` of each other."""
        self.dist, links = links_in_range(uav_pos, ok, self.comm_radius)
        return links

    def update_beacons(self, rng: np.random.Generator, links: np.ndarray) -> None:
        """Position beacons heard this step, each lost with probability ``comm_loss``."""
        self.beacons = links & (rng.random(links.shape) >= self.comm_loss)

    def communicate(self, rng: np.random.Generator, comm: np.ndarray, links: np.ndarray, sign_blocks: np.ndarray) -> None:
        """Broadcasts push and queries pull each UAV's knowledge; each message is lost with ``comm_loss``.

        :param comm: ``(n,)`` communication choices (0 none, 1 broadcast, 2 query)
        :param links: ``(n, n)`` links in range this step (see :meth:`in_range`)
        :param sign_blocks: block of every sign record (for the sign counts)
        """
        delivered = deliver(links, comm, self.dist, rng.random(links.shape), self.comm_loss)
        self.comm_links = delivered
        if not delivered.any():
            return
        self.knowledge, learned = merge_messages(delivered, self.knowledge, self.known_signs[:, :len(sign_blocks)])
        who, sign = np.nonzero(learned)
        if len(who):
            self.learn_signs(who, sign, sign_blocks[sign])

    # ------------------------------------------------------------------ maps
    def staleness(self, t: int, window: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Time since each window cell and each coarse block was seen, as far as each UAV knows.

        UAV r knows UAV s's visits up to ``knowledge[r, s]``: s's last visit if it is that old, else s's
        first visit if that one is, else nothing. Ages are ``min((t - newest known visit) / max_cycles, 1)``.

        :param window: ``(n, w, w)`` padded flat indices of each UAV's window
        :return: ``(n, w, w)`` and ``(n, blocks)`` ages in [0, 1]
        """
        n, w = self.n, window.shape[-1]
        t32, scale = np.float32(t), np.float32(1.0 / self.max_cycles)
        last, first = self._stamps.reshape(2, n, -1)
        cells = known_ages(last, first, self.knowledge, window.reshape(n, -1), t32, scale)
        blocks = known_ages(self._block_stamps[0], self._block_stamps[1], self.knowledge, self._all_blocks, t32, scale)
        return cells.reshape(n, w, w), blocks

    def belief(self, t: int) -> np.ndarray:
        """``(n, blocks)`` poacher activity from the readings each UAV knows of, in [0, 1)."""
        if not len(self.events):
            return np.zeros((self.n, self.n_blocks), dtype=np.float32)
        return beliefs(self.events, self.knowledge, self.n_blocks, self.belief_decay, float(t))

    def sign_map(self) -> np.ndarray:
        """``(n, blocks)`` signs of poacher activity each UAV knows of, as ``1 - exp(-count / SIGN_MAP_SCALE)``."""
        total = float(self.sign_counts.sum())  # counts only grow within an episode: their sum tells when to recompute
        if total != self._sign_map_total:
            self._sign_map = 1.0 - np.exp(-self.sign_counts * (1.0 / SIGN_MAP_SCALE))
            self._sign_map_total = total
        return self._sign_map

    def heard_from(self) -> list[tuple[int, ...]]:
        """For each UAV, the indices of the teammates whose message reached it this step (ascending)."""
        receiver, sender = np.nonzero(self.comm_links.T)  # grouped by receiver, senders ascending within each
        if not len(receiver):
            return [()] * self.n
        senders, ends = sender.tolist(), np.cumsum(np.bincount(receiver, minlength=self.n)).tolist()
        return [tuple(senders[start:end]) for start, end in zip([0, *ends], ends)]
