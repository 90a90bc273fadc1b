"""A fuzz of the reserve's arguments: seeded argument sets, and a runner that sorts what each one does.

Used by ``tests/test_fuzz_reserve.py`` (1000 cases, no failure allowed) and ``benchmarks/fuzz_reserve.py`` (the
counts). A plain module, not a test file.

A case starts from the defaults (no arguments) and mutates one to three arguments with values from
:data:`CATALOGUE`: wrong types (strings such as ``"false"`` or ``"0"``, lists, dicts, ``None``, bools where a
number is expected, floats where an int is expected, complex numbers, object arrays), NaN, infinities, zero,
negative and huge values, wrong shapes, unknown argument names, and valid values. Each value is labelled valid
or invalid *here*, from the documented contract (docs/env.md, Arguments), not from ``ReserveConfig``'s code: a
value that validation lets through although the catalogue calls it invalid shows up as a silent acceptance.

The valid values are small or moderate, so that valid cases run fast, and compatible with each other: every
valid grid side is >= 11 (the window of the largest valid ``sensor_radius``, 5) and >= the largest valid
``belief_size`` (10), and arrays labelled valid take the case's grid shape. A case whose mutations are all valid
is therefore valid whatever else it mutates, and a value labelled invalid is invalid next to any valid one.
Mutations whose validity depends on another argument (the smallest grids, the memory bound ``n_uavs x cells``,
terrain against ``grid_size``) come as combined entries that set every argument involved.

Running a case builds ``reserve_v1.parallel_env(**kwargs)`` and, if that succeeds, resets it and takes a few
random steps, under a time limit and with tracemalloc measuring the peak of Python and numpy memory. Outcomes:

==================== ===================================================================================
``ran``              a valid case built, reset and stepped, with finite observations in [-1, 1] and finite
                     rewards
``clean_error``      an invalid case raised a ValueError whose message names an invalid argument
``silent_acceptance`` an invalid case built, reset and stepped (failure)
``false_rejection``  a valid case raised a ValueError when built (failure)
``unclean_exception`` any other exception, a ValueError that names no invalid argument, or an invalid case
                     that was accepted and then failed in reset or step (failure)
``bad_output``       a valid case ran but gave non-finite rewards, observations outside [-1, 1] or numpy
                     RuntimeWarnings (overflow, invalid value) (failure)
``hang``             the case ran past the time limit (failure)
``memory``           the traced peak exceeded the memory limit, or a MemoryError (failure)
==================== ===================================================================================
"""

from __future__ import annotations

import math
import re
import reprlib
import resource
import signal
import time
import tracemalloc
import warnings
from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

import numpy as np

from wildlife_reserve import reserve_v1
from wildlife_reserve.reserve.config import MAX_CYCLES
from wildlife_reserve.reserve.reserve import compile_kernels

OUTCOMES = ("ran", "clean_error", "silent_acceptance", "false_rejection", "unclean_exception", "bad_output", "hang",
            "memory")
FAILURES = OUTCOMES[2:]
#: Chance that a mutation draws a valid value (so that about 30 % of the cases are valid throughout).
VALID_SHARE = 0.5
#: Default per-case limits.
TIME_LIMIT = 10.0
MEMORY_LIMIT = 2**30
#: Random steps after a reset.
STEPS = 3


@dataclass(frozen=True)
class Shaped:
    """A value made per case: ``make(shape, rng)``, with ``shape`` the case's grid (for arrays that must match it)."""

    make: Callable[[tuple[int, int], np.random.Generator], Any]
    note: str

    def __repr__(self) -> str:
        return f"<{self.note}>"


@dataclass(frozen=True)
class Entry:
    """One mutation of the catalogue: the arguments it sets (one, or several for a combined entry) and its label."""

    kwargs: dict[str, Any]
    valid: bool


