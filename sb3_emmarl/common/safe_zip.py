"""Model zips checked before anything in them is unpickled.

SB3 stores parts of a model (spaces, schedules, the policy class, buffers' classes, random generators) in the zip's
``data`` entry as ``:serialized:`` cloudpickle strings and unpickles them on ``load`` (and on
``load_from_zip_file(load_data=True)``): a pickle can name any function and call it, so a zip from an unknown source is
code. :func:`check_zip_pickles` reads those pickles' opcodes (``pickletools.genops``, nothing is run) and refuses a zip
whose pickles name a global outside :func:`allowed_global`: the classes SB3, sb3-contrib and this package save (policies,
buffers, extractors, action noise, schedules, their data classes), Gymnasium's spaces, numpy's arrays, dtypes and random
generators, torch's activation and optimizer classes, ``collections.deque``/``OrderedDict`` and a few builtin types.
The weights (``*.pth``) are loaded by SB3 with ``torch.load(weights_only=True)``, which takes tensors only.
"""

from __future__ import annotations

import base64
import binascii
import dataclasses
import enum
import importlib
import json
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
    activation or optimizer class of :data:`~sb3_emmarl.common.safe_config.SAFE_NAMES`; or a class of
    :data:`CLASS_PACKAGES` that is a policy, buffer, features extractor, action noise or ``torch`` module, a schedule
    (``*Schedule``), an enum, a named tuple or a data class (constructors that only store their arguments; a class
    that writes files, e.g. a logger, is refused).

    :param module: the global's module
    :param name: its name
    """
    from sb3_emmarl.common.safe_config import SAFE_NAMES

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


def check_zip_pickles(path: str | Path) -> None:
    """Refuse a model zip whose ``data`` pickles name a global outside :func:`allowed_global`, before SB3 unpickles
    anything in it.

    :param path: the zip
    :raise ValueError: one line naming the file, the entry and the global
    """
    try:
        with zipfile.ZipFile(path) as archive:
            if "data" not in archive.namelist():
                return  # not a model: check_model_file says so
            data = json.loads(archive.read("data"))
    except (zipfile.BadZipFile, OSError, EOFError, ValueError, UnicodeDecodeError) as error:
        raise ValueError(f"{path} is not a readable model zip ({type(error).__name__})") from None
    if not isinstance(data, dict):
        raise ValueError(f"{path}: its 'data' entry is not a mapping")
    for key, value in data.items():
        for entry, text in _serialized(value, str(key)):
            try:
                blob = base64.b64decode(text.encode(), validate=True)
            except (binascii.Error, ValueError):
                raise ValueError(f"{path}: refusing to load: its entry {entry!r} is not base64") from None
            try:
                names = pickle_globals(blob)
            except ValueError as error:
                raise ValueError(f"{path}: refusing to load: its entry {entry!r} is {error}") from None
            for module, name in names:
                if not allowed_global(module, name):
                    raise ValueError(f"{path}: refusing to load: its entry {entry!r} names {module}.{name}, which a "
                                     "model of this package never holds (a zip from an unknown source is code)")
