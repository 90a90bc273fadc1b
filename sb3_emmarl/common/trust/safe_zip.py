"""Model zips checked before anything in them is unpickled.

SB3 stores parts of a model (spaces, schedules, the policy class, buffers' classes, random generators) in the zip's
``data`` entry as ``:serialized:`` cloudpickle strings and unpickles them on ``load`` (and on
``load_from_zip_file(load_data=True)``): a pickle can name any function and call it, so a zip from an unknown source is
code. :func:`check_zip_pickles` reads those pickles' opcodes (``pickletools.genops``, nothing is run) and refuses a zip
whose pickles name a global outside :func:`allowed_global`: the classes SB3, sb3-contrib and this package save (policies,
buffers, extractors, action noise, schedules, their data classes), Gymnasium's spaces, numpy's arrays, dtypes and random
generators, torch's activation and optimizer classes, ``collections.deque``/``OrderedDict`` and a few builtin types.
Naming allowed globals only is not enough (some call or deserialise what they are given, data types allocate what an
argument asks for), so :func:`safe_data_objects` then unpickles the entries as data only
(:mod:`sb3_emmarl.common.trust.safe_pickle`) and hands them to SB3's ``load`` as ``custom_objects``, which SB3 takes in
place of
unpickling them itself. The weights (``*.pth``) are loaded by SB3 with ``torch.load(weights_only=True)``, which takes
tensors only.
"""

from __future__ import annotations

import base64
import binascii
import dataclasses
import enum
import importlib
import io
import json
import os
import pickletools
import zipfile
from pathlib import Path
from typing import Any, cast

#: Exact globals a model's pickles may name (beyond the classes :func:`allowed_global` accepts by kind).
ALLOWED_GLOBALS: frozenset[tuple[str, str]] = frozenset({
    *{(module, name) for module in ("numpy", "numpy.core.multiarray", "numpy._core.multiarray")
      for name in ("dtype", "ndarray", "_reconstruct", "scalar")},
    *{(module, "_frombuffer") for module in ("numpy.core.numeric", "numpy._core.numeric")},
    *{("numpy", name) for name in ("float16", "float32", "float64", "int8", "int16", "int32", "int64", "uint8",
                                   "uint16", "uint32", "uint64", "bool_", "longlong", "ulonglong")},
    *{("numpy.random._pickle", name) for name in ("__bit_generator_ctor", "__generator_ctor", "__randomstate_ctor")},
    ("numpy.random._pcg64", "PCG64"), ("numpy.random._pcg64", "PCG64DXSM"), ("numpy.random._mt19937", "MT19937"),
    ("numpy.random._philox", "Philox"), ("numpy.random._sfc64", "SFC64"), ("numpy.random._generator", "Generator"),
    ("numpy.random.mtrand", "RandomState"), ("numpy.random.bit_generator", "SeedSequence"),
    ("numpy.random.bit_generator", "__pyx_unpickle_SeedSequence"),
    ("collections", "deque"), ("collections", "OrderedDict"),
    *{("builtins", name) for name in ("set", "frozenset", "slice", "complex", "bytearray", "range", "float", "int",
                                      "bool", "str", "tuple", "list", "dict", "object")},
    ("copyreg", "_reconstructor"),
    ("torch", "device"), ("torch", "float32"), ("torch", "float64"),
    ("torch._utils", "_rebuild_tensor_v2"), ("torch._utils", "_rebuild_parameter"),
    ("torch.storage", "_load_from_bytes"),
})
#: Packages whose classes a model's pickles may name when they are of an allowed kind (see :func:`allowed_global`).
CLASS_PACKAGES = ("stable_baselines3", "sb3_contrib", "sb3_emmarl", "rl_zoo3")
#: Gymnasium's space classes.
SPACE_MODULE = "gymnasium.spaces"


def _allowed_kinds() -> tuple[type, ...]:
    import torch as th
    from stable_baselines3.common.buffers import BaseBuffer
    from stable_baselines3.common.noise import ActionNoise
    from stable_baselines3.common.policies import BasePolicy
    from stable_baselines3.common.torch_layers import BaseFeaturesExtractor

    return BasePolicy, BaseBuffer, BaseFeaturesExtractor, ActionNoise, th.nn.Module


