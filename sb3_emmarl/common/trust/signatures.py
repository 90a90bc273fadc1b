"""Keyword arguments checked against the annotations of the constructor that will receive them, before it runs.

SB3 builds a model without reading most of its arguments: ``ent_coef='auto'`` (SAC's) builds a PPO that fails in
its first update, a ``policy_kwargs`` ``optimizer_class`` given as a string builds nothing, a callback's
``max_episodes: 'abc'`` fails at the first step. The zoo's rules (:mod:`sb3_emmarl.common.trust.validation`) say what each
hyperparameter may be on any algorithm; :func:`check_arguments` adds what the receiving class says in its signature:
a value must be of the outer type the parameter is annotated with (``float``: any finite number; ``int``; ``bool``;
``str``; ``type[X]``: a subclass of ``X``; a ``Callable``: a callable; ``dict``/``list``/``tuple``: a mapping, a
list or tuple (not a string); a union: any of its members; ``Any`` and what cannot be resolved: anything). The check
is shallow on purpose: the contents of a mapping or a list are the rules' business.

:func:`check_optimizer` builds the optimizer a policy will use on one parameter and steps it as SB3 does (no
closure), so that optimizer keyword arguments it does not take, and optimizers that need a closure, fail here.
"""

from __future__ import annotations

import collections.abc
import functools
import inspect
import math
import types
import typing
from collections.abc import Callable
from typing import Any

import numpy as np
import torch as th


def constructor_chain(cls: type) -> list[Any]:
    """The ``__init__`` of ``cls`` and of the base classes it passes ``**kwargs`` on to, down to the first one that
    takes no ``**kwargs`` (what a keyword argument of ``cls(...)`` can reach)."""
    chain = []
    for klass in cls.__mro__:
        init = klass.__dict__.get("__init__")
        if init is None or klass is object:
            continue
        chain.append(init)
        if not any(p.kind is inspect.Parameter.VAR_KEYWORD for p in inspect.signature(init).parameters.values()):
            break
    return chain


def _resolve(function: Any, name: str, annotation: Any) -> Any:
    """One parameter's annotation as an object (a string annotation evaluated in the function's module, as
    ``typing.get_type_hints`` does); ``Any`` if it cannot be (a name imported only for type checkers)."""
    if annotation is inspect.Parameter.empty:
        return Any
    if not isinstance(annotation, str):
        return annotation
    holder = types.SimpleNamespace(__annotations__={name: annotation}, __module__=function.__module__)
    try:
        return typing.get_type_hints(holder, globalns=getattr(function, "__globals__", {}))[name]
    except Exception:  # an unresolvable annotation checks nothing
        return Any


@functools.cache
def parameter_hints(cls: type) -> dict[str, Any]:
    """The keyword parameters ``cls(...)`` takes (:func:`constructor_chain`) and each one's annotation (the most
    derived class's), without ``self`` and ``*args``/``**kwargs``."""
    hints: dict[str, Any] = {}
    for init in constructor_chain(cls):
        for name, parameter in inspect.signature(init).parameters.items():
            if name == "self" or parameter.kind in (inspect.Parameter.VAR_KEYWORD, inspect.Parameter.VAR_POSITIONAL):
                continue
            hints.setdefault(name, _resolve(init, name, parameter.annotation))
    return hints


_SEQUENCES = (list, tuple, collections.abc.Sequence)


