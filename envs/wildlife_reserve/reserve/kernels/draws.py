"""The kernels' draws from numpy's generator through its handle (:func:`~wildlife_reserve.reserve.stream.handle`):
numba's bit-generator struct rebuilt from the handle's addresses, and ``uniform`` and ``standard_normal`` through
numpy's own C entry points (see :mod:`wildlife_reserve.reserve.stream`)."""

from __future__ import annotations

from typing import Any

import numpy as np
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic
from numba.np.random.distributions import random_standard_normal
from numba.np.random.generator_core import next_double

#: What a handle holds, in order: the addresses numba's bit-generator struct is made of.
HANDLE_FIELDS = ("state_address", "state", "next_uint64", "next_uint32", "next_double", "bit_generator")
_BITGEN = types.NumPyRandomBitGeneratorType("bit_generator")


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
