"""The experiments' reports: the summary and its paired tests, the markdown table, the figures and the results page."""

from __future__ import annotations

import numpy as np
import pytest
from matplotlib.collections import PathCollection
from scipy import stats

from sb3_emmarl.experiments.report import (
    RESULTS_HEADING,
    figure_bars,
    figure_curves,
    figure_trajectories,
    markdown_table,
    render_section,
    summary_rows,
    update_results_page,
)
from sb3_emmarl.experiments.spec import parse_spec
from sb3_emmarl.experiments.store import ResultStore

SPEC = {
    "name": "tiny",
    "title": "A tiny experiment",
    "paper": "Table 9",
    "algorithms": {"a": {"algo": "ppo"}, "b": {"algo": "em_ppo"}},
    "conditions": {"clean": {}, "noisy": {"train": {"sensor_noise": 0.3}}},
    "reference": "a",
    "metrics": ["team_reward", "detection_rate"],
    "budgets": {"quick": {"n_timesteps": 100, "seeds": [0, 1, 2], "eval_episodes": 2},
                "full": {"episodes": 10, "seeds": [0, 1, 2, 3, 4], "eval_episodes": 5}},
    "outputs": [{"kind": "table"}, {"kind": "bars", "metric": "team_reward"},
                {"kind": "curves", "metric": "rollout/ep_rew_mean"}],
    "claims": {"b": {"clean": {"team_reward": "85.5 +- 2.5"}}},
}

#: Hand-made results: (algorithm, condition) -> seed -> metrics. (a, noisy) has no detection_rate and only seeds 0
#: and 1 (a partly finished experiment): b's noisy differences are paired over seeds 0 and 1.
RESULTS = {
    ("a", "clean"): {0: {"team_reward": 1.0, "detection_rate": 0.10},
                     1: {"team_reward": 2.0, "detection_rate": 0.20},
                     2: {"team_reward": 4.0, "detection_rate": 0.30}},
    ("b", "clean"): {0: {"team_reward": 3.0, "detection_rate": 0.15},
                     1: {"team_reward": 3.5, "detection_rate": 0.40},
                     2: {"team_reward": 7.0, "detection_rate": 0.35}},
    ("a", "noisy"): {0: {"team_reward": -1.0}, 1: {"team_reward": 0.5}},
    ("b", "noisy"): {0: {"team_reward": 0.0, "detection_rate": 0.05},
                     1: {"team_reward": 2.5, "detection_rate": 0.10},
                     2: {"team_reward": 9.0, "detection_rate": 0.20}},
}


@pytest.fixture
def spec():
    return parse_spec(SPEC)


@pytest.fixture
def rows(tmp_path):
    store = ResultStore(tmp_path / "results.sqlite")
    for (algorithm, condition), by_seed in RESULTS.items():
        for seed, metrics in by_seed.items():
            store.record("tiny", "quick", (algorithm, condition, seed), metrics, [metrics],
                         str(tmp_path / "runs" / f"{algorithm}_{condition}_{seed}"), "test machine")
    return store.rows("tiny", "quick")


def _entry(summary, algorithm, condition):
    (entry,) = [e for e in summary if e["algorithm"] == algorithm and e["condition"] == condition]
    return entry


def test_summary_means_stds_and_paired_tests(spec, rows):
    summary = summary_rows(spec, rows)
    # The specification's order: conditions outer, algorithms inner.
    assert [(e["condition"], e["algorithm"]) for e in summary] == [("clean", "a"), ("clean", "b"), ("noisy", "a"),
                                                                   ("noisy", "b")]
    for (algorithm, condition), by_seed in RESULTS.items():
        entry = _entry(summary, algorithm, condition)
        assert entry["n"] == len(by_seed) and entry["seeds"] == sorted(by_seed)
        for metric in spec.metrics:
            values = [m[metric] for m in by_seed.values() if metric in m]
            if not values:
                assert metric not in entry["mean"] and metric not in entry["std"]
                continue
            mean = sum(values) / len(values)
            std = (sum((v - mean) ** 2 for v in values) / len(values)) ** 0.5
            assert entry["mean"][metric] == pytest.approx(mean)
            assert entry["std"][metric] == pytest.approx(std)
    # The reference has no comparison with itself.
    assert _entry(summary, "a", "clean")["diff"] == {} and _entry(summary, "a", "noisy")["p"] == {}
    # b against a, paired by seed within the condition.
    clean = _entry(summary, "b", "clean")
    b = [RESULTS[("b", "clean")][s]["team_reward"] for s in (0, 1, 2)]
    a = [RESULTS[("a", "clean")][s]["team_reward"] for s in (0, 1, 2)]
    assert clean["diff"]["team_reward"] == pytest.approx(np.mean(np.subtract(b, a)))
    assert clean["p"]["team_reward"] == pytest.approx(stats.ttest_rel(b, a).pvalue)
    noisy = _entry(summary, "b", "noisy")
    b = [RESULTS[("b", "noisy")][s]["team_reward"] for s in (0, 1)]  # a has no seed 2 in noisy
    a = [RESULTS[("a", "noisy")][s]["team_reward"] for s in (0, 1)]
    assert noisy["pairs"]["team_reward"] == 2
    assert noisy["diff"]["team_reward"] == pytest.approx(np.mean(np.subtract(b, a)))
    assert noisy["p"]["team_reward"] == pytest.approx(stats.ttest_rel(b, a).pvalue)
    # b's mean over its three noisy seeds is unaffected by the pairing.
    assert noisy["mean"]["team_reward"] == pytest.approx(np.mean([0.0, 2.5, 9.0]))
    # No reference value of detection_rate in noisy: no comparison.
    assert "detection_rate" not in noisy["diff"] and noisy["mean"]["detection_rate"] == pytest.approx(0.35 / 3)


