"""``emmarl compare``: variants of the zoo's algorithms at one budget over seeds, each evaluated on the same held-out
team episodes, with paired tests against a baseline and the share of an oracle's gap recovered (``zoo/compare.py``).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from stable_baselines3.common.vec_env import VecEnv

from sb3_emmarl.cli import child_failure
from sb3_emmarl.common.centralized import ENV_ID
from sb3_emmarl.common.checkpoints import vec_normalize_stats
from sb3_emmarl.common.evaluation import evaluate_team, load_for_evaluation, make_eval_env
from sb3_emmarl.common.latent.config import lift_flat_settings
from sb3_emmarl.common.mode_aware import ModeObservationWrapper
from sb3_emmarl.common.model_files import check_model_file
from sb3_emmarl.common.statistics import paired_p_value
from sb3_emmarl.common.trust.safe_config import wrapper_from_config
from sb3_emmarl.common.trust.validation import MAX_EPISODES, MAX_SEED, MAX_TIMESTEPS, int_flag
from sb3_emmarl.common.vec_env import compile_reserve
from sb3_emmarl.oracle_ppo import OraclePPO
from sb3_emmarl.zoo.algos import ZOO_ALGOS, merge_hyperparams
from sb3_emmarl.zoo.cli import KeyValues, latest_run, parse_key_values
from sb3_emmarl.zoo.exp_manager import plain, read_yaml, zoo_hyperparams

#: Metrics of the method comparison's mean +- std table, with the latent accuracy at 50% and 100% of the
#: episode (present for EM models only; the table shows '-' for the others).
COMPARE_METRICS = ("team_reward", "detection_rate", "coverage_efficiency", "latent_accuracy_50", "latent_accuracy_100")
#: Metrics of the paired comparison against the baseline (every variant has them).
PAIRED_METRICS = ("team_reward", "detection_rate", "coverage_efficiency")
#: The metric whose oracle gap the paired comparison reports the recovered share of.
GAP_METRIC = "team_reward"


#: Evaluation episodes per run of the multi-seed comparisons (``zoo/compare.py``, ``benchmarks/mode_value.py``,
#: ``docs/lab/studies/fusion.py``). Every run plays the same episodes, so whatever those happen to hold moves every seed's
#: figure alike and no number of seeds averages it out; a team's reward varies widely from one episode to the next, and
#: 20 episodes once reversed the sign of a comparison that 200 gave (docs/lab/results-history.md).
COMPARISON_EVAL_EPISODES = 200

#: The method comparison's default variants:
#:
#: - ``em_ppo``: the method (PPO as the M-step, the EM-inferred belief over the hidden mode as input);
#: - ``ppo``: plain PPO on the current observation, the baseline;
#: - ``ppo_lstm``: RecurrentPPO, memory without EM (the history through an LSTM fitted by RL alone);
#: - ``oracle_ppo``: PPO told the true mode, the upper bound of every latent method;
#: - ``no_latent``: EM-PPO with the latent input removed;
#: - ``frozen_e_step``: EM-PPO with the transition models kept at their initialisation: the policy still sees
#:   a belief computed from the whole episode, but not from a model fitted by EM, which separates "a summary
#:   of the episode as input" from "the inferred mode as input".
DEFAULT_VARIANTS = ("em_ppo", "ppo", "ppo_lstm", "oracle_ppo", "no_latent=em_ppo:latent_kwargs=dict(use_latent=False)",
                    "frozen_e_step=em_ppo:latent_kwargs=dict(freeze_e_step=True)")


def _top_level_split(text: str, separator: str = ",") -> list[str]:
    """``text`` split at the ``separator`` characters outside brackets and quotes (a value such as
    ``dict(norm_obs=False, norm_reward=True)`` stays whole); written by hand because ``shlex`` and ``csv`` know
    quotes but not brackets."""
    parts, depth, quote, start = [], 0, "", 0
    for i, char in enumerate(text):
        if quote:
            quote = "" if char == quote else quote
        elif char in "'\"":
            quote = char
        elif char in "([{":
            depth += 1
        elif char in ")]}":
            depth -= 1
        elif char == separator and depth == 0:
            parts.append(text[start:i])
            start = i + 1
    return parts + [text[start:]]


def parse_variant(text: str) -> tuple[str, str, list[str]]:
    """``NAME=ALGO:key=value,key=value`` (or just ``ALGO``) -> (name, algo, ``-params`` items). Commas inside brackets
    or quotes belong to the value: ``norm=ppo:normalize=dict(norm_obs=False, norm_reward=True)``."""
    name, _, spec = text.partition("=") if "=" in text.split(":")[0] else (text.split(":")[0], "", text)
    algo, _, params = spec.partition(":")
    if algo not in ZOO_ALGOS:
        raise ValueError(f"variant {text!r}: unknown algorithm {algo!r}; the zoo trains {sorted(ZOO_ALGOS)}")
    items = [p.strip().replace("=", ":", 1) for p in _top_level_split(params) if p.strip()]
    return name, algo, items


def compare_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description="Compare variants at the same budget over seeds (train in fresh processes).")
    parser.add_argument("--variants", nargs="+", default=list(DEFAULT_VARIANTS),
                        help="NAME=ALGO:key=value,... (hyperparameter overrides)")
    add_run_arguments(parser, n_timesteps=1_000_000, seeds=[0, 1, 2], eval_episodes=COMPARISON_EVAL_EPISODES,
                      log_folder="logs/compare")
    parser.add_argument("--baseline", default="ppo",
                        help="variant every other one is compared with, paired by seed (must be among --variants)")
    parser.add_argument("--oracle", default="oracle_ppo",
                        help="variant told the true mode: the upper bound of the oracle-gap share ('-' if not run)")
    parser.add_argument("--ratio", nargs=2, default=["em_ppo", "ppo"], metavar=("A", "B"),
                        help="print the wall-time ratio of variant A to variant B")
    return parser


def check_compare_arguments(parser: argparse.ArgumentParser, args: argparse.Namespace) -> list[tuple[str, str, list[str]]]:
    """Reject bad flags of :func:`compare_parser`, naming them, and parse the variants.

    :return: the variants as :func:`parse_variant` returns them
    """
    check_run_arguments(parser, args)
    try:
        variants = [parse_variant(v) for v in args.variants]
    except ValueError as error:
        parser.error(str(error))
    names = [name for name, _, _ in variants]
    if len(set(names)) != len(names):
        parser.error(f"--variants must have distinct names, got {names}")
    if args.baseline not in names:
        parser.error(f"--baseline {args.baseline!r} is not among the variants {names}")
    return variants


def add_run_arguments(parser: argparse.ArgumentParser, n_timesteps: int, seeds: list[int], eval_episodes: int,
                      log_folder: str) -> None:
    """The flags of every multi-seed comparison: budget, seeds, evaluation, folder, environment, parallel jobs."""
    parser.add_argument("-n", "--n-timesteps", type=int_flag(1, MAX_TIMESTEPS), default=n_timesteps,
                        help="budget of every run, agent-steps")
    parser.add_argument("--seeds", type=int_flag(0, MAX_SEED), nargs="+", default=seeds, help="training seeds")
    parser.add_argument("--eval-episodes", type=int_flag(1, MAX_EPISODES), default=eval_episodes,
                        help="evaluation episodes per run")
    parser.add_argument("--eval-seed", type=int_flag(0, MAX_SEED), default=50_000, help="seed of the evaluation episodes")
    parser.add_argument("-f", "--log-folder", default=log_folder, help="where the runs are saved")
    parser.add_argument("--env-kwargs", type=str, nargs="+", action=KeyValues, help="reserve arguments, key:value")
    parser.add_argument("--n-jobs", type=int_flag(1, 64), default=1,
                        help="runs trained at once, each in its own process with one torch thread")
    parser.add_argument("--reuse-runs", action="store_true",
                        help="evaluate the runs already finished in the log folder instead of training them again "
                             "(each checked to have been trained with these settings; runs missing or stopped early "
                             "are trained): to evaluate a comparison again with more episodes, or finish one that "
                             "was interrupted")


def check_run_arguments(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """Reject bad values of :func:`add_run_arguments`' flags that one flag's range does not say, naming them."""
    if len(set(args.seeds)) != len(args.seeds):
        parser.error(f"--seeds must be distinct, got {args.seeds}")


def finished_run(folder: str | Path, algo: str, seed: int, n_timesteps: int, params: list[str],
                 env_kwargs: dict[str, Any] | None) -> Path | None:
    """The newest run of ``algo`` in ``folder`` if it finished (final model and ``run_stats.json`` saved) and was
    trained with these settings: the zoo's flags (seed, budget, ``-params``, ``--env-kwargs``, in its ``args.yml``)
    and the hyperparameters its YAML gives today with those overrides (its ``config.yml``).

    :param folder: the zoo's ``-f`` folder of the run
    :param params: ``-params`` items, ``key:value``
    :return: the run's folder, or None if there is no finished run (a run stopped early is not one)
    :raise ValueError: naming the first setting the finished run was trained with differently
    """
    run = latest_run(folder, algo)
    if not ((run / f"{ENV_ID}.zip").is_file() and (run / "run_stats.json").is_file()):
        return None
    overrides = parse_key_values(params, "-params") if params else {}
    saved = read_yaml(run / ENV_ID / "args.yml", "the run's arguments")
    flags = {"algo": algo, "seed": seed, "n_timesteps": n_timesteps, "hyperparams": overrides or None,
             "env_kwargs": env_kwargs or None}
    given = {key: (saved.get(key) or None) if isinstance(saved.get(key), dict) else saved.get(key) for key in flags}
    differences = [(key, given[key], value) for key, value in flags.items() if given[key] != value]
    if not differences:  # the YAML may have changed since: compare the run's hyperparameters with today's
        today = plain(merge_hyperparams(zoo_hyperparams(algo, ENV_ID), overrides))
        today["env_kwargs"] = {**(today.get("env_kwargs") or {}), **(env_kwargs or {})}
        config = lift_flat_settings(read_yaml(run / ENV_ID / "config.yml", "the run's config"))
        differences = [(key, config.get(key), value) for key, value in today.items()
                       if key != "n_timesteps" and config.get(key) != value]
    if differences:
        key, was, wanted = differences[0]
        raise ValueError(f"{run} was trained with {key} {was!r}, not {wanted!r}: give another -f/--log-folder, or "
                         "leave out --reuse-runs")
    return run


def evaluate_run(algo: str, run: str | Path, n_episodes: int, seed: int, relabel: Sequence[int] | None = None
                 ) -> list[dict]:
    """``evaluate_team`` of a finished zoo run on its own reserve arguments: ``n_episodes`` episodes from ``seed``.

    :param algo: the run's zoo algorithm
    :param run: the run's folder (``<log-folder>/<algo>/<env>_<n>``)
    :param relabel: for a run told the mode (``oracle_ppo``), the mode told for each true mode instead of it (see
        :class:`~sb3_emmarl.common.mode_aware.ModeObservationWrapper`); None tells the truth
    :return: one record per episode
    """
    check_model_file(Path(run) / f"{ENV_ID}.zip")  # its pickles name only allowed globals
    model = load_for_evaluation(ZOO_ALGOS[algo], Path(run) / f"{ENV_ID}.zip", device="cpu")
    if relabel is None:
        return evaluate_team(model, n_episodes, seed=seed, **run_settings(run))
    if not issubclass(ZOO_ALGOS[algo], OraclePPO):
        raise ValueError(f"relabel tells a run a wrong mode: it needs a run told the mode (oracle_ppo), not {algo}")
    venv = ModeObservationWrapper(run_eval_env(run, seed), relabel=relabel)
    try:
        return evaluate_team(model, n_episodes, seed=seed, vec_env=venv)
    finally:
        venv.close()


def run_settings(run: str | Path) -> dict[str, Any]:
    """What a finished zoo run's evaluation must reproduce of its training, from its ``config.yml``: the reserve's
    arguments, the ``vec_env_wrapper`` (None if it had none) and its ``VecNormalize`` statistics (None if it was not
    normalised), as keyword arguments of ``evaluate_team``.

    :param run: the run's folder (``<log-folder>/<algo>/<env>_<n>``)
    """
    config = read_yaml(Path(run) / ENV_ID / "config.yml", "the run's config")
    return {"env_kwargs": dict(config.get("env_kwargs") or {}),
            "vec_env_wrapper": wrapper_from_config(config, "vec_env_wrapper"),
            "vec_normalize_path": vec_normalize_stats(Path(run) / ENV_ID)}


def run_eval_env(run: str | Path, seed: int) -> VecEnv:
    """The evaluation reserve of a finished zoo run, as :func:`~sb3_emmarl.common.evaluation.evaluate_team` builds it
    from :func:`run_settings` (the parameter-sharing view, its wrapper, its frozen ``VecNormalize``), for callers that
    wrap it further before evaluating on it (``vec_env=``): episodes from ``seed``."""
    settings = run_settings(run)
    return make_eval_env(seed, settings["env_kwargs"], False, settings["vec_normalize_path"], None,
                         settings["vec_env_wrapper"])


def _one_torch_thread() -> None:
    import torch as th

    th.set_num_threads(1)


def run_folder(args: argparse.Namespace, name: str, seed: int) -> Path:
    """Where a comparison keeps variant ``name``'s run of ``seed`` (the zoo's ``-f``)."""
    return Path(args.log_folder) / name / f"seed_{seed}"


def _train_and_evaluate(name: str, algo: str, params: list[str], seed: int, args: argparse.Namespace,
                        run: Path | None, evaluators: Any) -> dict:
    """Train one run in a fresh process unless ``run`` (a finished run, see :func:`finished_run`) is given, then
    evaluate it in ``evaluators`` (a process pool); returns its metrics and run statistics."""
    import json
    import subprocess

    folder = str(run_folder(args, name, seed))
    if run is None:
        compile_reserve(args.env_kwargs)  # so that the run's timed training does not compile the reserve's kernels
        env_flags = ["--env-kwargs", *[f"{k}:{v!r}" for k, v in (args.env_kwargs or {}).items()]] \
            if args.env_kwargs else []
        command = [sys.executable, "-m", "sb3_emmarl.zoo.train", "--algo", algo, "-n", str(args.n_timesteps),
                   "--seed", str(seed), "-f", folder, "--eval-freq", "-1", "--team-eval-episodes", "0", "--verbose",
                   "0", *env_flags, *(["-params", *params] if params else [])]
        done = subprocess.run(command, capture_output=True, text=True)
        if done.returncode != 0:
            raise RuntimeError(f"training {name} (seed {seed}) failed:{child_failure(done.stderr, 2000)}")
        run = latest_run(folder, algo)
    stats = json.loads((run / "run_stats.json").read_text())
    records = evaluators.submit(evaluate_run, algo, run, args.eval_episodes, args.eval_seed).result()
    row = {m: float(np.mean([r[m] for r in records])) for m in COMPARE_METRICS if m in records[0]}
    print(f"{name} seed {seed}: {stats['train_seconds']:.0f} s, " + ", ".join(f"{k} {v:.3f}" for k, v in row.items()),
          flush=True)
    return {**row, **stats, "seed": seed}


def run_variants(variants: list[tuple[str, str, list[str]]], args: argparse.Namespace) -> dict[str, list[dict]]:
    """Train every variant on every seed (each run in a fresh process, ``args.n_jobs`` at once) and evaluate it.

    Runs are started interleaved by seed, so that machine load drifts hit every variant alike.

    :param variants: ``(name, algo, -params items)`` as :func:`parse_variant` returns them
    :param args: the flags of :func:`add_run_arguments`
    :return: ``{name: [one record per seed, in the order of args.seeds]}``
    """
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor

    tasks = [(name, algo, params, seed) for seed in args.seeds for name, algo, params in variants]
    # With --reuse-runs every finished run is found and checked before anything trains (a mismatch raises ValueError).
    runs = [finished_run(run_folder(args, name, seed), algo, seed, args.n_timesteps, params, args.env_kwargs)
            if args.reuse_runs else None for name, algo, params, seed in tasks]
    # Threads wait for the training processes; the evaluations run in worker processes (one torch thread each), so
    # that n_jobs of them use n_jobs cores (threads of one process would share its interpreter lock).
    spawn = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=args.n_jobs, mp_context=spawn, initializer=_one_torch_thread) as evaluators, \
            ThreadPoolExecutor(max_workers=args.n_jobs) as pool:
        futures = [(task[0], pool.submit(_train_and_evaluate, *task, args, run, evaluators))
                   for task, run in zip(tasks, runs)]
        results: dict[str, list[dict]] = {name: [] for name, _, _ in variants}
        for name, future in futures:
            results[name].append(future.result())
    return results


class PairedTest(NamedTuple):
    """One metric of two variants, paired by seed."""

    seeds: list[int]
    #: The first variant's values, one per seed.
    a: np.ndarray
    #: The second variant's values, in the same seed order.
    b: np.ndarray

    @property
    def difference(self) -> np.ndarray:
        """First minus second, per seed."""
        return self.a - self.b

    @property
    def p_value(self) -> float:
        """The paired t-test's p-value over seeds (see :func:`paired_p_value`)."""
        return paired_p_value(self.a, self.b)

    @property
    def higher_on(self) -> str:
        """On how many seeds the first variant is higher, as ``"3/5"``."""
        return f"{int((self.difference > 0).sum())}/{len(self.seeds)}"


