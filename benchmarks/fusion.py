"""What fusing teammates' evidence along the links does to trained EM-PPO teams: the same models, fusion on and off.

Reads the runs that ``zoo/compare.py`` left (``<folder>/<variant>/seed_<s>/``), evaluates each model on the same
episodes with fusion on and with fusion off (``model.fusion``; only the beliefs at execution change), and prints
latent accuracy at 25%, 50% and 100% of an episode and the team reward for both, paired over seeds.

Example: ``python benchmarks/fusion.py -f logs/compare --seeds 0 1 2 3 4`` (after ``zoo/compare.py``)
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch as th

from sb3_emmarl.common.centralized import ENV_ID
from sb3_emmarl.common.evaluation import evaluate_team
from sb3_emmarl.zoo.algos import ZOO_ALGOS
from sb3_emmarl.zoo.benchmark import COMPARISON_EVAL_EPISODES, paired_p_value
from sb3_emmarl.zoo.exp_manager import read_yaml

METRICS = ("latent_accuracy_25", "latent_accuracy_50", "latent_accuracy_100", "team_reward")


def latest_run(folder: Path, algo: str) -> Path:
    runs = sorted((folder / algo).glob(f"{ENV_ID}_*"), key=lambda p: int(p.name.rsplit("_", 1)[1]))
    if not runs:
        raise FileNotFoundError(f"no {algo} run in {folder / algo}")
    return runs[-1]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("-f", "--folder", default="logs/compare", help="the comparison's log folder")
    parser.add_argument("--variant", default="em_ppo", help="the variant whose runs to evaluate")
    parser.add_argument("--algo", default="em_ppo", choices=["em_ppo", "em_ddpg"])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    parser.add_argument("--eval-episodes", type=int, default=COMPARISON_EVAL_EPISODES,
                        help="evaluation episodes per model and setting")
    parser.add_argument("--eval-seed", type=int, default=50_000)
    args = parser.parse_args(argv)
    th.set_num_threads(1)
    results: dict[bool, list[dict]] = {True: [], False: []}
    for seed in args.seeds:
        run = latest_run(Path(args.folder) / args.variant / f"seed_{seed}", args.algo)
        config = read_yaml(run / ENV_ID / "config.yml", "the run's config")
        model = ZOO_ALGOS[args.algo].load(run / f"{ENV_ID}.zip", device="cpu")
        for fusion in (True, False):
            model.fusion = fusion
            records = evaluate_team(model, args.eval_episodes, seed=args.eval_seed, env_kwargs=config.get("env_kwargs"))
            results[fusion].append({m: float(np.mean([r[m] for r in records])) for m in METRICS})
        print(f"seed {seed}: " + "  ".join(f"{m} {results[True][-1][m]:.3f}/{results[False][-1][m]:.3f}" for m in METRICS),
              flush=True)
    print(f"\n{args.variant}: {len(args.seeds)} trained models, {args.eval_episodes} evaluation episodes from seed "
          f"{args.eval_seed}, fusion on / off; mean +- std over seeds, paired t-test")
    print(f"{'metric':<22}{'fusion on':>18}{'fusion off':>18}{'difference':>12}{'p':>10}")
    for metric in METRICS:
        on = [r[metric] for r in results[True]]
        off = [r[metric] for r in results[False]]
        print(f"{metric:<22}{np.mean(on):>10.3f} +- {np.std(on):<5.3f}{np.mean(off):>10.3f} +- {np.std(off):<5.3f}"
              f"{np.mean(on) - np.mean(off):>12.3f}{paired_p_value(on, off):>10.3g}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
