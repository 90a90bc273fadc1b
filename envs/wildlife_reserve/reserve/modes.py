"""The hidden scenario mode ``z*``: poacher strategy x weather.

Mode ``m`` decodes as ``strategy = m // len(WEATHERS)`` and ``weather = m % len(WEATHERS)``.
The UAVs never observe it; it decides where and when poachers enter, how they move and how
well the sensors see, so a team that infers it from its history can act on it.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class PoacherStrategy:
    """How the poachers of one episode behave.

    :param name: strategy name
    :param entry: where they enter: ``"near_den"`` (the edge point closest to a den), ``"one_side"``
        (anywhere along one side chosen per episode), ``"group"`` (one point, together) or
        ``"perimeter"`` (anywhere on the perimeter)
    :param entry_window: entry times as fractions of ``max_cycles``
    :param move_prob: chance per step of a step toward the target
    :param wander_prob: chance per step of a random step (otherwise they wait)
    :param evasion_prob: chance per step of evading a UAV they notice
    :param hide_in_cover: evade by standing still when on forest or mountain (else flee)
    """

    name: str
    entry: str
    entry_window: tuple[float, float]
    move_prob: float
    wander_prob: float
    evasion_prob: float
    hide_in_cover: bool


@dataclass(frozen=True)
class Weather:
    """Sensing conditions of one episode.

    :param name: weather name
    :param visual: factor on visual and motion detection probability
    :param thermal: factor on thermal detection probability
    :param range_factor: share of the sensor radius within which anything is detected
    :param notice_factor: factor on the radius within which poachers notice UAVs
    :param signs: factor on the chance of seeing signs of poacher activity
    """

    name: str
    visual: float
    thermal: float
    range_factor: float
    notice_factor: float
    signs: float


STRATEGIES: tuple[PoacherStrategy, ...] = (
    # Early, fast, straight for the dens from the nearest edge.
    PoacherStrategy("hotspot_raid", "near_den", (0.02, 0.35), move_prob=0.9, wander_prob=0.05, evasion_prob=0.2,
                    hide_in_cover=False),
    # Along one side, slow and cautious, hiding in cover.
    PoacherStrategy("edge_infiltration", "one_side", (0.1, 0.6), move_prob=0.4, wander_prob=0.4, evasion_prob=0.5,
                    hide_in_cover=True),
    # All at once, from one point, together toward one den.
    PoacherStrategy("coordinated_group", "group", (0.1, 0.5), move_prob=0.8, wander_prob=0.1, evasion_prob=0.3,
                    hide_in_cover=False),
    # Anywhere on the perimeter, late and spread out, wandering and evasive.
    PoacherStrategy("dispersed_evasion", "perimeter", (0.3, 0.9), move_prob=0.3, wander_prob=0.5, evasion_prob=0.9,
                    hide_in_cover=True),
)

WEATHERS: tuple[Weather, ...] = (
    Weather("clear", visual=1.0, thermal=1.0, range_factor=1.0, notice_factor=1.0, signs=1.0),
    Weather("fog", visual=0.35, thermal=0.8, range_factor=0.6, notice_factor=0.5, signs=0.6),
)

N_MODES = len(STRATEGIES) * len(WEATHERS)
MODE_NAMES: tuple[str, ...] = tuple(f"{s.name}/{w.name}" for s in STRATEGIES for w in WEATHERS)


def decode_mode(mode: int) -> tuple[PoacherStrategy, Weather]:
    """Split a mode index into its poacher strategy and weather.

    :param mode: mode index in ``[0, N_MODES)``
    """
    if not 0 <= int(mode) < N_MODES:
        raise ValueError(f"mode must be None or an int in [0, {N_MODES - 1}], got {mode!r}")
    return STRATEGIES[int(mode) // len(WEATHERS)], WEATHERS[int(mode) % len(WEATHERS)]


def encode_mode(strategy: int, weather: int) -> int:
    """The mode index of a poacher strategy and a weather (their indices in :data:`STRATEGIES` and :data:`WEATHERS`):
    the inverse of :func:`decode_mode`."""
    if not (0 <= int(strategy) < len(STRATEGIES) and 0 <= int(weather) < len(WEATHERS)):
        raise ValueError(f"strategy must be in [0, {len(STRATEGIES) - 1}] and weather in [0, {len(WEATHERS) - 1}], "
                         f"got {strategy!r} and {weather!r}")
    return int(strategy) * len(WEATHERS) + int(weather)


def next_strategy(mode: int) -> int:
    """The mode with the next poacher strategy (cyclically) and the same weather: a wrong strategy for every mode,
    for telling a policy a wrong mode (see ``sb3_emmarl.common.mode_aware.ModeObservationWrapper``'s ``relabel``)."""
    strategy, weather = decode_mode(mode)
    return encode_mode((STRATEGIES.index(strategy) + 1) % len(STRATEGIES), WEATHERS.index(weather))
