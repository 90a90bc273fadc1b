"""Inputs read as data, never run as code: one parser for every string that becomes a value, YAML with limits, and
allow-lists of the names a configuration may import or call.

Everything a user hands the zoo as text (``-params`` and ``--env-kwargs`` values, ``-conf`` files, a run folder's
``config.yml`` and ``args.yml`` on ``--resume`` or ``enjoy``, ``policy_kwargs``, ``normalize``, ``monitor_kwargs`` and
``replay_buffer_kwargs`` strings) goes through this module:

- :func:`parse_value` reads a Python-looking value by walking its syntax tree (``ast``), never with ``eval``: literals
  (numbers, strings, lists, dicts, tuples, ``True``/``False``/``None``), a minus sign before a number, ``dict(...)``,
  ``list(...)`` and ``tuple(...)`` of such values, and the classes of :data:`SAFE_NAMES` by name (``nn.ReLU``,
  ``th.optim.Adam``...). Anything else (arithmetic such as ``9**9**9``, ``lambda``, attribute walks such as
  ``().__class__``, calls of anything else, names not in the list) is refused with one line naming the key and the
  text. rl_zoo3's schedule strings (``lin_3e-4``) are kept as strings.
- :func:`load_yaml` reads a YAML file with ``yaml.safe_load``'s constructors (no Python tags), at most
  :data:`MAX_YAML_BYTES` long and expanding to at most :data:`MAX_YAML_NODES` values once its aliases are followed
  (a recursive alias is refused): a "billion laughs" file fails at once, naming the file.
- :func:`check_imports` accepts for the keys that make rl_zoo3 import or call something (``callback``,
  ``env_wrapper``, ``vec_env_wrapper``) only the names of :data:`IMPORT_KEYS`, with keyword arguments that are plain
  data, that the class takes (every required one) and of the types its signature says
  (:func:`~sb3_emmarl.common.trust.signatures.check_arguments`).
"""

from __future__ import annotations

import ast
import importlib
import inspect
import math
import re
from pathlib import Path
from typing import Any

import torch as th
import yaml
from stable_baselines3.common.sb2_compat.rmsprop_tf_like import RMSpropTFLike

from sb3_emmarl.common.trust.extras import requires
from sb3_emmarl.common.trust.signatures import check_arguments

#: Longest text :func:`parse_value` reads (a value longer than this is a mistake or an attack).
MAX_VALUE_CHARS = 10_000
#: Deepest nesting :func:`parse_value` reads.
MAX_VALUE_DEPTH = 32
#: Largest YAML file :func:`load_yaml` reads.
MAX_YAML_BYTES = 1 << 20
#: Most values (scalars, lists and mappings, counted once per use of an alias) a YAML file may expand to.
MAX_YAML_NODES = 100_000

#: Activation classes a value may name (``activation_fn=nn.ReLU``), each under ``nn.``, ``th.nn.`` and ``torch.nn.``.
ACTIVATIONS: dict[str, type] = {name: getattr(th.nn, name) for name in (
    "ReLU", "Tanh", "ELU", "LeakyReLU", "GELU", "SiLU", "Sigmoid", "Softplus", "Mish", "SELU", "CELU", "Identity",
    "Hardtanh", "ReLU6", "Tanhshrink", "Softsign")}
#: Optimizer classes a value may name (``optimizer_class=th.optim.Adam``), under ``th.optim.``, ``torch.optim.`` and
#: ``optim.``; and SB3's ``RMSpropTFLike`` (rl-zoo's Atari settings), by its name alone or its module path.
OPTIMIZERS: dict[str, type] = {
    **{name: getattr(th.optim, name) for name in ("Adam", "AdamW", "Adamax", "NAdam", "RAdam", "RMSprop", "SGD",
                                                   "Adagrad", "Adadelta")},
    "RMSpropTFLike": RMSpropTFLike}


def _safe_names() -> dict[str, Any]:
    names: dict[str, Any] = {}
    for name, cls in ACTIVATIONS.items():
        for prefix in ("nn.", "th.nn.", "torch.nn."):
            names[prefix + name] = cls
    for name, cls in OPTIMIZERS.items():
        if cls is RMSpropTFLike:
            names[name] = cls
            names[f"{cls.__module__}.{name}"] = cls
        else:
            for prefix in ("th.optim.", "torch.optim.", "optim."):
                names[prefix + name] = cls
    return names


