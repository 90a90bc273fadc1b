"""How much memory environment copies take, checked before they are built: ``n_envs`` copies of a large reserve can
ask for more than the machine has (256 copies of the largest allowed reserve, about 30 GB), which would end in the
kernel's out-of-memory kill or a ``MemoryError`` deep inside numpy instead of a refusal.

The size of a copy is measured on the first one built (the vector environments build a prototype to read the spaces):
the numpy arrays reachable from it, each base array counted once. Written by hand because the measure needed is that
of numpy buffers behind an object graph (``sys.getsizeof`` counts one object; ``pympler`` is not a dependency).
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

#: What a copy may grow by between its construction and its first episode (the reserve's episode arrays): a bound,
#: checked against reserves of several sizes by tests/test_vec_env_memory.py.
RESET_GROWTH = 1.4


def array_bytes(obj: Any) -> int:
    """The bytes of the numpy arrays reachable from ``obj`` (through attributes, slots, dicts, lists, tuples and
    sets), each base array counted once.

    :param obj: an environment (or any object)
    """
    seen: set[int] = set()
    total, stack = 0, [obj]
    while stack:
        item = stack.pop()
        if id(item) in seen or isinstance(item, (type, str, bytes, int, float, bool)) or item is None:
            continue
        seen.add(id(item))
        if isinstance(item, np.ndarray):
            base = item
            while isinstance(base.base, np.ndarray):
                base = base.base
            if base is item or id(base) not in seen:
                seen.add(id(base))
                total += base.nbytes
        elif isinstance(item, dict):
            stack.extend(item.values())
        elif isinstance(item, (list, tuple, set, frozenset)):
            stack.extend(item)
        else:
            stack.extend(getattr(item, "__dict__", {}).values())
            stack.extend(getattr(item, name) for name in getattr(type(item), "__slots__", ()) if hasattr(item, name))
    return total


def available_memory() -> int | None:
    """The bytes this machine can still give (Linux's ``MemAvailable``, else the free physical pages; None if
    unknown)."""
    try:
        with open("/proc/meminfo") as file:
            for line in file:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def check_copies_fit(prototype: Any, n_copies: int) -> None:
    """Refuse ``n_copies`` copies of ``prototype`` (one environment, as built) when they would take more memory than
    the machine has available.

    :param prototype: the first copy
    :param n_copies: how many copies are to be built (besides the prototype, which is then closed)
    :raise ValueError: one line with the estimate, the size of one copy and what is available
    """
    available = available_memory()
    each = array_bytes(prototype) * RESET_GROWTH
    if available is not None and each * n_copies > available:
        raise ValueError(f"{n_copies} copies of this environment need about {each * n_copies / 2**30:.1f} GiB "
                         f"({each / 2**20:.0f} MiB each) and this machine has {available / 2**30:.1f} GiB available: "
                         "use fewer copies (n_envs) or a smaller environment")
