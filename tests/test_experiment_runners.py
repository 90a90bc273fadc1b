"""Runners that share a store: cells claimed with a lease before they start, taken over when their runner is gone,
each cell finished once; a runner's cells die with it (SIGKILL, SIGTERM); stored cells name their version; the Ray
backend on a real two-node cluster."""

import contextlib
import os
import re
import secrets
import shutil
import signal
import socket
import sqlite3
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

import pytest

from sb3_emmarl.experiments import ResultStore
from sb3_emmarl.experiments.cli import experiment_main
from sb3_emmarl.experiments.spec import RUN_METRICS
from sb3_emmarl.experiments.store import Claim, RunnerId, code_version
from sb3_emmarl.version import __version__

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_experiments import TINY, mutate, write_spec  # noqa: E402

CELLS = [("ppo", "clean", 0), ("ppo", "clean", 1), ("a2c", "clean", 0)]
#: A cell's line in a runner's log.
FINISHED = re.compile(r"finished (\w+) / (\w+) / seed (\d+)")


def finished_process_id() -> int:
    """The id of a process that has ended (and been reaped)."""
    done = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    return int(done.stdout)


def claims(store: ResultStore) -> list[tuple]:
    with sqlite3.connect(store.path) as db:
        return db.execute("SELECT algorithm, condition, seed, runner FROM claims").fetchall()


def test_a_claim_holds_its_cell_while_its_runner_lives_and_is_taken_over_after(tmp_path):
    store = ResultStore(tmp_path / "results.sqlite")
    first, second = RunnerId(), RunnerId()
    assert store.claim("tiny", "quick", CELLS, first) == Claim(CELLS[0])
    # The first runner's process lives: the second skips its cell, and claims the next.
    assert store.claim("tiny", "quick", CELLS, second) == Claim(CELLS[1])
    assert store.held_by_others("tiny", "quick", second) == {CELLS[0]}
    assert store.record("tiny", "quick", CELLS[1], {"team_reward": 1.0}, [], "run", "hw", runner=second)
    assert store.claim("tiny", "quick", CELLS[:2], second) is None  # one held, one finished
    # A runner of this host whose process has ended holds nothing, whatever its heartbeat.
    dead = RunnerId(pid=finished_process_id(), process_start="1")
    store.release(first)
    assert store.claim("tiny", "quick", CELLS, dead) == Claim(CELLS[0])
    assert store.claim("tiny", "quick", CELLS, second) == Claim(CELLS[0], previous=dead.id)
    # ... and its late result is dropped: the cell is the taker's.
    assert not store.record("tiny", "quick", CELLS[0], {"team_reward": 9.0}, [], "run", "hw", runner=dead)
    assert store.record("tiny", "quick", CELLS[0], {"team_reward": 2.0}, [], "run", "hw", runner=second)
    assert {(r["algorithm"], r["seed"]): r["metrics"]["team_reward"] for r in store.rows("tiny", "quick")} == {
        ("ppo", 0): 2.0, ("ppo", 1): 1.0}
    # Another host's runner holds its cell while its heartbeat is younger than the lease, not after.
    remote = RunnerId(host="another-host", pid=1)
    assert store.claim("tiny", "quick", CELLS, remote) == Claim(CELLS[2])
    assert store.claim("tiny", "quick", CELLS, second, lease_seconds=60) is None
    time.sleep(0.3)
    store.heartbeat(remote)
    assert store.claim("tiny", "quick", CELLS, second, lease_seconds=0.25) is None  # renewed just now
    time.sleep(0.3)
    assert store.claim("tiny", "quick", CELLS, second, lease_seconds=0.25) == Claim(CELLS[2], previous=remote.id)
    store.release(second)
    assert claims(store) == []


