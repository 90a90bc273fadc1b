"""A policy trained with one team size, run unchanged on reserves with other team sizes: its team metrics at each.

The reserve's observation does not depend on the team size (the window, the own features, a fixed number of
neighbour slots and coarse maps), nor do the neighbour messages of the graph-attention and transformer policies
(a fixed number of slots, nearest first), so a model trained with 10 UAVs acts on 20 or 50. Each size is
evaluated on the same seeded episodes for every model given; actions are sampled as ``evaluate_team`` does.

Example (a model of a comparison run, e.g. ``make benchmark-message-policies``)::

    python benchmarks/team_size_transfer.py --sizes 10 20 50 --episodes 5 \\
        --models ppo_gat=logs/compare/ppo_gat/seed_0/ppo_gat/WildlifeReserve-v1_1/WildlifeReserve-v1.zip
"""

from __future__ import annotations

import argparse
import sys

import numpy as np
import torch as th

from sb3_emmarl.common.evaluation import evaluate_team
from sb3_emmarl.common.model_files import load_model
from sb3_emmarl.zoo.algos import ZOO_ALGOS

METRICS = ("team_reward", "detection_rate", "coverage_efficiency", "collisions")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--models", nargs="+", required=True, metavar="ALGO=PATH", help="zoo algorithm and model zip")
    parser.add_argument("--sizes", type=int, nargs="+", default=[10, 20, 50], help="team sizes (n_uavs)")
    parser.add_argument("--episodes", type=int, default=5, help="evaluation episodes per size")
    parser.add_argument("--seed", type=int, default=60_000, help="seed of the evaluation episodes")
    args = parser.parse_args()
    if any(size < 1 for size in args.sizes) or args.episodes < 1:
        parser.error("--sizes and --episodes must be >= 1")
    th.set_num_threads(1)
    print(f"{'model':<18}{'n_uavs':>7}" + "".join(f"{m:>22}" for m in METRICS))
    for spec in args.models:
        algo, sep, path = spec.partition("=")
        if not sep or algo not in ZOO_ALGOS:
            parser.error(f"--models expects ALGO=PATH with ALGO among {sorted(ZOO_ALGOS)}, got {spec!r}")
        model = load_model(ZOO_ALGOS[algo], path, candidates=ZOO_ALGOS, device="cpu")
        for size in args.sizes:
            records = evaluate_team(model, args.episodes, seed=args.seed, env_kwargs={"n_uavs": size})
            cells = "".join(f"{np.mean([r[m] for r in records]):>13.3f} +- {np.std([r[m] for r in records]):<6.3f}"
                            for m in METRICS)
            print(f"{algo:<18}{size:>7}{cells}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
