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
"""

from __future__ import annotations

import argparse
import re
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from sb3_emmarl.common.extras import MissingExtra, requires

if TYPE_CHECKING:
    import pandas as pd  # type: ignore[import-untyped]  # (no stubs installed)
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

#: The monitor files' keys and the axis label of each (a team episode: one episode of a copy's whole team).
MONITOR_KEYS: dict[str, str] = {"reward": "team reward", "length": "team episode length (steps)"}
#: The x-axes of a learning curve.
X_AXES = ("steps", "time")
#: The bands of a learning curve: ``se`` the mean and its standard error over runs, ``iqr`` the median and quartiles.
BANDS = ("se", "iqr")
#: The formats written, by the output's extension.
FORMATS = ("png", "pdf", "svg")
#: Points of the common grid the runs' curves are interpolated onto.
CURVE_POINTS = 200
#: The share of the axis the seeds that are not clipped keep at least (see :func:`readable_limits`).
MIN_SHARE = 0.25


def _require_matplotlib() -> None:
    """Fail with one line naming the extra when matplotlib is not installed."""
    with requires("matplotlib", "zoo", "plotting"):
        import matplotlib  # noqa: F401


# ---------------------------------------------------------------------------------------------- runs
@dataclass(frozen=True)
class Run:
    """One training run (one seed) of an algorithm.

    :param algo: the zoo algorithm (``ppo``, ``em_ppo``...)
    :param env_id: the environment id
    :param folder: the zoo run folder (``<log-folder>/<algo>/<env>_<n>``), or its tensorboard folder
    :param agents_per_copy: the vector entries of one environment copy (its UAVs; 1 on the centralised view): the
        monitor rows of one team episode
    :param team_size: the team's UAVs (``n_uavs``)
    """

    algo: str
    env_id: str
    folder: Path
    agents_per_copy: int
    team_size: int

    @property
    def uav_steps_per_timestep(self) -> int:
        """Agent-steps (one per UAV per step) in one of SB3's timesteps: 1 on the parameter-sharing view (a timestep
        is a vector entry's step), the team's UAVs on the centralised one (a timestep moves the whole team)."""
        return self.team_size // self.agents_per_copy


def _run_number(folder: Path, prefix: str) -> int | None:
    """``n`` of a folder named ``<prefix>_<n>``, else None."""
    match = re.fullmatch(re.escape(prefix) + r"_(\d+)", folder.name)
    return int(match.group(1)) if match and folder.is_dir() else None


def make_run(algo: str, env_id: str, folder: Path, env_kwargs: Mapping[str, Any]) -> Run:
    """A run of ``algo`` on ``env_id``: its team's UAVs (``n_uavs`` of the environment's configuration, built from
    ``env_kwargs`` without building the environment), each a vector entry on the parameter-sharing view, the team one
    entry on the centralised one.

    :param algo: the zoo algorithm
    :param env_id: the environment id
    :param folder: the run's folder
    :param env_kwargs: the environment's arguments the run was trained with
    """
    import importlib

    from sb3_emmarl.common.environments import ENV_CONFIGS
    from sb3_emmarl.zoo.algos import CENTRALIZED_ALGOS

    module, name = ENV_CONFIGS[env_id].split(":")
    team_size = int(getattr(importlib.import_module(module), name).from_kwargs(**env_kwargs).n_uavs)
    return Run(algo, env_id, folder, 1 if algo in CENTRALIZED_ALGOS else team_size, team_size)


def _run_env_kwargs(folder: Path, env_id: str) -> dict[str, Any]:
    """The environment's arguments of a zoo run, from its ``config.yml`` (empty when it has none)."""
    from sb3_emmarl.common.safe_config import load_yaml

    config_file = folder / env_id / "config.yml"
    if not config_file.is_file():
        return {}
    return dict(load_yaml(config_file, "the run's config").get("env_kwargs") or {})