@dataclass
class Case:
    """An argument set: ``kwargs`` for ``parallel_env`` and the mutations (with their labels) that made it."""

    index: int
    kwargs: dict[str, Any]
    mutations: tuple[Entry, ...]

    @property
    def valid(self) -> bool:
        return all(m.valid for m in self.mutations)

    @property
    def invalid_names(self) -> list[str]:
        """The argument names an error message may name: those of the invalid mutations."""
        return [name for m in self.mutations if not m.valid for name in m.kwargs]

    def describe(self) -> str:
        parts = []
        for m in self.mutations:
            args = ", ".join(f"{name}={abbreviate(self.kwargs[name])}" for name in m.kwargs)
            parts.append(f"{args} [{'valid' if m.valid else 'invalid'}]")
        return f"case {self.index}: " + "; ".join(parts)


@dataclass
class Result:
    case: Case
    outcome: str
    seconds: float
    peak_bytes: int
    detail: str = ""


_REPR = reprlib.Repr()
_REPR.maxstring, _REPR.maxother, _REPR.maxlong, _REPR.maxlevel = 30, 50, 20, 2
_REPR.maxlist = _REPR.maxtuple = _REPR.maxdict = _REPR.maxset = 4


def abbreviate(value: Any) -> str:
    """A short one-line repr of ``value`` (arrays by shape and dtype, huge ints by their digits)."""
    if isinstance(value, np.ndarray):
        return f"array{value.shape}:{value.dtype}" if value.size > 4 else " ".join(repr(value).split())
    if isinstance(value, int) and abs(value).bit_length() > 64:
        return f"<int of {int(abs(value).bit_length() * math.log10(2)) + 1} digits>"
    return " ".join(_REPR.repr(value).split())


# ---------------------------------------------------------------------- the catalogue
# Wrong types and non-finite or huge values: invalid for every int, number and bool argument respectively.
_OBJECT = object()
INT_JUNK = ["0", "1", "false", "abc", "", b"3", [3], [], (3,), {}, {"value": 3}, {3}, True, False, np.True_, None,
            2.0, 2.5, -1.0, np.float64(3.0), np.float32(1.0), 1 + 2j, np.complex128(3), np.array([3]),
            np.array([3, 4], dtype=object), float("nan"), float("inf"), float("-inf"), 1e308, 10**5000, -(10**5000),
            _OBJECT]
FLOAT_JUNK = ["0.5", "nan", "inf", "abc", "", b"1", [0.5], [], {}, {"value": 0.5}, True, False, np.False_, None,
              0.5 + 0j, 1j, np.complex64(1), np.array([0.5]), np.array([0.5], dtype=object), float("nan"),
              float("inf"), float("-inf"), np.float32("nan"), np.float64("inf"), 1e308, -1e308, 10**5000, -(10**5000),
              _OBJECT]
BOOL_JUNK = ["false", "False", "true", "no", "0", "1", "", b"True", 0, 1, 0.0, 1.0, np.int64(1), np.float64(0.0),
             float("nan"), None, [], [True], {}, np.array([True]), np.array([True, False]), 1 + 0j, _OBJECT]


def _ints(valid: list, invalid: list, optional: bool = False) -> list[tuple[Any, bool]]:
    junk = [v for v in INT_JUNK if not (optional and v is None)]
    return [(v, True) for v in valid + ([None] if optional else [])] + [(v, False) for v in invalid + junk]


def _floats(valid: list, invalid: list) -> list[tuple[Any, bool]]:
    return [(v, True) for v in valid] + [(v, False) for v in invalid + FLOAT_JUNK]


def _bools() -> list[tuple[Any, bool]]:
    return [(v, True) for v in (True, False, np.True_, np.False_, np.bool_(1))] + [(v, False) for v in BOOL_JUNK]