def test_runners_claiming_at_once_never_get_the_same_cell(tmp_path):
    path = tmp_path / "results.sqlite"
    ResultStore(path)
    # The store's module alone (no torch to import), so that the processes start claiming at the same moment.
    script = textwrap.dedent(f"""
        import importlib.util, sys, time
        spec = importlib.util.spec_from_file_location("store", {str(ROOT / "sb3_emmarl" / "experiments" / "store.py")!r})
        store_module = importlib.util.module_from_spec(spec)
        sys.modules["store"] = store_module
        spec.loader.exec_module(store_module)
        store, runner = store_module.ResultStore({str(path)!r}), store_module.RunnerId()
        cells = [("ppo", "clean", seed) for seed in range(150)]
        time.sleep(max(0.0, float(sys.argv[1]) - time.time()))
        while (claim := store.claim("tiny", "quick", cells, runner)) is not None:
            assert store.record("tiny", "quick", claim.cell, {{}}, [], "run", "hw", runner=runner, version=("v", "c"))
            print(claim.cell[2], flush=True)
            time.sleep(0.02)  # a cell takes time: the others claim meanwhile, even when one process started first
    """)
    start = str(time.time() + 3.0)
    runners = [subprocess.Popen([sys.executable, "-c", script, start], stdout=subprocess.PIPE, text=True)
               for _ in range(3)]
    taken = [[int(line) for line in runner.communicate()[0].split()] for runner in runners]
    assert all(runner.returncode == 0 for runner in runners)
    assert sorted(seed for seeds in taken for seed in seeds) == list(range(150)) and sum(bool(t) for t in taken) >= 2, taken


def test_an_old_store_gets_unknown_versions_and_a_report_refuses_to_mix_them(tmp_path, capsys):
    path = tmp_path / "runs" / "results.sqlite"
    path.parent.mkdir()
    with sqlite3.connect(path) as db:  # the store's schema before it recorded versions
        db.execute("CREATE TABLE cells (experiment TEXT NOT NULL, budget TEXT NOT NULL, algorithm TEXT NOT NULL, "
                   "condition TEXT NOT NULL, seed INTEGER NOT NULL, metrics TEXT NOT NULL, episodes TEXT NOT NULL, "
                   "run_dir TEXT NOT NULL, hardware TEXT NOT NULL, finished_at TEXT NOT NULL DEFAULT (datetime('now')), "
                   "PRIMARY KEY (experiment, budget, algorithm, condition, seed))")
        db.execute("INSERT INTO cells (experiment, budget, algorithm, condition, seed, metrics, episodes, run_dir, "
                   "hardware) VALUES ('tiny', 'quick', 'ppo', 'clean', 0, '{\"team_reward\": 1.0}', '[]', 'r', 'hw')")
    store = ResultStore(path)
    (old,) = store.rows("tiny", "quick")
    assert old["version"] == old["git_commit"] == "unknown" and old["metrics"] == {"team_reward": 1.0}
    store.record("tiny", "quick", ("a2c", "clean", 0), {"team_reward": 2.0}, [], "r", "hw")
    assert {r["version"] for r in store.rows("tiny", "quick")} == {"unknown", __version__}
    assert store.finished("tiny", "quick", __version__) == {("a2c", "clean", 0)}
    # --rerun-stale: a cell another version stored is claimed again (and replaced when it finishes).
    runner = RunnerId()
    assert store.claim("tiny", "quick", [("ppo", "clean", 0)], runner) is None
    assert store.claim("tiny", "quick", [("ppo", "clean", 0)], runner, version=__version__) == Claim(("ppo", "clean", 0))
    store.release(runner)
    spec = write_spec(tmp_path)
    argv = [str(spec), "-f", str(tmp_path / "runs"), "--report-only"]
    assert experiment_main(argv) == 1
    err = capsys.readouterr().err.strip()
    assert err == (f"error: tiny (quick): the store holds cells of sb3-emmarl {__version__} (1 cell) and unknown "
                   "(1 cell) (unknown: stored before cells recorded their version); run the others again with "
                   "--rerun-stale, or report them together with --allow-mixed-versions")
    assert not (tmp_path / "runs" / "tiny").exists()
    assert experiment_main([*argv, "--allow-mixed-versions"]) == 0
    report = (tmp_path / "runs" / "tiny" / "quick" / "results.md").read_text()
    commit = code_version()[1]
    assert (f"Made with sb3-emmarl {__version__} (1 cell) and unknown (1 cell), git commits "
            f"{commit[:12]}{commit[40:]} (1 cell) and unknown (1 cell).") in report


def ppo_only(seeds: list[int]) -> dict:
    """The tiny experiment with PPO alone and these seeds."""
    data = mutate("algorithms", {"ppo": TINY["algorithms"]["ppo"]})
    data["budgets"]["quick"]["seeds"] = seeds
    return data


def load_cells(spec: Path) -> list[tuple[str, str, int]]:
    from sb3_emmarl.experiments import load_spec

    return load_spec(spec).cells("quick")


def _processes() -> dict[int, tuple[int, str, str]]:
    """Every process of this machine: pid -> (parent pid, state, command line)."""
    found = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text().rsplit(")", 1)[1].split()
                command = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
            except OSError:
                continue
            found[int(entry.name)] = (int(stat[1]), stat[0], command)
    return found