def paired_over_seeds(results: dict[str, list[dict]], a: str, b: str, metric: str) -> PairedTest:
    """A metric of variant ``a`` against variant ``b``, paired by seed, with the p-value of the paired t-test.

    :param results: ``{variant: [record per seed]}``, each record with its ``seed``
    :param a: the first variant
    :param b: the second variant (the differences are ``a - b``)
    :param metric: the record key to compare
    :raises ValueError: if the two variants' seed lists differ (other seeds, or the same in another order),
        or a seed repeats
    """
    seeds = {name: [r["seed"] for r in results[name]] for name in (a, b)}
    if seeds[a] != seeds[b] or len(set(seeds[a])) != len(seeds[a]):
        raise ValueError(f"variants {a!r} and {b!r} must be evaluated on the same seeds, in the same order and each "
                         f"once, to be paired by seed: {a!r} has seeds {seeds[a]}, {b!r} has seeds {seeds[b]}")
    by_seed = {name: {r["seed"]: r[metric] for r in results[name]} for name in (a, b)}
    values_a = np.array([by_seed[a][seed] for seed in seeds[a]], dtype=float)
    values_b = np.array([by_seed[b][seed] for seed in seeds[a]], dtype=float)
    return PairedTest(seeds[a], values_a, values_b)


def oracle_gap_share(results: dict[str, list[dict]], variant: str, baseline: str, oracle: str,
                     metric: str = GAP_METRIC) -> str:
    """The share of the oracle's gain over the baseline that a variant recovers, formatted.

    ``(mean_variant - mean_baseline) / (mean_oracle - mean_baseline)``, the means over the same seeds.

    :param results: ``{variant: [record per seed]}``
    :param variant: the variant to score
    :param baseline: the reference variant (share 0)
    :param oracle: the variant told the true mode (share 1)
    :param metric: the metric the gap is measured on
    :return: e.g. ``"0.42"``; ``"-"`` when the oracle was not run, ``"n/a (oracle gap <= 0)"`` when the
        oracle's mean is not above the baseline's
    """
    if oracle not in results:
        return "-"
    gap = paired_over_seeds(results, oracle, baseline, metric).difference.mean()
    if gap <= 0:
        return "n/a (oracle gap <= 0)"
    return f"{paired_over_seeds(results, variant, baseline, metric).difference.mean() / gap:.2f}"