#: Every name a value may use, and the object it stands for (nothing else is looked up: no builtins, no modules).
SAFE_NAMES: dict[str, Any] = _safe_names()
#: The constructors a value may call, with literal arguments only.
SAFE_CALLS = ("dict", "list", "tuple")
#: rl_zoo3's schedule strings, kept as they are (``lin_3e-4``: a linear schedule from 3e-4).
SCHEDULE_TEXT = re.compile(r"^lin_[-+0-9.eE]+$")
_HINT = ("values are literals (numbers, strings, lists, dicts, tuples, True/False/None), dict(...), and the names of "
         "sb3_emmarl.common.trust.safe_config.SAFE_NAMES such as nn.ReLU or th.optim.Adam")


def _short(text: str) -> str:
    shown = repr(text)
    return shown if len(shown) <= 80 else shown[:77] + "..."


class _Refused(Exception):
    pass


def _dotted(node: ast.AST) -> str | None:
    parts = []
    while isinstance(node, ast.Attribute):
        parts.append(node.attr)
        node = node.value
    if not isinstance(node, ast.Name):
        return None
    parts.append(node.id)
    return ".".join(reversed(parts))


_WHAT = {ast.Lambda: "a lambda", ast.BinOp: "arithmetic", ast.BoolOp: "a boolean operation",
         ast.Compare: "a comparison", ast.Subscript: "indexing", ast.ListComp: "a comprehension",
         ast.DictComp: "a comprehension", ast.SetComp: "a comprehension", ast.GeneratorExp: "a generator",
         ast.IfExp: "a conditional expression", ast.JoinedStr: "an f-string", ast.NamedExpr: "an assignment",
         ast.Starred: "unpacking (*)", ast.Set: "a set", ast.Await: "await", ast.Yield: "yield"}


def _resolve_dict(node: ast.Dict, depth: int) -> dict[Any, Any]:
    result = {}
    for key, value in zip(node.keys, node.values, strict=True):
        if key is None:
            raise _Refused("unpacking (**)")
        resolved = _resolve(key, depth + 1)
        try:
            hash(resolved)
        except TypeError:
            raise _Refused(f"an unhashable key {resolved!r}") from None
        result[resolved] = _resolve(value, depth + 1)
    return result


def _resolve_name(node: ast.Name | ast.Attribute) -> Any:
    name = _dotted(node)
    if name is None:
        raise _Refused("an attribute of something other than a name")
    if "__" in name:
        raise _Refused(f"the dunder name {name!r}")
    if name not in SAFE_NAMES:
        raise _Refused(f"the unknown name {name!r} (quote strings)")
    return SAFE_NAMES[name]


def _resolve_call(node: ast.Call, depth: int) -> Any:
    callee = node.func.id if isinstance(node.func, ast.Name) else None
    if callee not in SAFE_CALLS:
        raise _Refused(f"a call of {_dotted(node.func) or 'an expression'} (only {', '.join(SAFE_CALLS)})")
    if any(keyword.arg is None for keyword in node.keywords) or any(isinstance(a, ast.Starred) for a in node.args):
        raise _Refused("unpacking (* or **)")
    if callee == "dict":
        base: dict[Any, Any] = {}
        if node.args:
            if len(node.args) > 1 or not isinstance(node.args[0], ast.Dict):
                raise _Refused("dict(...) with positional arguments other than one {...}")
            base = _resolve_dict(node.args[0], depth + 1)
        return {**base, **{keyword.arg: _resolve(keyword.value, depth + 1) for keyword in node.keywords}}
    if node.keywords or len(node.args) != 1 or not isinstance(node.args[0], (ast.List, ast.Tuple)):
        raise _Refused(f"{callee}(...) of something other than one [...] or (...)")
    items = _resolve(node.args[0], depth + 1)
    return list(items) if callee == "list" else tuple(items)