def _terrain() -> list[tuple[Any, bool]]:
    def rand(dtype: Any) -> Callable[[tuple[int, int], np.random.Generator], np.ndarray]:
        return lambda shape, rng: rng.integers(0, 3, shape).astype(dtype)

    valid = [
        None,
        Shaped(rand(np.int8), "terrain int8"),
        Shaped(rand(np.int64), "terrain int64"),
        Shaped(rand(np.uint8), "terrain uint8"),
        Shaped(rand(np.float64), "terrain float64 of whole numbers"),
        Shaped(lambda shape, rng: rng.integers(0, 3, shape).tolist(), "terrain nested list"),
        Shaped(lambda shape, rng: np.zeros(shape, dtype=int), "terrain all open"),
        Shaped(lambda shape, rng: np.full(shape, 2), "terrain all mountain"),
    ]
    invalid = [
        Shaped(lambda shape, rng: np.full(shape, 3), "terrain value 3"),
        Shaped(lambda shape, rng: np.full(shape, -1), "terrain value -1"),
        Shaped(lambda shape, rng: np.full(shape, 10**18), "terrain value 1e18"),
        Shaped(lambda shape, rng: np.full(shape, 0.5), "terrain value 0.5"),
        Shaped(lambda shape, rng: np.full(shape, np.nan), "terrain NaN"),
        Shaped(lambda shape, rng: np.full(shape, np.inf), "terrain inf"),
        Shaped(lambda shape, rng: np.ones(shape, dtype=bool), "terrain bool"),
        Shaped(lambda shape, rng: np.ones(shape, dtype=complex), "terrain complex"),
        Shaped(lambda shape, rng: np.full(shape, "1"), "terrain str"),
        Shaped(lambda shape, rng: np.ones(shape, dtype=int).astype(object), "terrain object"),
        Shaped(lambda shape, rng: np.zeros(shape[0], dtype=int), "terrain 1-D"),
        Shaped(lambda shape, rng: np.zeros((*shape, 2), dtype=int), "terrain 3-D"),
        Shaped(lambda shape, rng: np.zeros((2, 2), dtype=int), "terrain 2 x 2"),
        Shaped(lambda shape, rng: np.zeros((0, 0), dtype=int), "terrain empty"),
        Shaped(lambda shape, rng: np.zeros((2000, 2000), dtype=np.int8), "terrain 2000 x 2000"),
        Shaped(lambda shape, rng: np.zeros((1001, 20), dtype=np.int8), "terrain 1001 x 20"),
        "forest", 5, 1.5, True, [[0, 1], [2]], {"terrain": 1}, _OBJECT,
    ]
    return [(v, True) for v in valid] + [(v, False) for v in invalid]


def _risk() -> list[tuple[Any, bool]]:
    valid = [
        None,
        Shaped(lambda shape, rng: rng.uniform(size=shape), "risk uniform float64"),
        Shaped(lambda shape, rng: rng.uniform(size=shape).astype(np.float32), "risk float32"),
        Shaped(lambda shape, rng: np.zeros(shape, dtype=int), "risk int zeros"),
        Shaped(lambda shape, rng: np.ones(shape), "risk ones"),
        Shaped(lambda shape, rng: rng.uniform(size=shape).tolist(), "risk nested list"),
    ]
    invalid = [
        Shaped(lambda shape, rng: np.full(shape, 1.5), "risk 1.5"),
        Shaped(lambda shape, rng: np.full(shape, -0.1), "risk -0.1"),
        Shaped(lambda shape, rng: np.full(shape, np.nan), "risk NaN"),
        Shaped(lambda shape, rng: np.full(shape, np.inf), "risk inf"),
        Shaped(lambda shape, rng: np.full(shape, 1e308), "risk 1e308"),
        Shaped(lambda shape, rng: np.ones(shape, dtype=bool), "risk bool"),
        Shaped(lambda shape, rng: np.full(shape, 0.5 + 0.5j), "risk complex"),
        Shaped(lambda shape, rng: np.full(shape, 0.5, dtype=object), "risk object"),
        Shaped(lambda shape, rng: np.full(shape, "0.5"), "risk str"),
        Shaped(lambda shape, rng: np.zeros(shape[0]), "risk 1-D"),
        Shaped(lambda shape, rng: np.zeros((shape[0] + 1, shape[1])), "risk one row too many"),
        Shaped(lambda shape, rng: np.zeros((*shape, 1)), "risk 3-D"),
        "high", 0.5, [[0.5]], [[0.5, 0.5], [0.5]], True, {"risk": 0.5},
    ]
    return [(v, True) for v in valid] + [(v, False) for v in invalid]


