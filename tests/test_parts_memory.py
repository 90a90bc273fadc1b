"""The E-step's memory of rollouts (``PartsMemory``): a deque of parts with a maximum length, kept in a few blocks."""

from collections import deque

import numpy as np
import pytest
import torch as th

from sb3_emmarl.common.latent.em import FIELDS, EpisodeCounts, Transitions
from sb3_emmarl.common.latent.parts import MIN_ROWS, PartsMemory


def part(rng: np.random.Generator, rows: int) -> Transitions:
    return Transitions(th.as_tensor(rng.random((rows, 3)), dtype=th.float32),
                       th.as_tensor(rng.random((rows, 2)), dtype=th.float32),
                       th.as_tensor(rng.random((rows, 3)), dtype=th.float32),
                       th.as_tensor(rng.integers(0, 100, rows), dtype=th.long))


def assert_same(got, expected):
    if expected is None:
        assert got is None
        return
    for name in FIELDS:
        assert th.equal(getattr(got, name), getattr(expected, name))


@pytest.mark.parametrize("maxlen", [1, 3, 40])
def test_parts_come_back_as_a_deque_keeps_them_through_growth_and_compaction(maxlen):
    """Random parts (some None, some larger than the first block) against a plain deque: the same parts in the same
    order, and their concatenation, after every append."""
    rng = np.random.default_rng(maxlen)
    memory, reference = PartsMemory(Transitions, maxlen), deque(maxlen=maxlen)
    sizes = set()
    for step in range(300):
        rows = 3000 if step == 150 else int(rng.choice([1, 7, 50, 100]))  # one part larger than the first block
        new = None if rng.random() < 0.1 and step != 150 else part(rng, rows)
        memory.append(new)
        reference.append(new)
        sizes.add(len(memory._blocks[0]) if memory._blocks else 0)
        assert len(memory) == len(reference)
        for got, expected in zip(memory, reference, strict=True):
            assert_same(got, expected)
        kept = [p for p in reference if p is not None]
        whole = memory.contiguous()
        if kept:
            assert_same(whole, Transitions(*(th.cat([getattr(p, n) for p in kept]) for n in FIELDS)))
            assert memory.rows == sum(len(p) for p in kept)
        else:
            assert whole is None and memory.rows == 0
    assert len(sizes - {0}) >= 2  # the blocks grew at least once
    assert all(size == 0 or size >= MIN_ROWS for size in sizes)


def test_the_blocks_stay_a_few_times_the_rows_kept_however_many_parts_pass():
    """800 parts kept of 100 rows each, 5,000 appended: the blocks hold at most twice what is kept (plus the newest
    part), not a block per part."""
    rng = np.random.default_rng(0)
    memory = PartsMemory(Transitions, 800)
    for _ in range(5000):
        memory.append(part(rng, 100))
    assert memory.rows == 80_000
    assert len(memory._blocks[0]) <= 2 * (80_000 + 100)
    assert len(memory._blocks) == 4  # one per field


def test_clear_forgets_and_counts_of_episodes_keep_their_dtypes():
    memory = PartsMemory(EpisodeCounts, 2)
    counts = EpisodeCounts(th.tensor([3, 4]), th.ones(2, 5), th.zeros(2, 2))
    memory.append(counts)
    memory.append(None)
    memory.append(counts)  # the first leaves
    assert [p is None for p in memory] == [True, False]
    assert memory.contiguous().episodes.dtype == th.long and memory.rows == 2
    memory.clear()
    assert len(memory) == 0 and not memory and memory.contiguous() is None


@pytest.mark.parametrize("bad", [0, -1, 1.5, True])
def test_a_bad_maxlen_is_refused(bad):
    with pytest.raises(ValueError, match="maxlen must be an int >= 1"):
        PartsMemory(Transitions, bad)