def test_markdown_table(spec, rows):
    table = markdown_table(spec, rows)
    lines = table.strip().splitlines()
    header = [c.strip() for c in lines[0].strip("|").split("|")]
    assert header[:3] == ["condition", "algorithm", "seeds"]
    assert "team_reward: diff vs a (p)" in header and "team_reward: paper" in header
    assert header.index("team_reward: paper") == header.index("team_reward (mean +- std)") + 1
    assert set(lines[1]) <= set("|-:")
    body = {tuple(c.strip() for c in line.strip("|").split("|")[:2]): [c.strip() for c in line.strip("|").split("|")]
            for line in lines[2:]}
    assert len(body) == 4 and all(len(cells) == len(header) for cells in body.values())
    column = {name: i for i, name in enumerate(header)}
    # The claim in its row and next to its metric, and nowhere else.
    assert body[("clean", "b")][column["team_reward: paper"]] == "85.5 +- 2.5"
    assert table.count("85.5 +- 2.5") == 1
    assert body[("noisy", "b")][column["team_reward: paper"]] == "-"
    # No claim for detection_rate anywhere: no column for it.
    assert "detection_rate: paper" not in column
    # Numbers: 3 decimals; the metric a cell lacks is "-".
    values = [1.0, 2.0, 4.0]
    assert body[("clean", "a")][column["team_reward (mean +- std)"]] == f"{np.mean(values):.3f} +- {np.std(values):.3f}"
    assert body[("noisy", "a")][column["detection_rate (mean +- std)"]] == "-"
    assert body[("noisy", "b")][column["detection_rate: diff vs a (p)"]] == "-"
    assert body[("clean", "a")][column["team_reward: diff vs a (p)"]] == "-"
    b, a = [3.0, 3.5, 7.0], [1.0, 2.0, 4.0]
    p = stats.ttest_rel(b, a).pvalue
    assert body[("clean", "b")][column["team_reward: diff vs a (p)"]] == f"+2.167 ({p:.2g})"
    assert body[("clean", "b")][column["seeds"]] == "3" and body[("noisy", "a")][column["seeds"]] == "2"


def _write_curves(rows, points=6):
    """Every run's ``rollout/ep_rew_mean``: value = seed + step / 100, at steps that differ between seeds."""
    from torch.utils.tensorboard import SummaryWriter

    for row in rows:
        writer = SummaryWriter(log_dir=f"{row['run_dir']}/PPO_1")  # nested, as SB3 writes it
        for k in range(points):
            step = 100 * k + 10 * row["seed"]
            writer.add_scalar("rollout/ep_rew_mean", row["seed"] + step / 100, step)
        writer.close()


