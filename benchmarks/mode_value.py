"""How much knowing the hidden mode pays: PPO told the true mode against plain PPO, paired over seeds.

Both variants train with the zoo's ``ppo.yml`` settings (``oracle_ppo`` reads the same file) on the same
seeds, each run in a fresh process with one torch thread, then play the same evaluation episodes
(actions sampled, as ``evaluate_team`` does). The table gives mean +- std over seeds of each metric, the
paired difference (told minus plain) with its mean +- std, and the p-value of the paired t-test over seeds
(``scipy.stats.ttest_rel``), then the per-seed rows. The told-the-mode team is the upper bound every
latent method is measured against; the difference is what inferring the mode can win at most. Last, how
strongly each told run's networks read the one-hot (``tail_weight_norms``): a policy whose weights on it
stay far below its weights on the other inputs has barely learned to act on the mode.

Whether the mode *can* pay, whatever a learner makes of it, is measured first and without training:
the stalest-block patrol told the strategy (``ToldModePatrol``: it holds stations where the strategy's
poachers come from until their entry window closes) against the same patrol not told, on the same
``--patrol-episodes`` episodes, paired over episodes.

``--hide PART ...`` trains and evaluates both variants with those parts of the observation zeroed
(``sb3_emmarl.common.masking.HideObservationParts`` as the zoo's ``vec_env_wrapper``), for example
``--hide signs window.sign``: what knowing the mode pays to a team that cannot see the signs, where the
strategy shows. Give it its own ``-f``.

Example: ``python benchmarks/mode_value.py`` (or ``make benchmark-mode-value``; 5 seeds x 500k agent-steps)
"""

from __future__ import annotations

import argparse
import shlex
import sys
import time

from sb3_emmarl import OraclePPO
from sb3_emmarl.common.initialization import tail_weight_norms
from sb3_emmarl.common.masking import hidden_indices
from sb3_emmarl.zoo.benchmark import (
    COMPARISON_EVAL_EPISODES,
    add_run_arguments,
    check_run_arguments,
    paired_over_seeds,
    run_folder,
    run_variants,
)
from sb3_emmarl.zoo.cli import ENV_ID, latest_run
from wildlife_reserve import reserve_v0
from wildlife_reserve.reserve.modes import N_MODES
from wildlife_reserve.reserve.scripted import StalestBlockPatrol, ToldModePatrol, run_patrol

#: The two variants: (table name, zoo algorithm, hyperparameter overrides).
VARIANTS = [("told_mode", "oracle_ppo", []), ("ppo", "ppo", [])]
#: Metrics of the table.
METRICS = ("team_reward", "detection_rate", "coverage_efficiency")


def paired_table(results: dict[str, list[dict]], metrics: tuple[str, ...] = METRICS) -> str:
    """Mean +- std of each variant, and the paired difference (first variant minus second) with its p-value.

    :param results: ``{variant: [record per seed, same seed order for every variant]}``, two variants
    :param metrics: the metrics to compare
    :raises ValueError: if the two variants' seed lists differ (see :func:`~sb3_emmarl.zoo.benchmark.paired_over_seeds`)
    """
    (a_name, a_runs), (b_name, b_runs) = results.items()
    lines = [f"{'metric':<22}{a_name:>20}{b_name:>20}{'difference':>20}{'p (paired t)':>14}{'higher on':>11}"]
    for metric in metrics:
        test = paired_over_seeds(results, a_name, b_name, metric)
        a, b, diff = test.a, test.b, test.difference
        lines.append(f"{metric:<22}{a.mean():>11.3f} +- {a.std():<5.3f}{b.mean():>11.3f} +- {b.std():<5.3f}"
                     f"{diff.mean():>11.3f} +- {diff.std():<5.3f}{test.p_value:>14.3g}{test.higher_on:>11}")
    lines.append("")
    lines.append(f"{'seed':<6}" + "".join(f"{f'{name} {metric}':>34}" for name in (a_name, b_name) for metric in metrics))
    for a_run, b_run in zip(a_runs, b_runs):
        lines.append(f"{a_run['seed']:<6}" + "".join(f"{run[metric]:>34.3f}" for run in (a_run, b_run) for metric in metrics))
    return "\n".join(lines)


