"""Pickles read as data: nothing in them is run, nothing they declare is allocated beyond a stated bound.

A pickle is a program: it names globals and calls them (``REDUCE``, ``NEWOBJ``, ``INST``/``OBJ``), and it sets
attributes (``BUILD``). Naming only allowed globals is not enough, because some allowed functions call or deserialise
what they are given (``numpy.random._pickle.__generator_ctor`` calls a callable from the data,
``torch.storage._load_from_bytes`` runs a full ``torch.load``), and data types allocate what an argument asks for
(``bytearray(10**11)``, ``list(range(10**10))``, a ``BYTEARRAY8`` opcode declaring 100 GB).

:class:`DataUnpickler` is the standard library's own unpickler (``pickle._Unpickler``, the Python one, because its
opcodes can be overridden one by one; the C one cannot) with:

- ``find_class`` limited to :func:`~sb3_emmarl.common.trust.safe_zip.allowed_global` (plus any extra classes a caller names),
  and the helper functions that call or deserialise replaced by versions that take data only (:data:`SUBSTITUTES`);
- calls (``REDUCE``) limited to :data:`CALLABLES`, the substitutes and enum lookups, with arguments that allocate
  checked against :data:`MAX_ITEMS` and :data:`MAX_BYTES`; ``INST`` and ``OBJ`` (protocol 0 and 1 constructor calls,
  which SB3's cloudpickle never writes) refused; a byte array no larger than the pickle itself;
- ``NEWOBJ`` (``cls.__new__``, no ``__init__``) and ``BUILD`` (set an instance's state) only on instances of allowed
  classes, never on a class or a function (which would rewrite it for the whole process).

Written by hand because no maintained library offers it: Python's docs recommend overriding ``find_class``
("Restricting Globals"), which leaves calls and allocations open; ``torch.load(weights_only=True)`` reads tensors
only, not SB3's spaces and schedules; ``fickling`` and ``picklescan`` scan, they do not load.
"""

from __future__ import annotations

import collections
import copyreg
import enum
import io
import pickle
import struct
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import numpy as np
from stable_baselines3.common.vec_env import VecEnv, VecNormalize

#: The most items a call in a pickle may ask for (a ``range`` given to ``list``, an array's shape, a deque's length).
MAX_ITEMS = 100_000_000
#: The most bytes a call or an opcode in a pickle may ask to allocate beyond the bytes the pickle holds.
MAX_BYTES = 1 << 30


class UnsafePickle(pickle.UnpicklingError):
    """A pickle that names, calls or allocates what data does not."""


def _name(obj: Any) -> str:
    """``module.name`` of a class or function (what a message names), else its type's."""
    if not hasattr(obj, "__qualname__"):
        obj = type(obj)
    return f"{getattr(obj, '__module__', '?')}.{obj.__qualname__}"


def _bounded_count(value: Any, what: str) -> None:
    if isinstance(value, bool):
        return
    if isinstance(value, int) and not 0 <= value <= MAX_BYTES:
        raise UnsafePickle(f"its {what} asks for {value} items or bytes (at most {MAX_BYTES})")
    if isinstance(value, range) and len(value) > MAX_ITEMS:
        raise UnsafePickle(f"its {what} is given a range of {len(value)} items (at most {MAX_ITEMS})")


def _bounded(func: Callable[..., Any], name: str, module: str = "builtins") -> Callable[..., Any]:
    """``func`` whose positional arguments are checked by :func:`_bounded_count` (an int asks for that many bytes or
    items; a range is materialised)."""

    def call(*args: Any) -> Any:
        for arg in args:
            _bounded_count(arg, name)
        return func(*args)

    call.__name__ = call.__qualname__ = name
    call.__module__ = module
    return call


