"""How much knowing the hidden mode pays: PPO told the true mode against plain PPO, paired over seeds.

Both variants train with the zoo's ``ppo.yml`` settings (``oracle_ppo`` reads the same file) on the same
seeds, each run in a fresh process with one torch thread, then play the same evaluation episodes
(actions sampled, as ``evaluate_team`` does). The table gives mean +- std over seeds of each metric, the
paired difference (told minus plain) with its mean +- std, and the p-value of the paired t-test over seeds
(``scipy.stats.ttest_rel``), then the per-seed rows. The told-the-mode team is the upper bound every
latent method is measured against; the difference is what inferring the mode can win at most. Last, how
strongly each told run's networks read the one-hot (``tail_weight_norms``): a policy whose weights on it
stay far below its weights on the other inputs has barely learned to act on the mode.

Whether the mode *can* pay, whatever a learner makes of it, is measured first and without training, on
station patrols (``StationPatrol``: hold stations around the dens or the roads' entry points until a point of
the episode, then sweep as the stalest-block patrol does; the plans of ``STATION_PLANS``). Every plan plays
``--patrol-episodes`` fitting episodes (seeds ``FIT_SEED, FIT_SEED + 1, ...``); the best plan per poacher strategy
there is the team told the strategy, the best single plan the team not told. Both then play the same held-out
episodes (from ``--eval-seed``), paired over episodes: the difference is what knowing the strategy pays to
this family of teams, measured on episodes the choice did not see. The plain told-or-not comparison (the
told patrol, ``ToldModePatrol``, against the stalest-block patrol) credits the mode with what holding
stations pays in every mode; this one does not. Last, how many seeds a paired test of PPO would need to find a
gain of that size at PPO's spread over seeds (``seeds_needed``).

``--hide PART ...`` trains and evaluates both variants with those parts of the observation zeroed
(``sb3_emmarl.common.masking.HideObservationParts`` as the zoo's ``vec_env_wrapper``), for example
``--hide signs window.sign``: what knowing the mode pays to a team that cannot see the signs, where the
strategy shows. Give it its own ``-f``.

Told PPO reads an input that plain PPO does not have, constant over an episode: whatever such an input costs PPO to
learn with is in told minus plain PPO too. The control (``told_random``, ``--no-control`` skips it) is PPO told a label
drawn at random per episode instead of the mode (``OraclePPO(random_label=True)``): the same input, no information.
Told PPO against it is what the mode's information is worth apart from that cost; the control against PPO is the cost.

Whether told PPO acts on what it is told, run by run: every told run plays the evaluation episodes again told a
wrong strategy (the next one, cyclically, in the same weather: ``next_strategy``), and the mode-use table pairs the two
over seeds. A policy that acts on the mode scores less when told a wrong one; one that ignores it scores the same.
Unlike told against plain PPO, this compares one trained network with itself, so the seeds' spread in what they
learned drops out of the difference.

``-params key:value ...`` gives both variants the same hyperparameter overrides of ``ppo.yml`` (the zoo's
``-params``), for example ``-params n_epochs:10 ent_coef:0.03``. Give it its own ``-f``.

Whether PPO can act on the mode at all, wherever it pays: ``--env-kwargs coverage_sectors:True
"reward_weights:{'coverage':0.2}"`` makes the coverage term pay only in the sector of the episode's poacher strategy,
which nothing a UAV observes marks (the reserve's ``coverage_sectors``): the strategy alone decides where about half
of what a trained team earns lies, and the mode-use table tells whether the told runs go there
(docs/lab/results-history.md, "On 0.18.9"). Give it its own ``-f``.

``--scripted-only`` stops after the scripted part: with ``--env-kwargs`` it tells in a few minutes how much a
candidate reserve's mode can pay, before any training on it.

Example: ``python benchmarks/mode_value.py`` (or ``make benchmark-mode-value``; 5 seeds x 500k agent-steps);
``python benchmarks/mode_value.py --scripted-only --env-kwargs n_poachers:8``
"""

