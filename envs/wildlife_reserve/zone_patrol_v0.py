"""ZonePatrol's first version (``zone_cue=0``, ``comm_range=4``:
:data:`~wildlife_reserve.zone_patrol.zone_patrol.FORMER_DEFAULTS`), kept so that its episodes and results can be
regenerated; the current version is :mod:`wildlife_reserve.zone_patrol_v1` (the card's version history says what
changed). Each function takes the current version's keyword arguments, with version 0's defaults under them."""

from typing import Any

from pettingzoo.utils import wrappers
from pettingzoo.utils.conversions import parallel_to_aec_wrapper

from wildlife_reserve.zone_patrol import zone_patrol
from wildlife_reserve.zone_patrol.zone_patrol import ZonePatrolParallelEnv

__all__ = ["env", "parallel_env", "raw_env"]


def env(**kwargs: Any) -> wrappers.OrderEnforcingWrapper:
    """The AEC form of version 0, with PettingZoo's order-enforcing wrapper."""
    return zone_patrol.env(0, **kwargs)


def raw_env(**kwargs: Any) -> parallel_to_aec_wrapper:
    """The AEC form of version 0."""
    return zone_patrol.raw_env(0, **kwargs)


def parallel_env(version: int = 0, **kwargs: Any) -> ZonePatrolParallelEnv:
    """The parallel environment of version 0 (another ``version`` is refused: import that version's module)."""
    if version != 0:
        raise ValueError(f"zone_patrol_v0 builds version 0, got version={version!r}: import wildlife_reserve.zone_patrol_v"
                         f"{version}")
    return zone_patrol.parallel_env(0, **kwargs)