def _reconstruct_array(subtype: Any, shape: Any, dtype: Any) -> Any:
    if subtype is not np.ndarray:
        raise UnsafePickle(f"its numpy _reconstruct is given {_name(subtype)}, not numpy.ndarray")
    if not isinstance(shape, tuple) or not all(isinstance(n, int) and 0 <= n <= MAX_ITEMS for n in shape) \
            or int(np.prod(shape, dtype=np.float64)) > MAX_ITEMS:
        raise UnsafePickle(f"its numpy _reconstruct asks for an array of shape {shape!r} (at most {MAX_ITEMS} items)")
    return np.ndarray.__new__(np.ndarray, shape, dtype)


def _bit_generator(name: Any) -> Any:
    from numpy.random._pickle import BitGenerators

    kinds: dict[str, Any] = dict(BitGenerators)
    if name in kinds.values():  # numpy 2 pickles the class, numpy 1 its name
        return name()
    if not isinstance(name, str) or name not in kinds:
        raise UnsafePickle(f"a random generator in it names {_name(name)}, not one of {sorted(kinds)}")
    return kinds[name]()


def _generator(kind: type) -> Callable[..., Any]:
    """numpy's ``__generator_ctor`` / ``__randomstate_ctor`` taking a bit generator or its name, never a callable."""

    def build(bit_generator: Any = "MT19937", bit_generator_ctor: Any = None) -> Any:
        from numpy.random.bit_generator import BitGenerator

        if bit_generator_ctor not in (None, _bit_generator):
            raise UnsafePickle(f"a random generator in it is given the constructor {_name(bit_generator_ctor)}")
        return kind(bit_generator if isinstance(bit_generator, BitGenerator) else _bit_generator(bit_generator))

    return build


def _seed_sequence(kind: Any, checksum: Any, state: Any) -> Any:
    from numpy.random.bit_generator import SeedSequence, __pyx_unpickle_SeedSequence  # type: ignore[attr-defined]

    if kind is not SeedSequence:
        raise UnsafePickle(f"its numpy SeedSequence is given {_name(kind)}")
    return __pyx_unpickle_SeedSequence(kind, checksum, state)


def _storage_from_bytes(data: Any) -> Any:
    import torch as th

    if not isinstance(data, bytes):
        raise UnsafePickle("a torch storage in it is not bytes")
    try:  # tensors only (torch's own _load_from_bytes runs any pickle)
        return th.load(io.BytesIO(data), weights_only=True)
    except pickle.UnpicklingError:
        raise UnsafePickle("it holds a torch storage that is more than tensors") from None


_DATA_TYPES = (int, float, complex, str, bytes, tuple, list, dict, set, frozenset)


def _reconstructor(cls: Any, base: Any, state: Any) -> Any:
    """``copyreg._reconstructor`` for a base that is ``object`` or a plain data type (bounded)."""
    if base is not object and base not in _DATA_TYPES:
        raise UnsafePickle(f"its copyreg._reconstructor is given the base {_name(base)}")
    _bounded_count(state, "copyreg._reconstructor")
    return copyreg._reconstructor(cls, base, state)  # type: ignore[attr-defined]


def _view(base: Any, offset: Any, shape: Any, strides: Any, dtype: Any, writeable: Any) -> Any:
    """:func:`~sb3_emmarl.common.trust.pickling.rebuild_view` of an array the pickle holds (numpy checks that the view lies
    within it)."""
    from sb3_emmarl.common.trust.pickling import rebuild_view

    if type(base) is not np.ndarray or not isinstance(offset, int) or not isinstance(writeable, bool):
        raise UnsafePickle(f"its numpy view is given {_name(base)}, not an array")
    return rebuild_view(base, offset, shape, strides, np.dtype(dtype), writeable)


