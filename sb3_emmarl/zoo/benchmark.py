"""Benchmarks of trained teams against the random team on the same evaluation episodes (``zoo/benchmark.py``)."""

from __future__ import annotations

import argparse
import time

import numpy as np

from sb3_emmarl.common.centralized import ENV_ID
from sb3_emmarl.common.evaluation import RandomPolicy, evaluate_team, is_centralized, load_for_evaluation
from sb3_emmarl.common.statistics import paired_p_value
from sb3_emmarl.common.trust.arguments import OneLineParser
from sb3_emmarl.common.trust.validation import MAX_EPISODES, MAX_SEED, MAX_TIMESTEPS, int_flag
from sb3_emmarl.zoo.algos import ZOO_ALGOS
from sb3_emmarl.zoo.cli import KeyValues, latest_run, train_main
from sb3_emmarl.zoo.compare import run_settings

#: Metrics in the comparison table.
TABLE_METRICS = ("team_reward", "detection_rate", "coverage_efficiency", "poaching_events", "collisions")


def paired_comparison(trained: list[dict], reference: list[dict], metric: str) -> tuple[float, float, float]:
    """Mean of a metric for both teams over the same episodes, and the paired t-test's p-value."""
    a = np.array([r[metric] for r in trained], dtype=float)
    b = np.array([r[metric] for r in reference], dtype=float)
    return float(a.mean()), float(b.mean()), paired_p_value(a, b)


def benchmark_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(description="Train each algorithm, then compare it with the random team.")
    parser.add_argument("--algos", nargs="+", default=["ppo"], choices=sorted(ZOO_ALGOS), help="algorithms")
    parser.add_argument("-n", "--n-timesteps", type=int_flag(1, MAX_TIMESTEPS), default=3_000_000,
                        help="training budget in agent-steps")
    parser.add_argument("--seeds", type=int_flag(0, MAX_SEED), nargs="+", default=[0], help="training seeds")
    parser.add_argument("--eval-episodes", type=int_flag(2, MAX_EPISODES), default=20,
                        help="evaluation episodes (the same for every team; a paired test needs two)")
    parser.add_argument("--eval-seed", type=int_flag(0, MAX_SEED), default=50_000, help="seed of the evaluation episodes")
    parser.add_argument("-f", "--log-folder", default="logs/benchmark", help="where the trained runs are saved")
    parser.add_argument("--env-kwargs", type=str, nargs="+", action=KeyValues, help="reserve arguments, key:value")
    parser.add_argument("-params", "--hyperparams", type=str, nargs="+", action=KeyValues, help="hyperparameter overrides")
    return parser


def benchmark_main(argv: list[str] | None = None) -> int:
    """Train, evaluate trained and random teams on the same episodes, print the table."""
    parser = benchmark_parser()
    args = parser.parse_args(argv)
    env_kwargs = args.env_kwargs or {}
    rows = []
    for algo in args.algos:
        for seed in args.seeds:
            flags = ["--algo", algo, "-n", str(args.n_timesteps), "--seed", str(seed), "-f", args.log_folder,
                     "--eval-freq", "-1", "--team-eval-episodes", "0", "--verbose", "0"]
            if args.env_kwargs:
                flags += ["--env-kwargs", *[f"{k}:{v!r}" for k, v in env_kwargs.items()]]
            if args.hyperparams:
                flags += ["-params", *[f"{k}:{v!r}" for k, v in args.hyperparams.items()]]
            start = time.perf_counter()
            if train_main(flags) != 0:
                return 2
            wall = time.perf_counter() - start
            run = latest_run(args.log_folder, algo)
            model = load_for_evaluation(ZOO_ALGOS[algo], run / f"{ENV_ID}.zip", device="cpu")  # no threads here; harmless
            settings = run_settings(run)
            run_env_kwargs = settings["env_kwargs"]
            trained = evaluate_team(model, args.eval_episodes, seed=args.eval_seed, **settings)
            # The random team acts in the model's action space (per UAV, or joint for a centralised model).
            reference = evaluate_team(RandomPolicy(model.action_space, seed=seed), args.eval_episodes, seed=args.eval_seed,
                                      env_kwargs=run_env_kwargs)
            rows.append((algo, seed, wall, args.n_timesteps / wall, is_centralized(model, run_env_kwargs),
                         {m: paired_comparison(trained, reference, m) for m in TABLE_METRICS}))
    print(f"\n{args.eval_episodes} evaluation episodes from seed {args.eval_seed}, the same for the trained and the "
          f"random team (sampled actions); budget {args.n_timesteps:,} agent-steps; p: paired t-test over episodes")
    for algo, seed, wall, rate, centralized, comparison in rows:
        view = "centralised" if centralized else "parameter-shared"
        print(f"\n{algo} ({view}), seed {seed}: trained in {wall:.0f} s, {rate:,.0f} agent-steps/s")
        print(f"{'metric':<22}{'trained':>10}{'random':>10}{'p':>10}")
        for metric, (a, b, p) in comparison.items():
            print(f"{metric:<22}{a:>10.3f}{b:>10.3f}{p:>10.2g}")
    return 0