def test_figures(spec, rows, tmp_path):
    _write_curves(rows)
    path = tmp_path / "figures" / "curves.png"
    figure = figure_curves(spec, rows, "rollout/ep_rew_mean", path)
    assert path.is_file() and path.stat().st_size > 0
    (ax,) = figure.axes
    assert ax.get_xlabel() == "agent-steps" and ax.get_ylabel() == "rollout/ep_rew_mean"
    lines = {line.get_label(): line for line in ax.get_lines()}
    (label,) = [name for name in lines if name.startswith("b, clean")]
    assert "3 seeds" in label
    # Seeds 0, 1, 2 on the steps they all reached ([20, 500]); their mean is 1 + step / 100 there.
    steps, mean = lines[label].get_data()
    assert steps[0] == pytest.approx(20) and steps[-1] == pytest.approx(500)
    np.testing.assert_allclose(mean, 1 + np.asarray(steps) / 100)
    assert any(name.startswith("a, noisy") and "2 seeds" in name for name in lines)
    with pytest.raises(ValueError, match="train/no_such_scalar"):
        figure_curves(spec, rows, "train/no_such_scalar", tmp_path / "none.png")

    path = tmp_path / "figures" / "bars.png"
    figure = figure_bars(spec, rows, "team_reward", path)
    assert path.is_file() and path.stat().st_size > 0
    (ax,) = figure.axes
    assert ax.get_xlabel() == "condition" and ax.get_ylabel() == "team_reward"
    assert "Table 9" in ax.get_title() and "team_reward" in ax.get_title()
    # One bar per (condition, algorithm), in the conditions' groups: the median over seeds (the legend names each
    # algorithm once).
    bars = sorted((patch.get_x() + patch.get_width() / 2, patch.get_height()) for container in ax.containers
                  if hasattr(container, "patches") for patch in container.patches)
    np.testing.assert_allclose([height for _, height in bars], [2.0, 3.5, 0.5 * (-1.0 + 0.5), 2.5])
    assert [x for x, _ in bars] == pytest.approx([-0.2, 0.2, 0.8, 1.2])
    assert [text.get_text() for text in ax.get_legend().get_texts()] == ["a", "b"]
    # One dot per seed: 3 + 3 + 2 + 3.
    assert sum(len(c.get_offsets()) for c in ax.collections if isinstance(c, PathCollection)) == 11
    # A collapsed seed does not flatten the others: it is drawn at the axis' edge with its value.
    collapsed = [dict(r, metrics={**r["metrics"], "team_reward": -1300.0}) if (r["algorithm"], r["condition"],
                 r["seed"]) == ("a", "clean", 2) else r for r in rows]
    ax = figure_bars(spec, collapsed, "team_reward", tmp_path / "figures" / "collapsed.png").axes[0]
    assert ax.get_ylim()[0] > -100 and any("-1300" in text.get_text() for text in ax.texts)
    with pytest.raises(ValueError, match="latent_nmi"):
        figure_bars(spec, rows, "latent_nmi", tmp_path / "none.png")

    steps = np.arange(20)
    positions = np.stack([np.stack([steps % 10, steps // 2 + i], axis=-1) for i in range(12)], axis=1)
    poachers = np.full((20, 2, 2), np.nan)
    poachers[5:15, 0] = [[9, 3]] * 10
    terrain = np.random.default_rng(0).integers(0, 3, (12, 24))
    path = tmp_path / "figures" / "trajectories.png"
    figure = figure_trajectories(positions, path, "an episode", terrain=terrain, poachers=poachers)
    assert path.is_file() and path.stat().st_size > 0
    (ax,) = figure.axes
    assert ax.get_xlabel() == "col (cells)" and ax.get_ylabel() == "row (cells)"
    assert ax.yaxis_inverted()  # row 0 at the top, as on the reserve's grid
    legend = [text.get_text() for text in ax.get_legend().get_texts()]
    assert legend[:10] == [f"UAV {i}" for i in range(10)] and "UAV 10" not in legend and "poachers" in legend
    assert {"open", "forest", "mountain"} <= set(legend)  # the terrain's colours named
    figure = figure_trajectories(positions[:, :2], tmp_path / "plain.png", "no terrain")
    assert figure.axes[0].yaxis_inverted() and (tmp_path / "plain.png").stat().st_size > 0


def test_render_section(spec, rows, tmp_path):
    _write_curves(rows, points=3)
    figures = tmp_path / "docs" / "figures"
    section = render_section(spec, rows, "quick", figures, "python -m sb3_emmarl.experiments run tiny", "2 cores")
    assert section.startswith("### Table 9: A tiny experiment")
    assert "`python -m sb3_emmarl.experiments run tiny`" in section and "2 cores" in section
    assert "100 agent-steps" in section and "0, 1, 2" in section and "2 evaluation episodes" in section
    assert markdown_table(spec, rows).strip() in section
    for file in ("tiny_bars_team_reward.png", "tiny_curves_rollout_ep_rew_mean.png"):
        assert f"](figures/{file})" in section and (figures / file).stat().st_size > 0
    empty = render_section(spec, [], "full", figures, "cmd", "hw")
    assert "finished yet" in empty and "|" not in empty and "20,000 agent-steps" in empty


def test_update_results_page(tmp_path):
    page = tmp_path / "results.md"
    before = "# Results\n\nSome text.\n\n"
    after = "\n\n## Another table\n\nMore text, kept as it is.\n"
    page.write_text(before + "<!-- experiment:one:begin -->\nold section\n<!-- experiment:one:end -->" + after)
    sections = {"one": "### One\n\nnew section\n", "two": "### Two\n\nsecond\n"}
    update_results_page(page, sections)
    text = page.read_text()
    assert text.startswith(before + "<!-- experiment:one:begin -->\n### One\n\nnew section\n<!-- experiment:one:end -->"
                           + after)
    assert "old section" not in text
    assert text.count(RESULTS_HEADING) == 1
    assert text.index(RESULTS_HEADING) < text.index("<!-- experiment:two:begin -->") < text.index("### Two")
    assert text.rstrip().endswith("<!-- experiment:two:end -->")
    update_results_page(page, sections)
    assert page.read_text() == text
    # Changing one section changes only what is between its markers.
    update_results_page(page, {"two": "### Two\n\nchanged\n"})
    assert page.read_text() == text.replace("### Two\n\nsecond", "### Two\n\nchanged")
    page.write_text("<!-- experiment:one:begin -->\nno end\n")
    with pytest.raises(ValueError, match="one"):
        update_results_page(page, {"one": "x"})