def _cells_of(runner: int, root: Path) -> list[int]:
    """The live cell processes that ``runner`` started for the results folder ``root``."""
    return [pid for pid, (parent, state, command) in _processes().items()
            if parent == runner and state not in "ZX" and "sb3_emmarl.experiments.runner" in command
            and str(root) in command]


def _alive(pid: int) -> bool:
    """Whether a process runs (a zombie waiting for its new parent to reap it does not)."""
    info = _processes().get(pid)
    return info is not None and info[1] not in "ZX"


def _wait_for(condition, timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.1)


def _start_runner(spec: Path, runs: Path, log: Path, *flags: str) -> subprocess.Popen:
    with open(log, "w") as file:
        return subprocess.Popen([sys.executable, str(ROOT / "zoo" / "experiment.py"), str(spec), "-f", str(runs),
                                 "--n-jobs", "1", "--no-report", *flags], stdout=file, stderr=subprocess.STDOUT,
                                start_new_session=True, env={**os.environ, "OMP_NUM_THREADS": "1",
                                                             "PYTHONUNBUFFERED": "1"})


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_two_runners_on_one_store_finish_every_cell_once_and_a_killed_one_leaves_no_orphan(tmp_path):
    spec, runs = write_spec(tmp_path, ppo_only([0, 1])), tmp_path / "runs"
    logs = {name: tmp_path / f"{name}.log" for name in ("a", "b")}
    a, b = (_start_runner(spec, runs, logs[name]) for name in ("a", "b"))
    try:
        _wait_for(lambda: _cells_of(a.pid, runs), 240, "the first runner's cell")
        (cell,) = _cells_of(a.pid, runs)
        a.kill()  # SIGKILL: no cleanup of its own
        a.wait()
        _wait_for(lambda: not _alive(cell), 10, f"the killed runner's cell process {cell} to end")
        assert b.wait(timeout=300) == 0
    finally:
        for runner in (a, b):
            if runner.poll() is None:
                os.killpg(runner.pid, signal.SIGKILL)
    text = {name: log.read_text() for name, log in logs.items()}
    done = [(m[0], m[1], int(m[2])) for name in ("a", "b") for m in FINISHED.findall(text[name])]
    store = ResultStore(runs / "results.sqlite")
    cells = set(load_cells(spec))
    assert sorted(done) == sorted(cells), text  # every cell finished, each once
    assert store.finished("tiny", "quick") == cells and claims(store) == []
    assert "taking over" in text["b"] and "which is gone" in text["b"], text["b"]
    assert {r["version"] for r in store.rows("tiny", "quick")} == {__version__}
    # The taken-over cell's folder holds the taker's run only.
    for algorithm, condition, seed in cells:
        folder = runs / "tiny" / "quick" / algorithm / condition / f"seed_{seed}" / "stage_0" / algorithm
        assert [p.name for p in folder.iterdir()] == ["WildlifeReserve-v1_1"]


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_a_stopped_runner_kills_its_cells_and_releases_their_claims(tmp_path):
    spec, runs = write_spec(tmp_path, ppo_only([0])), tmp_path / "runs"
    runner = _start_runner(spec, runs, tmp_path / "runner.log")
    try:
        _wait_for(lambda: _cells_of(runner.pid, runs), 240, "the runner's cell")
        (cell,) = _cells_of(runner.pid, runs)
        runner.send_signal(signal.SIGTERM)
        assert runner.wait(timeout=30) != 0
    finally:
        if runner.poll() is None:
            os.killpg(runner.pid, signal.SIGKILL)
    assert not _alive(cell)
    assert "stopped by SIGTERM" in (tmp_path / "runner.log").read_text()
    assert claims(ResultStore(runs / "results.sqlite")) == []


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