from __future__ import annotations

import argparse
import shlex
import sys
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np
import torch as th

from sb3_emmarl import OraclePPO
from sb3_emmarl.common.appended.initialization import tail_weight_norms
from sb3_emmarl.common.masking import hidden_indices
from sb3_emmarl.common.statistics import seeds_needed
from sb3_emmarl.zoo.cli import ENV_ID, latest_run, parse_key_values
from sb3_emmarl.zoo.compare import (
    COMPARISON_EVAL_EPISODES,
    add_run_arguments,
    check_run_arguments,
    evaluate_run,
    paired_over_seeds,
    run_folder,
    run_variants,
)
from wildlife_reserve import reserve_v1
from wildlife_reserve.reserve.modes import N_MODES, STRATEGIES, decode_mode, next_strategy
from wildlife_reserve.reserve.scripted import STATION_SPOTS, StationPlan, play_station_plan

#: The variants: (table name, zoo algorithm, hyperparameter overrides): told PPO, plain PPO, and the control told a
#: random label per episode instead of the mode (``OraclePPO(random_label=True)``).
VARIANTS = [("told_mode", "oracle_ppo", []), ("ppo", "ppo", []), ("told_random", "oracle_ppo", ["random_label:True"])]
#: Metrics of the table.
METRICS = ("team_reward", "detection_rate", "coverage_efficiency")
#: The station plans the scripted part chooses among: sweep all along, or guard the dens or the roads' entry points
#: until a quarter, half, three quarters or all of the episode.
STATION_PLANS: tuple[StationPlan, ...] = (StationPlan(None),) + tuple(
    StationPlan(spots, until) for spots in STATION_SPOTS for until in (0.25, 0.5, 0.75, 1.0))
#: First seed of the episodes on which the scripted part chooses its plans (the held-out ones start at --eval-seed).
FIT_SEED = 0
#: The mode the mode-use table tells each told run instead of the true one: the next strategy, the same weather.
WRONG_STRATEGY: tuple[int, ...] = tuple(next_strategy(mode) for mode in range(N_MODES))


def paired_table(results: dict[str, list[dict]], metrics: tuple[str, ...] = METRICS) -> str:
    """Mean +- std of each variant, and the paired difference (first variant minus second) with its p-value.

    :param results: ``{variant: [record per seed, same seed order for every variant]}``, two variants
    :param metrics: the metrics to compare
    :raises ValueError: if the two variants' seed lists differ (see :func:`~sb3_emmarl.zoo.compare.paired_over_seeds`)
    """
    (a_name, a_runs), (b_name, b_runs) = results.items()
    lines = [f"{'metric':<22}{a_name:>20}{b_name:>20}{'difference':>20}{'p (paired t)':>14}{'higher on':>11}"]
    for metric in metrics:
        test = paired_over_seeds(results, a_name, b_name, metric)
        a, b, diff = test.a, test.b, test.difference
        lines.append(f"{metric:<22}{a.mean():>11.3f} +- {a.std():<5.3f}{b.mean():>11.3f} +- {b.std():<5.3f}"
                     f"{diff.mean():>11.3f} +- {diff.std():<5.3f}{test.p_value:>14.3g}{test.higher_on:>11}")
    lines.append("")
    width = max(34, *(len(f"{name} {metric}") + 2 for name in (a_name, b_name) for metric in metrics))
    lines.append(f"{'seed':<6}" + "".join(f"{f'{name} {metric}':>{width}}" for name in (a_name, b_name) for metric in metrics))
    for a_run, b_run in zip(a_runs, b_runs):
        lines.append(f"{a_run['seed']:<6}" + "".join(f"{run[metric]:>{width}.3f}" for run in (a_run, b_run)
                                                    for metric in metrics))
    return "\n".join(lines)


def strategy_of(record: dict) -> str:
    """The poacher strategy of an episode's metrics record."""
    return decode_mode(record["mode"])[0].name