def allowed_global(module: str, name: str) -> bool:
    """Whether a model's pickle may name ``module.name``: one of :data:`ALLOWED_GLOBALS`; a Gymnasium space class; an
    activation or optimizer class of :data:`~sb3_emmarl.common.trust.safe_config.SAFE_NAMES`; or a class of
    :data:`CLASS_PACKAGES` that is a policy, buffer, features extractor, action noise or ``torch`` module, a schedule
    (``*Schedule``), an enum, a named tuple or a data class (constructors that only store their arguments; a class
    that writes files, e.g. a logger, is refused).

    :param module: the global's module
    :param name: its name
    """
    from sb3_emmarl.common.trust.safe_config import SAFE_NAMES

    if (module, name) in ALLOWED_GLOBALS:
        return True
    if "__" in name or not name.isidentifier():
        return False
    if any(getattr(obj, "__module__", None) == module and getattr(obj, "__name__", None) == name
           for obj in SAFE_NAMES.values()):
        return True
    root = module.split(".")[0]
    if module != SPACE_MODULE and not module.startswith(SPACE_MODULE + ".") and root not in CLASS_PACKAGES:
        return False
    try:
        obj = getattr(importlib.import_module(module), name)
    except (ImportError, AttributeError):
        return False
    if not isinstance(obj, type):
        return False
    if root == "gymnasium":
        from gymnasium.spaces import Space

        return issubclass(obj, Space)
    return (issubclass(obj, _allowed_kinds()) or name.endswith("Schedule") or issubclass(obj, enum.Enum)
            or (issubclass(obj, tuple) and hasattr(obj, "_fields")) or dataclasses.is_dataclass(obj))


_STRINGS = {"SHORT_BINUNICODE", "BINUNICODE", "BINUNICODE8", "UNICODE", "SHORT_BINSTRING", "BINSTRING", "STRING"}


def pickle_globals(blob: bytes) -> list[tuple[str, str]]:
    """The globals a pickle names (``GLOBAL``, ``INST`` and ``STACK_GLOBAL`` opcodes), read with ``pickletools.genops``
    without running it; a ``STACK_GLOBAL`` whose module and name are not plain strings is returned as ``("?", "?")``.

    :param blob: the pickle
    :raise ValueError: if the pickle does not parse
    """
    found: list[tuple[str, str]] = []
    pushed: list[Any] = []  # what each opcode pushed, as far as it matters (strings), else None
    memo: dict[int, Any] = {}
    try:
        for opcode, raw, _ in pickletools.genops(blob):
            op, arg = opcode.name, cast(Any, raw)
            if op in _STRINGS:
                pushed.append(arg)
            elif op == "MEMOIZE":
                memo[len(memo)] = pushed[-1] if pushed else None
            elif op in ("PUT", "BINPUT", "LONG_BINPUT"):
                memo[int(arg)] = pushed[-1] if pushed else None
            elif op in ("GET", "BINGET", "LONG_BINGET"):
                pushed.append(memo.get(int(arg)))
            elif op in ("GLOBAL", "INST"):
                module, _, name = str(arg).partition(" ")
                found.append((module, name))
                pushed.append(None)
            elif op == "STACK_GLOBAL":
                pair = (pushed[-2], pushed[-1]) if len(pushed) >= 2 else (None, None)
                ok = isinstance(pair[0], str) and isinstance(pair[1], str)
                found.append((str(pair[0]), str(pair[1])) if ok else ("?", "?"))
                pushed.append(None)
            elif op not in ("FRAME", "PROTO", "MARK", "STOP"):
                pushed.append(None)
    except Exception as error:  # pickletools raises ValueError and others on a malformed pickle
        raise ValueError(f"not a readable pickle ({type(error).__name__}: {error})") from None
    return found


def _serialized(value: Any, key: str) -> list[tuple[str, str]]:
    """``(entry, base64 text)`` of every ``:serialized:`` string in a ``data`` value (nested ones included)."""
    found = []
    if isinstance(value, dict):
        for sub_key, sub in value.items():
            if sub_key == ":serialized:" and isinstance(sub, str):
                found.append((key, sub))
            else:
                found.extend(_serialized(sub, key if sub_key.startswith(":") else f"{key}.{sub_key}"))
    elif isinstance(value, list):
        for item in value:
            found.extend(_serialized(item, key))
    return found