def zoo_runs(log_folders: Sequence[str | Path], algos: Sequence[str] | None = None,
             env_id: str | None = None) -> list[Run]:
    """The runs of the zoo's log folders, in the zoo's layout ``<log-folder>/<algo>/<env>_<n>/``.

    :param log_folders: the folders given to ``train -f``
    :param algos: the algorithms (None: every zoo algorithm that has a folder)
    :param env_id: the environment (None: every known environment); the runs saved under its former ids
        (:func:`~sb3_emmarl.common.environments.folder_ids`) count as its own
    :return: the runs, by algorithm (in ``algos``' order), environment and run number
    """
    from sb3_emmarl.common.environments import ENV_MODULES, folder_ids
    from sb3_emmarl.zoo.algos import ZOO_ALGOS

    names = list(algos) if algos is not None else sorted(ZOO_ALGOS)
    env_ids = [env_id] if env_id is not None else sorted(ENV_MODULES)
    runs = []
    for algo in names:
        for env in env_ids:
            for name in folder_ids(env):  # runs saved under a former id count as the current id's
                for log_folder in log_folders:
                    algo_folder = Path(log_folder) / algo
                    found = sorted((n, f) for f in (algo_folder.iterdir() if algo_folder.is_dir() else [])
                                   if (n := _run_number(f, name)) is not None)
                    runs += [make_run(algo, env, folder, _run_env_kwargs(folder, name)) for _, folder in found]
    return runs


def tensorboard_name(algo: str) -> str:
    """The name SB3 gives the tensorboard runs of ``algo`` (``learn``'s ``tb_log_name``: ``PPO``, ``EMPPO``...), under
    which the zoo writes them (``<tb>/<env>/<name>_<n>``)."""
    import inspect

    from sb3_emmarl.zoo.algos import ZOO_ALGOS

    return str(inspect.signature(ZOO_ALGOS[algo].learn).parameters["tb_log_name"].default)


def tensorboard_runs(tensorboard_log: str | Path, zoo: Sequence[Run]) -> list[Run]:
    """The tensorboard runs the zoo wrote with ``train -tb <tensorboard_log>`` beside the zoo runs ``zoo``:
    ``<tensorboard_log>/<env>/<name>_<n>``, ``name`` the algorithm's :func:`tensorboard_name`. A tensorboard folder does
    not say its team's size: each algorithm's runs take its zoo runs' (which must agree on the centralised view, where
    it converts SB3's timesteps to agent-steps).

    :param tensorboard_log: the folder given to ``train -tb``
    :param zoo: the zoo runs (one environment's) whose algorithms to look for
    :raise ValueError: when two of the algorithms write runs of one name (PPO's variants), which cannot be told apart,
        or a centralised algorithm's zoo runs have teams of several sizes
    """
    env_id = zoo[0].env_id
    like: dict[str, Run] = {}
    for run in zoo:
        known = like.setdefault(run.algo, run)
        if known.uav_steps_per_timestep != run.uav_steps_per_timestep:
            raise ValueError(f"{run.algo}'s runs have teams of {known.team_size} and {run.team_size} UAVs, and its "
                             "tensorboard runs do not say which is which: plot its scalars from its run folders")
    names: dict[str, str] = {}
    for algo in like:
        name = tensorboard_name(algo)
        if name in names:
            raise ValueError(f"{names[name]} and {algo} both write their tensorboard runs as {name}_<n>, which cannot "
                             f"be told apart: plot them one at a time, each from the -tb folder it was trained with")
        names[name] = algo
    from sb3_emmarl.common.environments import folder_ids

    runs = []
    for name, algo in names.items():
        for folder in (Path(tensorboard_log) / saved for saved in folder_ids(env_id)):
            found = sorted((n, f) for f in (folder.iterdir() if folder.is_dir() else [])
                           if (n := _run_number(f, name)) is not None)
            runs += [Run(algo, env_id, run_folder, like[algo].agents_per_copy, like[algo].team_size)
                     for _, run_folder in found]
    return runs


