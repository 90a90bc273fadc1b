"""Lab (2026-12-06): does told PPO separate from PPO on the zone raids with more agent-steps?

The pilot (docs/zone_raids.md) found told PPO and PPO alike at 1M agent-steps, both far below the scripted blind team
(28-32 against 82). This trains one variant of ``benchmarks/zone_patrol_value.py`` (its zoo settings, its seed) in
stages and evaluates it after each on the benchmark's 200 held-out team episodes (seed 50,000); told PPO is also
evaluated told the next zone (a wrong one), which says whether it reads what it is told. One JSON per run in FOLDER,
rewritten after every stage (a crash loses one stage at most).

Usage: ``python docs/lab/2026-12-06/zone_raids_budget_curve.py VARIANT SEED [BUDGET] [STAGE] [FOLDER]``.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "benchmarks"))
import zone_patrol_value as bench

TASK = "zone_raids"


def main() -> None:
    import torch as th

    from sb3_emmarl.common.checkpoints import write_text

    th.set_num_threads(1)
    variant, seed = sys.argv[1], int(sys.argv[2])
    budget = int(float(sys.argv[3])) if len(sys.argv) > 3 else 4_000_000
    stage = int(float(sys.argv[4])) if len(sys.argv) > 4 else 1_000_000
    folder = Path(sys.argv[5] if len(sys.argv) > 5 else "logs/zone_raids_budget_curve")
    folder.mkdir(parents=True, exist_ok=True)
    model = bench.build(variant, seed, task=TASK)
    wrap = getattr(model, "wrap_env", lambda v: v)
    record: dict = {"variant": variant, "seed": seed, "stage": stage, "stages": []}
    seconds = 0.0
    while model.num_timesteps < budget:
        start = time.perf_counter()
        model.learn(stage, reset_num_timesteps=False)
        seconds += time.perf_counter() - start
        row = {"agent_steps": int(model.num_timesteps), "seconds": seconds,
               "team_reward": bench.play(model, wrap(bench.make_env(bench.EVAL_SEED, task=TASK)), 200,
                                         bench.EVAL_SEED)[0]}
        if variant == "told":
            row["wrong_zone_1"] = bench.play(model, bench.wrong(bench.WRONG["wrong_zone_1"], task=TASK)(), 200,
                                             bench.EVAL_SEED)[0]
        record["stages"].append(row)
        write_text(folder / f"{variant}_{seed}.json", json.dumps(record))
        told = f", told the next zone {np.mean(row['wrong_zone_1']):.2f}" if "wrong_zone_1" in row else ""
        print(f"{variant} seed {seed} at {row['agent_steps']:,}: {np.mean(row['team_reward']):.2f}{told} "
              f"({seconds:.0f} s)", flush=True)


if __name__ == "__main__":
    main()
