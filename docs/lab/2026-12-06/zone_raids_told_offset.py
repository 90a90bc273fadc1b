"""Lab (2026-12-06): does PPO act on the mode on the zone raids when it is told *where to go* rather than *which mode*?

Told PPO (a one-hot of the mode appended) hardly reads the mode on the zone raids at 1M agent-steps (docs/zone_raids.md,
the pilot). This variant appends instead the offset from the UAV to its strategy's zone (2 floats: the row of the zone
compass that the mode selects), so that acting on the mode needs no product of one-hot and compass. Evaluated as the
benchmark evaluates (200 held-out team episodes from seed 50,000) and again told the next zone (a wrong one).

Usage: ``python docs/lab/2026-12-06/zone_raids_told_offset.py SEED [BUDGET] [FOLDER]``; one JSON per run in FOLDER.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "benchmarks"))
import zone_patrol_value as bench

from sb3_emmarl.common.mode_aware import ModeObservationWrapper
from wildlife_reserve import reserve_v1
from wildlife_reserve.reserve.modes import N_MODES


class ToldZoneOffset(ModeObservationWrapper):
    """Appends each UAV's offset to the zone of its episode's strategy (``shift`` zones on: a wrong one): the told
    wrapper's modes, relabelled by the shift, in another form (:meth:`ModeObservationWrapper._append`)."""

    def __init__(self, venv, shift: int = 0) -> None:
        self.zones = reserve_v1.parallel_env(scenario="zone_raids").observation_layout["zones"][0]
        super().__init__(venv, relabel=[2 * ((m // 2 + shift) % 4) + m % 2 for m in range(N_MODES)])

    def _bounds(self, dtype):
        return -np.ones(2, dtype), np.ones(2, dtype)

    def _append(self, observations: np.ndarray, told: np.ndarray) -> np.ndarray:
        return observations[:, self.zones].reshape(len(observations), 4, 2)[np.arange(len(observations)), told // 2]


def main() -> None:
    import torch as th

    from sb3_emmarl.common.env_ids import ENV_ID
    from sb3_emmarl.zoo.exp_manager import zoo_model

    th.set_num_threads(1)
    seed = int(sys.argv[1])
    budget = int(sys.argv[2]) if len(sys.argv) > 2 else 1_000_000
    folder = Path(sys.argv[3] if len(sys.argv) > 3 else "logs/zone_raids_told_offset")
    folder.mkdir(parents=True, exist_ok=True)
    model = zoo_model("ppo", ToldZoneOffset(bench.make_env(seed, task="zone_raids")), seed, ENV_ID)
    start = time.perf_counter()
    model.learn(budget)
    seconds = time.perf_counter() - start
    right = bench.play(model, ToldZoneOffset(bench.make_env(bench.EVAL_SEED, task="zone_raids")), 200,
                       bench.EVAL_SEED)[0]
    wrong = bench.play(model, ToldZoneOffset(bench.make_env(bench.EVAL_SEED, task="zone_raids"), shift=1), 200,
                       bench.EVAL_SEED)[0]
    record = {"seed": seed, "budget": budget, "seconds": seconds, "team_reward": right, "wrong_zone_1": wrong}
    (folder / f"told_offset_{seed}.json").write_text(json.dumps(record))
    print(f"seed {seed}: told the zone's offset {np.mean(right):.3f}, told the next zone's {np.mean(wrong):.3f} "
          f"({seconds:.0f} s)")


if __name__ == "__main__":
    main()
