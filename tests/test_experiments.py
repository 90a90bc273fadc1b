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
    ("conditions.clean.train", {"n_drones": 3}, r"conditions.clean.train: not valid WildlifeReserve-v0 arguments"),
    ("conditions.clean.train", {"sensor_noise": 2.0},
     r"conditions.clean.train: not valid WildlifeReserve-v0 arguments.*sensor_noise"),
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


def test_unknown_experiment_and_bad_flags_are_refused(capsys):
    for argv, message in ((["table99"], "unknown experiment 'table99'"), ([], "name experiments or give --all"),
                          (["table5_latent", "--n-jobs", "0"], "--n-jobs must be >= 1")):
        with pytest.raises(SystemExit):
            experiment_main(argv)
        assert message in capsys.readouterr().err


def test_a_killed_runner_resumes_without_redoing_finished_cells_then_reports(tmp_path, capsys):
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
    assert experiment_main([str(spec), "-f", str(runs), "--n-jobs", "2", "--page", str(page)]) == 0
    out = capsys.readouterr().out
    assert f"4 cells, {len(before)} finished, {4 - len(before)} to run" in out
    rows = store.rows("tiny", "quick")
    assert len(rows) == 4 and all(r["finished_at"] == before[(r["algorithm"], r["seed"])] for r in rows
                                  if (r["algorithm"], r["seed"]) in before)
    assert all(set(RUN_METRICS) <= set(r["metrics"]) and "team_reward" in r["metrics"] for r in rows)
    text = page.read_text()
    assert text.startswith("# Results\n\nHand-written text stays.\n") and "### Table 0: A tiny experiment" in text
    assert "85.5 +- 2.5" in text and (tmp_path / "figures" / "tiny_bars_team_reward.png").stat().st_size > 0


def test_the_ray_backend_fills_the_store_as_the_local_backend_does(tmp_path):
    pytest.importorskip("ray")
    data = mutate("algorithms", {"ppo": TINY["algorithms"]["ppo"]})
    data["budgets"]["quick"]["seeds"] = [3, 4]
    spec = write_spec(tmp_path, data)
    for backend in ("local", "ray"):
        assert experiment_main([str(spec), "-f", str(tmp_path / backend), "--backend", backend, "--n-jobs", "2",
                                "--no-report"]) == 0

    def content(backend):
        rows = ResultStore(tmp_path / backend / "results.sqlite").rows("tiny", "quick")
        timing = set(RUN_METRICS) - {"n_timesteps"}
        return [(r["algorithm"], r["condition"], r["seed"], {k: v for k, v in r["metrics"].items() if k not in timing},
                 r["episodes"]) for r in rows]

    assert len(content("local")) == 2 and content("local") == content("ray")


def test_the_runner_compiles_the_kernels_for_every_reserve_of_a_condition_before_its_cells(monkeypatch):
    from sb3_emmarl.experiments.runner import compile_for_condition
    from wildlife_reserve.reserve import reserve as reserve_module

    calls = []
    monkeypatch.setattr(reserve_module, "compile_kernels", lambda **kwargs: calls.append(kwargs))
    compile_for_condition(load_spec("table3_transfer"), "fine_tuned")
    regions = [(c["region"], c["continuous_actions"]) for c in calls]
    # Trained on the source, fine-tuned and evaluated on the target: each with discrete and continuous actions.
    assert set(regions) == {("mixed", False), ("mixed", True), ("forest", False), ("forest", True)}