#: The largest member a model zip may hold, uncompressed (a model of the paper's largest team is a few MB).
MAX_MEMBER_BYTES = 1 << 31


def check_zip_sizes(archive: zipfile.ZipFile, path: object) -> None:
    """Refuse a zip with a member larger than :data:`MAX_MEMBER_BYTES` uncompressed, before anything is read.

    :raise ValueError: one line naming the file, the member and its size
    """
    for info in archive.infolist():
        if info.file_size > MAX_MEMBER_BYTES:
            raise ValueError(f"{path}: refusing to load: its member {info.filename!r} is {info.file_size} bytes "
                             f"uncompressed (at most {MAX_MEMBER_BYTES})")


def read_data(path: str | Path | io.IOBase) -> dict[str, Any] | None:
    """A model zip's ``data`` entry as JSON (nothing unpickled), or None if the zip has none.

    :raise ValueError: one line naming the file when it is not a readable zip, a member is too large, or the entry is
        not a JSON mapping (nested too deep included)
    """
    try:
        with zipfile.ZipFile(path) as archive:
            check_zip_sizes(archive, path)
            if "data" not in archive.namelist():
                return None  # not a model: check_model_file says so
            data = json.loads(archive.read("data"))
    except (zipfile.BadZipFile, OSError, EOFError, UnicodeDecodeError, RecursionError) as error:
        raise ValueError(f"{path} is not a readable model zip ({type(error).__name__})") from None
    except json.JSONDecodeError as error:
        raise ValueError(f"{path}: its 'data' entry is not JSON ({error})") from None
    if not isinstance(data, dict):
        raise ValueError(f"{path}: its 'data' entry is not a mapping")
    return data


def _decoded(path: object, entry: str, text: str) -> bytes:
    try:
        return base64.b64decode(text.encode(), validate=True)
    except (binascii.Error, ValueError):
        raise ValueError(f"{path}: refusing to load: its entry {entry!r} is not base64") from None


def safe_data_objects(path: str | Path | io.IOBase, custom_objects: dict[str, Any] | None = None) -> dict[str, Any]:
    """Every pickled entry of a model zip's ``data``, unpickled as data only
    (:func:`~sb3_emmarl.common.trust.safe_pickle.loads`), as SB3's ``custom_objects``: given to ``load`` or
    ``load_from_zip_file``, SB3 takes them in place of unpickling the entries itself.

    :param path: the zip
    :param custom_objects: the caller's own objects, which win
    :raise ValueError: one line naming the file, the entry and what it names, calls or allocates
    """
    from sb3_emmarl.common.trust.safe_pickle import loads

    if isinstance(path, (str, os.PathLike)) and not Path(path).exists() and Path(f"{path}.zip").exists():
        path = f"{path}.zip"  # as SB3's load finds it
    start = path.tell() if isinstance(path, io.IOBase) else None
    try:
        data = check_zip_pickles(path)
        objects: dict[str, Any] = {}
        for key, value in (data or {}).items():
            if custom_objects and key in custom_objects:
                continue
            if isinstance(value, dict) and isinstance(value.get(":serialized:"), str):
                objects[key] = loads(_decoded(path, key, value[":serialized:"]), f"{path}: its entry {key!r}")
    finally:
        if start is not None:
            cast(io.IOBase, path).seek(start)
    return {**objects, **(custom_objects or {})}


def check_zip_pickles(path: str | Path | io.IOBase) -> dict[str, Any] | None:
    """Refuse a model zip whose ``data`` pickles name a global outside :func:`allowed_global`, before anything in it
    is unpickled (:func:`safe_data_objects` then unpickles them as data only).

    :param path: the zip (a path or an open binary file)
    :return: the zip's ``data`` as JSON, or None if it has none
    :raise ValueError: one line naming the file, the entry and the global
    """
    data = read_data(path)
    if data is None:
        return None
    for key, value in data.items():
        for entry, text in _serialized(value, str(key)):
            blob = _decoded(path, entry, text)
            try:
                names = pickle_globals(blob)
            except ValueError as error:
                raise ValueError(f"{path}: refusing to load: its entry {entry!r} is {error}") from None
            for module, name in names:
                if not allowed_global(module, name):
                    raise ValueError(f"{path}: refusing to load: its entry {entry!r} names {module}.{name}, which a "
                                     "model of this package never holds (a zip from an unknown source is code)")
    return data