def choose_plans(fitted: dict[str, list[dict]]) -> tuple[str, dict[str, str]]:
    """The plan with the highest mean team reward over all fitting episodes, and over each strategy's.

    :param fitted: ``{plan name: [metrics per episode]}``, every plan on the same episodes
    :return: the best single plan's name and ``{strategy name: best plan's name}`` (a strategy no episode drew gets
        the best single plan)
    """
    def mean(name: str, strategy: str | None = None) -> float:
        rewards = [r["team_reward"] for r in fitted[name] if strategy is None or strategy_of(r) == strategy]
        return float(np.mean(rewards)) if rewards else -np.inf

    single = max(fitted, key=mean)
    per_strategy = {}
    for strategy in STRATEGIES:
        best = max(fitted, key=lambda name, s=strategy.name: mean(name, s))
        per_strategy[strategy.name] = best if np.isfinite(mean(best, strategy.name)) else single
    return single, per_strategy


def station_value(episodes: int, eval_seed: int, env_kwargs: dict | None = None, n_jobs: int = 1,
                  plans: tuple[StationPlan, ...] = STATION_PLANS) -> tuple[dict, str, dict[str, str], dict]:
    """What knowing the strategy pays to the station patrols: every plan on ``episodes`` fitting episodes (from
    :data:`FIT_SEED`) and as many held-out ones (from ``eval_seed``); the best plan per strategy and the best single
    plan chosen on the first, compared on the second.

    :return: the fitting episodes' records per plan, the best single plan, the best plan per strategy, and
        ``{"told": [held-out record per episode], "not_told": [...]}`` (told: the plan of the episode's strategy)
    """
    with ProcessPoolExecutor(max_workers=n_jobs) as pool:
        fitting = {plan.name: pool.submit(play_station_plan, plan, episodes, FIT_SEED, env_kwargs) for plan in plans}
        held_out = {plan.name: pool.submit(play_station_plan, plan, episodes, eval_seed, env_kwargs) for plan in plans}
        fitted = {name: job.result() for name, job in fitting.items()}
        played = {name: job.result() for name, job in held_out.items()}
    single, per_strategy = choose_plans(fitted)
    told = [played[per_strategy[strategy_of(record)]][i] for i, record in enumerate(played[single])]
    return fitted, single, per_strategy, {"told": told, "not_told": played[single]}