def difference_rows(results: dict[str, list[dict]], baseline: str, oracle: str,
                    metrics: tuple[str, ...] = PAIRED_METRICS) -> list[tuple[str, str, float, float, str, str]]:
    """Every variant but the baseline against the baseline, paired by seed, one row per variant and metric.

    :param results: ``{variant: [record per seed]}``
    :param baseline: the variant the others are compared with
    :param oracle: the variant told the true mode (for the share of the oracle gap)
    :param metrics: the metrics to compare; a metric missing from a variant's records is left out of its rows
    :return: ``(variant, metric, mean difference, p-value, higher on, share of the oracle gap)``; the share is
        given for :data:`GAP_METRIC` only (``""`` for the other metrics)
    """
    rows = []
    for variant in results:
        if variant == baseline:
            continue
        for metric in metrics:
            if not all(metric in r for r in (*results[variant], *results[baseline])):
                continue
            test = paired_over_seeds(results, variant, baseline, metric)
            share = oracle_gap_share(results, variant, baseline, oracle, metric) if metric == GAP_METRIC else ""
            rows.append((variant, metric, float(test.difference.mean()), test.p_value, test.higher_on, share))
    return rows


def summary_table(results: dict[str, list[dict]], columns: tuple[str, ...]) -> str:
    """Mean +- std over seeds of each variant; ``'-'`` where a variant's records lack the column.

    :param results: ``{variant: [record per seed]}``
    :param columns: the record keys to show
    """
    width = max(12, *(len(name) + 2 for name in results))
    lines = [f"{'variant':<{width}}" + "".join(f"{c:>22}" for c in columns)]
    for name, runs in results.items():
        cells = []
        for column in columns:
            values = [r[column] for r in runs if column in r]
            cells.append(f"{np.mean(values):>13.3f} +- {np.std(values):<5.3f}" if values else f"{'-':>22}")
        lines.append(f"{name:<{width}}" + "".join(cells))
    return "\n".join(lines)


