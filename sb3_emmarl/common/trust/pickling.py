"""Pickling that keeps numpy views views of their base arrays: a reserve's step records hold views of its arrays
(written through one, read through another), which plain pickle would copy apart. The vector environments pickle
their copies with :func:`dumps` (for checkpoints and for moving copies between processes); between processes
``pickle.loads`` reads it back, from a checkpoint file :mod:`sb3_emmarl.common.trust.safe_pickle` does (as data only)."""

from __future__ import annotations

import io
import pickle
from typing import Any

import numpy as np


def rebuild_view(base: np.ndarray, offset: int, shape: tuple[int, ...], strides: tuple[int, ...], dtype: np.dtype,
                 writeable: bool) -> np.ndarray:
    """The view of ``base`` that :class:`ViewPickler` pickled (what unpickling calls)."""
    view = np.ndarray(shape, dtype, buffer=base, offset=offset, strides=strides)
    view.flags.writeable = writeable
    return view


class ViewPickler(pickle.Pickler):
    """A pickler that keeps numpy views views of their base array (plain pickle copies each view's data, so an
    environment writing through one view and reading through another behaves differently once unpickled)."""

    def reducer_override(self, obj: Any) -> Any:
        if type(obj) is not np.ndarray or not isinstance(obj.base, np.ndarray) or obj.dtype.hasobject:
            return NotImplemented
        base = obj.base
        while isinstance(base.base, np.ndarray):  # the outermost array (an unpickled one owns a bytes buffer)
            base = base.base
        if type(base) is np.ndarray and base.flags.c_contiguous and not base.dtype.hasobject:
            offset = obj.__array_interface__["data"][0] - base.__array_interface__["data"][0]
            return rebuild_view, (base, offset, obj.shape, obj.strides, obj.dtype, bool(obj.flags.writeable))
        return NotImplemented


def dumps(obj: Any) -> bytes:
    """``pickle.dumps`` that keeps numpy views sharing memory with their base arrays (read back with ``pickle.loads``)."""
    buffer = io.BytesIO()
    ViewPickler(buffer, protocol=pickle.HIGHEST_PROTOCOL).dump(obj)
    return buffer.getvalue()