def _substitutes() -> dict[tuple[str, str], Callable[..., Any]]:
    table: dict[tuple[str, str], Callable[..., Any]] = {
        ("torch.storage", "_load_from_bytes"): _storage_from_bytes,
        ("copyreg", "_reconstructor"): _reconstructor,
        ("numpy.random._pickle", "__bit_generator_ctor"): _bit_generator,
        ("numpy.random._pickle", "__generator_ctor"): _generator(np.random.Generator),
        ("numpy.random._pickle", "__randomstate_ctor"): _generator(np.random.RandomState),
        ("numpy.random.bit_generator", "__pyx_unpickle_SeedSequence"): _seed_sequence,
        ("sb3_emmarl.common.trust.pickling", "rebuild_view"): _view,
        ("sb3_emmarl.common.pickling", "rebuild_view"): _view,  # where it was before the trust folder
        ("sb3_emmarl.common.checkpoints", "_view"): _view,  # what checkpoints before the pickling module named
    }
    for module in ("numpy.core.multiarray", "numpy._core.multiarray"):
        table[(module, "_reconstruct")] = _reconstruct_array
    for name, kind in (("bytearray", bytearray), ("bytes", bytes), ("list", list), ("tuple", tuple), ("set", set),
                       ("frozenset", frozenset), ("dict", dict)):
        table[("builtins", name)] = _bounded(kind, name)
    table[("collections", "deque")] = _bounded(collections.deque, "deque", "collections")
    return table


#: Classes saved files name where they were before they moved (old name -> today's), read at today's place.
MOVED: dict[tuple[str, str], tuple[str, str]] = {
    ("sb3_emmarl.common.extractors", "SplitFeaturesExtractor"): ("sb3_emmarl.common.appended.extractor",
                                                                 "SplitFeaturesExtractor"),
}

#: Allowed globals that call or deserialise what they are given, or allocate what an argument asks for, and the
#: versions of them :class:`DataUnpickler` uses instead.
SUBSTITUTES: dict[tuple[str, str], Callable[..., Any]] = _substitutes()


def _callables() -> frozenset[Any]:
    import torch as th
    from numpy._core import multiarray, numeric
    from torch import _utils

    frombuffer = numeric._frombuffer  # type: ignore[attr-defined]
    return frozenset({*SUBSTITUTES.values(), multiarray.scalar, frombuffer, np.dtype, range, slice, complex, float, int,
                      bool, str, object, collections.OrderedDict, th.device, _utils._rebuild_tensor_v2,
                      _utils._rebuild_parameter})


#: What a pickle may call (``REDUCE``) besides an enum's lookup by value.
CALLABLES: frozenset[Any] = _callables()


#: The standard library's unpickler written in Python (its opcodes are methods in ``dispatch``); typed as Any because
#: typeshed does not describe it.
_PythonUnpickler: Any = pickle._Unpickler  # type: ignore[attr-defined]


