"""What a UAV receives from its teammates: their messages, appended to its observation (the table 6 baselines).

:class:`NeighbourMessageWrapper` appends to every UAV's flat observation ``n_slots`` neighbour slots, one per
teammate whose broadcast reached it this step (``infos[i]["heard_from"]``: range, communication loss and
jamming are already applied by the reserve), nearest first, zero-padded. A slot is
``(d_row, d_col, distance, present, message)``:

- ``d_row, d_col``: the sender's position minus the receiver's, in cells divided by ``max(comm_radius, 1)`` (the
  scale of the observation's own ``neighbours`` block), taken from the two UAVs' ``own`` features (row and col
  there are ``cell / (side - 1)``, capped at 1); ``distance`` is their Euclidean norm;
- ``present``: 1 for a real message, 0 for padding (a padded slot is all zeros);
- ``message`` (:data:`MESSAGE_DIM` = 16 floats), computed from the sender's own current observation by
  :func:`message_summary`: its ``own`` features (row, col, d_row, d_col, battery, progress: 6), the mean of each of
  the 7 window channels (occlusion, risk, staleness, poacher, leopard, UAVs, signs: 7) and the mean of each of the
  three coarse maps (block staleness, belief, signs: 3).

The size added, ``n_slots * (4 + 16)`` (160 floats with the default 8 slots), does not depend on the team size: a
policy trained with 10 UAVs runs on 20 or 50. With the default reserve (10 UAVs, sensor radius 3, 8 x 8 maps) a
UAV's observation grows from 553 to 713 floats.

The terminal observation's slots use the links of the episode's last step, which the parameter-sharing vector
environment keeps in ``infos[i]["terminal_heard_from"]`` (SuperSuit's automatic reset would overwrite them); an
environment without that key gets the links of the step before.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any, cast

import numpy as np
from gymnasium import spaces
from stable_baselines3.common.vec_env import VecEnv

from sb3_emmarl.common.appended.wrapping import TERMINAL_OBSERVATION, AppendingVecEnvWrapper
from sb3_emmarl.common.vec_env import LINKS_KEY, TERMINAL_LINKS_KEY

#: Floats per message: own features (6) + window channel means (7) + coarse map means (3).
MESSAGE_DIM = 16
#: Floats per slot before the message: d_row, d_col, distance, present.
EDGE_DIM = 4


@dataclass(frozen=True)
class MessageLayout:
    """Where everything lives in a wrapped observation ``[observation, slots]`` (what the extractors need).

    :param obs_dim: length of the reserve's own observation
    :param n_slots: neighbour slots appended
    :param window_shape: ``(channels, w, w)`` of the sensing window
    :param window_start: where the window starts in the observation
    :param own_start: where the 6 own features start
    :param n_own: number of own features
    :param map_starts: where each of the coarse maps starts
    :param map_size: side ``b`` of the (b, b) maps
    :param position_scale: cells per unit of row and col in the own features, ``(height - 1, width - 1)``
    :param comm_scale: the distance unit of the slots, ``max(comm_radius, 1)`` cells
    :param message_dim: floats per message
    """

    obs_dim: int
    n_slots: int
    window_shape: tuple[int, int, int]
    window_start: int
    own_start: int
    n_own: int
    map_starts: tuple[int, ...]
    map_size: int
    position_scale: tuple[float, float]
    comm_scale: float
    message_dim: int = MESSAGE_DIM

    @property
    def slot_dim(self) -> int:
        """Floats per slot: ``d_row, d_col, distance, present`` and the message."""
        return EDGE_DIM + self.message_dim

    @property
    def total_dim(self) -> int:
        """Length of the wrapped observation."""
        return self.obs_dim + self.n_slots * self.slot_dim

    @classmethod
    def from_reserve(cls, reserve: Any, n_slots: int = 8) -> MessageLayout:
        """The layout of a reserve (``venv.unwrapped.prototype``) with ``n_slots`` slots."""
        layout, cfg = reserve.observation_layout, reserve.config
        window, own = layout["window"], layout["own"]
        maps = [layout[name] for name in ("block_staleness", "belief", "signs")]
        height, width = int(reserve.height), int(reserve.width)
        window_shape = cast("tuple[int, int, int]", tuple(int(s) for s in window[1]))  # (the reserve's (channels, w, w))
        return cls(obs_dim=int(reserve.obs_dim), n_slots=int(n_slots), window_shape=window_shape,
                   window_start=window[0].start, own_start=own[0].start, n_own=int(own[1][0]),
                   map_starts=tuple(part.start for part, _ in maps), map_size=int(maps[0][1][0]),
                   position_scale=(float(max(height - 1, 1)), float(max(width - 1, 1))),
                   comm_scale=float(max(cfg.comm_radius, 1.0)))

    @classmethod
    def from_dict(cls, data: dict[str, Any] | MessageLayout) -> MessageLayout:
        """Rebuild from :meth:`to_dict` (or return a layout unchanged)."""
        if isinstance(data, MessageLayout):
            return data
        data = dict(data)
        for key in ("window_shape", "map_starts", "position_scale"):
            data[key] = tuple(data[key])
        return cls(**data)

    def to_dict(self) -> dict[str, Any]:
        """Plain values (for saving)."""
        return asdict(self)


def message_summary(observations: Any, layout: MessageLayout) -> Any:
    """The 16-float message of each observation ``(..., obs_dim or more)``: own features, window channel means, map means.

    Works on numpy arrays and torch tensors alike (the extractors summarise the UAV's own observation with it).
    """
    c, w, _ = layout.window_shape
    lead = observations.shape[:-1]
    own = observations[..., layout.own_start:layout.own_start + layout.n_own]
    window = observations[..., layout.window_start:layout.window_start + c * w * w].reshape(*lead, c, w * w)
    b2 = layout.map_size ** 2
    maps = [observations[..., s:s + b2].mean(-1, keepdims=True) for s in layout.map_starts]
    parts = [own, window.mean(-1), *maps]
    if isinstance(observations, np.ndarray):
        return np.concatenate(parts, axis=-1).astype(np.float32)
    import torch as th

    return th.cat(parts, dim=-1)


class NeighbourMessageWrapper(AppendingVecEnvWrapper):
    """Append to each UAV's observation the messages of the teammates whose broadcasts reached it this step.

    :param venv: the parameter-sharing vector environment of the reserve (``make_vec_env``; entry ``i`` is agent
        ``i % agents_per_copy`` of copy ``i // agents_per_copy``)
    :param max_messages: neighbour slots (the nearest senders are kept), int >= 1
    """

    def __init__(self, venv: VecEnv, max_messages: int = 8) -> None:
        if isinstance(max_messages, bool) or not isinstance(max_messages, (int, np.integer)) or max_messages < 1:
            raise ValueError(f"max_messages must be an int >= 1, got {max_messages!r}")
        inner = venv.unwrapped
        reserve = getattr(inner, "prototype", None)
        if reserve is None or not hasattr(reserve, "observation_layout") or not hasattr(inner, "agents_per_copy"):
            raise ValueError("venv must be the reserve's parameter-sharing vector environment "
                             f"(sb3_emmarl.common.vec_env.make_vec_env), got {type(venv).__name__}")
        space = venv.observation_space
        if not isinstance(space, spaces.Box) or space.shape != (reserve.obs_dim,):
            raise ValueError(f"venv must give the reserve's flat observations of {reserve.obs_dim} floats, got {space}")
        self.layout = MessageLayout.from_reserve(reserve, int(max_messages))
        self.agents_per_copy = int(inner.agents_per_copy)
        extra = self.layout.n_slots * self.layout.slot_dim
        super().__init__(venv, np.full(extra, -np.inf, np.float32), np.full(extra, np.inf, np.float32))
        self._last_links: list[tuple[int, ...]] = [() for _ in range(self.num_envs)]

    # ------------------------------------------------------------------ building the slots
    def slots(self, observations: np.ndarray, links: Sequence[Sequence[int]],
              entries: Sequence[int] | None = None) -> np.ndarray:
        """The neighbour slots ``(len(entries), n_slots * slot_dim)`` of ``entries`` (default: all).

        :param observations: ``(num_envs, obs_dim)`` raw observations of every entry (the senders' included)
        :param links: per entry in ``entries``, the senders (agent indices within its copy) heard from
        :param entries: vector entries to build slots for
        """
        lay = self.layout
        entries = range(len(observations)) if entries is None else entries
        messages = message_summary(observations, lay)
        scale = np.asarray(lay.position_scale) / lay.comm_scale
        positions = observations[:, lay.own_start:lay.own_start + 2].astype(np.float64) * scale
        out = np.zeros((len(entries), lay.n_slots, lay.slot_dim), dtype=np.float32)
        for row, (i, senders) in enumerate(zip(entries, links)):
            if not senders:
                continue
            base = i - i % self.agents_per_copy
            idx = base + np.asarray(senders, dtype=np.int64)
            rel = positions[idx] - positions[i]
            dist = np.hypot(rel[:, 0], rel[:, 1])
            order = np.lexsort((idx, dist))[:lay.n_slots]  # nearest first, ties by sender
            k = len(order)
            out[row, :k, 0:2] = rel[order]
            out[row, :k, 2] = dist[order]
            out[row, :k, 3] = 1.0
            out[row, :k, EDGE_DIM:] = messages[idx[order]]
        return out.reshape(len(entries), -1)

    @staticmethod
    def _links(infos: Sequence[dict[str, Any]], key: str = LINKS_KEY) -> list[tuple[int, ...]]:
        return [tuple(info.get(key, ())) if isinstance(info, dict) else () for info in infos]

    # ------------------------------------------------------------------ checkpoints
    def get_state(self) -> list[tuple[int, ...]]:
        """The links of the last step (for :mod:`~sb3_emmarl.common.checkpoints`: a resumed run rebuilds the same
        terminal observations)."""
        return list(self._last_links)

    def set_state(self, state: list[tuple[int, ...]]) -> None:
        """Restore :meth:`get_state`."""
        if len(state) != self.num_envs:
            raise ValueError(f"the saved links are for {len(state)} entries, this environment has {self.num_envs}")
        self._last_links = [tuple(int(j) for j in links) for links in state]

    # ------------------------------------------------------------------ the appended slots
    def _reset_extra(self, observations: np.ndarray) -> np.ndarray:
        self.reset_infos = list(getattr(self.venv.unwrapped, "reset_infos", None) or self.reset_infos)
        infos = self.reset_infos if len(self.reset_infos) == self.num_envs else [{}] * self.num_envs
        self._last_links = self._links(infos)
        return self.slots(self._rows(observations), self._last_links)

    def _step_extra(self, observations: np.ndarray, dones: np.ndarray, infos: list[dict[str, Any]]
                    ) -> tuple[np.ndarray, dict[int, np.ndarray]]:
        links = self._links(infos)
        terminal: dict[int, np.ndarray] = {}
        for c in sorted({int(i) // self.agents_per_copy for i in np.flatnonzero(dones)}):
            # a copy's UAVs end together: rebuild its terminal observations from one another's
            members = range(c * self.agents_per_copy, (c + 1) * self.agents_per_copy)
            if not all(TERMINAL_OBSERVATION in infos[i] for i in members):
                continue
            final = np.zeros_like(observations, dtype=np.float32)
            for i in members:
                final[i] = infos[i][TERMINAL_OBSERVATION]
            final_links = [tuple(infos[i][TERMINAL_LINKS_KEY]) if TERMINAL_LINKS_KEY in infos[i]
                           else self._last_links[i] for i in members]
            terminal.update(zip(members, self.slots(final, final_links, list(members))))
        self._last_links = links
        return self.slots(self._rows(observations), links), terminal

    @staticmethod
    def _rows(observations: np.ndarray) -> np.ndarray:
        return np.asarray(observations, dtype=np.float32).reshape(len(observations), -1)