# ---------------------------------------------------------------------------------------------- reading
def team_episodes(folder: str | Path, agents_per_copy: int, team_size: int | None = None) -> pd.DataFrame:
    """A run's team episodes from its monitor files (SB3's ``load_results``: ``*monitor.csv``, in time order).

    A parameter-sharing run's monitor file holds one row per UAV episode; the ``agents_per_copy`` rows of a copy's
    episode are written together when it ends, so each block of ``agents_per_copy`` rows is one team episode.

    :param folder: the run folder
    :param agents_per_copy: the rows of one team episode (1: each row is one)
    :param team_size: the team's UAVs (default ``agents_per_copy``; on the centralised view one row is a whole team's)
    :return: one row per team episode: ``r`` the team reward (the mean of its UAVs' returns: each UAV's return is the
        team reward unless the environment shapes rewards per UAV), ``l`` its agent-steps (UAVs x steps, so that SB3's
        ``ts2xy`` counts agent-steps), ``steps`` its length in steps, ``t`` the wall time in seconds at its end
    :raise ValueError: when the rows are not blocks of ``agents_per_copy`` episodes of one length
    """
    import pandas as pd
    from stable_baselines3.common.monitor import load_results

    rows = load_results(str(folder))
    if len(rows) % agents_per_copy:
        raise ValueError(f"{folder}: {len(rows)} monitor rows, not whole team episodes of {agents_per_copy} UAVs")
    rewards, lengths, times = (rows[column].to_numpy(dtype=float).reshape(-1, agents_per_copy)
                               for column in ("r", "l", "t"))
    if (lengths != lengths[:, :1]).any():
        raise ValueError(f"{folder}: monitor rows of one team episode of {agents_per_copy} UAVs differ in length; "
                         "is this a parameter-sharing run?")
    return pd.DataFrame({"r": rewards.mean(axis=1), "l": lengths[:, 0] * (team_size or agents_per_copy),
                         "steps": lengths[:, 0],
                         "t": times.max(axis=1)})


def _event_files(folder: Path) -> list[Path]:
    return sorted(folder.rglob("events.out.tfevents.*")) if folder.is_dir() else []