def patrol_comparison(episodes: int, seed: int, env_kwargs: dict | None = None) -> dict[str, list[dict]]:
    """The stalest-block patrol told the strategy and not told, on the same episodes (seeds ``seed, seed + 1, ...``).

    :return: ``{"told_mode": [metrics per episode], "not_told": [...]}``, each record with its episode's ``seed``
    """
    env = reserve_v0.parallel_env(**dict(env_kwargs or {}))
    results = {}
    for name, patrol in (("told_mode", ToldModePatrol), ("not_told", StalestBlockPatrol)):
        records = run_patrol(env, patrol(env), episodes, seed=seed)
        results[name] = [{**record, "seed": seed + i} for i, record in enumerate(records)]
    return results


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_run_arguments(parser, n_timesteps=500_000, seeds=[0, 1, 2, 3, 4], eval_episodes=COMPARISON_EVAL_EPISODES,
                      log_folder="logs/mode_value")
    parser.set_defaults(n_jobs=2)
    parser.add_argument("--patrol-episodes", type=int, default=300,
                        help="episodes of the scripted comparison (told the strategy or not); 0 skips it")
    parser.add_argument("--hide", nargs="+", metavar="PART", default=None,
                        help="observation parts both variants train and play without (zeroed): names of the "
                             "reserve's observation_layout or window.<channel>, e.g. signs window.sign")
    args = parser.parse_args(argv)
    check_run_arguments(parser, args)
    variants = VARIANTS
    if args.hide:
        env = reserve_v0.parallel_env(**dict(args.env_kwargs or {}))
        layout = env.observation_layout
        env.close()
        try:
            hidden_indices(layout, args.hide)
        except ValueError as error:
            parser.error(f"--hide: {error}")
        wrapper = {"sb3_emmarl.common.masking.HideObservationParts": {"parts": list(args.hide)}}
        variants = [(name, algo, [*params, f"vec_env_wrapper:{wrapper!r}"]) for name, algo, params in VARIANTS]
    if len(args.seeds) < 2:
        parser.error(f"--seeds must name at least 2 seeds for a paired test, got {args.seeds}")
    if args.patrol_episodes == 1 or args.patrol_episodes < 0:
        parser.error(f"--patrol-episodes must be 0 or >= 2 (a paired test), got {args.patrol_episodes}")
    command = shlex.join(["python", "benchmarks/mode_value.py", *(sys.argv[1:] if argv is None else argv)])
    print(f"$ {command}", flush=True)
    if args.patrol_episodes:
        patrols = patrol_comparison(args.patrol_episodes, args.eval_seed, args.env_kwargs)
        print(f"\nScripted: the stalest-block patrol told the strategy or not, {args.patrol_episodes} episodes from seed "
              f"{args.eval_seed}; mean +- std over episodes; p: paired t-test over episodes")
        print(paired_table(patrols, METRICS + ("poaching_events",)).split("\n\nseed")[0], flush=True)
    start = time.perf_counter()
    try:
        results = run_variants(variants, args)
    except (RuntimeError, ValueError) as error:
        print(error, file=sys.stderr)
        return 2
    hidden = f" without {' '.join(args.hide)} in the observation" if args.hide else ""
    print(f"\nPPO told the mode or not{hidden}: ppo.yml settings for both; {len(args.seeds)} seeds x "
          f"{args.n_timesteps:,} agent-steps per run; "
          f"{args.eval_episodes} evaluation episodes from seed {args.eval_seed} per run (actions sampled); "
          f"mean +- std over seeds; wall time {time.perf_counter() - start:.0f} s with {args.n_jobs} jobs")
    print(paired_table({name: results[name] for name, _, _ in VARIANTS}))
    print(mode_weight_table(args))
    return 0


def mode_weight_table(args: argparse.Namespace) -> str:
    """How strongly each told run's networks read the one-hot: the mean norm of a first-layer weight column on the
    mode against the other inputs' (:func:`~sb3_emmarl.common.initialization.tail_weight_norms`), per seed."""
    lines = ["\nHow strongly the told runs read the mode: mean norm of a first-layer weight column on the one-hot / on "
             "the other inputs (the policy's and the value's networks)",
             f"{'seed':<6}{'policy: mode':>14}{'other':>8}{'value: mode':>14}{'other':>8}"]
    for seed in args.seeds:
        run = latest_run(run_folder(args, VARIANTS[0][0], seed), VARIANTS[0][1])
        norms = tail_weight_norms(OraclePPO.load(run / f"{ENV_ID}.zip", device="cpu").policy, N_MODES)
        lines.append(f"{seed:<6}{norms['policy'][0]:>14.3f}{norms['policy'][1]:>8.3f}"
                     f"{norms['value'][0]:>14.3f}{norms['value'][1]:>8.3f}")
    return "\n".join(lines)


if __name__ == "__main__":
    raise SystemExit(main())