class DataUnpickler(_PythonUnpickler):
    """Unpickle data only (module docstring).

    :param file: the pickle, opened for binary reading
    :param source: what the pickle is, for messages (a file and an entry)
    :param extra: further ``(module, name)`` classes this kind of file holds (``VecNormalize`` statistics)
    :param class_modules: modules (and their submodules) any of whose classes it may hold, never their functions
        (:data:`ENV_STATE_MODULES` for an environment's state)
    """

    dispatch: dict[int, Callable[..., None]] = dict(_PythonUnpickler.dispatch)

    def __init__(self, file: io.BufferedIOBase | io.BytesIO, source: str,
                 extra: Iterable[tuple[str, str]] = (), class_modules: Iterable[str] = ()) -> None:
        super().__init__(file)
        position = file.tell()
        self.size = file.seek(0, io.SEEK_END) - position  # what the pickle holds: no opcode may declare more
        file.seek(position)
        self.source = source
        self.extra = frozenset(extra)
        self.class_modules = tuple(class_modules)
        self.classes: set[type] = set()

    def find_class(self, module: str, name: str) -> Any:
        from sb3_emmarl.common.trust.safe_zip import allowed_global

        module, name = MOVED.get((module, name), (module, name))
        if (module, name) in SUBSTITUTES:
            return SUBSTITUTES[(module, name)]
        if any(module == root or module.startswith(root + ".") for root in self.class_modules) \
                and "__" not in name and name.isidentifier():
            obj = super().find_class(module, name)
            if not isinstance(obj, type):
                raise UnsafePickle(f"it names {module}.{name}, which is not a class")
        elif (module, name) in self.extra or allowed_global(module, name):
            obj = super().find_class(module, name)
        else:
            raise UnsafePickle(f"it names {module}.{name}, which data of this package never holds")
        if isinstance(obj, type):
            self.classes.add(obj)
        return obj

    def persistent_load(self, pid: Any) -> Any:
        raise UnsafePickle(f"it refers to an outside object {str(pid)[:80]!r}")

    def _allowed_instance(self, obj: Any) -> bool:
        from numpy.random.bit_generator import BitGenerator, SeedSequence

        named = tuple(cls for cls in self.classes if cls is not object)  # (every function is an object instance)
        return isinstance(obj, (*named, *_DATA_TYPES, np.ndarray, BitGenerator, SeedSequence, np.random.Generator,
                                np.random.RandomState))

    def load_reduce(self) -> None:
        args = self.stack.pop()
        func = self.stack[-1]
        if not (func in CALLABLES or (isinstance(func, type) and issubclass(func, enum.Enum))):
            raise UnsafePickle(f"it calls {_name(func)}, which data of this package never calls")
        self.stack[-1] = func(*args)

    dispatch[pickle.REDUCE[0]] = load_reduce

    def _new(self, cls: Any, args: tuple, kwargs: dict) -> None:
        if not isinstance(cls, type) or cls not in self.classes:
            raise UnsafePickle(f"it builds an instance of {_name(cls)}, which is not a class it named")
        for arg in (*args, *kwargs.values()):
            _bounded_count(arg, f"{cls.__qualname__}.__new__")
        self.append(cls.__new__(cls, *args, **kwargs))

    def load_newobj(self) -> None:
        args = self.stack.pop()
        self._new(self.stack.pop(), args, {})

    dispatch[pickle.NEWOBJ[0]] = load_newobj

    def load_newobj_ex(self) -> None:
        kwargs = self.stack.pop()
        args = self.stack.pop()
        self._new(self.stack.pop(), args, kwargs)

    dispatch[pickle.NEWOBJ_EX[0]] = load_newobj_ex

    def load_inst_or_obj(self) -> None:
        raise UnsafePickle("it calls a constructor by INST or OBJ (protocol 0 or 1), which this package never writes")

    dispatch[pickle.INST[0]] = load_inst_or_obj
    dispatch[pickle.OBJ[0]] = load_inst_or_obj

    def load_build(self) -> None:
        inst = self.stack[-2]  # (the state is on top)
        if isinstance(inst, type) or not self._allowed_instance(inst):
            raise UnsafePickle(f"it sets the state of {_name(inst) if isinstance(inst, type) else type(inst).__qualname__}"
                               ", which is not an instance of a class it named")
        super().load_build()

    dispatch[pickle.BUILD[0]] = load_build

    def load_bytearray8(self) -> None:
        size, = struct.unpack("<Q", self.read(8))
        if size > self.size:
            raise UnsafePickle(f"it declares a byte array of {size} bytes, more than its own {self.size}")
        data = self.read(size)
        if len(data) != size:
            raise pickle.UnpicklingError(f"a byte array declares {size} bytes and holds {len(data)}")
        self.append(bytearray(data))

    dispatch[pickle.BYTEARRAY8[0]] = load_bytearray8


