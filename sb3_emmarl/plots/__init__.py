"""Figures of training runs (``emmarl plot``, ``python -m sb3_emmarl.plots``): learning curves over seeds, and
per-seed bars that one outlying seed does not flatten.

Runs are found in the zoo's layout, ``<log-folder>/<algo>/<env>_<n>/`` (one run per seed, as ``emmarl train`` and
``zoo/train.py`` write them), and read with the libraries that wrote them:

- ``-k reward`` / ``-k length`` read the runs' monitor files with SB3's ``monitor.load_results`` and
  ``results_plotter.ts2xy``. On a parameter-sharing environment every vector entry is a UAV that receives the team
  reward, so a monitor file holds one row per *UAV* episode: the rows of one team episode (the ``agents_per_copy`` UAVs
  of a copy, written together when the copy's episode ends) are taken as one team episode (:func:`team_episodes`), as
  :func:`sb3_emmarl.common.evaluation.evaluate_policy` counts them.
- any other key is a tensorboard scalar (``reserve/team_reward``, ``rollout/ep_rew_mean``, ``eval/mean_reward``...),
  read with tensorboard's ``EventAccumulator`` (:func:`read_scalars`) from the event files under each run folder, or,
  with ``-tb``, from the folder given to ``train -tb`` (``<tb>/<env>/<ALGO>_<n>/``).

:func:`aggregate_curves` puts each run's curve on a common grid (agent-steps or wall time) and takes the mean and its
standard error (or the median and quartiles) over runs; :func:`seed_bars` draws one bar per arm (the median over seeds,
the quartiles as whiskers, every seed as a dot) on an axis chosen by :func:`readable_limits`, where a seed that would
squeeze the others into a sliver of the axis is drawn as an arrow at the axis' edge with its value written beside it.

Figures are drawn with matplotlib (the ``[zoo]`` extra) on its ``Agg`` canvas, without pyplot, and saved in the
format of the output's extension (``.png``, ``.pdf``, ``.svg``).


The package's modules: :mod:`~sb3_emmarl.plots.runs` (finding runs), :mod:`~sb3_emmarl.plots.reading` (monitor
and tensorboard files), :mod:`~sb3_emmarl.plots.drawing` (curves and bars) and :mod:`~sb3_emmarl.plots.command` (the
command); the names below are theirs. It sits beside the zoo, not in it: ``sb3_emmarl.zoo`` imports rl_zoo3 on import,
which drawing a figure does not need.
"""

from sb3_emmarl.plots.command import FORMATS, X_AXES, build_figure, main, plot_parser, run_curves
from sb3_emmarl.plots.drawing import (
    BANDS,
    CURVE_POINTS,
    MIN_SHARE,
    Curve,
    SeedBars,
    _require_matplotlib,
    aggregate_curves,
    draw_curves,
    readable_limits,
    seed_bars,
    time_unit,
)
from sb3_emmarl.plots.reading import MONITOR_KEYS, monitor_curve, read_scalars, team_episodes
from sb3_emmarl.plots.runs import Run, make_run, tensorboard_name, tensorboard_runs, zoo_runs

__all__ = ["BANDS", "CURVE_POINTS", "FORMATS", "MIN_SHARE", "MONITOR_KEYS", "X_AXES", "Curve", "Run", "SeedBars",
           "_require_matplotlib", "aggregate_curves", "build_figure", "draw_curves", "main", "make_run", "monitor_curve",
           "plot_parser", "read_scalars", "readable_limits", "run_curves", "seed_bars", "team_episodes", "tensorboard_name",
           "tensorboard_runs", "time_unit", "zoo_runs"]
