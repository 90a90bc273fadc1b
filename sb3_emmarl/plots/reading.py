"""Reading runs with the libraries that wrote them: team episodes from SB3's monitor files, scalars from tensorboard's
event files."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from sb3_emmarl.plots.runs import Run

if TYPE_CHECKING:
    import pandas as pd  # type: ignore[import-untyped]  # (no stubs installed)

#: The monitor files' keys and the axis label of each (a team episode: one episode of a copy's whole team).
MONITOR_KEYS: dict[str, str] = {"reward": "team reward", "length": "team episode length (steps)"}


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