@pytest.fixture
def ray_cluster(tmp_path, monkeypatch):
    """A real Ray cluster of two nodes on this machine: a head and a worker node started with ``ray start --address``,
    each from its own working directory with its own temporary folder and one CPU; stopped (their process groups
    killed) at the end. Yields the head's address."""
    try:
        import ray  # noqa: F401
    except ImportError:
        pytest.fail("the Ray cluster test needs Ray: pip install 'sb3-emmarl[ray]' (make test installs it)")
    port = _free_port()
    address = f"127.0.0.1:{port}"
    temp = Path(tempfile.mkdtemp(prefix="ray", dir="/tmp"))  # short: Ray's socket paths must fit in 107 characters
    # A token of the cluster's own (not ~/.ray/auth_token, which other Ray instances on this machine may rewrite), for
    # every process of the cluster, the status queries and the driver.
    monkeypatch.setenv("RAY_AUTH_MODE", "token")
    monkeypatch.setenv("RAY_AUTH_TOKEN", secrets.token_hex(32))
    nodes: list[subprocess.Popen] = []

    def start(name: str, *flags: str) -> None:
        folder = tmp_path / name
        folder.mkdir()
        command = ["ray", "start", "--block", "--num-cpus", "1", "--object-store-memory", str(80 * 2**20),
                   "--node-ip-address", "127.0.0.1", "--disable-usage-stats", "--temp-dir", str(temp / name),
                   "--dashboard-agent-listen-port", str(_free_port()), "--metrics-export-port", str(_free_port()),
                   *flags]
        with open(tmp_path / f"{name}.log", "w") as log:
            nodes.append(subprocess.Popen(command, cwd=folder, stdout=log, stderr=subprocess.STDOUT,
                                          start_new_session=True))

    def active_nodes() -> int:
        status = subprocess.run(["ray", "status", "--address", address], capture_output=True, text=True)
        return len(re.findall(r"^\s*1 node_", status.stdout.split("Pending:")[0], flags=re.MULTILINE))

    try:
        start("head", "--head", "--port", str(port), "--include-dashboard", "false",
              "--ray-client-server-port", str(_free_port()))
        _wait_for(lambda: active_nodes() == 1, 120, "the head node")
        start("worker", "--address", address)
        _wait_for(lambda: active_nodes() == 2, 120, "the worker node")
        yield address
    finally:
        for node in reversed(nodes):
            with contextlib.suppress(ProcessLookupError):
                os.killpg(node.pid, signal.SIGTERM)
        deadline = time.monotonic() + 5
        for node in reversed(nodes):
            with contextlib.suppress(subprocess.TimeoutExpired):
                node.wait(timeout=max(0.1, deadline - time.monotonic()))
            with contextlib.suppress(ProcessLookupError):
                os.killpg(node.pid, signal.SIGKILL)  # whatever of the node's processes is left
            node.wait()
        shutil.rmtree(temp, ignore_errors=True)


def test_the_ray_backend_runs_on_a_two_node_cluster_and_gathers_the_run_folders(tmp_path, ray_cluster):
    driver = tmp_path / "driver"
    driver.mkdir()
    spec = write_spec(driver, ppo_only([0, 1]))
    # A relative results folder: the driver makes it absolute, so the workers (in other folders) write there.
    done = subprocess.run([sys.executable, str(ROOT / "zoo" / "experiment.py"), spec.name, "-f", "runs", "--backend",
                           "ray", "--address", ray_cluster, "--gather", "--no-report"], cwd=driver, capture_output=True,
                          text=True, timeout=600, env={**os.environ, "OMP_NUM_THREADS": "1"})
    assert done.returncode == 0, done.stdout + done.stderr
    runs = driver / "runs"
    store = ResultStore(runs / "results.sqlite")
    assert store.finished("tiny", "quick") == {("ppo", "clean", 0), ("ppo", "clean", 1)} and claims(store) == []
    # One cell ran on each node (one CPU each); the worker node's run folder came back to the driver.
    assert len(re.findall(r"run folder gathered from node \w+", done.stdout)) == 1, done.stdout
    for row in store.rows("tiny", "quick"):
        assert Path(row["run_dir"]).is_relative_to(runs) and row["version"] == __version__
        assert (Path(row["run_dir"]) / "stage_0" / "ppo" / "WildlifeReserve-v1_1" / "WildlifeReserve-v1.zip").is_file()
    for node in ("head", "worker"):
        assert sorted(p.name for p in (tmp_path / node).iterdir()) == [], f"{node} wrote into its working directory"
    # The same store contents as the local backend's for the same seeds (timings aside).
    assert experiment_main([str(spec), "-f", str(tmp_path / "local"), "--n-jobs", "2", "--no-report"]) == 0

    def content(folder: Path) -> list[tuple]:
        timing = set(RUN_METRICS) - {"n_timesteps"}
        return [(r["algorithm"], r["condition"], r["seed"], {k: v for k, v in r["metrics"].items() if k not in timing},
                 r["episodes"]) for r in ResultStore(folder / "results.sqlite").rows("tiny", "quick")]

    assert len(content(runs)) == 2 and content(runs) == content(tmp_path / "local")
