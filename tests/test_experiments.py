"""The experiment specifications, the resumable runner (local and Ray) and the command that reports them."""

import copy
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from sb3_emmarl.experiments import ResultStore, list_specs, load_spec
from sb3_emmarl.experiments.cli import experiment_main
from sb3_emmarl.experiments.spec import RUN_METRICS, parse_spec
from sb3_emmarl.version import __version__

ROOT = Path(__file__).resolve().parents[1]
FAST = {"n_steps": 16, "batch_size": 32, "n_epochs": 1}
TINY = {
    "name": "tiny", "title": "A tiny experiment", "paper": "Table 0",
    "algorithms": {"ppo": {"algo": "ppo", "hyperparams": FAST},
                   "a2c": {"algo": "a2c", "hyperparams": {"n_steps": 4}}},
    "conditions": {"clean": {"train": {"n_uavs": 2, "grid_size": 20, "max_cycles": 10}}},
    "reference": "ppo",
    "metrics": ["team_reward", "detection_rate", "train_seconds"],
    "budgets": {"quick": {"n_timesteps": 64, "seeds": [0, 1], "eval_episodes": 1},
                "full": {"episodes": 1, "seeds": [0], "eval_episodes": 1}},
    "outputs": [{"kind": "table"}, {"kind": "bars", "metric": "team_reward"}],
    "claims": {"ppo": {"clean": {"team_reward": "85.5 +- 2.5"}}},
}


def write_spec(folder: Path, data: dict = TINY) -> Path:
    path = folder / f"{data['name']}.yml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_every_table_and_figure_of_the_paper_has_a_specification():
    tables, figures = set(), set()
    for name in list_specs():
        spec = load_spec(name)
        for kind, numbers in re.findall(r"(Table|Figures?) ([\d, -]+)", spec.paper):
            found = set()
            for part in numbers.split(","):
                low, _, high = part.strip().partition("-")
                if low:
                    found |= set(range(int(low), int(high or low) + 1))
            (tables if kind == "Table" else figures).update(found)
        assert spec.cells("quick") and spec.budgets["full"].n_timesteps == 10_000_000
        assert len(spec.budgets["full"].seeds) == 5
    assert tables == set(range(1, 8)) and figures >= set(range(2, 13))


def mutate(path: str, value):
    data = copy.deepcopy(TINY)
    *parents, key = path.split(".")
    target = data
    for part in parents:
        target = target[part]
    if value is KeyError:
        del target[key]
    else:
        target[key] = value
    return data


@pytest.mark.parametrize("path,value,message", [
    ("algorithms.ppo.algo", "ppo2", r"algorithms.ppo.algo: unknown algorithm 'ppo2'"),
    ("conditions.clean.train", {"n_drones": 3}, r"conditions.clean.train: not valid WildlifeReserve-v1 arguments"),
    ("conditions.clean.train", {"sensor_noise": 2.0},
     r"conditions.clean.train: not valid WildlifeReserve-v1 arguments.*sensor_noise"),
    ("conditions.clean.weather", "rain", r"conditions.clean: unknown field\(s\) \['weather'\]"),
    ("metrics", ["team_reward", "happiness"], r"metrics: unknown metric 'happiness'"),
    ("budgets.quick.n_timesteps", 0, r"budgets.quick.n_timesteps: must be a positive whole number, got 0"),
    ("budgets.quick.n_timesteps", "many", r"budgets.quick.n_timesteps: must be a positive whole number, got 'many'"),
    ("budgets.quick.seeds", [0, 0], r"budgets.quick.seeds: must be a non-empty list of distinct ints"),
    ("budgets.medium", {"n_timesteps": 1, "seeds": [0], "eval_episodes": 1}, r"budgets: unknown field\(s\) \['medium'\]"),
    ("budgets.full", KeyError, r"budgets: missing field\(s\) \['full'\]"),
    ("outputs", [{"kind": "pie"}], r"outputs\[0\].kind: unknown output 'pie'"),
    ("outputs", [{"kind": "bars"}], r"outputs\[0\].metric: bars needs a metric"),
    ("reference", "dqn", r"reference: 'dqn' is not among the algorithms"),
    ("claims", {"qmix": {}}, r"claims: 'qmix' is not among the algorithms"),
    ("env", "CartPole-v1", r"env: unknown environment id 'CartPole-v1'"),
])
def test_bad_specifications_fail_before_anything_runs_naming_the_field(tmp_path, capsys, path, value, message):
    with pytest.raises(ValueError, match=message):
        parse_spec(mutate(path, value), "tiny.yml")
    spec = write_spec(tmp_path, mutate(path, value))
    with pytest.raises(SystemExit) as exit_info:
        experiment_main([str(spec), "-f", str(tmp_path / "runs")])
    assert exit_info.value.code == 2 and re.search(message, capsys.readouterr().err)
    assert not (tmp_path / "runs").exists()