def loads(blob: bytes | io.BufferedIOBase, source: str, extra: Iterable[tuple[str, str]] = (),
          class_modules: Iterable[str] = (), unpickler: Callable[..., DataUnpickler] = DataUnpickler) -> Any:
    """Unpickle ``blob`` with :class:`DataUnpickler`.

    :param blob: the pickle, or a file opened for binary reading at its start
    :param source: what it is, for the message (a file and an entry)
    :param extra: further ``(module, name)`` classes it may hold
    :param class_modules: modules any of whose classes it may hold (:class:`DataUnpickler`)
    :param unpickler: builds the unpickler: :class:`DataUnpickler`, or a subclass with its own arguments bound (one that
        puts back a live environment's open files)
    :raise ValueError: one line naming ``source`` and what it names, calls or allocates, or why it does not parse
    """
    try:
        return unpickler(io.BytesIO(blob) if isinstance(blob, bytes) else blob, source, extra, class_modules).load()
    except UnsafePickle as error:
        raise ValueError(f"{source}: refusing to load: {error} (a file from an unknown source is code)") from None
    except (pickle.UnpicklingError, EOFError, ValueError, TypeError, AttributeError, KeyError, IndexError,
            struct.error, RecursionError, MemoryError, UnicodeDecodeError, OverflowError) as error:
        first = str(error).strip().splitlines()[0][:200] if str(error).strip() else ""
        raise ValueError(f"{source} is not a readable pickle ({type(error).__name__}: {first})") from None


#: The modules whose classes an environment's state is made of: the reserve and ZonePatrol, this package's vector
#: environments, belief and centralised (one-agent) reserve, SuperSuit's and SB3's vector environments, Gymnasium's
#: spaces, wrappers and environment specs, PettingZoo's wrappers. A training state
#: (:func:`~sb3_emmarl.common.training_state.load_training_state`) may build instances of their classes, and names no
#: function of them.
ENV_STATE_MODULES = ("wildlife_reserve", "sb3_emmarl.common.vec_env", "sb3_emmarl.common.latent",
                     "sb3_emmarl.common.centralized", "supersuit.vector", "gymnasium.spaces", "gymnasium.wrappers",
                     "gymnasium.envs.registration", "pettingzoo.utils", "stable_baselines3.common.running_mean_std",
                     "stable_baselines3.common.vec_env", "stable_baselines3.common.monitor")

#: The classes a ``VecNormalize`` statistics file holds beyond what a model's data may (see :func:`load_data_pickle`).
VEC_NORMALIZE_CLASSES = (("stable_baselines3.common.vec_env.vec_normalize", "VecNormalize"),
                         ("stable_baselines3.common.running_mean_std", "RunningMeanStd"))


def load_data_pickle(path: str | Path, extra: tuple[tuple[str, str], ...] = (), class_modules: tuple[str, ...] = ()
                     ) -> Any:
    """Unpickle a file of data (a replay buffer, ``VecNormalize`` statistics, a training state) as data only: nothing
    in it runs (:func:`loads`).

    :param path: the file (a regular file)
    :param extra: further ``(module, name)`` classes it may hold
    :param class_modules: modules any of whose classes it may hold (:data:`ENV_STATE_MODULES`)
    :raise ValueError: one line naming the file: not a regular file, cut short, or naming, calling or allocating what
        data does not
    """
    if not Path(path).is_file():
        raise ValueError(f"{path} is not a regular file")
    try:
        with open(path, "rb") as file:
            return loads(file, str(path), extra, class_modules)
    except OSError as error:
        raise ValueError(f"{path} cannot be read ({error.strerror or error})") from None


def load_vec_normalize(path: str | Path, venv: VecEnv | None) -> VecNormalize:
    """``VecNormalize.load(path, venv)`` with the statistics read as data only (:func:`load_data_pickle`).

    :param path: the statistics (``vecnormalize.pkl``)
    :param venv: the environment they wrap (None: the statistics alone, wrapping nothing)

    :raise ValueError: one line naming the file when it does not hold ``VecNormalize`` statistics
    """
    stats = load_data_pickle(path, VEC_NORMALIZE_CLASSES)
    if not isinstance(stats, VecNormalize):
        raise ValueError(f"{path} does not hold VecNormalize statistics (it holds a {type(stats).__name__})")
    if venv is not None:
        stats.set_venv(venv)
    return stats
