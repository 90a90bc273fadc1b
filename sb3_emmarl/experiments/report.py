"""Reports of an experiment's finished cells: the table, the figures and their section of ``docs/results.md``.

Everything here reads the rows of a :class:`~sb3_emmarl.experiments.store.ResultStore` (one per finished
(algorithm, condition, seed) cell) and the specification that produced them:

- :func:`summary_rows` / :func:`markdown_table`: mean +- std over seeds of every metric of the specification, per
  (condition, algorithm), the mean paired difference against the reference algorithm with its paired t-test over seeds
  (:func:`sb3_emmarl.common.statistics.paired_p_value`), and the paper's claimed value beside it;
- :func:`figure_bars`: a metric as grouped per-seed bars (conditions x algorithms): medians, quartiles, every seed a
  dot, on an axis one collapsed seed does not flatten (:func:`sb3_emmarl.plots.seed_bars`);
- :func:`figure_curves`: learning curves read from the cells' tensorboard event files, mean +- standard error over
  seeds on a common grid of agent-steps (:func:`sb3_emmarl.plots.aggregate_curves`);
- :func:`figure_trajectories`: a team's paths over one episode on the reserve's grid;
- :func:`render_section` / :func:`update_results_page`: one markdown section per experiment, kept between markers in
  the results page so that regenerating one experiment leaves the rest of the page as it was.

The figures are drawn on matplotlib's ``Agg`` canvas (no display, no pyplot state): each function returns its
:class:`~matplotlib.figure.Figure` after saving it as a PNG.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from sb3_emmarl.common.statistics import paired_p_value
from sb3_emmarl.common.trust.atomic_files import write_atomic, write_text
from sb3_emmarl.common.trust.extras import requires
from sb3_emmarl.experiments.spec import ExperimentSpec
from sb3_emmarl.experiments.store import UNKNOWN
from wildlife_reserve.reserve.terrain import TERRAIN_NAMES

with requires("matplotlib", "zoo", "the experiments' figures"):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.colors import ListedColormap
    from matplotlib.figure import Figure

#: Shown in a table where there is no value.
MISSING = "-"
#: The heading above the experiments' sections of the results page (added once).
RESULTS_HEADING = "## The paper's experiments, regenerated"
#: UAVs named in a trajectory plot's legend.
MAX_LEGEND_UAVS = 10
#: The reserve's terrain colours (open, forest, mountain: ``wildlife_reserve.reserve.terrain``).
TERRAIN_CMAP = ListedColormap(["#efe9cf", "#9cc68a", "#b3aa9c"], name="reserve_terrain")


# ---------------------------------------------------------------------------------------------- table
def _cells(spec: ExperimentSpec, rows: Sequence[dict[str, Any]]) -> dict[tuple[str, str], list[dict[str, Any]]]:
    """The rows of every (condition, algorithm) of the specification that has some, in the specification's order."""
    cells: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for condition in spec.conditions:
        for algorithm in spec.algorithms:
            found = sorted((r for r in rows if r["condition"] == condition and r["algorithm"] == algorithm),
                           key=lambda r: r["seed"])
            if found:
                cells[(condition, algorithm)] = found
    return cells


def _by_seed(cell_rows: Sequence[dict[str, Any]], metric: str) -> dict[int, float]:
    """A metric's value per seed, for the seeds whose cell has it."""
    return {int(r["seed"]): float(r["metrics"][metric]) for r in cell_rows
            if r["metrics"].get(metric) is not None}


