"""The UAV sensor model: thermal, visual and motion sensors with occlusion, weather and corruption.

Each sensor fires independently; a target is detected when any of them fires, so the detection
probability is ``1 - (1 - p_visual)(1 - p_thermal)(1 - p_motion)``. Signs of poacher activity are
seen by the visual sensor alone. The whole noise model lives here: detection, false-alarm, decoy and sign
probabilities (as tables over distance and terrain) and the noise on the signal channels
(:data:`SIGNAL_NOISE_STD`); the compiled loops that apply them to a step's draws are ``kernels.sense`` and
``kernels.noisy_signals``.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from wildlife_reserve.reserve.modes import Weather
from wildlife_reserve.reserve.terrain import THERMAL_OCCLUSION, VISUAL_OCCLUSION

#: Peak probability of the thermal sensor (at range <= 1, no occlusion).
THERMAL_PEAK = 0.6
#: Peak probability of the motion sensor, for a target that moved this step.
MOTION_PEAK = 0.4
#: Chance per UAV-step of a false alarm with clean sensors.
FALSE_ALARM_BASE = 0.002
#: Extra false-alarm chance per UAV-step per unit of sensor noise.
FALSE_ALARM_PER_NOISE = 0.05
#: Chance that a decoy in range reads as a poacher (adversarial condition), times the range falloff.
DECOY_PEAK = 0.5
#: Peak probability of seeing a sign of poacher activity (at range <= 1, open ground, clear weather).
SIGN_PEAK = 1.0
#: Standard deviation of the noise on the signal channels per unit of ``sensor_noise``.
SIGNAL_NOISE_STD = 0.3


def effective_radius(sensor_radius: int, weather: Weather) -> int:
    """Chebyshev radius within which anything is sensed: fog shrinks it (never below 1).

    :param sensor_radius: nominal sensor radius in cells
    :param weather: the episode's weather
    """
    return max(1, int(np.ceil(weather.range_factor * sensor_radius)))


def range_falloff(dist: np.ndarray, sensor_radius: int, reach: int) -> np.ndarray:
    """1 within one cell, falling linearly to 0.5 at the nominal radius, 0 beyond ``reach``.

    :param dist: Chebyshev distances in cells
    :param sensor_radius: nominal sensor radius
    :param reach: effective radius (see :func:`effective_radius`)
    """
    falloff = 1.0 - 0.5 * np.maximum(dist - 1, 0) / max(sensor_radius, 1)
    return np.where(dist <= reach, falloff, 0.0)


def detection_probability(
    dist: np.ndarray,
    terrain: np.ndarray,
    moved: np.ndarray,
    sensor_radius: int,
    weather: Weather,
    noise: float,
) -> np.ndarray:
    """Chance that a UAV detects a ground target this step.

    :param dist: Chebyshev distance UAV -> target, in cells
    :param terrain: terrain type under the target
    :param moved: whether the target moved this step (motion sensor)
    :param sensor_radius: nominal sensor radius
    :param weather: the episode's weather
    :param noise: sensor corruption level in [0, 1]; scales every probability by ``1 - noise / 2``
    """
    base = range_falloff(dist, sensor_radius, effective_radius(sensor_radius, weather))
    visual = base * (1.0 - VISUAL_OCCLUSION[terrain]) * weather.visual
    thermal = THERMAL_PEAK * base * (1.0 - THERMAL_OCCLUSION[terrain]) * weather.thermal
    motion = MOTION_PEAK * base * moved * (1.0 - VISUAL_OCCLUSION[terrain]) * weather.visual
    p = 1.0 - (1.0 - visual) * (1.0 - thermal) * (1.0 - motion)
    return p * (1.0 - 0.5 * noise)


def detection_table(sensor_radius: int, weather: Weather, noise: float) -> np.ndarray:
    """:func:`detection_probability` tabulated as ``table[distance, terrain, moved]``.

    Distances beyond ``sensor_radius`` share the last row (probability 0), so a lookup clips the
    distance to ``sensor_radius + 1``.

    :param sensor_radius: nominal sensor radius
    :param weather: the episode's weather
    :param noise: sensor corruption level in [0, 1]
    """
    dist = np.arange(sensor_radius + 2)[:, None, None]
    terrain = np.arange(len(VISUAL_OCCLUSION))[None, :, None]
    moved = np.array([0.0, 1.0])[None, None, :]
    return detection_probability(dist, terrain, moved, sensor_radius, weather, noise)


def false_alarm_probability(noise: float) -> float:
    """Chance per UAV-step of a spurious poacher reading.

    :param noise: sensor corruption level in [0, 1]
    """
    return FALSE_ALARM_BASE + FALSE_ALARM_PER_NOISE * noise


def sign_detection_table(sensor_radius: int, weather: Weather, noise: float) -> np.ndarray:
    """Chance that a UAV sees a sign, as ``table[distance, terrain]`` (distances clipped to ``sensor_radius + 1``).

    ``SIGN_PEAK * f(d) * (1 - visual occlusion) * weather.signs * (1 - noise / 2)``.

    :param sensor_radius: nominal sensor radius
    :param weather: the episode's weather
    :param noise: sensor corruption level in [0, 1]
    """
    dist = np.arange(sensor_radius + 2)[:, None]
    base = range_falloff(dist, sensor_radius, effective_radius(sensor_radius, weather))
    return SIGN_PEAK * base * (1.0 - VISUAL_OCCLUSION[None, :]) * weather.signs * (1.0 - 0.5 * noise)


def decoy_table(sensor_radius: int, reach: int, noise: float) -> np.ndarray:
    """Chance that a decoy reads as a poacher (adversarial condition), ``DECOY_PEAK * f(d) * (1 - noise / 2)`` as
    ``table[distance]`` (terrain and weather do not apply; distances clipped to ``reach + 1``, where it is 0).

    :param sensor_radius: nominal sensor radius
    :param reach: effective radius (see :func:`effective_radius`)
    :param noise: sensor corruption level in [0, 1]
    """
    return DECOY_PEAK * range_falloff(np.arange(reach + 2), sensor_radius, reach) * (1 - 0.5 * noise)



class SensorTables(NamedTuple):
    """What the sensors read in one weather (:func:`sensor_tables`): the ``reach`` (:func:`effective_radius`), the
    window offsets within it ``reach_offsets`` ``(k, 2)``, the :func:`detection_table`, the :func:`decoy_table` and the
    :func:`sign_detection_table` by window cell ``sign`` ``(w * w, terrain types)``."""

    reach: int
    reach_offsets: np.ndarray
    detection: np.ndarray
    decoy: np.ndarray
    sign: np.ndarray


def sensor_tables(sensor_radius: int, weather: Weather, sensor_noise: float) -> SensorTables:
    """The :class:`SensorTables` of ``weather``.

    :param sensor_radius: nominal sensor radius
    :param weather: the episode's weather
    :param sensor_noise: sensor corruption level in [0, 1]
    """
    offsets = np.arange(-sensor_radius, sensor_radius + 1)
    ring = np.maximum(np.abs(offsets)[:, None], np.abs(offsets)[None, :])  # each window cell's Chebyshev distance
    reach = effective_radius(sensor_radius, weather)
    # Readings (true or false) come from within the weather's reach; the whole window counts as flown over.
    return SensorTables(reach=reach, reach_offsets=np.argwhere(ring <= reach) - sensor_radius,
                        detection=detection_table(sensor_radius, weather, sensor_noise),
                        decoy=decoy_table(sensor_radius, reach, sensor_noise),
                        sign=sign_detection_table(sensor_radius, weather, sensor_noise)[ring.ravel()])


def signal_noise(sensor_noise: float) -> float:
    """The standard deviation of the noise on the signal channels at ``sensor_noise`` (:data:`SIGNAL_NOISE_STD` per
    unit)."""
    return SIGNAL_NOISE_STD * sensor_noise