def _mode_prior() -> list[tuple[Any, bool]]:
    valid = [None, [1] * 8, tuple(range(1, 9)), np.arange(8), np.ones(8, dtype=np.float32), [0] * 7 + [1], [1e308] * 8,
             [5e-324] * 8, np.full(8, 1e-300), np.arange(1, 9, dtype=np.uint8), [0.5] * 8]
    invalid = [[1, 2], np.ones(9), np.ones(7), [], np.ones((2, 4)), np.ones((8, 1)), [[1] * 8], [-1] + [1] * 7, [0] * 8,
               [-0.0] * 8, [float("nan")] * 8, [1] * 7 + [float("nan")], [float("inf")] * 8, [1] * 7 + [float("-inf")],
               "uniform", 8, 1.0, True, {"a": 1}, [1] * 7 + ["a"], [True] * 8, np.ones(8, dtype=complex),
               np.ones(8, dtype=object), [[1, 2], [3]], [1] * 100_000, [10**400] * 8, _OBJECT]
    return [(v, True) for v in valid] + [(v, False) for v in invalid]


def _reward_weights() -> list[tuple[Any, bool]]:
    every = ("detection", "coverage", "sign", "poaching", "collision", "energy")
    valid = [None, {}, {"coverage": 1e6}, {"energy": 0}, {"detection": 5, "poaching": 0.5}, dict.fromkeys(every, 1e6),
             {"sign": np.float32(2.0)}, {"collision": 3}, MappingProxyType({"energy": 2.0})]
    invalid = [{"bananas": 1.0}, {"Coverage": 1.0}, {1: 2.0}, {None: 1.0}, {("coverage",): 1.0}, {"coverage": 1e6 + 1},
               {"coverage": 1e308}, {"energy": -1}, {"energy": -1e-9}, {"sign": float("nan")}, {"sign": float("inf")},
               {"coverage": "1"}, {"coverage": True}, {"coverage": None}, {"coverage": [1]}, {"coverage": 1 + 0j},
               {"coverage": 10**400}, [("coverage", 1.0)], "coverage", 1.0, 0, True, {"coverage"}, _OBJECT]
    return [(v, True) for v in valid] + [(v, False) for v in invalid]


def _grid_size() -> list[tuple[Any, bool]]:
    valid = [None, 11, 12, 20, 30, 64, np.int64(40), (16, 24), [20, 30], (np.int32(20), np.int64(25)),
             np.array([24, 16]), (11, 200), 200]
    invalid = [0, -1, 1, 2, 1001, 10**9, 10**18, -(10**18), (20,), (20, 20, 20), [], (1001, 20), (20, 0), (20, -5),
               (20.0, 20), (20.5, 20), (20, "20"), (True, 20), (None, 20), [[20, 20]], np.array([[20, 20], [20, 20]]),
               np.zeros((2, 2)), np.array([20.0, 20.0]), {"height": 20}, {20, 30}, "100", "20x20", 100.0,
               np.float64(20), float("nan"), float("inf"), True, 1 + 0j, (10**5000, 20), _OBJECT]
    return [(v, True) for v in valid] + [(v, False) for v in invalid]


def _region() -> list[tuple[Any, bool]]:
    valid = ["mixed", "forest", "mountain", "steppe", np.str_("steppe")]
    invalid = ["atlantis", "", "Mixed", " mixed", ["mixed"], ("forest",), {"mixed"}, {"region": "mixed"}, None, 0, 1.5,
               True, b"mixed", np.array(["mixed"]), _OBJECT]
    return [(v, True) for v in valid] + [(v, False) for v in invalid]


def _render_mode() -> list[tuple[Any, bool]]:
    valid = [None, "rgb_array"]
    invalid = ["ascii", "", "RGB_ARRAY", "human ", 0, True, ["human"], np.array(["human", "rgb_array"]), b"human",
               {"mode": "human"}, 1.0, _OBJECT]
    return [(v, True) for v in valid] + [(v, False) for v in invalid]


def _zero_one() -> list[tuple[Any, bool]]:
    return _floats([0, 0.0, 0.25, 0.5, 1, 1.0, np.float32(0.75)], [-0.1, -1e-12, 1.0000001, 2, 10**9, -(10**18)])