def conforms(value: Any, hint: Any) -> bool:
    """Whether ``value`` is of the outer type ``hint`` names (see the module docstring).

    :param value: the value
    :param hint: a resolved annotation
    """
    if hint is Any or isinstance(hint, typing.TypeVar):
        return True
    if hint is None or hint is type(None):
        return value is None
    origin = typing.get_origin(hint)
    if origin is typing.Union or origin is types.UnionType:
        return any(conforms(value, member) for member in typing.get_args(hint))
    if origin is typing.Literal:
        return value in typing.get_args(hint)
    if origin is type:
        args = typing.get_args(hint)
        target = args[0] if args else Any
        if not isinstance(value, type):
            return False
        if isinstance(target, type):
            return issubclass(value, target)
        return True  # type[Union[...]] or a TypeVar: any class
    if origin is collections.abc.Callable or hint is collections.abc.Callable or hint is typing.Callable:
        return callable(value)
    outer = origin if isinstance(origin, type) else hint
    if not isinstance(outer, type):
        return True
    if outer is float:
        return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_)) \
            and math.isfinite(float(value))
    if outer is int:
        return isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))
    if outer is bool:
        return isinstance(value, (bool, np.bool_))
    if outer in _SEQUENCES:  # YAML gives lists where the code says tuple; a string is not a sequence of values here
        return isinstance(value, (list, tuple))
    return isinstance(value, outer)


def describe(hint: Any) -> str:
    """``hint`` in words, for messages (``float | Callable`` -> ``a number or a callable (a schedule)``)."""
    origin = typing.get_origin(hint)
    if origin is typing.Union or origin is types.UnionType:
        return " or ".join(dict.fromkeys(describe(member) for member in typing.get_args(hint)))
    if hint is None or hint is type(None):
        return "null"
    if origin is typing.Literal:
        return f"one of {list(typing.get_args(hint))}"
    if origin is type:
        args = typing.get_args(hint)
        return f"a class derived from {args[0].__name__}" if args and isinstance(args[0], type) else "a class"
    if origin is collections.abc.Callable or hint is collections.abc.Callable or hint is typing.Callable:
        return "a callable (a schedule)"
    outer = origin if isinstance(origin, type) else hint
    names = {float: "a number", int: "an int", bool: "true or false", str: "a string", dict: "a mapping"}
    if outer in names:
        return names[outer]
    if outer in _SEQUENCES:
        return "a list"
    return f"a {getattr(outer, '__name__', outer)}"


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def check_arguments(cls: type, kwargs: dict[str, Any], where: str, unknown: bool = True) -> None:
    """Refuse a keyword argument that ``cls(...)`` does not take (if ``unknown``) or whose value is not of its
    parameter's annotated type (:func:`conforms`).

    :param cls: the class that will receive ``kwargs``
    :param kwargs: the keyword arguments
    :param where: what the arguments are (``"the hyperparameters"``, ``"policy_kwargs"``...), for the message
    :raise ValueError: one line naming ``where``, the key, what ``cls`` takes and the value
    """
    hints = parameter_hints(cls)
    for key, value in kwargs.items():
        if key not in hints:
            if unknown:
                raise ValueError(f"{where}: {key!r} is not an argument of {cls.__name__}; it takes {sorted(hints)}")
            continue
        if not conforms(value, hints[key]):
            raise ValueError(f"{where}: {key} must be {describe(hints[key])} for {cls.__name__} (its constructor's "
                             f"annotation), got {_short(value)}")


def check_optimizer(optimizer_class: Callable[..., th.optim.Optimizer], optimizer_kwargs: dict[str, Any] | None,
                    where: str) -> None:
    """Build ``optimizer_class`` on one parameter with ``optimizer_kwargs`` (and a learning rate, as SB3 gives it) and
    step it once without a closure, as SB3's ``train()`` does.

    :param optimizer_class: the optimizer's class
    :param optimizer_kwargs: its keyword arguments (None: none)
    :param where: what is checked (``"policy_kwargs"``), for the message
    :raise ValueError: one line naming ``where``, the optimizer and why it cannot be used
    """
    parameter = th.nn.Parameter(th.zeros(1))
    try:
        optimizer = optimizer_class([parameter], lr=1e-3, **(optimizer_kwargs or {}))
        parameter.grad = th.zeros(1)
        optimizer.step()
    except Exception as error:  # whatever it raises, SB3 would raise mid-run
        name = getattr(optimizer_class, "__name__", optimizer_class)
        raise ValueError(f"{where}: the optimizer {name} with optimizer_kwargs {optimizer_kwargs or {}} cannot be "
                         f"stepped as SB3 steps it (without a closure): {' '.join(str(error).split())}") from None