def _resolve(node: ast.AST, depth: int) -> Any:
    if depth > MAX_VALUE_DEPTH:
        raise _Refused(f"nested deeper than {MAX_VALUE_DEPTH}")
    if isinstance(node, ast.Constant):
        if node.value is Ellipsis or isinstance(node.value, (bytes, complex)):
            raise _Refused(f"a {type(node.value).__name__} literal")
        return node.value
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.USub, ast.UAdd)):
        operand = node.operand
        if isinstance(operand, ast.Constant) and isinstance(operand.value, (int, float)) \
                and not isinstance(operand.value, bool):
            return -operand.value if isinstance(node.op, ast.USub) else operand.value
        raise _Refused("a sign before something other than a number")
    if isinstance(node, (ast.List, ast.Tuple)):
        items = [_resolve(item, depth + 1) for item in node.elts]
        return items if isinstance(node, ast.List) else tuple(items)
    if isinstance(node, ast.Dict):
        return _resolve_dict(node, depth)
    if isinstance(node, (ast.Name, ast.Attribute)):
        return _resolve_name(node)
    if isinstance(node, ast.Call):
        return _resolve_call(node, depth)
    raise _Refused(_WHAT.get(type(node), f"a {type(node).__name__} expression"))


def parse_value(text: str, where: str) -> Any:
    """The value a string stands for, read by an ``ast`` walk (never ``eval``); see the module docstring for what is
    accepted.

    :param text: the value as written (``"dict(net_arch=[64, 64])"``, ``"0.5"``, ``"'forest'"``, ``"lin_3e-4"``)
    :param where: what the value is (the flag and key, e.g. ``"-params policy_kwargs"``), for the message
    :return: the value
    :raise ValueError: one line naming ``where``, the text and why it is refused
    """
    if not isinstance(text, str):
        raise ValueError(f"{where}: expected a string to parse, got {type(text).__name__}")
    stripped = text.strip()
    if SCHEDULE_TEXT.match(stripped):
        return stripped
    if len(text) > MAX_VALUE_CHARS:
        raise ValueError(f"{where}: refusing a value of {len(text)} characters (at most {MAX_VALUE_CHARS})")
    try:
        tree = ast.parse(stripped, mode="eval")
    except (SyntaxError, ValueError, RecursionError, MemoryError, OverflowError) as error:
        reason = error.msg if isinstance(error, SyntaxError) else type(error).__name__
        raise ValueError(f"{where}: {_short(text)} is not a valid Python value ({reason}); {_HINT}") from None
    try:
        return _resolve(tree.body, 0)
    except _Refused as refusal:
        raise ValueError(f"{where}: {_short(text)} is not a valid Python value (refused: {refusal}); {_HINT}") from None
    except RecursionError:
        raise ValueError(f"{where}: refusing {_short(text)}: nested too deeply") from None


def is_plain(value: Any, depth: int = 0) -> bool:
    """Whether ``value`` is plain data: None, bool, int, finite or not float, str, and lists, tuples and dicts of them
    (no classes, no callables).

    :param value: the value
    :param depth: nesting so far (deeper than :data:`MAX_VALUE_DEPTH` is not plain)
    """
    if depth > MAX_VALUE_DEPTH:
        return False
    if value is None or isinstance(value, (bool, int, float, str)):
        return True
    if isinstance(value, (list, tuple)):
        return all(is_plain(item, depth + 1) for item in value)
    if isinstance(value, dict):
        return all(is_plain(k, depth + 1) and is_plain(v, depth + 1) for k, v in value.items())
    return False


_SOURCE_NAMES = {id(obj): name for name, obj in reversed(list(SAFE_NAMES.items()))
                 if name.startswith(("nn.", "th.optim.")) or name == "RMSpropTFLike"}


def to_source(value: Any) -> str:
    """The text :func:`parse_value` reads back as ``value`` (for ``config.yml``: a value holding classes is saved as
    the text that names them, e.g. ``"dict(activation_fn=nn.ReLU)"``).

    :param value: plain data and the objects of :data:`SAFE_NAMES`
    :raise ValueError: for anything else
    """
    if id(value) in _SOURCE_NAMES:
        return _SOURCE_NAMES[id(value)]
    if isinstance(value, dict):
        if all(isinstance(key, str) and key.isidentifier() for key in value):
            return "dict(" + ", ".join(f"{key}={to_source(v)}" for key, v in value.items()) + ")"
        return "{" + ", ".join(f"{to_source(k)}: {to_source(v)}" for k, v in value.items()) + "}"
    if isinstance(value, list):
        return "[" + ", ".join(to_source(v) for v in value) + "]"
    if isinstance(value, tuple):
        if len(value) == 1:
            return f"({to_source(value[0])},)"
        return "(" + ", ".join(to_source(v) for v in value) + ")"
    if value is None or isinstance(value, (bool, int, str)) or (isinstance(value, float) and math.isfinite(value)):
        return repr(value)
    raise ValueError(f"cannot write {value!r} as a value the zoo reads back")