#: Per argument: (value, valid) pairs. Bounds as documented in docs/env.md (Arguments).
VALUES: dict[str, list[tuple[Any, bool]]] = {
    "n_uavs": _ints([1, 2, 3, 5, np.int64(4), np.uint8(7), 20, 50], [0, -1, -(10**18), 1001, 10**9, 10**18]),
    "grid_size": _grid_size(),
    "max_cycles": _ints([1, 2, 3, 50, 200, np.int32(100), 100_000], [0, -1, 100_001, 10**9, 10**18]),
    "n_leopards": _ints([0, 1, 2, 10, 50, 1000], [-1, 1001, 10**9, 10**18]),
    "n_poachers": _ints([0, 1, 2, 10, 50, 1000], [-1, 1001, 10**9, 10**18]),
    "sensor_radius": _ints([1, 2, 3, 4, 5], [0, -1, 11, 10**9, 10**18]),
    "comm_radius": _floats([0, 0.0, 1, 5.5, 20.0, np.float32(7.5), np.int64(3), 10_000.0, 10_000],
                           [-1, -1e-9, 10_000.5, 1e5, 10**9]),
    "continuous_actions": _bools(),
    "agent_ids": _bools(),
    "compass": _bools(),
    "coverage_sectors": _bools(),
    # True needs a leopard per zone (4): invalid with the base's 3 leopards; valid ones with 4+ in COMBINED.
    "strategy_zones": [(v, True) for v in (False, np.False_)] + [(v, False) for v in (True, np.True_, *BOOL_JUNK)],
    "scenario": [(v, True) for v in (None, "zone_raids", np.str_("zone_raids"))]
    + [(v, False) for v in ("Zone_raids", "zone raids", "", "default", 0, True, ["zone_raids"], {"zone_raids"},
                            b"zone_raids", {"scenario": "zone_raids"}, _OBJECT)],
    "region": _region(),
    "terrain": _terrain(),
    "risk": _risk(),
    "terrain_seed": _ints([0, 1, 123, np.uint64(5), np.int64(2**62), 10**18, 2**63 - 1],
                          [-1, -(10**18), 2**63, 2**64, 10**30], optional=True),
    "mode": _ints([0, 3, 7, np.int8(5)], [-1, 8, 10**9, 10**18], optional=True),
    "mode_prior": _mode_prior(),
    "sensor_noise": _zero_one(),
    "comm_loss": _zero_one(),
    "adversarial": _bools(),
    "n_decoys": _ints([0, 1, 5, 100, 1000], [-1, 1001, 10**9, 10**18]),
    "jam_radius": _floats([0, 3, 10.0, 1e4], [-1, 10_001, 1e9]),
    "uav_speed": _floats([1e-6, 0.5, 1, 2.0, 10, 1e4], [0, -1, 5e-7, 1e-300, 10_000.1, 1e9]),
    "max_neighbors": _ints([0, 1, 4, 10, 1000], [-1, 1001, 10**9, 10**18]),
    "belief_size": _ints([1, 2, 5, 8, 10], [0, -1, 17, 100, 10**9, 10**18], optional=True),
    "belief_decay": _floats([1e-6, 0.001, 0.5, 0.98, 1, 1.0], [0, -0.5, 1.01, 5e-7, 2]),
    "poaching_time": _ints([1, 2, 5, 100, 100_000], [0, -1, 100_001, 10**9, 10**18]),
    "leopard_range": _floats([0, 1, 8.0, 100, 1e4], [-1, -0.5, 10_001, 1e9]),
    "reward_weights": _reward_weights(),
    "shaping": _zero_one(),
    "render_mode": _render_mode(),
}

#: Unknown argument names (always invalid).
UNKNOWN = [{"n_drones": 3}, {"gridsize": 20}, {"N_UAVS": 2}, {"seed": 0}, {"render": True}, {"num_agents": 4},
           {"n_uav": 10}, {"weights": {}}, {"sensor_range": 3}, {"x" * 60: 1}, {"belief size": 8}]

