"""ZonePatrol, as PettingZoo names an environment: :func:`~wildlife_reserve.zone_patrol.zone_patrol.env` (AEC),
:func:`~wildlife_reserve.zone_patrol.zone_patrol.parallel_env` (a
:class:`~wildlife_reserve.zone_patrol.zone_patrol.ZonePatrolParallelEnv`) and
:func:`~wildlife_reserve.zone_patrol.zone_patrol.raw_env`; its card is :mod:`wildlife_reserve.zone_patrol.zone_patrol`."""

from wildlife_reserve.zone_patrol.zone_patrol import env, parallel_env, raw_env

__all__ = ["env", "parallel_env", "raw_env"]