def difference_header(results: dict[str, list[dict]], baseline: str, oracle: str) -> str:
    """What :func:`difference_table`'s columns are (the oracle-gap formula only when the oracle was run)."""
    gap = (f"oracle gap recovered: (variant - {baseline}) / ({oracle} - {baseline}) in mean {GAP_METRIC}"
           if oracle in results else f"no oracle variant ({oracle!r}) was run, so no oracle gap ('-')")
    return (f"Against {baseline}, paired by seed: mean difference (variant minus {baseline}), p-value of the paired "
            f"t-test over seeds, seeds on which the variant is higher; {gap}")


def difference_table(results: dict[str, list[dict]], baseline: str, oracle: str) -> str:
    """:func:`difference_rows` as text."""
    rows = difference_rows(results, baseline, oracle)
    width = max(12, *(len(name) + 2 for name in results))
    lines = [f"{'variant':<{width}}{'metric':<22}{'difference':>12}{'p (paired t)':>14}{'higher on':>11}"
             "  oracle gap recovered"]
    for variant, metric, difference, p_value, higher_on, share in rows:
        lines.append(f"{variant:<{width}}{metric:<22}{difference:>12.3f}{p_value:>14.3g}{higher_on:>11}  {share}".rstrip())
    return "\n".join(lines)


def compare_main(argv: list[str] | None = None) -> int:
    """Train every variant on every seed (each in a fresh process), evaluate, print both tables and the ratio."""
    parser = compare_parser()
    args = parser.parse_args(argv)
    variants = check_compare_arguments(parser, args)
    try:
        results = run_variants(variants, args)
    except (RuntimeError, ValueError) as error:
        print(error, file=sys.stderr)
        return 2
    print(f"\n{len(args.seeds)} seeds x {args.n_timesteps:,} agent-steps per run; {args.eval_episodes} evaluation "
          f"episodes from seed {args.eval_seed} per run; mean +- std over seeds")
    print(summary_table(results, (*COMPARE_METRICS, "train_seconds", "peak_rss_mib")))
    print(f"\n{difference_header(results, args.baseline, args.oracle)}")
    print(difference_table(results, args.baseline, args.oracle))
    a, b = args.ratio
    if a in results and b in results:
        ratio = np.mean([r["train_seconds"] for r in results[a]]) / np.mean([r["train_seconds"] for r in results[b]])
        print(f"\nwall-time ratio {a} / {b}: {ratio:.2f}")
    return 0