def plan_table(fitted: dict[str, list[dict]]) -> str:
    """Mean team reward of every plan per strategy and over all episodes (and how many episodes drew each)."""
    records = next(iter(fitted.values()))
    counts = {s.name: sum(strategy_of(r) == s.name for r in records) for s in STRATEGIES}
    lines = [f"{'plan':<12}" + "".join(f"{f'{name} ({counts[name]})':>26}" for name in counts) + f"{'all':>10}"]
    for name, runs in fitted.items():
        means = [np.mean([r["team_reward"] for r in runs if strategy_of(r) == s]) if counts[s] else np.nan for s in counts]
        lines.append(f"{name:<12}" + "".join(f"{m:>26.2f}" for m in means)
                     + f"{np.mean([r['team_reward'] for r in runs]):>10.2f}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_run_arguments(parser, n_timesteps=500_000, seeds=[0, 1, 2, 3, 4], eval_episodes=COMPARISON_EVAL_EPISODES,
                      log_folder="logs/mode_value")
    parser.set_defaults(n_jobs=2)
    parser.add_argument("--patrol-episodes", type=int, default=300,
                        help="episodes of the scripted comparison (told the strategy or not); 0 skips it")
    parser.add_argument("--scripted-only", action="store_true",
                        help="stop after the scripted part (what knowing the strategy pays to the station patrols): "
                             "a candidate reserve's value of information in minutes, before training on it")
    parser.add_argument("--hide", nargs="+", metavar="PART", default=None,
                        help="observation parts both variants train and play without (zeroed): names of the "
                             "reserve's observation_layout or window.<channel>, e.g. signs window.sign")
    parser.add_argument("--no-control", action="store_true",
                        help="skip the control (PPO told a random label per episode instead of the mode)")
    parser.add_argument("-params", "--hyperparams", nargs="+", metavar="KEY:VALUE", default=None,
                        help="hyperparameter overrides of ppo.yml for both variants (the zoo's -params)")
    args = parser.parse_args(argv)
    check_run_arguments(parser, args)
    variants = VARIANTS[:2] if args.no_control else VARIANTS
    if args.hyperparams:
        try:
            parse_key_values(args.hyperparams, "-params")
        except ValueError as error:
            parser.error(str(error))
        variants = [(name, algo, [*params, *args.hyperparams]) for name, algo, params in variants]
    if args.hide:
        env = reserve_v1.parallel_env(**dict(args.env_kwargs or {}))
        layout = env.observation_layout
        env.close()
        try:
            hidden_indices(layout, args.hide)
        except ValueError as error:
            parser.error(f"--hide: {error}")
        wrapper = {"sb3_emmarl.common.masking.HideObservationParts": {"parts": list(args.hide)}}
        variants = [(name, algo, [*params, f"vec_env_wrapper:{wrapper!r}"]) for name, algo, params in variants]
    if len(args.seeds) < 2:
        parser.error(f"--seeds must name at least 2 seeds for a paired test, got {args.seeds}")
    if args.patrol_episodes == 1 or args.patrol_episodes < 0:
        parser.error(f"--patrol-episodes must be 0 or >= 2 (a paired test), got {args.patrol_episodes}")
    if args.scripted_only and not args.patrol_episodes:
        parser.error("--scripted-only needs --patrol-episodes >= 2 (it runs only the scripted part)")
    episodes = args.patrol_episodes
    if episodes and FIT_SEED < args.eval_seed + episodes and args.eval_seed < FIT_SEED + episodes:
        parser.error(f"--eval-seed {args.eval_seed}: the held-out episodes must not overlap the fitting episodes "
                     f"(seeds {FIT_SEED} to {FIT_SEED + args.patrol_episodes - 1})")
    command = shlex.join(["python", "benchmarks/mode_value.py", *(sys.argv[1:] if argv is None else argv)])
    print(f"$ {command}", flush=True)
    scripted = None
    if args.patrol_episodes:
        fitted, single, per_strategy, scripted = station_value(args.patrol_episodes, args.eval_seed, args.env_kwargs,
                                                               args.n_jobs)
        print(f"\nScripted: station patrols (hold stations at the dens or the roads' entry points until a point of the "
              f"episode, then sweep); mean team reward per strategy (episodes) on {args.patrol_episodes} fitting "
              f"episodes from seed {FIT_SEED}")
        print(plan_table(fitted))
        print(f"Not told: the best single plan, {single}. Told the strategy: the best plan per strategy, "
              + ", ".join(f"{name} {plan}" for name, plan in per_strategy.items()) + ".")
        print(f"\nThe two on {args.patrol_episodes} held-out episodes from seed {args.eval_seed}; mean +- std over "
              f"episodes; p: paired t-test over episodes")
        print(paired_table(scripted, METRICS + ("poaching_events", "collisions")).split("\n\nseed")[0], flush=True)
        if args.scripted_only:
            return 0
    start = time.perf_counter()
    try:
        results = run_variants(variants, args)
    except (RuntimeError, ValueError) as error:
        print(error, file=sys.stderr)
        return 2
    hidden = f" without {' '.join(args.hide)} in the observation" if args.hide else ""
    overrides = f" with {' '.join(args.hyperparams)}" if args.hyperparams else ""
    print(f"\nPPO told the mode or not{hidden}: ppo.yml settings{overrides} for both; {len(args.seeds)} seeds x "
          f"{args.n_timesteps:,} agent-steps per run; "
          f"{args.eval_episodes} evaluation episodes from seed {args.eval_seed} per run (actions sampled); "
          f"mean +- std over seeds; wall time {time.perf_counter() - start:.0f} s with {args.n_jobs} jobs")
    told, plain, control = (name for name, _, _ in VARIANTS)
    print(paired_table({told: results[told], plain: results[plain]}))
    if scripted is not None:
        print(power_line(scripted, results))
    if control in results:
        print("\nThe control: PPO told a random label per episode instead of the mode (the same input, no information). "
              "Told PPO against it, what the mode's information is worth; mean +- std over seeds; p: paired t-test over "
              "seeds")
        print(paired_table({told: results[told], control: results[control]}).split("\n\nseed")[0])
        print("\nThe control against PPO: what an input constant over an episode costs PPO by itself")
        print(paired_table({control: results[control], plain: results[plain]}))
    print(mode_weight_table(args))
    print(mode_use_table(args, results[VARIANTS[0][0]]))
    return 0


