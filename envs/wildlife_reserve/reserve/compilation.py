"""The first episode after an install compiles the reserve's numba kernels (:mod:`wildlife_reserve.reserve.kernels`,
``cache=True``): 55 s on an idle 2-core machine, about 150 s on a busy one. This module says so, once, instead of
leaving that time silent; later processes load numba's cache in well under a second and say nothing.
"""

from __future__ import annotations

import functools
import sys
from pathlib import Path

from wildlife_reserve.reserve import kernels


def cache_folder() -> Path | None:
    """The folder of numba's cache of the kernels (``kernels/__pycache__``, or numba's user-wide or
    ``NUMBA_CACHE_DIR`` folder where that one is read-only); None when numba does not compile (``NUMBA_DISABLE_JIT=1``)."""
    cache = getattr(kernels.advance_world, "_cache", None)  # numba's cache object of a ``cache=True`` kernel
    folder = getattr(cache, "cache_path", None)
    return None if folder is None else Path(folder)


def cache_is_cold() -> bool:
    """Whether numba's cache holds no compiled kernel of the ``kernels`` package yet (each compiled kernel has an index
    file ``<module>.<name>-<line>.py<version>.nbi`` there), as after an install."""
    folder = cache_folder()
    if folder is None:
        return False
    return not any(folder.glob("*.nbi"))


@functools.cache
def announce_compilation() -> None:
    """Say on stderr, once per process and only while the cache is cold (:func:`cache_is_cold`), that the kernels
    are being compiled and roughly how long that takes; the reserve calls this at each ``reset``."""
    if cache_is_cold():
        print(f"wildlife_reserve: compiling the reserve's kernels with numba, once per install (one to three minutes "
              f"on 2 cores); later runs load them from {cache_folder()}", file=sys.stderr)
