"""The checks every environment of the package makes on what a caller hands it (constructor arguments: ints, finite
numbers, bools, arrays; seeds, reset options, agent names, action dicts, discrete actions), so that the reserve and
ZonePatrol refuse the same bad input with the same message, before anything changes."""

from __future__ import annotations

import difflib
import math
import reprlib
import warnings
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

# ---------------------------------------------------------------------------------------------- arguments
_REPR = reprlib.Repr()
_REPR.maxstring, _REPR.maxother, _REPR.maxlong = 40, 60, 30
_REPR.maxlist = _REPR.maxtuple = _REPR.maxset = _REPR.maxfrozenset = _REPR.maxdict = 8
_REPR.maxlevel = 3


def show(value: Any, with_type: bool = False) -> str:
    """``value`` for an error message: its repr, abbreviated when long (and big arrays by shape and dtype).

    :param with_type: append the type name (for "must be an int"-type messages)
    """
    try:
        if isinstance(value, np.ndarray) and value.size > 8:
            text = f"an array of shape {value.shape} and dtype {value.dtype}"
            with_type = False
        elif isinstance(value, int) and abs(value).bit_length() > 128:  # repr of a huge int can fail (digit limit)
            text = f"an int of about {int(abs(value).bit_length() * math.log10(2))} digits"
            with_type = False
        else:
            text = " ".join(_REPR.repr(value).split())  # one line (numpy spreads arrays over several)
    except Exception:  # a broken __repr__ must not hide the real error
        text = f"a {type(value).__name__} object"
        with_type = False
    if len(text) > 80:
        text = text[:76] + "...'" if text[:1] in "'\"" else text[:77] + "..."
    return f"{text} ({type(value).__name__})" if with_type else text


def _allowed(low: float, high: float | None) -> str:
    return f">= {low}" if high is None else f"in [{low}, {high}]"


def check_int(name: str, value: Any, low: int, high: int | None = None) -> int:
    """``value`` as an int in ``[low, high]`` (bools, floats and anything else but ints are rejected)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"{name} must be an int {_allowed(low, high)}, got {show(value, with_type=True)}")
    number = int(value)
    if number < low or (high is not None and number > high):
        raise ValueError(f"{name} must be {_allowed(low, high)}, got {show(value)}")
    return number


def check_float(name: str, value: Any, low: float, high: float | None = None) -> float:
    """``value`` as a finite float in ``[low, high]`` (ints accepted; bools, strings and anything else rejected)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{name} must be a finite number {_allowed(low, high)}, got {show(value, with_type=True)}")
    if isinstance(value, (int, np.integer)):  # compared exactly: a huge int must not overflow a float first
        number: float = int(value)
    else:
        number = float(value)
        if not math.isfinite(number):
            raise ValueError(f"{name} must be a finite number {_allowed(low, high)}, got {show(value)}")
    if number < low or (high is not None and number > high):
        raise ValueError(f"{name} must be {_allowed(low, high)}, got {show(value)}")
    return float(number)


def check_bool(name: str, value: Any) -> bool:
    """``value`` as a bool: only ``True``, ``False`` and numpy bools (no strings, numbers or None)."""
    if not isinstance(value, (bool, np.bool_)):
        raise ValueError(f"{name} must be a bool (True or False), got {show(value, with_type=True)}")
    return bool(value)


def check_array(name: str, value: Any, kinds: str, what: str) -> np.ndarray:
    """``value`` as a numpy array whose dtype kind is one of ``kinds`` (``"i"``, ``"u"``, ``"f"``).

    :param what: what is allowed, for the message (e.g. ``"a float array (height, width)"``)
    """
    try:
        array = np.asarray(value)
    except (ValueError, TypeError, OverflowError) as error:  # ragged nesting, unconvertible objects
        raise ValueError(f"{name} must be {what}, got {show(value)} ({error})") from None
    if array.dtype.kind not in kinds:
        got = show(value)
        got = got if "dtype" in got else f"{got} of dtype {array.dtype}"
        raise ValueError(f"{name} must be {what}, got {got}")
    return array


