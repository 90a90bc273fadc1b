"""The environments the zoo, the evaluation and the experiments know by id, and the PettingZoo module of each.

Each id names a PettingZoo parallel environment (``<module>.parallel_env``) whose agents share one policy; the same id
is registered with Gymnasium for the centralised view (:mod:`sb3_emmarl.common.centralized`), as rl-zoo expects.
"""

from __future__ import annotations

import importlib
import warnings
from collections.abc import Callable
from typing import Any

#: The wildlife reserve (:mod:`wildlife_reserve.reserve_v1`): the zoo's default environment.
ENV_ID = "WildlifeReserve-v1"
#: ZonePatrol (:mod:`wildlife_reserve.zone_patrol_v1`): the team task where the hidden mode decides the best action.
ZONE_PATROL_ID = "ZonePatrol-v1"
#: ZonePatrol's first version (:mod:`wildlife_reserve.zone_patrol_v0`: no zone readings, short links), kept so that its
#: runs load and its results regenerate; the zoo's YAML files give it the settings of :data:`ZONE_PATROL_ID`.
ZONE_PATROL_V0_ID = "ZonePatrol-v0"
#: Every environment id and the module whose ``parallel_env`` builds it.
ENV_MODULES: dict[str, str] = {ENV_ID: "wildlife_reserve.reserve_v1", ZONE_PATROL_ID: "wildlife_reserve.zone_patrol_v1",
                               ZONE_PATROL_V0_ID: "wildlife_reserve.zone_patrol_v0"}
#: The configuration class of each id (``module:class``): its ``from_kwargs`` checks arguments without building.
ENV_CONFIGS: dict[str, str] = {ENV_ID: "wildlife_reserve.reserve.config:ReserveConfig",
                               ZONE_PATROL_ID: "wildlife_reserve.zone_patrol.world:ZonePatrolConfig",
                               ZONE_PATROL_V0_ID: "wildlife_reserve.zone_patrol.world:ZonePatrolConfig"}


#: Former ids, still taken (with a warning, once per process), and the current id each gives: PettingZoo's rule, the
#: version rises whenever a change can change an episode, and the reserve kept ``v0`` from 0.1.0 to 0.20.0.
FORMER_ENV_IDS: dict[str, str] = {"WildlifeReserve-v0": ENV_ID}
_warned: set[str] = set()


def current_env_id(env_id: Any) -> Any:
    """``env_id``, or the current id a former one (:data:`FORMER_ENV_IDS`) now gives, warning once per process that
    its episodes differ from those the former id named at first."""
    if isinstance(env_id, str) and env_id in FORMER_ENV_IDS:
        current = FORMER_ENV_IDS[env_id]
        if env_id not in _warned:
            _warned.add(env_id)
            warnings.warn(f"{env_id} is the reserve's former id: its episodes differ from sb3-emmarl 0.1.0's {env_id}; "
                          f"it now gives {current}, the current version: use --env {current}", FutureWarning,
                          stacklevel=2)
        return current
    return env_id


def folder_ids(env_id: str) -> tuple[str, ...]:
    """The ids under which runs of ``env_id`` are saved (the zoo's ``<algo>/<id>_<n>/<id>.zip``): its own, then the
    former ids that now give it, whose runs (made before the id changed) load and play on ``env_id``."""
    return (env_id, *(former for former, current in FORMER_ENV_IDS.items() if current == env_id))


def check_env_id(env_id: Any) -> str:
    """``env_id`` if it is one of :data:`ENV_MODULES`' ids; a former id (:data:`FORMER_ENV_IDS`) gives its current one.

    :raise ValueError: naming the id and the known ones
    """
    env_id = current_env_id(env_id)
    if not isinstance(env_id, str) or env_id not in ENV_MODULES:
        raise ValueError(f"unknown environment id {env_id!r}; known: {sorted(ENV_MODULES)}")
    return env_id


def parallel_env_fn(env_id: str) -> Callable[..., Any]:
    """The ``parallel_env`` constructor of ``env_id`` (its keyword arguments are the environment's own).

    :raise ValueError: for an unknown id
    """
    return importlib.import_module(ENV_MODULES[check_env_id(env_id)]).parallel_env


def check_env_kwargs(env_id: str, env_kwargs: dict[str, Any]) -> None:
    """Check ``env_kwargs`` as ``env_id``'s configuration does, without building the environment.

    :raise ValueError: naming the argument (or for an unknown id)
    """
    module, name = ENV_CONFIGS[check_env_id(env_id)].split(":")
    try:
        getattr(importlib.import_module(module), name).from_kwargs(**env_kwargs)
    except TypeError as error:
        raise ValueError(str(error)) from None