def mode_use_table(args: argparse.Namespace, told: list[dict]) -> str:
    """Told PPO told the true mode (``told``: its records per seed) against the same runs told a wrong strategy, on
    the same evaluation episodes, paired over seeds: what each told run's team loses when it is told wrong."""
    name, algo, _ = VARIANTS[0]
    with ProcessPoolExecutor(max_workers=args.n_jobs, initializer=th.set_num_threads, initargs=(1,)) as pool:
        jobs = [pool.submit(evaluate_run, algo, latest_run(run_folder(args, name, seed), algo), args.eval_episodes,
                            args.eval_seed, WRONG_STRATEGY) for seed in args.seeds]
        played = [job.result() for job in jobs]
    wrong = [{**{m: float(np.mean([r[m] for r in records])) for m in METRICS}, "seed": seed}
             for seed, records in zip(args.seeds, played)]
    return ("\nDoes told PPO act on the mode? The told runs on the same episodes told the true mode or the next strategy "
            "(same weather); mean +- std over seeds; p: paired t-test over seeds\n"
            + paired_table({"true_mode": told, "wrong_strategy": wrong}))


def power_line(scripted: dict[str, list[dict]], results: dict[str, list[dict]]) -> str:
    """How many seeds a paired test of told PPO against PPO needs to find the scripted teams' gain in team reward
    with 80% power at p < 0.05, if the differences spread over seeds as they did here (and, with the control, if told
    PPO minus the control spreads as it did)."""
    gain = paired_over_seeds(scripted, "told", "not_told", "team_reward").difference.mean()
    spread = paired_over_seeds(results, VARIANTS[0][0], VARIANTS[1][0], "team_reward").difference.std(ddof=1)
    if not gain > 0 or not spread > 0:
        return f"\nPower: the scripted gain ({gain:.3f}) or the spread of PPO's differences ({spread:.3f}) is not > 0."
    line = (f"\nPower: a paired t-test over seeds finds a gain of {gain:.3f} (the scripted teams') in team reward with 80% "
            f"power at p < 0.05 from {_seeds(gain, spread)} seeds, if told minus plain PPO spreads over seeds as here "
            f"(std {spread:.3f})")
    control = VARIANTS[2][0]
    if control in results:
        spread = paired_over_seeds(results, VARIANTS[0][0], control, "team_reward").difference.std(ddof=1)
        line += f"; from {_seeds(gain, spread)} if told PPO minus the control spreads as here (std {spread:.3f})"
    return line + "."


def _seeds(gain: float, spread: float) -> str:
    n = seeds_needed(gain, spread) if spread > 0 else 2
    return str(n) if n is not None else "more than 100,000"


def mode_weight_table(args: argparse.Namespace) -> str:
    """How strongly each told run's networks read the one-hot: the mean norm of a first-layer weight column on the
    mode against the other inputs' (:func:`~sb3_emmarl.common.appended.initialization.tail_weight_norms`), per seed."""
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