# ---------------------------------------------------------------------------------------------- YAML
class _LimitedLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` that counts what the document expands to before building it."""

    def get_single_node(self) -> Any:
        node = super().get_single_node()
        if node is not None:
            _expanded_size(node, {}, set())
        return node


class _TooLarge(Exception):
    pass


class _Recursive(Exception):
    pass


def _expanded_size(node: yaml.Node, sizes: dict[int, int], active: set[int]) -> int:
    key = id(node)
    if key in sizes:
        return sizes[key]
    if key in active:
        raise _Recursive
    active.add(key)
    size = 1
    if isinstance(node, yaml.SequenceNode):
        for item in node.value:
            size += _expanded_size(item, sizes, active)
            if size > MAX_YAML_NODES:
                raise _TooLarge
    elif isinstance(node, yaml.MappingNode):
        for k, v in node.value:
            size += _expanded_size(k, sizes, active) + _expanded_size(v, sizes, active)
            if size > MAX_YAML_NODES:
                raise _TooLarge
    active.discard(key)
    sizes[key] = size
    return size


def load_yaml_text(text: str, source: str | Path) -> Any:
    """A YAML document read as data (see :func:`load_yaml`).

    :param text: the document
    :param source: where it comes from (a file name), for messages
    :raise ValueError: one line naming ``source``
    """
    if len(text) > MAX_YAML_BYTES:
        raise ValueError(f"{source}: refusing a YAML file of {len(text)} characters (at most {MAX_YAML_BYTES})")
    try:
        return yaml.load(text, Loader=_LimitedLoader)
    except _TooLarge:
        raise ValueError(f"{source}: refusing a YAML file whose aliases expand to more than {MAX_YAML_NODES} values"
                         ) from None
    except _Recursive:
        raise ValueError(f"{source}: refusing a YAML file with a recursive alias (an anchor used inside itself)"
                         ) from None
    except yaml.constructor.ConstructorError as error:
        raise ValueError(f"{source}: refusing to load a YAML file holding a Python object tag ({error.problem}); "
                         "run folders and configs are read as data only") from None
    except yaml.YAMLError as error:
        raise ValueError(f"{source} is not valid YAML ({' '.join(str(error).split())})") from None
    except RecursionError:
        raise ValueError(f"{source}: refusing a YAML file nested too deeply") from None


def load_yaml(path: str | Path, what: str = "a YAML file") -> Any:
    """A YAML file read as data: ``yaml.safe_load``'s types only (a Python tag is refused), at most
    :data:`MAX_YAML_BYTES` bytes, expanding to at most :data:`MAX_YAML_NODES` values once its aliases are followed, no
    recursive alias.

    :param path: the file
    :param what: what the file is, for messages
    :raise ValueError: one line naming the file
    """
    path = Path(path)
    try:
        if not path.is_file():  # a folder, a FIFO or a device (/dev/zero reads without end) is no YAML file
            raise ValueError(f"{path}: {what} must be a regular file")
        with open(path, "rb") as file:
            data = file.read(MAX_YAML_BYTES + 1)  # (not the size the file claims: it may grow or lie)
        if len(data) > MAX_YAML_BYTES:
            raise ValueError(f"{path}: refusing {what} of more than {MAX_YAML_BYTES} bytes")
        text = data.decode()
    except (OSError, UnicodeDecodeError) as error:
        raise ValueError(f"{path}: cannot read {what} ({error})") from None
    try:
        return load_yaml_text(text, path)
    except ValueError as error:
        raise ValueError(str(error).replace("a YAML file", what, 1)) from None


# ---------------------------------------------------------------------------------------------- imports
#: The names each key that makes rl_zoo3 import and call something may take (their keyword arguments plain data the
#: class takes). ``vec_env_wrapper``: :class:`~sb3_emmarl.common.masking.HideObservationParts` (observation parts
#: zeroed, ``{name: {parts: [...]}}``); ``callback``: SB3's ``StopTrainingOnMaxEpisodes``; ``env_wrapper`` (the
#: centralised view's Gymnasium wrappers): none.
IMPORT_KEYS: dict[str, tuple[str, ...]] = {
    "vec_env_wrapper": ("sb3_emmarl.common.masking.HideObservationParts",),
    "env_wrapper": (),
    "callback": ("stable_baselines3.common.callbacks.StopTrainingOnMaxEpisodes",),
}


def _load_name(name: str) -> Any:
    module, _, attribute = name.rpartition(".")
    return getattr(importlib.import_module(module), attribute)


def check_imports(key: str, value: Any) -> Any:
    """Check the value of a key that names classes to import and call (``callback``, ``env_wrapper``,
    ``vec_env_wrapper``): None, a name of :data:`IMPORT_KEYS`, ``{name: {keyword: value}}``, or a list of those; the
    keyword arguments plain data among the class's arguments.

    :param key: the key
    :param value: its value
    :return: ``value``, unchanged
    :raise ValueError: one line naming the key, the value and the allowed names
    """
    allowed = IMPORT_KEYS[key]
    names = ", ".join(allowed) if allowed else "none (only null)"
    if value is None:
        return None
    for item in value if isinstance(value, list) else [value]:
        kwargs: Any = {}
        if isinstance(item, dict) and len(item) == 1:
            item, kwargs = next(iter(item.items()))
        if not isinstance(item, str) or item not in allowed:
            raise ValueError(f"{key} must name one of the allowed classes: {names}; got {_short(str(item))}")
        if kwargs is None:
            kwargs = {}
        if not isinstance(kwargs, dict) or not all(isinstance(k, str) for k in kwargs) or not is_plain(kwargs):
            raise ValueError(f"{key} {item}: its keyword arguments must be a mapping of names to plain values, "
                             f"got {_short(repr(kwargs))}")
        cls = _load_name(item)
        signature = inspect.signature(cls.__init__).parameters
        parameters = set(signature) - {"self", "venv", "env"}
        unknown = sorted(set(kwargs) - parameters)
        if unknown:
            raise ValueError(f"{key} {item}: unknown keyword argument(s) {unknown}; it takes {sorted(parameters)}")
        missing = sorted(name for name in parameters - set(kwargs) if signature[name].default is inspect.Parameter.empty
                         and signature[name].kind not in (inspect.Parameter.VAR_POSITIONAL, inspect.Parameter.VAR_KEYWORD))
        if missing:
            raise ValueError(f"{key} {item}: missing keyword argument(s) {missing} (give {{{item}: {{{missing[0]}: ...}}}})")
        check_arguments(cls, kwargs, f"{key} {item}")  # the types its signature says (max_episodes: int)
    return value


def wrapper_from_config(config: dict[str, Any], key: str = "vec_env_wrapper") -> Any:
    """rl_zoo3's ``get_wrapper_class(config, key)`` after :func:`check_imports` (for a run folder's ``config.yml``).

    :param config: the run's hyperparameters
    :param key: ``vec_env_wrapper`` or ``env_wrapper``
    :raise ValueError: for a name outside :data:`IMPORT_KEYS`
    """
    with requires("rl_zoo3", "zoo", "a run folder's wrappers"):
        from rl_zoo3.utils import get_wrapper_class

    check_imports(key, config.get(key))
    return get_wrapper_class(config, key)


def parse_kwargs(key: str, value: Any, allowed: tuple[str, ...] | None = None) -> dict[str, Any]:
    """A ``*_kwargs``-like value (``normalize``, ``monitor_kwargs``, ``replay_buffer_kwargs``) as a plain dict: a
    mapping, or a string :func:`parse_value` reads as one; None is an empty dict.

    :param key: the key, for messages
    :param value: its value
    :param allowed: the keys the dict may hold (None: any name)
    :raise ValueError: one line naming the key
    """
    if value is None:
        return {}
    if isinstance(value, str):
        value = parse_value(value, key)
    if not isinstance(value, dict) or not all(isinstance(k, str) for k in value):
        raise ValueError(f"{key} must be a mapping of names to values (or a \"dict(...)\" string), got {_short(repr(value))}")
    if not is_plain(value):
        raise ValueError(f"{key} must hold plain values (numbers, strings, lists, booleans), got {_short(repr(value))}")
    if allowed is not None:
        unknown = sorted(set(value) - set(allowed))
        if unknown:
            raise ValueError(f"{key} keys must be among {sorted(allowed)}, got {unknown}")
    return dict(value)