def summary_rows(spec: ExperimentSpec, rows: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Mean and std over seeds of every metric of the specification, per (condition, algorithm).

    :param spec: the experiment's specification (its conditions, algorithms, metrics and reference)
    :param rows: finished cells as :meth:`ResultStore.rows` returns them; cells of algorithms or conditions the
        specification does not name are ignored
    :return: one dict per (condition, algorithm) with at least one finished seed, in the specification's order:
        ``condition``, ``algorithm``, ``n`` (seeds), ``seeds``, and per metric (dicts keyed by metric; a metric
        no seed of the cell has, such as a latent metric of a non-EM algorithm, is absent): ``mean``, ``std``
        (numpy, ``ddof=0``), ``values`` (per seed, in the order of ``seeds``); when the specification has a
        reference and this is not it: ``diff`` (mean of algorithm - reference over the seeds both have in the same
        condition), ``p`` (paired t-test over those seeds, :func:`~sb3_emmarl.common.statistics.paired_p_value`) and
        ``pairs`` (how many seeds)
    """
    cells = _cells(spec, rows)
    summary = []
    for (condition, algorithm), cell_rows in cells.items():
        entry: dict[str, Any] = {"condition": condition, "algorithm": algorithm, "n": len(cell_rows),
                                 "seeds": [int(r["seed"]) for r in cell_rows], "mean": {}, "std": {}, "values": {},
                                 "diff": {}, "p": {}, "pairs": {}}
        reference_rows = cells.get((condition, spec.reference)) if spec.reference not in (None, algorithm) else None
        for metric in spec.metrics:
            values = _by_seed(cell_rows, metric)
            if not values:
                continue
            array = np.array(list(values.values()), dtype=float)
            entry["mean"][metric] = float(np.mean(array))
            entry["std"][metric] = float(np.std(array, ddof=0))
            entry["values"][metric] = array.tolist()
            if reference_rows is None:
                continue
            reference = _by_seed(reference_rows, metric)
            seeds = sorted(set(values) & set(reference))
            if not seeds:
                continue
            a = np.array([values[s] for s in seeds])
            b = np.array([reference[s] for s in seeds])
            entry["diff"][metric] = float(np.mean(a - b))
            entry["p"][metric] = paired_p_value(a, b)
            entry["pairs"][metric] = len(seeds)
        summary.append(entry)
    return summary


def _number(value: float) -> str:
    return f"{value:.3f}"


def _p(value: float) -> str:
    return f"{value:.2g}"


def _cell_text(value: Any) -> str:
    """A value as a markdown table cell (pipes escaped)."""
    return str(value).replace("|", "\\|").replace("\n", " ")


def claim(spec: ExperimentSpec, algorithm: str, condition: str, metric: str) -> Any:
    """The paper's claimed value of a metric, as written in the specification, or None.

    :param spec: the specification (its ``claims``: algorithm -> condition -> metric -> value)
    :param algorithm: the specification's name of the algorithm
    :param condition: the condition
    :param metric: the metric
    """
    return ((spec.claims.get(algorithm) or {}).get(condition) or {}).get(metric)


def _claimed_metrics(spec: ExperimentSpec) -> set[str]:
    return {metric for by_condition in spec.claims.values() for values in (by_condition or {}).values()
            for metric in (values or {})}


def markdown_table(spec: ExperimentSpec, rows: Sequence[dict[str, Any]]) -> str:
    """The experiment's table in GitHub markdown (from :func:`summary_rows`).

    Columns: condition, algorithm, seeds, then per metric its ``mean +- std`` over seeds, the paper's claim beside it
    (only for metrics the specification claims something for; ``-`` where the paper claims nothing) and, when the
    specification has a reference, ``diff vs REF (p)``: the mean paired difference over seeds and the paired t-test's
    p-value (``-`` on the reference's own rows). A metric a cell does not have is ``-``.

    :param spec: the experiment's specification
    :param rows: finished cells as :meth:`ResultStore.rows` returns them
    :return: the table, one line per (condition, algorithm) with finished seeds, ending with a newline
    """
    claimed = _claimed_metrics(spec)
    header = ["condition", "algorithm", "seeds"]
    for metric in spec.metrics:
        header.append(f"{metric} (mean +- std)")
        if metric in claimed:
            header.append(f"{metric}: paper")
        if spec.reference is not None:
            header.append(f"{metric}: diff vs {spec.reference} (p)")
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join(["---"] * 2 + ["---:"] * (len(header) - 2)) + "|"]
    for entry in summary_rows(spec, rows):
        cells = [entry["condition"], entry["algorithm"], str(entry["n"])]
        for metric in spec.metrics:
            if metric in entry["mean"]:
                cells.append(f"{_number(entry['mean'][metric])} +- {_number(entry['std'][metric])}")
            else:
                cells.append(MISSING)
            if metric in claimed:
                value = claim(spec, entry["algorithm"], entry["condition"], metric)
                cells.append(MISSING if value is None else value)
            if spec.reference is not None:
                if metric in entry["diff"]:
                    cells.append(f"{entry['diff'][metric]:+.3f} ({_p(entry['p'][metric])})")
                else:
                    cells.append(MISSING)
        lines.append("| " + " | ".join(_cell_text(c) for c in cells) + " |")
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------------------------------------- figures
def _new_figure(size: tuple[float, float]) -> Figure:
    figure = Figure(figsize=size, layout="constrained")
    FigureCanvasAgg(figure)
    return figure


def _save(figure: Figure, path: str | Path) -> Figure:
    """Save a figure as a PNG (parent folders created) and release its renderer's memory."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    # The figure was never registered with pyplot: there is nothing to close, and it is freed with the caller's
    # last reference.
    write_atomic(path, lambda file: figure.savefig(file, format="png", dpi=120))
    return figure


def figure_bars(spec: ExperimentSpec, rows: Sequence[dict[str, Any]], metric: str, path: str | Path) -> Figure:
    """A metric as grouped per-seed bars that one outlying seed does not flatten: one group per condition, one bar per
    algorithm (:func:`sb3_emmarl.plots.seed_bars`).

    Bar height: median over seeds; whiskers: the quartiles; every seed's value is a dot on its bar; the y range keeps
    the other seeds readable, a seed far outside it drawn as an arrow at the axis' edge with its value beside it.

    :param spec: the experiment's specification (order of conditions and algorithms, the paper's name for the title)
    :param rows: finished cells as :meth:`ResultStore.rows` returns them
    :param metric: the metric drawn (a key of the rows' ``metrics``)
    :param path: the PNG written (parent folders created)
    :return: the figure
    :raise ValueError: when no finished cell has the metric
    """
    from sb3_emmarl.plots.drawing import seed_bars

    conditions = list(spec.conditions)
    algorithms = list(spec.algorithms)
    width = 0.8 / len(algorithms)
    values: dict[str, list[float]] = {}
    positions: dict[str, float] = {}
    colours: dict[str, str] = {}
    labels: dict[str, str] = {}
    for (condition, algorithm), cell_rows in _cells(spec, rows).items():
        seeds = list(_by_seed(cell_rows, metric).values())
        if not seeds:
            continue
        arm = f"{algorithm}, {condition}"
        values[arm] = seeds
        positions[arm] = conditions.index(condition) + (algorithms.index(algorithm) - (len(algorithms) - 1) / 2) * width
        colours[arm] = f"C{algorithms.index(algorithm) % 10}"
        if algorithm not in labels.values():
            labels[arm] = algorithm  # the legend names each algorithm once
    if not values:
        raise ValueError(f"no finished cell of {spec.name} has the metric {metric!r}")
    figure = _new_figure((max(5.0, 1.2 + 0.5 * len(conditions) * len(algorithms)), 4.0))
    ax = figure.add_subplot()
    seed_bars(ax, values, ylabel=metric, positions=positions, colors=colours, labels=labels, width=width)
    ax.set_xticks(range(len(conditions)), conditions)
    ax.set_xlim(-0.6, len(conditions) - 0.4)
    ax.set_xlabel("condition")
    ax.set_title(f"{spec.paper}: {metric}\n(medians over seeds, quartiles, seeds as dots)")
    ax.legend(title="algorithm", fontsize="small")
    return _save(figure, path)


def read_curve(run_dir: str | Path, tag: str) -> tuple[np.ndarray, np.ndarray] | None:
    """A tensorboard scalar of a run, from every event file under its folder (a resumed run writes several), as
    :func:`sb3_emmarl.plots.read_scalars` reads them.

    :param run_dir: the run's folder, searched recursively
    :param tag: the scalar's tag (``rollout/ep_rew_mean``, ...)
    :return: (steps, values) sorted by step, the last written value kept where a step repeats; None when no event
        file under ``run_dir`` has the tag
    """
    from sb3_emmarl.plots.reading import read_scalars

    scalar = read_scalars(run_dir).get(tag) if Path(run_dir).is_dir() else None
    return None if scalar is None else (scalar[0], scalar[2])


def figure_curves(spec: ExperimentSpec, rows: Sequence[dict[str, Any]], tag: str, path: str | Path) -> Figure:
    """Learning curves: a tensorboard scalar against agent-steps, mean +- standard error over seeds.

    Each seed's curve is interpolated linearly onto a common grid of the steps all seeds of the (algorithm, condition)
    reached (from the latest first step to the earliest last step: no extrapolation;
    :func:`sb3_emmarl.plots.aggregate_curves`); one line per algorithm (and condition, when the specification has
    several), a shaded band of +- the standard error.

    :param spec: the experiment's specification
    :param rows: finished cells as :meth:`ResultStore.rows` returns them; their ``run_dir`` is searched recursively
        for event files, and rows whose files lack the tag are skipped
    :param tag: the scalar (``rollout/ep_rew_mean``, ``train/entropy_loss``, ...)
    :param path: the PNG written (parent folders created)
    :return: the figure
    :raise ValueError: naming the tag when no row has it
    """
    from sb3_emmarl.plots.drawing import aggregate_curves

    curves: dict[tuple[str, str], list[tuple[np.ndarray, np.ndarray]]] = {}
    for (condition, algorithm), cell_rows in _cells(spec, rows).items():
        found = [curve for curve in (read_curve(r["run_dir"], tag) for r in cell_rows) if curve is not None]
        if found:
            curves[(condition, algorithm)] = found
    if not curves:
        raise ValueError(f"no tensorboard scalar {tag!r} under the run folders of {spec.name}'s {len(rows)} finished "
                         f"cell(s)")
    figure = _new_figure((6.4, 4.2))
    ax = figure.add_subplot()
    several = len(spec.conditions) > 1
    algorithms = list(spec.algorithms)
    conditions = list(spec.conditions)
    styles = ("-", "--", ":", "-.")
    for (condition, algorithm), seeds in curves.items():
        curve = aggregate_curves(seeds, band="se")
        colour = f"C{algorithms.index(algorithm) % 10}"
        label = f"{algorithm}, {condition}" if several else algorithm
        ax.plot(curve.x, curve.center, styles[conditions.index(condition) % len(styles)], color=colour,
                marker="o" if curve.x.size == 1 else None,
                label=f"{label} ({len(seeds)} seed{'s' * (len(seeds) > 1)})")
        ax.fill_between(curve.x, curve.low, curve.high, color=colour, alpha=0.2, linewidth=0)
    ax.set_xlabel("agent-steps")
    ax.set_ylabel(tag)
    ax.set_title(f"{spec.paper}: {tag}\n(mean +- standard error over seeds)")
    ax.legend(fontsize="small")
    ax.grid(alpha=0.3)
    return _save(figure, path)


def figure_trajectories(positions: np.ndarray, path: str | Path, title: str, terrain: np.ndarray | None = None,
                        poachers: np.ndarray | None = None) -> Figure:
    """A team's paths over one episode on the reserve's grid (row 0 at the top, as the reserve draws it).

    :param positions: (T, n_uavs, 2) positions (row, col) of the UAVs at every step
    :param path: the PNG written (parent folders created)
    :param title: the figure's title
    :param terrain: optional (H, W) integer terrain (0 open, 1 forest, 2 mountain) drawn underneath
    :param poachers: optional (T, n_poachers, 2) positions (row, col) of the poachers, NaN where a poacher is absent
        (not entered yet, or gone); drawn as black ``x`` markers along their paths
    :return: the figure; the legend names the first :data:`MAX_LEGEND_UAVS` UAVs (and the poachers and the terrain's
        kinds, if any)
    :raise ValueError: on arrays of the wrong shape
    """
    positions = np.asarray(positions, dtype=float)
    if positions.ndim != 3 or positions.shape[2] != 2 or positions.shape[0] < 1:
        raise ValueError(f"positions must have the shape (T, n_uavs, 2) with T >= 1, got {positions.shape}")
    if poachers is not None:
        poachers = np.asarray(poachers, dtype=float)
        if poachers.ndim != 3 or poachers.shape[2] != 2:
            raise ValueError(f"poachers must have the shape (T, n_poachers, 2), got {poachers.shape}")
    if terrain is not None:
        terrain = np.asarray(terrain)
        if terrain.ndim != 2:
            raise ValueError(f"terrain must have the shape (H, W), got {terrain.shape}")
    figure = _new_figure((6.0, 6.0))
    ax = figure.add_subplot()
    if terrain is not None:
        ax.imshow(terrain, cmap=TERRAIN_CMAP, vmin=0, vmax=TERRAIN_CMAP.N - 1, origin="upper", interpolation="nearest",
                  alpha=0.8)
    n_uavs = positions.shape[1]
    for i in range(n_uavs):
        rows_, cols = positions[:, i, 0], positions[:, i, 1]
        colour = f"C{i % 10}"
        ax.plot(cols, rows_, "-", color=colour, linewidth=1.2, alpha=0.9,
                label=f"UAV {i}" if i < MAX_LEGEND_UAVS else None)
        ax.plot(cols[0], rows_[0], "o", color=colour, markersize=6, markeredgecolor="black")
        ax.plot(cols[-1], rows_[-1], "s", color=colour, markersize=6, markeredgecolor="black")
    if terrain is not None:
        for value, name in enumerate(TERRAIN_NAMES):
            ax.fill_between([], [], color=TERRAIN_CMAP(value), alpha=0.8, label=name)
    if poachers is not None:
        for k in range(poachers.shape[1]):
            ax.plot(poachers[:, k, 1], poachers[:, k, 0], "x", color="black", markersize=4, linestyle=":",
                    linewidth=0.6, label="poachers" if k == 0 else None)
    if terrain is None:
        ax.invert_yaxis()  # imshow's origin="upper" does it when there is a terrain
    ax.set_aspect("equal")
    ax.set_xlabel("col (cells)")
    ax.set_ylabel("row (cells)")
    ax.set_title(f"{title}\n(o: start, s: end)" if n_uavs else title)
    if n_uavs or poachers is not None or terrain is not None:
        ax.legend(fontsize="x-small", loc="upper right", framealpha=0.8)
    return _save(figure, path)


# ---------------------------------------------------------------------------------------------- the results page
def figure_file(spec: ExperimentSpec, kind: str, metric: str) -> str:
    """The file name of an output's figure: ``<spec.name>_<kind>_<metric with / as _>.png``."""
    return f"{spec.name}_{kind}_{metric.replace('/', '_')}.png"


def render_section(spec: ExperimentSpec, rows: Sequence[dict[str, Any]], budget: str, figures_dir: str | Path,
                   command: str, hardware: str) -> str:
    """The experiment's section of a results page: heading, command, hardware, budget, table, the package versions
    and git commits that made its cells (:func:`made_with`), and figures.

    The figures of the outputs of kind ``bars`` and ``curves`` are drawn into ``figures_dir`` and linked as
    ``figures/<file>`` (the page sits beside its ``figures`` folder); a figure that cannot be drawn (no cell has its
    metric or tag yet) is replaced by a line saying why. An output of kind ``trajectories`` draws, for every
    condition and algorithm, the episode its lowest-seed cell recorded (``trajectory.npz`` in the cell's folder).

    :param spec: the experiment's specification
    :param rows: its finished cells in ``budget`` (:meth:`ResultStore.rows`)
    :param budget: the budget's name (``quick`` or ``full``)
    :param figures_dir: where the figures are written
    :param command: the command that regenerates the section (shown verbatim)
    :param hardware: the machine it ran on
    :return: the section's markdown, ending with a newline
    """
    plan = spec.budgets[budget]
    lines = [f"### {spec.paper}: {spec.title}", "",
             f"`{command}` on {hardware}.", "",
             f"Budget `{budget}`: {plan.n_timesteps:,} agent-steps of training per cell, seeds "
             f"{', '.join(str(s) for s in plan.seeds)}, {plan.eval_episodes} evaluation episodes (seed "
             f"{plan.eval_seed}) per cell.", ""]
    if spec.notes:
        lines += [spec.notes.strip(), ""]
    if not rows:
        lines.append(f"No cell of this experiment has finished yet in the `{budget}` budget.")
        return "\n".join(lines) + "\n"
    finished = len({(r["algorithm"], r["condition"], r["seed"]) for r in rows})
    lines.append(f"{finished} of {len(spec.cells(budget))} cells finished. Mean +- std over seeds of each cell's mean "
                 "over its evaluation episodes"
                 + (f"; diff: mean paired difference from {spec.reference} over the seeds both have, p: paired t-test "
                    "over those seeds" if spec.reference is not None else "")
                 + ("; paper: the value the paper reports." if spec.claims else "."))
    lines += ["", markdown_table(spec, rows).rstrip("\n"), "", made_with(rows)]
    figures_dir = Path(figures_dir)
    for output in spec.outputs:
        if output.kind == "trajectories":
            lines += _trajectory_figures(spec, rows, figures_dir)
            continue
        if output.kind not in ("bars", "curves") or output.metric is None:
            continue
        file = figure_file(spec, output.kind, output.metric)
        draw = figure_bars if output.kind == "bars" else figure_curves
        try:
            draw(spec, rows, output.metric, figures_dir / file)
        except ValueError as error:
            lines += ["", f"*No {output.kind} figure of {output.metric}: {error}.*"]
            continue
        lines += ["", f"![{spec.paper}: {output.metric} ({output.kind})](figures/{file})"]
    return "\n".join(lines) + "\n"


def _trajectory_figures(spec: ExperimentSpec, rows: Sequence[dict[str, Any]], figures_dir: Path) -> list[str]:
    """Draw the recorded episode of each (condition, algorithm)'s lowest-seed cell; markdown links or reasons."""
    from sb3_emmarl.experiments.runner import TRAJECTORY_FILE

    lines: list[str] = []
    for (condition, algorithm), cell_rows in _cells(spec, rows).items():
        row = min(cell_rows, key=lambda r: r["seed"])
        path = Path(row["run_dir"]) / TRAJECTORY_FILE
        if not path.is_file():
            lines += ["", f"*No trajectory of {algorithm} / {condition}: {path} is missing.*"]
            continue
        with np.load(path) as data:
            file = figure_file(spec, "trajectories", f"{condition}_{algorithm}")
            title = f"{algorithm}, {condition}, seed {row['seed']}"
            figure_trajectories(data["positions"], figures_dir / file, title, data["terrain"], data["poachers"])
        lines += ["", f"![{spec.paper}: {title}, one evaluation episode](figures/{file})"]
    return lines


def _count(items: Sequence[str]) -> str:
    """``"a (3 cells) and b (9 cells)"`` (a and b two package versions): each distinct item with how many cells have it,
    sorted."""
    counts = {item: items.count(item) for item in sorted(set(items))}
    parts = [f"{item} ({n} cell{'s' * (n != 1)})" for item, n in counts.items()]
    return parts[0] if len(parts) == 1 else ", ".join(parts[:-1]) + " and " + parts[-1]


def check_versions(name: str, budget: str, rows: Sequence[dict[str, Any]], allow_mixed: bool = False) -> list[str]:
    """The package versions that made an experiment's finished cells, refused when there are several.

    :param name: the experiment (for the message)
    :param budget: its budget (for the message)
    :param rows: its finished cells (:meth:`~sb3_emmarl.experiments.store.ResultStore.rows`; cells stored before the
        store recorded versions are ``"unknown"``)
    :param allow_mixed: report several versions together
    :return: the versions, sorted
    :raise ValueError: one line naming the versions and how to go on, when there are several and not ``allow_mixed``
    """
    versions = [str(r.get("version") or UNKNOWN) for r in rows]
    if len(set(versions)) > 1 and not allow_mixed:
        raise ValueError(f"{name} ({budget}): the store holds cells of sb3-emmarl {_count(versions)}"
                         + (" (unknown: stored before cells recorded their version)" if UNKNOWN in versions else "")
                         + "; run the others again with --rerun-stale, or report them together with "
                         "--allow-mixed-versions")
    return sorted(set(versions))


def _short_commit(commit: str) -> str:
    """A commit's first 12 hex digits, with its ``+dirty`` mark if any."""
    sha, plus, mark = commit.partition("+")
    return sha[:12] + plus + mark


def made_with(rows: Sequence[dict[str, Any]]) -> str:
    """The sentence naming the package versions and git commits that made the cells (a table's provenance)."""
    versions = [str(r.get("version") or UNKNOWN) for r in rows]
    commits = [_short_commit(str(r.get("git_commit") or UNKNOWN)) for r in rows]
    several = len(set(commits)) > 1
    return (f"Made with sb3-emmarl {_count(versions) if len(set(versions)) > 1 else versions[0]}, git commit"
            f"{'s' * several} {_count(commits) if several else commits[0]}.")


def _markers(name: str) -> tuple[str, str]:
    return f"<!-- experiment:{name}:begin -->", f"<!-- experiment:{name}:end -->"


def update_results_page(page: str | Path, sections: dict[str, str]) -> None:
    """Put each experiment's section between its markers in the results page, leaving the rest of the page as it was.

    A section whose markers (``<!-- experiment:NAME:begin -->`` ... ``<!-- experiment:NAME:end -->``) are in the page
    replaces what is between them; the others are appended at the end, after the heading :data:`RESULTS_HEADING`
    (added once if the page lacks it). The page is written atomically; running it twice gives the same file.

    :param page: the markdown file (created if missing)
    :param sections: experiment name -> the section's markdown (:func:`render_section`)
    :raise ValueError: when a name's markers are not exactly one begin followed by one end
    """
    page = Path(page)
    text = page.read_text() if page.exists() else ""
    for name, section in sections.items():
        begin, end = _markers(name)
        block = f"{begin}\n{section.strip(chr(10))}\n{end}"
        n_begin, n_end = text.count(begin), text.count(end)
        if n_begin == 0 and n_end == 0:
            if not re.search(rf"^{re.escape(RESULTS_HEADING)}\s*$", text, flags=re.MULTILINE):
                text = (text.rstrip("\n") + "\n\n" if text.strip() else "") + RESULTS_HEADING + "\n"
            text = text.rstrip("\n") + "\n\n" + block + "\n"
            continue
        if n_begin != 1 or n_end != 1 or text.index(begin) > text.index(end):
            raise ValueError(f"{page}: the markers of experiment {name!r} must be one {begin} followed by one {end} "
                             f"(found {n_begin} and {n_end})")
        start, stop = text.index(begin), text.index(end) + len(end)
        text = text[:start] + block + text[stop:]
    write_text(page, text)
