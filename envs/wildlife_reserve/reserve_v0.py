"""The reserve's former name, kept so that old code runs: importing it warns once and gives
:mod:`wildlife_reserve.reserve_v1`'s environments.

The reserve kept the name ``reserve_v0`` from its first release on while its observation grew from 440 to 553 floats
and its dynamics changed many times, so a ``reserve_v0`` episode of today is not one of the first release. Following
PettingZoo's rule (the version rises whenever a change can change an episode), the environment is now ``reserve_v1``
(the environment card's version history says what changed when).
"""

import warnings

from wildlife_reserve.reserve_v1 import env, parallel_env, raw_env

warnings.warn("wildlife_reserve.reserve_v0 is the reserve's former name: its episodes differ from sb3-emmarl 0.1.0's "
              "reserve_v0 (the observation and dynamics changed); this alias gives reserve_v1, the current version: "
              "import wildlife_reserve.reserve_v1", FutureWarning, stacklevel=2)

__all__ = ["env", "parallel_env", "raw_env"]
