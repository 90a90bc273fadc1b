"""The step's random stream inside compiled code: numpy's own generator, called from the kernels.

numba can take a ``np.random.Generator`` as an argument, but unboxing one costs about 20 microseconds per call (it
reads the generator's ``ctypes`` interface through Python every time), more than most of a step's kernels take. The
kernels take that interface once read instead, as a small int array (:func:`handle`), and call numpy's own C entry
points through it with numba's own generator code (``numba.np.random``), so their draws are numpy's, bit for bit, and
the generator's state moves as if numpy had drawn them.

Hand-written (a dozen lines of LLVM through numba's ``intrinsic``) because neither numba nor numpy offers a cheaper
way to hand a generator to compiled code.
"""

from __future__ import annotations

import ctypes
from typing import Any

import numpy as np
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic
from numba.np.random.distributions import random_standard_normal
from numba.np.random.generator_core import next_double

#: What :func:`handle` holds, in order: the addresses numba's bit-generator struct is made of.
HANDLE_FIELDS = ("state_address", "state", "next_uint64", "next_uint32", "next_double", "bit_generator")
_BITGEN = types.NumPyRandomBitGeneratorType("bit_generator")


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


@intrinsic
def _bit_generator(typingctx, addresses):  # pragma: no cover - compiled
    """numba's bit-generator struct (what unboxing a ``Generator``'s ``bit_generator`` makes) from a handle."""
    def codegen(context, builder, signature, args):
        array = context.make_array(signature.args[0])(context, builder, args[0])
        struct = cgutils.create_struct_proxy(_BITGEN)(context, builder)
        for i, name in enumerate(HANDLE_FIELDS):
            pointer = cgutils.gep_inbounds(builder, array.data, i)
            value = builder.load(pointer)
            setattr(struct, "fnptr_" + name if name.startswith("next_") else name, value)
        struct.parent = cgutils.get_null_value(struct.parent.type)
        return struct._getvalue()

    return _BITGEN(addresses), codegen


@njit(cache=True)
def uniform(addresses: np.ndarray, size: int) -> np.ndarray:  # pragma: no cover - compiled
    """``rng.random(size)``: ``size`` float64 draws in [0, 1) from the generator of ``addresses``."""
    bitgen: Any = _bit_generator(addresses)  # type: ignore[call-arg]  # (numba passes the typing context)
    out = np.empty(size)
    for i in range(size):
        out[i] = next_double(bitgen)
    return out


@njit(cache=True)
def standard_normal(addresses: np.ndarray, size: int) -> np.ndarray:  # pragma: no cover - compiled
    """``rng.standard_normal(size)`` (and ``rng.normal(loc, scale, size)`` is ``loc + scale *`` these, as numpy
    computes it) from the generator of ``addresses``."""
    bitgen: Any = _bit_generator(addresses)  # type: ignore[call-arg]  # (numba passes the typing context)
    out = np.empty(size)
    for i in range(size):
        out[i] = random_standard_normal(bitgen)
    return out
