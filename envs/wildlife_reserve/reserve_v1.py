"""The wildlife reserve, as PettingZoo names an environment: :func:`~wildlife_reserve.reserve.reserve.env` (AEC),
:func:`~wildlife_reserve.reserve.reserve.parallel_env` (a :class:`~wildlife_reserve.reserve.reserve.ReserveParallelEnv`)
and :func:`~wildlife_reserve.reserve.reserve.raw_env`; its card is :mod:`wildlife_reserve.reserve.reserve`."""

from wildlife_reserve.reserve.reserve import env, parallel_env, raw_env

__all__ = ["env", "parallel_env", "raw_env"]