#: Mutations whose validity depends on several arguments, each setting all of them.
COMBINED: list[tuple[dict[str, Any], bool]] = [
    ({"strategy_zones": True, "n_leopards": 4}, True),  # a leopard per zone
    ({"strategy_zones": True, "n_leopards": 9, "compass": True}, True),
    ({"scenario": "zone_raids", "n_leopards": 3}, False),  # the explicit argument overrides the scenario's 8
    ({"scenario": "zone_raids", "strategy_zones": False, "n_leopards": 3}, True),
    ({"scenario": "zone_raids", "reward_weights": {"coverage": -1.0}}, False),
    ({"grid_size": 7, "sensor_radius": 3, "belief_size": None}, True),  # the documented minimum with the default radius
    ({"grid_size": 3, "sensor_radius": 1, "belief_size": None}, True),  # the smallest grid
    ({"grid_size": (7, 40), "sensor_radius": 3, "belief_size": 7}, True),
    ({"grid_size": 7, "sensor_radius": 4, "belief_size": None}, False),  # the window (9) does not fit
    ({"grid_size": (7, 7), "sensor_radius": 3, "belief_size": 8}, False),  # belief_size above the grid side
    ({"grid_size": 12, "sensor_radius": 3, "belief_size": 13}, False),
    ({"n_uavs": 1000, "grid_size": 1000}, False),  # n_uavs x padded cells above 25_000_000
    ({"n_uavs": 200, "grid_size": 400}, False),
    ({"n_uavs": 30, "grid_size": (1000, 1000)}, False),
    ({"n_uavs": 1000, "grid_size": 200}, False),
    ({"terrain": Shaped(lambda shape, rng: np.zeros((21, 20), dtype=int), "terrain 21 x 20"), "grid_size": (20, 20)},
     False),
    ({"risk": Shaped(lambda shape, rng: np.zeros((20, 21)), "risk 20 x 21"), "grid_size": 20}, False),
]

#: Every group a mutation is drawn from: the arguments, unknown names and combined entries.
CATALOGUE: dict[str, list[Entry]] = {
    **{name: [Entry({name: value}, valid) for value, valid in values] for name, values in VALUES.items()},
    "(unknown name)": [Entry(kwargs, False) for kwargs in UNKNOWN],
    "(combined)": [Entry(kwargs, valid) for kwargs, valid in COMBINED],
}

#: Grid shapes for valid terrain arrays when ``grid_size`` is not set (the terrain's shape then sets the grid).
TERRAIN_SHAPES = [(12, 12), (20, 30), (31, 17), (16, 16)]


def _case_shape(entries: Iterable[Entry], rng: np.random.Generator) -> tuple[int, int]:
    """The grid that arrays labelled valid must match: a valid ``grid_size``'s, else a terrain's own, else 100 x 100."""
    for entry in entries:
        value = entry.kwargs.get("grid_size")
        if "grid_size" in entry.kwargs and value is not None:
            if not entry.valid:
                return (20, 20)  # the case is invalid anyway
            return (int(value), int(value)) if np.ndim(value) == 0 else (int(value[0]), int(value[1]))
    if any(isinstance(entry.kwargs.get("terrain"), Shaped) for entry in entries):
        return TERRAIN_SHAPES[int(rng.integers(len(TERRAIN_SHAPES)))]
    return (100, 100)


def generate_cases(count: int, seed: int = 0) -> list[Case]:
    """``count`` cases, each mutating 1 to 3 argument groups of the catalogue; the same for the same seed."""
    rng = np.random.default_rng(seed)
    groups = list(CATALOGUE)
    cases = []
    for index in range(count):
        wanted = int(rng.integers(1, 4))
        chosen: list[Entry] = []
        names: set[str] = set()
        for g in rng.permutation(len(groups)):
            if len(chosen) == wanted:
                break
            entries = CATALOGUE[groups[g]]
            valid = bool(rng.random() < VALID_SHARE)
            pool = [e for e in entries if e.valid == valid] or entries
            entry = pool[int(rng.integers(len(pool)))]
            if names & set(entry.kwargs):  # a combined entry and an argument's own: one value per argument
                continue
            chosen.append(entry)
            names |= set(entry.kwargs)
        case_rng = np.random.default_rng([seed, index])
        shape = _case_shape(chosen, case_rng)
        kwargs = {name: value.make(shape, case_rng) if isinstance(value, Shaped) else value
                  for entry in chosen for name, value in entry.kwargs.items()}
        cases.append(Case(index, kwargs, tuple(chosen)))
    return cases


# ---------------------------------------------------------------------- running
class CaseTimeout(BaseException):
    """Raised by the alarm in a case that runs past its time limit (a BaseException: ``except Exception`` in the
    code under test cannot swallow it)."""