# ---------------------------------------------------------------------------------------------- reset and step
def check_seed(seed: Any) -> int | None:
    """A reset's seed as Gymnasium takes it: an int >= 0 (numpy's included) or None.

    :raise ValueError: naming the value
    """
    if seed is None:
        return None
    if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be an int >= 0 or None, got {seed!r}")
    return int(seed)


#: How close (``difflib``'s ratio, case ignored) an unknown option's name must be to a known one to be refused as a
#: misspelling of it ("uav_pos", "Mode"); PettingZoo's API test resets with ``options={"options": 1}`` (0.6 from
#: "uav_positions"), which an environment must take.
TYPO_RATIO = 0.65


def check_options(options: Any, known: Sequence[str]) -> Mapping[str, Any]:
    """A reset's options: None or a dict. A key close to a known one (:data:`TYPO_RATIO`) is refused as its
    misspelling; any other unknown key is named in a warning and ignored (PettingZoo's API test passes one, so an
    environment must take it).

    :return: the options (an empty dict for None)
    :raise ValueError: naming the type, or the misspelt key and the known one
    """
    if options is None:
        return {}
    if not isinstance(options, Mapping):
        raise ValueError(f"options must be a dict or None, got {type(options).__name__}")
    unknown = [str(key) for key in options if key not in known]
    for key in unknown:
        close = [name for name in known
                 if difflib.SequenceMatcher(None, key.lower(), name.lower()).ratio() >= TYPO_RATIO]
        if close:
            raise ValueError(f"unknown reset option {key!r}: did you mean {close[0]!r}? (the options are {list(known)})")
    if unknown:
        warnings.warn(f"reset ignores the options {unknown}: it takes {list(known)}", stacklevel=3)
    return options


def check_agent(agent: Any, possible_agents: Sequence[str]) -> None:
    """An agent name asked for (``observation_space(agent)``, ``action_space(agent)``).

    :raise ValueError: naming the value and the agents
    """
    if agent not in possible_agents:
        shown = list(possible_agents[:3]) + (["..."] if len(possible_agents) > 3 else [])
        raise ValueError(f"no agent {agent!r}: the agents are {shown} ({len(possible_agents)})")


def check_action_dict(actions: Any, agents: Sequence[str]) -> Mapping[str, Any]:
    """A step's actions: a dict whose keys are live agents (an agent left out takes the environment's documented
    default; a key that is no live agent, a typo for one, is refused rather than leave that agent idle).

    :raise ValueError: naming the type, or the unknown keys
    """
    if not isinstance(actions, Mapping):
        raise ValueError(f"actions must be a dict of agent -> action, got {type(actions).__name__}")
    unknown = [key for key in actions if key not in agents]
    if unknown:
        shown = list(agents[:3]) + (["..."] if len(agents) > 3 else [])
        raise ValueError(f"actions for agents that are not in the episode: {unknown[:5]!r} (the agents: {shown})")
    return actions


def discrete_action(agent: str, value: Any, n_actions: int, none_too: bool = False) -> int:
    """One agent's discrete action: an int in ``[0, n_actions)`` (a Python or numpy integer, or a 0-d integer array, as
    ``Discrete.contains`` takes it; no float, bool, list or array of another shape).

    :param none_too: the environment also takes None (its default action): the message says so
    :raise ValueError: naming the agent, the value and the range
    """
    choice = np.asarray(value)  # (a bool's kind is "b", a string's "U": refused with the floats)
    if choice.shape != () or choice.dtype.kind not in "iu" or not 0 <= int(choice) < n_actions:
        raise ValueError(f"the action of {agent} must be an int in [0, {n_actions - 1}]{' or None' if none_too else ''}, "
                         f"got {value!r}")
    return int(choice)