def read_scalars(folder: str | Path) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Every tensorboard scalar of a run, from every event file under its folder (a resumed run writes several).

    :param folder: the run's folder, searched recursively
    :return: ``{tag: (steps, hours, values)}`` sorted by step, ``hours`` the wall time since the run's first event (its
        event file's creation, when training starts), the last written value kept where a step repeats
    """
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    events: dict[str, list[Any]] = {}
    start = np.inf
    for file in _event_files(Path(folder)):
        accumulator = EventAccumulator(str(file), size_guidance={"scalars": 0})  # 0: keep every point
        accumulator.Reload()
        start = min(start, accumulator.FirstEventTimestamp())
        for tag in accumulator.Tags().get("scalars", []):
            events.setdefault(tag, []).extend(accumulator.Scalars(tag))
    scalars = {}
    for tag, tag_events in events.items():
        by_step = {int(e.step): e for e in sorted(tag_events, key=lambda e: e.wall_time)}
        ordered = [by_step[step] for step in sorted(by_step)]
        scalars[tag] = (np.array([e.step for e in ordered], dtype=float),
                        np.array([(e.wall_time - start) / 3600.0 for e in ordered]),
                        np.array([e.value for e in ordered], dtype=float))
    return scalars


def monitor_curve(run: Run, key: str, x_axis: str, window: int) -> tuple[np.ndarray, np.ndarray] | None:
    """A run's curve of team episodes from its monitor files: the rolling mean of ``key`` over ``window`` team
    episodes (SB3's ``window_func``) against agent-steps or wall time (SB3's ``ts2xy``: hours).

    :param run: the run
    :param key: a key of :data:`MONITOR_KEYS`
    :param x_axis: ``steps`` or ``time``
    :param window: team episodes per rolling mean
    :return: (x, y), None when the run has no finished team episode
    :raise ValueError: when the run has fewer team episodes than ``window``
    """
    from stable_baselines3.common.results_plotter import X_TIMESTEPS, X_WALLTIME, ts2xy, window_func

    episodes = team_episodes(run.folder, run.agents_per_copy, run.team_size)
    if episodes.empty:
        return None
    if len(episodes) < window:
        raise ValueError(f"{run.folder} has {len(episodes)} team episodes, fewer than -w/--episode-window {window}: "
                         f"give -w {len(episodes)} or less")
    x, _ = ts2xy(episodes, X_TIMESTEPS if x_axis == "steps" else X_WALLTIME)
    y = episodes["r" if key == "reward" else "steps"].to_numpy(dtype=float)
    return window_func(np.asarray(x, dtype=float), y, window, np.mean)


# ---------------------------------------------------------------------------------------------- curves
@dataclass(frozen=True)
class Curve:
    """Runs' curves on a common grid: the centre and the band over runs at each point.

    :param x: the grid
    :param center: the mean (band ``se``) or the median (band ``iqr``) over runs
    :param low: the lower edge of the band (mean - standard error, or the lower quartile)
    :param high: the upper edge of the band
    :param n_runs: the runs
    """

    x: np.ndarray
    center: np.ndarray
    low: np.ndarray
    high: np.ndarray
    n_runs: int


def aggregate_curves(curves: Sequence[tuple[np.ndarray, np.ndarray]], band: str = "se",
                     points: int = CURVE_POINTS) -> Curve:
    """Runs' curves interpolated linearly onto a common grid of the x range all of them cover (from the latest first x
    to the earliest last x: no extrapolation), then summarised over runs at each point.

    :param curves: each run's (x, y), x increasing
    :param band: ``se``: the mean and the mean +- its standard error (sample std / sqrt(runs); no band for one run);
        ``iqr``: the median and the quartiles (numpy's linear interpolation)
    :param points: grid points
    :raise ValueError: for an unknown band, no curve, or runs that share no x range
    """
    if band not in BANDS:
        raise ValueError(f"unknown band {band!r}; allowed: {', '.join(BANDS)}")
    if not curves:
        raise ValueError("no curve to aggregate")
    low_x = max(float(x[0]) for x, _ in curves)
    high_x = min(float(x[-1]) for x, _ in curves)
    if high_x < low_x:
        raise ValueError(f"the runs share no x range (one ends at {high_x:.4g}, another starts at {low_x:.4g})")
    grid = np.linspace(low_x, high_x, points) if high_x > low_x else np.array([low_x])
    stacked = np.stack([np.interp(grid, x, y) for x, y in curves])
    if band == "iqr":
        low, center, high = np.percentile(stacked, [25, 50, 75], axis=0)
    else:
        center = stacked.mean(axis=0)
        error = stacked.std(axis=0, ddof=1) / np.sqrt(len(curves)) if len(curves) > 1 else np.zeros_like(center)
        low, high = center - error, center + error
    return Curve(grid, center, low, high, len(curves))


def time_unit(hours: float) -> tuple[str, float]:
    """The unit a wall-time axis reaching ``hours`` reads best in, and its factor from hours."""
    if hours * 3600 < 120:
        return "s", 3600.0
    if hours < 2:
        return "min", 60.0
    return "h", 1.0


def draw_curves(ax: Axes, curves: Mapping[str, Curve], x_axis: str = "steps", ylabel: str = "") -> None:
    """One line per label (its centre) with its band shaded.

    :param ax: the axes drawn on
    :param curves: a :class:`Curve` per label (an algorithm)
    :param x_axis: ``steps`` (agent-steps) or ``time`` (the curves' x in hours, shown in the unit that reads best)
    :param ylabel: the y axis' label
    """
    unit, factor = time_unit(max(float(c.x[-1]) for c in curves.values())) if x_axis == "time" else ("", 1.0)
    for i, (label, curve) in enumerate(curves.items()):
        colour = f"C{i % 10}"
        x = curve.x * factor
        ax.plot(x, curve.center, color=colour, marker="o" if x.size == 1 else None,
                label=f"{label} ({curve.n_runs} run{'s' * (curve.n_runs > 1)})")
        ax.fill_between(x, curve.low, curve.high, color=colour, alpha=0.2, linewidth=0)
    if x_axis == "steps":
        from matplotlib.ticker import EngFormatter

        ax.xaxis.set_major_formatter(EngFormatter(sep=""))  # 300k, 2M
    ax.set_xlabel("agent-steps (one per UAV per step)" if x_axis == "steps" else f"wall time ({unit})")
    ax.set_ylabel(ylabel)
    ax.grid(alpha=0.3)
    ax.legend(fontsize="small")


# ---------------------------------------------------------------------------------------------- bars
def readable_limits(values: Sequence[float] | np.ndarray, keep: Sequence[float], min_share: float = MIN_SHARE
                    ) -> tuple[float, float, np.ndarray]:
    """The range of an axis that keeps ``values`` readable when a few of them lie far from the rest.

    A group of the lowest (or highest) values is clipped when the gap between it and the rest is larger than
    ``1 / min_share - 1`` times the rest's span: drawn on one axis, it would squeeze every other value into less than
    ``min_share`` of it. The points of ``keep`` (the medians, the bars' baseline) are never clipped. Of the ways to
    clip that satisfy this at each clipped end, the one whose rest spans least is taken (the fewest values clipped
    among equals); none when the rest would have no span.

    :param values: every value drawn (every seed of every arm)
    :param keep: points the range must include
    :param min_share: the share of the axis the values that are not clipped keep at least, in (0, 1)
    :return: (low, high, clipped): the range of the values kept and ``keep``, and a mask over ``values`` of those
        outside it
    :raise ValueError: for no values or keep, a value that is not finite, or ``min_share`` outside (0, 1)
    """
    data = np.asarray(values, dtype=float)
    kept = np.asarray(keep, dtype=float)
    if not data.size or not kept.size:
        raise ValueError("readable_limits needs values and points to keep")
    if not (np.isfinite(data).all() and np.isfinite(kept).all()):
        raise ValueError("readable_limits takes finite values only")
    if not 0 < min_share < 1:
        raise ValueError(f"min_share must be in (0, 1), got {min_share}")
    order = np.sort(data)
    n = order.size
    keep_low, keep_high = float(kept.min()), float(kept.max())
    max_low = int(np.searchsorted(order, keep_low, side="left"))  # values below every kept point
    max_high = n - int(np.searchsorted(order, keep_high, side="right"))
    factor = 1.0 / min_share - 1.0
    best = (0, 0)
    best_span = max(order[-1], keep_high) - min(order[0], keep_low)
    for n_low in range(max_low + 1):
        for n_high in range(max_high + 1):
            if n_low + n_high == 0 or n_low + n_high >= n:
                continue
            low = min(float(order[n_low]), keep_low)
            high = max(float(order[n - n_high - 1]), keep_high)
            span = high - low
            if span <= 0:
                continue
            if n_low and low - order[n_low - 1] <= factor * span:
                continue
            if n_high and order[n - n_high] - high <= factor * span:
                continue
            if span < best_span or (span == best_span and n_low + n_high < sum(best)):
                best, best_span = (n_low, n_high), span
    low = min(float(order[best[0]]), keep_low)
    high = max(float(order[n - best[1] - 1]), keep_high)
    return low, high, (data < low) | (data > high)


@dataclass(frozen=True)
class SeedBars:
    """What :func:`seed_bars` drew.

    :param medians: the bar of each arm
    :param quartiles: the whiskers of each arm (lower, upper quartile)
    :param clipped: each arm's seeds drawn as arrows at the axis' edge (empty lists for the others)
    :param ylim: the y range of the axes
    """

    medians: dict[str, float]
    quartiles: dict[str, tuple[float, float]]
    clipped: dict[str, list[float]]
    ylim: tuple[float, float]


def seed_bars(ax: Axes, values_by_arm: Mapping[str, Sequence[float]], *, ylabel: str | None = None,
              positions: Mapping[str, float] | None = None, colors: Mapping[str, str] | None = None,
              labels: Mapping[str, str] | None = None, width: float = 0.8, baseline: float | None = 0.0,
              min_share: float = MIN_SHARE, seed: int = 0) -> SeedBars:
    """Per-seed bars robust to outliers: one bar per arm from ``baseline`` to the median over its seeds, whiskers at
    the quartiles (numpy's linear interpolation), every seed a dot, on a y range from :func:`readable_limits`. A seed
    that would squeeze the others into less than ``min_share`` of the axis is drawn as an arrow at the axis' edge with
    its value written beside it (a whisker that reaches beyond the range runs off the axis).

    :param ax: the axes drawn on
    :param values_by_arm: each arm's values, one per seed (an arm: an algorithm, or an (algorithm, condition) pair)
    :param ylabel: the y axis' label
    :param positions: each arm's x (grouped bars); None: 0, 1, ... with the arms' names as ticks
    :param colors: each arm's colour (default matplotlib's cycle, by arm)
    :param labels: each arm's legend label (an arm absent here gets none)
    :param width: the bars' slot width (the bar takes 90 % of it, the dots 40 %)
    :param baseline: where the bars start (drawn as a line); None: no bars, the medians drawn as wide ticks
    :param min_share: see :func:`readable_limits`
    :param seed: seed of the dots' jitter (the same figure at every redraw)
    :return: the medians, quartiles, clipped seeds and y range drawn
    :raise ValueError: for no arm, an arm without values, a value that is not finite, or an arm without a position
    """
    if not values_by_arm:
        raise ValueError("seed_bars needs at least one arm")
    arrays = {arm: np.asarray(values, dtype=float) for arm, values in values_by_arm.items()}
    for arm, array in arrays.items():
        if not array.size or not np.isfinite(array).all():
            raise ValueError(f"arm {arm!r}: seed_bars needs at least one value, all finite; got {array.tolist()}")
    xs = dict(positions) if positions is not None else {arm: float(i) for i, arm in enumerate(arrays)}
    if missing := [arm for arm in arrays if arm not in xs]:
        raise ValueError(f"positions has no x for the arm(s) {missing}; it has {list(xs)}")
    medians = {arm: float(np.median(a)) for arm, a in arrays.items()}
    quartiles = {arm: (float(np.percentile(a, 25)), float(np.percentile(a, 75))) for arm, a in arrays.items()}
    keep = [*medians.values(), *([baseline] if baseline is not None else [])]
    low, high, _ = readable_limits(np.concatenate(list(arrays.values())), keep, min_share)
    span = high - low if high > low else max(abs(high), 1.0)
    below = any((a < low).any() for a in arrays.values())
    above = any((a > high).any() for a in arrays.values())
    ylim = (low - (0.2 if below else 0.06) * span, high + (0.2 if above else 0.06) * span)
    rng = np.random.default_rng(seed)
    clipped: dict[str, list[float]] = {}
    for i, (arm, array) in enumerate(arrays.items()):
        x, colour = xs[arm], (colors or {}).get(arm, f"C{i % 10}")
        label = (labels or {}).get(arm)
        if baseline is not None:
            ax.bar(x, medians[arm] - baseline, width * 0.9, bottom=baseline, color=colour, alpha=0.8,
                   label=label or "_nolegend_")
        else:
            ax.hlines(medians[arm], x - 0.45 * width, x + 0.45 * width, color=colour, linewidth=3,
                      label=label or "_nolegend_")
        q1, q3 = quartiles[arm]
        ax.errorbar([x], [medians[arm]], yerr=[[medians[arm] - q1], [q3 - medians[arm]]], fmt="none", ecolor="black",
                    elinewidth=1, capsize=3, zorder=3)
        jitter = x + rng.uniform(-0.2, 0.2, array.size) * width
        inside = (array >= low) & (array <= high)
        ax.scatter(jitter[inside], array[inside], s=14, color="black", zorder=4, linewidths=0)
        clipped[arm] = sorted(array[~inside].tolist())
        for edge, outside in ((ylim[0], array < low), (ylim[1], array > high)):
            if outside.any():
                text = ", ".join(f"{v:.4g}" for v in sorted(array[outside]))
                inner = edge + (0.12 if edge == ylim[0] else -0.12) * span
                ax.annotate(text, xy=(x, edge), xytext=(x, inner), ha="center",
                            va="bottom" if edge == ylim[0] else "top", fontsize="small", annotation_clip=False,
                            arrowprops={"arrowstyle": "->", "color": "black", "lw": 1})
    if baseline is not None:
        ax.axhline(baseline, color="grey", linewidth=0.6)
    if positions is None:
        ax.set_xticks(list(xs.values()), list(xs))
        ax.set_xlim(-0.75, len(xs) - 0.25)
    ax.set_ylim(*ylim)
    if ylabel is not None:
        ax.set_ylabel(ylabel)
    return SeedBars(medians, quartiles, clipped, (float(ax.get_ylim()[0]), float(ax.get_ylim()[1])))


# ---------------------------------------------------------------------------------------------- command line
def plot_parser() -> argparse.ArgumentParser:
    """The flags of ``emmarl plot`` (rl-baselines3-zoo's ``plot_train`` / ``all_plots`` names where they fit)."""
    from sb3_emmarl.common.environments import ENV_MODULES
    from sb3_emmarl.common.validation import float_flag, int_flag
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
    from sb3_emmarl.common.atomic_files import write_atomic

    write_atomic(output, lambda file: figure.savefig(file, format=output.suffix.lower().lstrip("."), dpi=120))
    print(f"wrote {output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
