"""The E-step's memory of recent rollouts: their parts kept back to back in a few large tensors.

Hand-written because a ``deque(maxlen=window)`` of each rollout's small tensors scatters hundreds of long-lived
allocations of some 30 KB through the C heap, between the short-lived arrays of every training step, and the heap
then cannot give the space between them back (with ``em_ddpg.yml``, an E-step part every ``train()`` call and 800
kept, by far more than the data: docs/lab/results-history.md, EM-DDPG against DDPG). Here the parts live in one
preallocated tensor per field, which grows (doubling) and is compacted when the newest part does not fit after the
oldest, so the memory holds a handful of large blocks whatever the number of parts.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterator
from dataclasses import fields
from typing import TYPE_CHECKING, Generic, TypeVar

import torch as th

if TYPE_CHECKING:
    from _typeshed import DataclassInstance

T = TypeVar("T", bound="DataclassInstance")  # (the parts' dataclass)

#: Rows of the first block (at least: a first part larger than this gets twice its size).
MIN_ROWS = 1024


class PartsMemory(Generic[T]):
    """The last ``maxlen`` parts appended (a ``deque(maxlen=...)`` of them, oldest first), each part a dataclass of
    tensors sharing their first dimension (:class:`~sb3_emmarl.common.latent.em.Transitions`,
    :class:`~sb3_emmarl.common.latent.em.EpisodeCounts`), or None. The parts come out as views of the blocks: read
    them before the next :meth:`append` (which may move them).

    :param kind: the parts' dataclass
    :param maxlen: parts kept (the oldest leaves when one more is appended)
    """

    def __init__(self, kind: type[T], maxlen: int) -> None:
        if isinstance(maxlen, bool) or not isinstance(maxlen, int) or maxlen < 1:
            raise ValueError(f"maxlen must be an int >= 1, got {maxlen!r}")
        self.kind = kind
        self.maxlen = maxlen
        self._names = [field.name for field in fields(kind)]
        self._blocks: list[th.Tensor] = []
        self._spans: deque[tuple[int, int] | None] = deque()  # (first row, rows) of each part, None for a None part
        self._begin = self._end = 0  # the rows in use: [begin, end)

    def __len__(self) -> int:
        return len(self._spans)

    def __bool__(self) -> bool:
        return bool(self._spans)

    def __iter__(self) -> Iterator[T | None]:
        for span in self._spans:
            yield None if span is None else self._view(*span)

    def _view(self, start: int, rows: int) -> T:
        return self.kind(*(block[start:start + rows] for block in self._blocks))

    @property
    def rows(self) -> int:
        """Rows of the parts kept."""
        return self._end - self._begin

    def contiguous(self) -> T | None:
        """Every part kept, concatenated in order (a view, no copy), or None if no part holds rows."""
        return self._view(self._begin, self.rows) if self._blocks and self.rows else None

    def clear(self) -> None:
        """Forget every part (the blocks are freed)."""
        self._blocks, self._spans = [], deque()
        self._begin = self._end = 0

    def append(self, part: T | None) -> None:
        """Keep ``part`` (copied into the blocks); the oldest part leaves if ``maxlen`` are kept."""
        if len(self._spans) == self.maxlen:
            self._spans.popleft()
            self._begin = next((span[0] for span in self._spans if span is not None), self._end)
        if part is None:
            self._spans.append(None)
            return
        tensors = [getattr(part, name) for name in self._names]
        rows = len(tensors[0])
        self._make_room(tensors, rows)
        for block, tensor in zip(self._blocks, tensors):
            block[self._end:self._end + rows] = tensor
        self._spans.append((self._end, rows))
        self._end += rows

    def _make_room(self, tensors: list[th.Tensor], rows: int) -> None:
        """Room for ``rows`` more after the last part: the parts kept move to the blocks' start, into blocks twice
        as large as they and the new part need if the present ones are smaller."""
        if self._blocks and self._end + rows <= len(self._blocks[0]):
            return
        used = self.rows
        capacity = len(self._blocks[0]) if self._blocks else 0
        if used + rows > capacity // 2:
            capacity = max(MIN_ROWS, 2 * (used + rows))
        blocks = [th.empty((capacity, *tensor.shape[1:]), dtype=tensor.dtype, device=tensor.device)
                  for tensor in tensors]
        for new, old in zip(blocks, self._blocks):
            new[:used] = old[self._begin:self._end]
        self._spans = deque(None if span is None else (span[0] - self._begin, span[1]) for span in self._spans)
        self._blocks, self._begin, self._end = blocks, 0, used