def names_argument(message: str, names: Iterable[str]) -> bool:
    """Whether ``message`` names one of ``names`` as a whole word (``mode`` is not named by ``mode_prior``)."""
    return any(re.search(rf"(?<![A-Za-z0-9_]){re.escape(name)}(?![A-Za-z0-9_])", message) for name in names)


def _random_actions(env: Any, rng: np.random.Generator) -> dict[str, Any]:
    if env.config.continuous_actions:
        return {a: rng.uniform(-1, 1, 3).astype(np.float32) for a in env.agents}
    return {a: int(rng.integers(env.action_space(a).n)) for a in env.agents}


def _bad_output(observations: dict, rewards: dict | None) -> str:
    for agent, obs in observations.items():
        if not (np.all(np.isfinite(obs)) and np.all(np.abs(obs) <= 1.0)):
            return f"observation of {agent} not finite or outside [-1, 1]"
    if rewards is not None and not all(math.isfinite(r) for r in rewards.values()):
        return f"non-finite reward: {rewards}"
    return ""


def _on_alarm(signum: int, frame: Any) -> None:
    raise CaseTimeout


def _play(case: Case, steps: int, stage: list[str]) -> str:
    """Build, reset and step; returns what was wrong with the output ("" if nothing). ``stage[0]`` tracks progress."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", RuntimeWarning)
        env = reserve_v1.parallel_env(**case.kwargs)
        stage[0] = "reset"
        observations, _ = env.reset(seed=case.index)
        detail = _bad_output(observations, None)
        stage[0] = "step"
        rng = np.random.default_rng(case.index)
        for _ in range(steps):
            if not env.agents or detail:
                break
            observations, rewards, _, _, _ = env.step(_random_actions(env, rng))
            detail = _bad_output(observations, rewards)
        env.close()
    runtime = [w for w in caught if issubclass(w.category, RuntimeWarning)]
    return detail or (f"RuntimeWarning: {runtime[0].message}" if runtime else "")


def _sort_error(case: Case, error: Exception, stage: str) -> tuple[str, str]:
    """The outcome of a case that raised ``error`` in ``stage``."""
    detail = f"{type(error).__name__} in {stage}: {error}"
    if stage != "build" or not isinstance(error, ValueError):
        return "unclean_exception", detail
    if case.valid:
        return "false_rejection", detail
    if names_argument(str(error), case.invalid_names):
        return "clean_error", detail
    return "unclean_exception", f"names none of {case.invalid_names}: {detail}"


def run_case(case: Case, time_limit: float = TIME_LIMIT, memory_limit: int = MEMORY_LIMIT, steps: int = STEPS) -> Result:
    """Build, reset and step the case's environment and sort the outcome (tracemalloc must be tracing)."""
    tracemalloc.reset_peak()
    base = tracemalloc.get_traced_memory()[0]
    try:
        previous = signal.signal(signal.SIGALRM, _on_alarm)
        signal.setitimer(signal.ITIMER_REAL, time_limit)
        alarm = True
    except (ValueError, AttributeError):  # not the main thread, or no SIGALRM: the limit is checked afterwards
        alarm = False
    stage = ["build"]
    start = time.perf_counter()
    try:
        detail = _play(case, steps, stage)
        if not case.valid:
            outcome, detail = "silent_acceptance", "accepted invalid arguments" + (f"; {detail}" if detail else "")
        else:
            outcome = "bad_output" if detail else "ran"
    except CaseTimeout:
        outcome, detail = "hang", f"still in {stage[0]} after {time_limit} s"
    except MemoryError as error:
        outcome, detail = "memory", f"MemoryError in {stage[0]}: {error}"
    except Exception as error:  # sorting every exception is the point
        outcome, detail = _sort_error(case, error, stage[0])
    finally:
        if alarm:
            signal.setitimer(signal.ITIMER_REAL, 0)
            signal.signal(signal.SIGALRM, previous)
    seconds = time.perf_counter() - start
    peak = tracemalloc.get_traced_memory()[1] - base
    if not alarm and seconds > time_limit:
        outcome, detail = "hang", f"took {seconds:.1f} s (limit {time_limit} s)"
    if peak > memory_limit:
        outcome, detail = "memory", f"traced peak {peak / 2**20:.0f} MiB (limit {memory_limit / 2**20:.0f} MiB); {detail}"
    return Result(case, outcome, seconds, peak, detail)