def test_an_experiment_on_zone_patrol_runs_its_cells_through_the_zoo(tmp_path):
    from sb3_emmarl.experiments.runner import run_cell

    data = copy.deepcopy(TINY)
    data.update(env="ZonePatrol-v0", metrics=["team_reward", "detections", "escapes", "train_seconds"],
                conditions={"clean": {"train": {"n_uavs": 2}}})
    with pytest.raises(ValueError, match=r"conditions.clean.train: not valid ZonePatrol-v0 arguments.*n_drones"):
        parse_spec({**data, "conditions": {"clean": {"train": {"n_drones": 2}}}}, "tiny.yml")
    with pytest.raises(ValueError, match="trajectories are drawn on the reserve's map only, not on ZonePatrol-v0"):
        parse_spec({**data, "outputs": [{"kind": "trajectories"}]}, "tiny.yml")
    spec = parse_spec(data, "tiny.yml")
    cell = run_cell(spec, "quick", "ppo", "clean", 0, tmp_path)
    assert spec.env == "ZonePatrol-v0" and {"detections", "escapes", "team_reward"} <= set(cell["metrics"])
    assert (Path(cell["run_dir"]) / "stage_0" / "ppo" / "ZonePatrol-v0_1" / "ZonePatrol-v0.zip").is_file()


