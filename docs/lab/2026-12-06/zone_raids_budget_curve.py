"""Lab (2026-12-06): does told PPO separate from PPO on the zone raids with more agent-steps?

The pilot (docs/zone_raids.md) found told PPO and PPO alike at 1M agent-steps, both far below the scripted blind team
(28-32 against 82). This trains one variant of ``benchmarks/zone_patrol_value.py`` (its zoo settings, its seed) in
stages and evaluates it after each on the benchmark's 200 held-out team episodes (seed 50,000); told PPO is also
evaluated told the next zone (a wrong one), which says whether it reads what it is told. One JSON per run in FOLDER,
rewritten after every stage (a crash loses one stage at most).

Usage: ``python docs/lab/2026-12-06/zone_raids_budget_curve.py VARIANT SEED [--budget N] [--stage N] [--folder F]
[--env-kwargs JSON]``.
"""

from __future__ import annotations

import argparse
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

    from sb3_emmarl.common.trust.atomic_files import write_text

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("variant", choices=bench.VARIANTS)
    parser.add_argument("seed", type=int)
    parser.add_argument("--budget", type=float, default=4e6, help="agent-steps in all")
    parser.add_argument("--stage", type=float, default=1e6, help="agent-steps between evaluations")
    parser.add_argument("--folder", default="logs/zone_raids_budget_curve")
    parser.add_argument("--env-kwargs", type=json.loads, default={}, help='the scenario\'s arguments beyond it, as JSON: '
                        "'{\"shaping\": 0.5}'")
    args = parser.parse_args()
    th.set_num_threads(1)
    variant, seed, budget, stage = args.variant, args.seed, int(args.budget), int(args.stage)
    folder = Path(args.folder)
    folder.mkdir(parents=True, exist_ok=True)
    model = bench.build(variant, seed, args.env_kwargs, task=TASK)
    wrap = getattr(model, "wrap_env", lambda v: v)
    record: dict = {"variant": variant, "seed": seed, "stage": stage, "env_kwargs": args.env_kwargs, "stages": []}
    seconds = 0.0
    while model.num_timesteps < budget:
        start = time.perf_counter()
        model.learn(stage, reset_num_timesteps=False)
        seconds += time.perf_counter() - start
        evaluation = wrap(bench.make_env(bench.EVAL_SEED, env_kwargs=args.env_kwargs, task=TASK))
        row = {"agent_steps": int(model.num_timesteps), "seconds": seconds,
               "team_reward": bench.play(model, evaluation, 200, bench.EVAL_SEED)[0]}
        if variant == "told":
            wrong = bench.wrong(bench.WRONG["wrong_zone_1"], args.env_kwargs, task=TASK)()
            row["wrong_zone_1"] = bench.play(model, wrong, 200, bench.EVAL_SEED)[0]
        record["stages"].append(row)
        name = f"{variant}_{seed}" + "".join(f"_{k}_{v}" for k, v in sorted(args.env_kwargs.items()))
        write_text(folder / f"{name}.json", json.dumps(record))
        told = f", told the next zone {np.mean(row['wrong_zone_1']):.2f}" if "wrong_zone_1" in row else ""
        print(f"{variant} seed {seed} at {row['agent_steps']:,}: {np.mean(row['team_reward']):.2f}{told} "
              f"({seconds:.0f} s)", flush=True)


if __name__ == "__main__":
    main()
