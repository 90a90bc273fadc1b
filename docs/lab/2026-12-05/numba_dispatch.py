"""How long numba takes to dispatch a call whose arrays come apart, in a tuple and in a namedtuple:
``python numba_dispatch.py`` (issue "A house you can read": which named records cost nothing at the kernels' boundary)."""

import time
from typing import NamedTuple

import numpy as np
from numba import njit


class Record(NamedTuple):
    a: np.ndarray
    b: np.ndarray
    c: np.ndarray
    d: np.ndarray
    e: np.ndarray


@njit
def apart(a, b, c, d, e):
    return a[0] + e[0]


@njit
def in_tuple(t):
    return t[0][0] + t[4][0]


@njit
def in_record(r):
    return r.a[0] + r.e[0]


@njit
def rebuilt(t):
    r = Record(*t)  # a plain tuple at the boundary, named inside
    return r.a[0] + r.e[0]


def main() -> None:
    arrays = [np.zeros(5) for _ in range(5)]
    plain, record = tuple(arrays), Record(*arrays)
    calls = {"apart": lambda: apart(*arrays), "tuple": lambda: in_tuple(plain), "namedtuple": lambda: in_record(record),
             "tuple, named inside": lambda: rebuilt(plain)}
    for call in calls.values():
        call()  # compile
    for name, call in calls.items():
        start = time.perf_counter()
        for _ in range(100_000):
            call()
        print(f"{name:22s} {(time.perf_counter() - start) * 10:.2f} us per call")


if __name__ == "__main__":
    main()
