"""The reserve's hot loops, compiled with numba, one module per phase of a step.

At 10 UAVs a step of the reserve is dominated by fixed numpy call overhead on small arrays, not by
arithmetic; these loops replace chains of small array operations with compiled code, and a step after
the actions' decoding is one compiled call (:func:`~wildlife_reserve.reserve.kernels.world.advance_world`). Each kernel
computes exactly what the numpy expression in its docstring computes (same float32/float64 arithmetic, same random
draws: numpy's own generator, called from compiled code through ``stream.handle``), so results are bit-identical.

================ ===================================================================================================
module           what it holds
================ ===================================================================================================
``records``      the named records a step reads and updates (:class:`World` by phase, the :class:`Step`)
``flight``       the actions decoded, the UAVs' flight, energy, windows and collisions
``ground``       the leopards and poachers: entry, moves, evasion, poaching; the jammer's travel
``signs``        the signs' records: placed on and off the grid, in the windows, learned
``sensing``      detections, false alarms, decoys, sign sightings, the signal noise
``team``         staleness, looks, links, beacons, messages, the jammer's silence, the readings record
``observe``      every UAV's observation and belief
``world``        :func:`advance_world` (the phases in order) and the rewards
================ ===================================================================================================

Compiled code is cached beside the modules (``cache=True``, in ``kernels/__pycache__``): the first episode on a
machine compiles them, later processes load the cache. numba checks a cached kernel against its own module's file
only, not against the modules it calls into: after editing a phase module, delete ``kernels/__pycache__`` (or the
``*.nbi``/``*.nbc`` files there), else :func:`advance_world` keeps the machine code of the old phase.
"""

from __future__ import annotations

from wildlife_reserve.reserve.kernels.flight import (
    collisions,
    decode_actions,
    fly,
    fly_and_collide,
    place_windows,
)
from wildlife_reserve.reserve.kernels.ground import (
    enter_poachers,
    move_ground_actors,
    move_jammer,
    move_leopards,
    move_poachers,
    poach,
    poacher_targets,
    poaching_timers,
)
from wildlife_reserve.reserve.kernels.observe import (
    beliefs,
    fill_observations,
)
from wildlife_reserve.reserve.kernels.records import (
    Candidates,
    Coverage,
    Flight,
    Ground,
    Jammer,
    Leopards,
    Looks,
    Observe,
    Poachers,
    Rewards,
    Sensing,
    SignRecords,
    Spots,
    Step,
    StepOutcome,
    Talk,
    Tally,
    Team,
    World,
)
from wildlife_reserve.reserve.kernels.sensing import (
    decoy_reading_cells,
    detection_probabilities,
    false_reading_cells,
    noisy_signals,
    record_readings,
    see_signs,
    sense,
)
from wildlife_reserve.reserve.kernels.signs import (
    add_signs_off_grid,
    learn_signs,
    place_new_signs,
    place_signs,
    sign_candidates,
)
from wildlife_reserve.reserve.kernels.team import (
    deliver,
    jam,
    known_ages,
    known_block_ages,
    links_in_range,
    look,
    look_and_talk,
    merge_messages,
    record_readings_seen,
    sender_masks,
    senders_by_receiver,
)
from wildlife_reserve.reserve.kernels.world import (
    ActionError,
    advance_world,
    named,
    pairwise_sum,
    plain,
    step_rewards,
)

__all__ = [
    "ActionError",
    "Candidates",
    "Coverage",
    "Flight",
    "Ground",
    "Jammer",
    "Leopards",
    "Looks",
    "Observe",
    "Poachers",
    "Rewards",
    "Sensing",
    "SignRecords",
    "Spots",
    "Step",
    "StepOutcome",
    "Talk",
    "Tally",
    "Team",
    "World",
    "add_signs_off_grid",
    "advance_world",
    "beliefs",
    "collisions",
    "decode_actions",
    "decoy_reading_cells",
    "deliver",
    "detection_probabilities",
    "enter_poachers",
    "false_reading_cells",
    "fill_observations",
    "fly",
    "fly_and_collide",
    "jam",
    "known_ages",
    "known_block_ages",
    "learn_signs",
    "links_in_range",
    "look",
    "look_and_talk",
    "merge_messages",
    "move_ground_actors",
    "move_jammer",
    "move_leopards",
    "move_poachers",
    "named",
    "noisy_signals",
    "pairwise_sum",
    "place_new_signs",
    "place_signs",
    "place_windows",
    "plain",
    "poach",
    "poacher_targets",
    "poaching_timers",
    "record_readings",
    "record_readings_seen",
    "see_signs",
    "sender_masks",
    "senders_by_receiver",
    "sense",
    "sign_candidates",
    "step_rewards",
]
