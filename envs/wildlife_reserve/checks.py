"""The checks every environment of the package makes on what a caller hands it (seeds, reset options, agent names,
action dicts, discrete actions), so that the reserve and ZonePatrol refuse the same bad input with the same message,
before anything changes."""

from __future__ import annotations

import difflib
import warnings
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np


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
