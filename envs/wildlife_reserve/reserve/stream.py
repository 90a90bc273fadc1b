"""The step's random stream inside compiled code: numpy's own generator, called from the kernels.

numba can take a ``np.random.Generator`` as an argument, but unboxing one costs about 20 microseconds per call (it
reads the generator's ``ctypes`` interface through Python every time), more than most of a step's kernels take. The
kernels take that interface once read instead, as a small int array (:func:`handle`), and call numpy's own C entry
points through it with numba's own generator code (``numba.np.random``; the compiled draws are
:mod:`wildlife_reserve.reserve.kernels.draws`), so their draws are numpy's, bit for bit, and the generator's state
moves as if numpy had drawn them.

Hand-written (a dozen lines of LLVM through numba's ``intrinsic``) because neither numba nor numpy offers a cheaper
way to hand a generator to compiled code.
"""

from __future__ import annotations

import ctypes
from typing import Any

import numpy as np

from wildlife_reserve.reserve.kernels.draws import HANDLE_FIELDS


def handle(rng: np.random.Generator) -> np.ndarray:
    """The C interface of ``rng``'s bit generator as ``(6,)`` uint64 addresses (:data:`HANDLE_FIELDS`), for the
    kernels' draws. Valid while ``rng`` lives: keep the two together (see :class:`Stream`).

    :param rng: a numpy generator
    """
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be a numpy Generator, got {type(rng).__name__}")
    interface = rng.bit_generator.ctypes

    def address(value: Any) -> int:
        if isinstance(value, int):
            return value
        return int(ctypes.cast(value, ctypes.c_void_p).value or 0)

    return np.array([address(getattr(interface, name)) for name in HANDLE_FIELDS], dtype=np.uint64)


class Stream:
    """A generator and its :func:`handle`, kept together so that the addresses never outlive what they point into.
    Pickles as the generator alone (the addresses are remade on loading).

    :param rng: the numpy generator the kernels draw from
    """

    def __init__(self, rng: np.random.Generator) -> None:
        self.rng = rng
        self.handle = handle(rng)

    def __getstate__(self) -> dict:
        return {"rng": self.rng}

    def __setstate__(self, state: dict) -> None:
        self.__init__(state["rng"])  # type: ignore[misc]