def test_the_listing_keeps_its_columns_apart_and_gives_each_budget_s_cost(capsys):
    assert experiment_main(["--list"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("experiment ") and len(lines) == len(list_specs()) + 1
    (line,) = [line for line in lines if line.startswith("table4_fig3_coverage_detection")]
    assert re.match(r"table4_fig3_coverage_detection +Table 4, Figure 3 +\d+ x [\d,]+ +\d+ x 10,000,000 +\S", line)


def test_unknown_experiment_and_bad_flags_are_refused(capsys):
    for argv, message in ((["table99"], "unknown experiment 'table99'"), ([], "name experiments or give --all"),
                          (["table5_latent", "--n-jobs", "0"], "--n-jobs: must be an int in [1, 1024], got 0"),
                          (["table5_latent", "--conditions", "zone_raids"],
                           "--conditions: conditions of table5_latent are ['default'], got ['zone_raids']")):
        with pytest.raises(SystemExit):
            experiment_main(argv)
        assert message in capsys.readouterr().err


def docs_state() -> tuple[str, int, list[str]]:
    """The checkout's results page (its ``git status`` and modification time) and the tiny experiment's figures in
    docs/figures (none: the files other work adds there meanwhile are not this test's)."""
    page = ROOT / "docs" / "results.md"
    status = subprocess.run(["git", "status", "--porcelain", "--", str(page)], cwd=ROOT, capture_output=True, text=True)
    return status.stdout, page.stat().st_mtime_ns, sorted(p.name for p in (ROOT / "docs" / "figures").glob("tiny_*"))


def test_a_killed_runner_resumes_without_redoing_finished_cells_then_reports(tmp_path, capsys, monkeypatch):
    spec = write_spec(tmp_path)
    runs, store_path = tmp_path / "runs", tmp_path / "runs" / "results.sqlite"
    command = [sys.executable, str(ROOT / "zoo" / "experiment.py"), str(spec), "-f", str(runs), "--n-jobs", "1",
               "--no-report"]
    runner = subprocess.Popen(command, cwd=tmp_path, start_new_session=True, stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL, env={**os.environ, "OMP_NUM_THREADS": "1"})
    deadline = time.monotonic() + 240
    while time.monotonic() < deadline and runner.poll() is None:
        if store_path.exists() and len(ResultStore(store_path).finished("tiny", "quick")) >= 1:
            break
        time.sleep(0.2)
    os.killpg(runner.pid, signal.SIGKILL)
    runner.wait()
    store = ResultStore(store_path)
    before = {(r["algorithm"], r["seed"]): r["finished_at"] for r in store.rows("tiny", "quick")}
    assert 1 <= len(before) < 4, "the runner was to be killed mid-way"
    page = tmp_path / "results.md"
    page.write_text("# Results\n\nHand-written text stays.\n")
    # Run from the checkout: the tracked results page and figures stay as they are (only the results folder changes).
    monkeypatch.chdir(ROOT)
    docs = docs_state()
    assert not docs[2]
    assert experiment_main([str(spec), "-f", str(runs), "--n-jobs", "2"]) == 0
    out = capsys.readouterr().out
    assert f"4 cells, {len(before)} finished, {4 - len(before)} to run" in out
    assert f"{4 - len(before)} cells to run: about 0 h " in out  # (estimated from the cells stored before the kill)
    assert docs_state() == docs and page.read_text() == "# Results\n\nHand-written text stays.\n"
    report = (runs / "tiny" / "quick" / "results.md").read_text()
    assert report.startswith("### Table 0: A tiny experiment") and f"Made with sb3-emmarl {__version__}" in report
    assert (runs / "tiny" / "quick" / "figures" / "tiny_bars_team_reward.png").stat().st_size > 0
    assert experiment_main([str(spec), "-f", str(runs), "--report-only", "--update-docs", "--page", str(page)]) == 0
    rows = store.rows("tiny", "quick")
    assert len(rows) == 4 and all(r["finished_at"] == before[(r["algorithm"], r["seed"])] for r in rows
                                  if (r["algorithm"], r["seed"]) in before)
    assert all(set(RUN_METRICS) <= set(r["metrics"]) and "team_reward" in r["metrics"] for r in rows)
    text = page.read_text()
    assert text.startswith("# Results\n\nHand-written text stays.\n") and "### Table 0: A tiny experiment" in text
    assert "85.5 +- 2.5" in text and (tmp_path / "figures" / "tiny_bars_team_reward.png").stat().st_size > 0
    assert f"Made with sb3-emmarl {__version__}, git commit" in text


def test_the_report_goes_under_the_results_folder_and_the_docs_change_only_with_update_docs(tmp_path, monkeypatch,
                                                                                          capsys):
    spec = write_spec(tmp_path)
    monkeypatch.chdir(tmp_path)
    page, figures = Path("docs/results.md"), Path("docs/figures")
    page.parent.mkdir()
    page.write_text("# Results\n")
    store = ResultStore("runs/results.sqlite")
    for seed in (0, 1):
        store.record("tiny", "quick", ("ppo", "clean", seed), {"team_reward": 1.0 + seed}, [], "r", "hw")
    assert experiment_main([str(spec), "-f", "runs", "--report-only"]) == 0
    assert page.read_text() == "# Results\n" and not figures.exists()
    assert "wrote runs/tiny/quick/results.md" in capsys.readouterr().out
    assert "| clean | ppo | 2 | 1.500 +- 0.500 |" in Path("runs/tiny/quick/results.md").read_text()
    assert experiment_main([str(spec), "-f", "runs", "--report-only", "--update-docs"]) == 0
    text = page.read_text()
    assert "<!-- experiment:tiny:begin -->" in text and "| clean | ppo | 2 | 1.500 +- 0.500 |" in text
    assert f"Made with sb3-emmarl {__version__}" in text and (figures / "tiny_bars_team_reward.png").is_file()
    with pytest.raises(SystemExit):
        experiment_main([str(spec), "-f", "runs", "--report-only", "--page", "elsewhere.md"])
    assert "give --update-docs with them" in capsys.readouterr().err


#: The tiny experiment's A2C cell of seed 0 (2 UAVs on 20 x 20, 64 agent-steps; A2C's team reward moves with its seed
#: at this budget, PPO's does not yet), as its table row shows it, and the
#: SHA-256 of its evaluation episodes' records: pinned (sb3-emmarl 0.20.0, torch 2.13.0 CPU, one thread). A change
#: that means to change training or evaluation updates them and says so in the changelog.
TINY_ROW = "| clean | a2c | 1 | 2.381 +- 0.000 | - | - | 0.500 +- 0.000 | - |"
TINY_EPISODES = "0f8b19e9521d592a"


def test_conditions_chosen_run_alone_and_the_others_stay_to_run(tmp_path):
    from sb3_emmarl.experiments.runner import run_experiment

    data = copy.deepcopy(TINY)
    data.update(algorithms={"ppo": TINY["algorithms"]["ppo"]},
                conditions={"clean": TINY["conditions"]["clean"],
                            "small": {"train": {"n_uavs": 2, "grid_size": 16, "max_cycles": 8}}})
    data["budgets"]["quick"]["seeds"] = [0]
    path = write_spec(tmp_path, data)
    spec = load_spec(path)
    assert spec.cells("quick", ["small"]) == [("ppo", "small", 0)]
    with pytest.raises(ValueError, match=r"conditions of tiny are \['clean', 'small'\], got \['foggy'\]"):
        spec.cells("quick", ["foggy"])
    store, lines = ResultStore(tmp_path / "results.sqlite"), []
    run = {"n_jobs": 1, "log": lines.append, "spec_path": str(path), "conditions": ["small"]}
    assert run_experiment(spec, "quick", store, tmp_path, **run) == 1
    assert lines[0] == "tiny (quick): 1 cells, 0 finished, 1 to run (local)"
    assert lines[1] == "1 cells to run; no stored cell yet to estimate their time from"
    assert store.finished("tiny", "quick") == {("ppo", "small", 0)}
    assert run_experiment(spec, "quick", store, tmp_path, **run) == 0


def test_a_tiny_cell_regenerates_its_stored_digits(tmp_path):
    import hashlib
    import json

    from sb3_emmarl.experiments.report import markdown_table
    from sb3_emmarl.experiments.runner import run_cell

    data = copy.deepcopy(TINY)
    data["metrics"] = ["team_reward", "detection_rate"]
    spec = parse_spec(data, "tiny.yml")
    cell = run_cell(spec, "quick", "a2c", "clean", 0, tmp_path)
    row = {"algorithm": "a2c", "condition": "clean", "seed": 0, **cell}
    assert markdown_table(spec, [row]).splitlines()[2] == TINY_ROW
    digest = hashlib.sha256(json.dumps(cell["episodes"], sort_keys=True).encode()).hexdigest()[:16]
    assert digest == TINY_EPISODES


def test_the_runner_compiles_the_kernels_for_every_reserve_of_a_condition_before_its_cells(monkeypatch):
    from sb3_emmarl.experiments.runner import compile_for_condition
    from wildlife_reserve.reserve import reserve as reserve_module

    calls = []
    monkeypatch.setattr(reserve_module, "compile_kernels", lambda **kwargs: calls.append(kwargs))
    compile_for_condition(load_spec("table3_transfer"), "fine_tuned")
    regions = [(c["region"], c["continuous_actions"]) for c in calls]
    # Trained on the source, fine-tuned and evaluated on the target: each with discrete and continuous actions.
    assert set(regions) == {("mixed", False), ("mixed", True), ("forest", False), ("forest", True)}


def test_a_ray_address_no_cluster_answers_at_is_refused_at_once(tmp_path, capsys):
    """ray.init retries such an address for minutes; the command refuses it in one line before writing anything."""
    import socket

    with socket.socket() as probe:  # a port nobody listens on
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    with pytest.raises(SystemExit) as stop:
        experiment_main(["table5_latent", "--backend", "ray", "--address", f"127.0.0.1:{port}", "-f",
                         str(tmp_path / "runs")])
    assert stop.value.code == 2 and f"--address 127.0.0.1:{port}: no Ray cluster answers there" in capsys.readouterr().err
    assert not (tmp_path / "runs").exists()


def test_the_time_to_go_is_each_cell_at_its_algorithm_s_median_seconds_over_the_slots():
    from sb3_emmarl.experiments.runner import slots_hint, time_to_go

    rows = [{"algorithm": "ppo", "metrics": {"train_seconds": 600.0}},
            {"algorithm": "ppo", "metrics": {"train_seconds": 1800.0}},
            {"algorithm": "a2c", "metrics": {"train_seconds": 300.0}}, {"algorithm": "a2c", "metrics": {}}]
    todo = [("ppo", "clean", 5), ("ppo", "clean", 6), ("em_ppo", "clean", 0)]  # em_ppo: the median of every cell, 600
    assert time_to_go(rows, todo, 2).startswith("3 cells to run: about 0 h 25 min of training at 2 at a time")
    assert time_to_go(rows, todo, None).startswith("3 cells to run: about 0 h 50 min of training at 1 at a time")
    assert slots_hint("local", 3) == 3 and slots_hint("local", None) >= 1 and slots_hint("ray", None) is None
