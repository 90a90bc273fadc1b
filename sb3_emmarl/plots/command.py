"""``emmarl plot`` (``python -m sb3_emmarl.plots``): the runs found, read, aggregated and drawn into one figure."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from sb3_emmarl.common.trust.extras import MissingExtra
from sb3_emmarl.plots.drawing import BANDS, _require_matplotlib, aggregate_curves, draw_curves, seed_bars
from sb3_emmarl.plots.reading import MONITOR_KEYS, monitor_curve, read_scalars
from sb3_emmarl.plots.runs import Run, tensorboard_name, tensorboard_runs, zoo_runs

if TYPE_CHECKING:
    from matplotlib.figure import Figure

#: The x-axes of a learning curve.
X_AXES = ("steps", "time")
#: The formats written, by the output's extension.
FORMATS = ("png", "pdf", "svg")


def plot_parser() -> argparse.ArgumentParser:
    """The flags of ``emmarl plot`` (rl-baselines3-zoo's ``plot_train`` / ``all_plots`` names where they fit)."""
    from sb3_emmarl.common.env_ids import ENV_MODULES
    from sb3_emmarl.common.trust.validation import float_flag, int_flag
    from sb3_emmarl.zoo.algos import ZOO_ALGOS
    from sb3_emmarl.zoo.cli import OneLineParser

    parser = OneLineParser(prog="emmarl plot", description=(
        "Learning curves (mean and spread over runs, in agent-steps or wall time) or per-run bars robust to outliers, "
        "from the zoo's runs (<log-folder>/<algo>/<env>_<n>/, one run per seed)."))
    parser.add_argument("-f", "--log-folder", nargs="+", default=["logs"], help="the zoo's log folder(s) (train -f)")
    parser.add_argument("-a", "--algo", "--algos", dest="algos", nargs="+", choices=sorted(ZOO_ALGOS), metavar="ALGO",
                        help="algorithms to include (default: every algorithm with runs)")
    parser.add_argument("-e", "--env", choices=sorted(ENV_MODULES), help="environment (default: the one with runs)")
    parser.add_argument("-k", "--key", default="reward",
                        help="reward or length: the team episodes of the monitor files; anything else: a tensorboard "
                             "scalar (reserve/team_reward, rollout/ep_rew_mean, eval/mean_reward...)")
    parser.add_argument("-tb", "--tensorboard-log", default="",
                        help="read tensorboard scalars from the folder given to train -tb (default: under each run)")
    parser.add_argument("-x", "--x-axis", choices=X_AXES, default="steps", help="agent-steps or wall time")
    parser.add_argument("-w", "--episode-window", type=int_flag(1, 1_000_000), default=20,
                        help="team episodes per rolling mean (monitor keys)")
    parser.add_argument("--band", choices=BANDS, default="se",
                        help="se: mean +- standard error over runs; iqr: median and quartiles")
    parser.add_argument("--bars", action="store_true",
                        help="one bar per algorithm of each run's final value (the last point of its curve): the "
                             "median, quartiles and every run")
    parser.add_argument("-o", "--output", default=None,
                        help="the figure; its extension decides the format: .png, .pdf or .svg (default: "
                             "curves.png, or bars.png with --bars)")
    parser.add_argument("--figsize", nargs=2, type=float_flag(1.0, 60.0), default=[6.4, 4.2], metavar=("W", "H"),
                        help="figure size in inches (1 to 60; at 120 dpi)")
    return parser


def _select_runs(args: argparse.Namespace) -> list[Run]:
    """The zoo runs of the flags, one environment's."""
    runs = zoo_runs(args.log_folder, args.algos, args.env)
    folders = ", ".join(map(str, args.log_folder))
    if not runs:
        what = f"{', '.join(args.algos)}" if args.algos else "any algorithm"
        raise ValueError(f"no runs of {what} on {args.env or 'any environment'} under {folders} (the zoo's layout: "
                         "<log-folder>/<algo>/<env>_<n>/)")
    env_ids = sorted({run.env_id for run in runs})
    if len(env_ids) > 1:
        raise ValueError(f"runs of several environments under {folders}: give -e/--env, one of {', '.join(env_ids)}")
    return runs


def run_curves(args: argparse.Namespace) -> tuple[dict[str, list[tuple[np.ndarray, np.ndarray]]], str, str]:
    """Each algorithm's run curves of the flags, the y label and the environment.

    :param args: the parsed flags of :func:`plot_parser`
    :raise ValueError: naming the input that finds nothing
    """
    _require_matplotlib()  # (SB3's results_plotter imports it)
    runs = _select_runs(args)
    env_id = runs[0].env_id
    curves: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {}
    if args.key in MONITOR_KEYS:
        for run in runs:
            curve = monitor_curve(run, args.key, args.x_axis, args.episode_window)
            if curve is None:
                print(f"skipped {run.folder}: no finished team episode", file=sys.stderr)
            else:
                curves.setdefault(run.algo, []).append(curve)
        if not curves:
            raise ValueError(f"no finished team episode in the monitor files of {len(runs)} run(s)")
        window = args.episode_window
        return curves, f"{MONITOR_KEYS[args.key]}, mean of {window} team episode{'s' * (window > 1)}", env_id
    if args.tensorboard_log:
        zoo = runs
        runs = tensorboard_runs(args.tensorboard_log, zoo)
        if not runs:
            names = ", ".join(f"{tensorboard_name(algo)}_<n>" for algo in dict.fromkeys(run.algo for run in zoo))
            raise ValueError(f"no tensorboard runs ({names}) under {Path(args.tensorboard_log) / env_id}")
    tags: set[str] = set()
    for run in runs:
        scalars = read_scalars(run.folder)
        tags.update(scalars)
        if args.key in scalars:
            steps, hours, values = scalars[args.key]
            x = steps * run.uav_steps_per_timestep if args.x_axis == "steps" else hours
            curves.setdefault(run.algo, []).append((x, values))
    if not curves:
        known = f"or a tensorboard scalar of these runs: {', '.join(sorted(tags))}" if tags else (
            "and these runs have no tensorboard event files (train with -tb, and give its folder here with -tb)")
        raise ValueError(f"unknown key {args.key!r}: {' or '.join(MONITOR_KEYS)} (the monitor files), {known}")
    return curves, args.key, env_id


def build_figure(args: argparse.Namespace) -> Figure:
    """The figure of the flags: learning curves, or with ``--bars`` the per-run bars.

    :param args: the parsed flags of :func:`plot_parser`
    :raise ValueError: naming the input that finds nothing
    """
    _require_matplotlib()
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    curves, ylabel, env_id = run_curves(args)
    figure = Figure(figsize=tuple(args.figsize), layout="constrained")
    FigureCanvasAgg(figure)
    ax = figure.add_subplot()
    if args.bars:
        finals = {algo: [float(y[-1]) for _, y in algo_curves] for algo, algo_curves in curves.items()}
        seed_bars(ax, finals, ylabel=ylabel.replace("mean of", "mean of the last"))
        ax.set_title(f"{env_id}: each run's final value (its curve's last point)\nbars: median over runs; whiskers: "
                     "quartiles; dots: runs",
                     fontsize="medium")
    else:
        aggregated = {algo: aggregate_curves(algo_curves, args.band) for algo, algo_curves in curves.items()}
        draw_curves(ax, aggregated, args.x_axis, ylabel)
        spread = "mean ± standard error" if args.band == "se" else "median and quartiles"
        ax.set_title(f"{env_id}: {spread} over runs", fontsize="medium")
    return figure


def main(argv: list[str] | None = None) -> int:
    """``emmarl plot``: draw the figure of the flags and save it in the format of its extension.

    :param argv: the flags (default: the command line's)
    :return: 0 (a bad input exits with code 2 and one line naming it)
    """
    parser = plot_parser()
    args = parser.parse_args(argv)
    output = Path(args.output or ("bars.png" if args.bars else "curves.png"))
    if output.suffix.lower().lstrip(".") not in FORMATS:
        parser.error(f"-o/--output {str(output)!r}: the extension decides the format, one of "
                     f"{', '.join('.' + f for f in FORMATS)}")
    try:
        figure = build_figure(args)
    except (ValueError, MissingExtra) as error:
        parser.error(str(error))
    output.parent.mkdir(parents=True, exist_ok=True)
    from sb3_emmarl.common.trust.atomic_files import write_atomic

    write_atomic(output, lambda file: figure.savefig(file, format=output.suffix.lower().lstrip("."), dpi=120))
    print(f"wrote {output}")
    return 0