@dataclass
class Report:
    results: list[Result] = field(default_factory=list)
    seconds: float = 0.0

    @property
    def counts(self) -> dict[str, int]:
        counter = Counter(r.outcome for r in self.results)
        return {outcome: counter.get(outcome, 0) for outcome in OUTCOMES}

    @property
    def failures(self) -> list[Result]:
        return [r for r in self.results if r.outcome in FAILURES]

    def format(self, max_failures: int = 20) -> str:
        counts = self.counts
        lines = [f"{len(self.results)} cases in {self.seconds:.1f} s: "
                 + ", ".join(f"{outcome} {counts[outcome]}" for outcome in OUTCOMES)]
        if self.results:
            worst = max(self.results, key=lambda r: r.peak_bytes)
            slowest = max(self.results, key=lambda r: r.seconds)
            lines.append(f"worst memory peak {worst.peak_bytes / 2**20:.1f} MiB ({worst.outcome}, {worst.case.describe()})")
            lines.append(f"slowest case {slowest.seconds:.2f} s ({slowest.outcome}, {slowest.case.describe()})")
        for r in self.failures[:max_failures]:
            lines.append(f"FAILURE {r.outcome}: {r.case.describe()}: {r.detail[:300]}")
        if len(self.failures) > max_failures:
            lines.append(f"... and {len(self.failures) - max_failures} more failures")
        return "\n".join(lines)


def _vm_size() -> int | None:
    try:
        with open("/proc/self/status") as status:
            for line in status:
                if line.startswith("VmSize:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return None


#: Arguments that reach kernels (or kernel specialisations) the default reserve does not call: each is compiled before
#: the cases run. (On a fresh clone of a loaded 2-core machine, the adversarial jammer's first compilation took more
#: than the 10 s time limit inside seven cases.)
WARM_UP = ({}, {"max_cycles": MAX_CYCLES}, {"adversarial": True}, {"continuous_actions": True},
           {"scenario": "zone_raids", "n_uavs": 2})


def warm_up() -> None:
    """Compile the reserve's kernels (``compile_kernels``) for every set of :data:`WARM_UP` (both widths of the visit
    stamps, int16 and the int32 of episodes of 32,767 steps or more; the adversarial condition; continuous actions;
    the zone raids), so that no case carries numba's one-time compilation: a valid case with ``max_cycles=100_000``
    otherwise compiled the int32 kernels inside its time limit (52 s under tracemalloc)."""
    for kwargs in WARM_UP:
        compile_kernels(**{"n_uavs": 2, "grid_size": 20, "max_cycles": 200, **kwargs})


def run_cases(cases: Iterable[Case], time_limit: float = TIME_LIMIT, memory_limit: int = MEMORY_LIMIT,
              steps: int = STEPS, guard: int | None = 4 * 2**30) -> Report:
    """Run every case (see :func:`run_case`) with tracemalloc tracing.

    :param guard: while the cases run, cap the process's address space at its current size plus this many bytes
        (``RLIMIT_AS``, restored afterwards), so that a regression that allocates without bound raises MemoryError
        (counted as ``memory``) instead of exhausting the machine; ``None`` leaves the limit alone
    """
    warm_up()
    started = not tracemalloc.is_tracing()
    if started:
        tracemalloc.start()
    limits = None
    size = _vm_size() if guard is not None else None
    if size is not None:
        limits = resource.getrlimit(resource.RLIMIT_AS)
        cap = size + guard  # type: ignore[operator]
        if limits[0] == resource.RLIM_INFINITY or limits[0] > cap:
            resource.setrlimit(resource.RLIMIT_AS, (cap, limits[1]))
        else:
            limits = None
    report = Report()
    start = time.perf_counter()
    try:
        for case in cases:
            report.results.append(run_case(case, time_limit, memory_limit, steps))
    finally:
        if limits is not None:
            resource.setrlimit(resource.RLIMIT_AS, limits)
        if started:
            tracemalloc.stop()
    report.seconds = time.perf_counter() - start
    return report
