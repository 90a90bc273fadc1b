"""Drawing: curves aggregated over runs on a common grid, and per-seed bars on an axis one outlying seed does not
flatten (matplotlib's ``Agg`` canvas, without pyplot)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from sb3_emmarl.common.trust.extras import requires

if TYPE_CHECKING:
    from matplotlib.axes import Axes

#: The bands of a learning curve: ``se`` the mean and its standard error over runs, ``iqr`` the median and quartiles.
BANDS = ("se", "iqr")
#: Points of the common grid the runs' curves are interpolated onto.
CURVE_POINTS = 200
#: The share of the axis the seeds that are not clipped keep at least (see :func:`readable_limits`).
MIN_SHARE = 0.25


def _require_matplotlib() -> None:
    """Fail with one line naming the extra when matplotlib is not installed."""
    with requires("matplotlib", "zoo", "plotting"):
        import matplotlib  # noqa: F401


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
