"""Run an experiment's missing cells, in parallel on this machine or as tasks on a Ray cluster.

A cell is one (algorithm, condition, seed) of a specification at a budget. Each runs in a fresh process
(``python -m sb3_emmarl.experiments.runner``, one torch thread): it trains through the zoo (``zoo/train.py``'s own
code, so the run folder is a zoo run: model, config, tensorboard logs, ``run_stats.json``), optionally fine-tunes on
another reserve (``-i``), evaluates the team on the budget's evaluation episodes (the same episodes for every cell)
and writes its result as JSON. The runner records each finished cell in the :class:`ResultStore` as soon as it
finishes, so that a runner killed mid-way and started again runs only the missing cells.

Several runners can share a store: each claims a cell in the store before starting it (a lease renewed by a heartbeat,
:meth:`ResultStore.claim`), skips the cells other live runners hold, waits for them at the end and takes over those
whose runner died. A runner's cells die with it: each cell process leads its own process group, which the runner
kills when it stops (an error, SIGINT, SIGTERM); a runner killed outright (SIGKILL) cannot, so each cell asks Linux to
kill it when its parent dies (``prctl(PR_SET_PDEATHSIG)``, chosen over polling ``os.getppid()`` because it acts at
once and costs nothing while the cell trains; elsewhere a thread of the cell polls its parent every second).

Backends: ``"local"`` (``n_jobs`` cells at once, each a subprocess) and ``"ray"`` (each cell a Ray task with one CPU
running the same subprocess; ``address`` names a running cluster, None starts a local instance). Ray is an optional
extra (``pip install sb3-emmarl[ray]``). A cell names its specification by name (the package's data, read on the
worker) or ships the YAML text of a file the driver read; the results root is made absolute by the driver. Every node
needs the same sb3-emmarl version as the driver (a cell refuses to run otherwise). On a cluster without a shared file
system the run folders stay on the workers unless ``gather`` is set, which brings each one to the driver's root.
"""

from __future__ import annotations

import argparse
import ctypes
import io
import json
import os
import platform
import shutil
import signal
import socket
import subprocess
import sys
import tarfile
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ThreadPoolExecutor, wait
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from sb3_emmarl.cli import child_failure, os_error_text
from sb3_emmarl.common.env_ids import ENV_ID
from sb3_emmarl.common.model_files import load_model
from sb3_emmarl.common.trust.extras import requires
from sb3_emmarl.common.trust.safe_config import load_yaml_text
from sb3_emmarl.experiments.spec import EPISODE_METRICS, SPECS_DIR, ExperimentSpec, load_spec, parse_spec
from sb3_emmarl.experiments.store import LEASE_SECONDS, ResultStore, RunnerId, code_version


def check_ray_address(address: str | None, timeout: float = 5.0) -> None:
    """Refuse a Ray cluster address that no one answers at, before anything starts (``ray.init`` retries such an
    address for minutes). ``None`` and ``"auto"`` (a local instance, or the cluster this machine belongs to) pass.

    :param address: ``--address``: ``host:port`` or ``ray://host:port``
    :param timeout: seconds to wait for the connection
    :raise ValueError: one line naming the address and why
    """
    if address is None or address == "auto":
        return
    host, _, port = address.removeprefix("ray://").rpartition(":")
    if not host or not port.isdigit():
        raise ValueError(f"--address {address!r}: expected host:port or ray://host:port (or leave it out: a local Ray)")
    try:
        socket.create_connection((host, int(port)), timeout=timeout).close()
    except OSError as error:
        raise ValueError(f"--address {address}: no Ray cluster answers there ({error.strerror or error}); start one "
                         "with `ray start --head`, or leave --address out for a local Ray instance") from None

#: The backends of :func:`run_experiment`.
BACKENDS = ("local", "ray")
#: A cell's trajectory of one evaluation episode (for the trajectory figures), in its folder.
TRAJECTORY_FILE = "trajectory.npz"
#: Seconds between a waiting runner's looks at the store (for cells other runners hold).
POLL_SECONDS = 1.0
#: Linux's ``prctl`` option that sends a signal to a process when its parent dies.
PR_SET_PDEATHSIG = 1

#: The cell processes this process runs, by process id (each leads its own process group).
_CELLS: dict[int, subprocess.Popen] = {}
_CELLS_LOCK = threading.Lock()


def hardware() -> str:
    """This machine, as the reports name it: CPU model, cores, memory, Python, torch."""
    import torch

    model = platform.machine()
    try:
        with open("/proc/cpuinfo") as info:
            model = next(line.split(":", 1)[1].strip() for line in info if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    memory = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30
    return (f"{model}, {os.cpu_count()} cores, {memory:.0f} GiB, Python {platform.python_version()}, "
            f"torch {torch.__version__}, one torch thread per cell")


def cell_folder(root: str | Path, spec: ExperimentSpec, budget: str, algorithm: str, condition: str,
                seed: int) -> Path:
    """Where a cell's runs live."""
    return Path(root) / spec.name / budget / algorithm / condition / f"seed_{seed}"


def _flags(pairs: dict[str, Any]) -> list[str]:
    return [f"{key}:{value!r}" for key, value in pairs.items()]


def _train(algo: str, n_timesteps: int, seed: int, folder: Path, env_kwargs: dict, hyperparams: dict,
           trained_agent: Path | None = None, env_id: str = ENV_ID) -> tuple[Path, dict]:
    """One zoo training run on ``env_id``; returns its run folder and run_stats.json."""
    from sb3_emmarl.zoo.cli import latest_run, train_main

    flags = ["--algo", algo, "--env", env_id, "-n", str(n_timesteps), "--seed", str(seed), "-f", str(folder),
             "--eval-freq", "-1", "--team-eval-episodes", "0", "--verbose", "0", "-tb", str(folder / "tensorboard")]
    if env_kwargs:
        flags += ["--env-kwargs", *_flags(env_kwargs)]
    if hyperparams:
        flags += ["-params", *_flags(hyperparams)]
    if trained_agent is not None:
        flags += ["-i", str(trained_agent)]
    code = train_main(flags)
    if code != 0:
        raise RuntimeError(f"zoo training failed with exit code {code}: {' '.join(flags)}")
    run = latest_run(folder, algo, env_id)
    return run, json.loads((run / "run_stats.json").read_text())


def run_cell(spec: ExperimentSpec, budget: str, algorithm: str, condition: str, seed: int,
             root: str | Path) -> dict[str, Any]:
    """Train, fine-tune if the condition says so, and evaluate one cell, in this process.

    The cell's folder is cleared first (what an earlier, dead attempt left behind): call it only for a cell that no
    live process works on (the runner's claim in the store ensures it).

    :return: ``{"metrics": {name: value}, "episodes": [evaluation records], "run_dir": folder}``: the mean of every
        episode metric over the evaluation episodes, and the run's ``train_seconds`` (both stages), ``peak_rss_mib``,
        ``cpu_percent`` (CPU time over wall time of training), ``agent_steps_per_second`` and ``n_timesteps``
    """
    import torch as th

    from sb3_emmarl.common.evaluation import evaluate_team
    from sb3_emmarl.zoo.algos import ZOO_ALGOS

    th.set_num_threads(1)
    variant, cond, plan = spec.algorithms[algorithm], spec.conditions[condition], spec.budgets[budget]
    folder = cell_folder(root, spec, budget, algorithm, condition, seed)
    shutil.rmtree(folder, ignore_errors=True)  # what a dead attempt left behind
    stages = [(plan.n_timesteps, cond.train)]
    if cond.fine_tune is not None:
        tuned = max(1, round(plan.n_timesteps * cond.fine_tune["fraction"]))
        stages = [(plan.n_timesteps - tuned, cond.train), (tuned, cond.fine_tune["env_kwargs"])]
    run, runs = None, []
    for i, (steps, env_kwargs) in enumerate(stages):
        run, stats = _train(variant.algo, steps, seed, folder / f"stage_{i}", env_kwargs, variant.hyperparams,
                            None if run is None else run / f"{spec.env}.zip", spec.env)
        runs.append(stats)
    assert run is not None  # (one stage at least)
    seconds = sum(s["train_seconds"] for s in runs)
    # A run continued with -i counts the first stage's steps again: with a fine-tuning stage, the budget is the count.
    steps = sum(s["n_timesteps"] for s in runs) if cond.fine_tune is None else plan.n_timesteps
    metrics: dict[str, float] = {
        "train_seconds": seconds, "peak_rss_mib": max(s["peak_rss_mib"] for s in runs),
        "cpu_percent": 100.0 * sum(s.get("cpu_seconds", 0.0) for s in runs) / max(seconds, 1e-9),
        "agent_steps_per_second": steps / max(seconds, 1e-9), "n_timesteps": float(steps)}
    model = load_model(ZOO_ALGOS[variant.algo], run / f"{spec.env}.zip", device="cpu")
    records = evaluate_team(model, plan.eval_episodes, seed=plan.eval_seed, env_kwargs=cond.eval_kwargs, env_id=spec.env)
    for metric in EPISODE_METRICS:
        if all(metric in r for r in records):
            metrics[metric] = float(np.mean([r[metric] for r in records]))
    if any(output.kind == "trajectories" for output in spec.outputs):
        from sb3_emmarl.common.recording import record_trajectory
        from sb3_emmarl.common.trust.atomic_files import write_atomic

        paths = record_trajectory(model, seed=plan.eval_seed, env_kwargs=cond.eval_kwargs)
        write_atomic(folder / TRAJECTORY_FILE, lambda file: np.savez_compressed(
            file, positions=paths["positions"], poachers=paths["poachers"], terrain=paths["terrain"]))
    return {"metrics": metrics, "episodes": records, "run_dir": str(folder)}


def compile_for_condition(spec: ExperimentSpec, condition: str) -> None:
    """Compile the reserve's kernels in this process for every reserve a cell of ``condition`` trains or is evaluated
    on (:func:`~sb3_emmarl.common.vec_env.compile_reserve`), so that the cells' fresh processes load them from numba's
    cache instead of each compiling them inside its timed training (nothing for another environment)."""
    from sb3_emmarl.common.vec_env import compile_reserve

    if spec.env != ENV_ID:
        return
    cond = spec.conditions[condition]
    stages = [cond.train, cond.eval_kwargs] + ([cond.fine_tune["env_kwargs"]] if cond.fine_tune is not None else [])
    for env_kwargs in stages:
        compile_reserve(env_kwargs)


def spec_from(name: str, text: str | None) -> ExperimentSpec:
    """A cell's specification: the package's own by ``name`` (read where the cell runs), or parsed from the YAML
    ``text`` the driver read from a file named ``name``."""
    if text is None:
        return load_spec(name)
    spec = parse_spec(load_yaml_text(text, f"{name}.yml"), f"{name}.yml")
    if spec.name != name:
        raise ValueError(f"{name}.yml: name: {spec.name!r} must be the file's name {name!r}")
    return spec


def _pack(folder: Path) -> bytes:
    """A folder as an in-memory gzipped tar (its entries relative to the folder)."""
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w:gz") as archive:
        archive.add(folder, arcname=".")
    return buffer.getvalue()


def unpack(data: bytes, folder: Path) -> None:
    """Replace ``folder`` by the content of a :func:`_pack` archive (regular files and folders only)."""
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir(parents=True)
    with tarfile.open(fileobj=io.BytesIO(data), mode="r:gz") as archive:
        archive.extractall(folder, filter="data")


def run_cell_process(spec_name: str, spec_text: str | None, budget: str, algorithm: str, condition: str, seed: int,
                     root: str, *, version: str | None = None, gather_from: str | None = None) -> dict[str, Any]:
    """:func:`run_cell` in a fresh process (one torch thread, its own process group, killed if this process dies),
    after :func:`compile_for_condition` in this one; returns its result.

    :param spec_name: the specification's name (the package's own when ``spec_text`` is None)
    :param spec_text: the YAML of a specification file the driver read, or None
    :param budget: the budget
    :param algorithm: the cell's algorithm
    :param condition: its condition
    :param seed: its seed
    :param root: the (absolute) results root
    :param version: the driver's package version: refused when this process's differs (None: not checked)
    :param gather_from: when set, the id of the driver's Ray node: a cell run on another node returns its folder as
        ``result["folder_archive"]`` (a gzipped tar) for the driver to unpack, and its node's id as ``result["node"]``
    :return: the cell's result (:func:`run_cell`) with the ``hardware`` it ran on
    :raise RuntimeError: when the cell fails or the versions differ
    """
    mine = code_version()[0]
    if version is not None and mine != version:
        raise RuntimeError(f"{platform.node()} has sb3-emmarl {mine} and the driver {version}: install the driver's "
                           "version on every node")
    spec = spec_from(spec_name, spec_text)
    compile_for_condition(spec, condition)
    result_file = Path(root) / ".results" / f"{spec.name}-{budget}-{algorithm}-{condition}-{seed}.json"
    result_file.parent.mkdir(parents=True, exist_ok=True)
    result_file.unlink(missing_ok=True)
    command = [sys.executable, "-m", "sb3_emmarl.experiments.runner", spec_name, budget, algorithm, condition,
               str(seed), root, str(result_file), "--parent-pid", str(os.getpid())]
    if spec_text is not None:
        command.append("--spec-stdin")
    cell = subprocess.Popen(command, stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            text=True, start_new_session=True, env={**os.environ, "OMP_NUM_THREADS": "1"})
    with _CELLS_LOCK:
        _CELLS[cell.pid] = cell
    try:
        _, stderr = cell.communicate(spec_text)
    finally:
        with _CELLS_LOCK:
            _CELLS.pop(cell.pid, None)
        _kill_group(cell)  # anything the cell left running in its group
    if cell.returncode != 0 or not result_file.is_file():
        raise RuntimeError(f"cell {algorithm} / {condition} / seed {seed} failed (exit code {cell.returncode}):"
                           f"{child_failure(stderr)}")
    result = json.loads(result_file.read_text())
    result_file.unlink()
    result["hardware"] = hardware()
    if gather_from is not None:
        import ray

        node = ray.get_runtime_context().get_node_id()
        if node != gather_from:
            result["folder_archive"], result["node"] = _pack(Path(result["run_dir"])), node
    return result


def _kill_group(cell: subprocess.Popen) -> None:
    """Kill a cell's process group (the cell leads it), if anything of it is left."""
    try:
        os.killpg(cell.pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        pass
    cell.wait()


def kill_cells() -> None:
    """Kill the process group of every cell this process is running (their threads see them fail)."""
    with _CELLS_LOCK:
        cells = list(_CELLS.values())
    for cell in cells:
        try:
            os.killpg(cell.pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass


@contextmanager
def _stopped_by_signals() -> Iterator[None]:
    """In the main thread, turn SIGTERM into :class:`SystemExit` (SIGINT is already KeyboardInterrupt), so that the
    runner's cleanup runs; the previous handler is restored after."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def stop(signum: int, frame: Any) -> None:
        raise SystemExit(f"stopped by {signal.Signals(signum).name}")

    previous = signal.signal(signal.SIGTERM, stop)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


class _Heartbeat(threading.Thread):
    """Renews a runner's claims every ``interval`` seconds until stopped."""

    def __init__(self, store: ResultStore, runner: RunnerId, interval: float) -> None:
        super().__init__(name="experiment-heartbeat", daemon=True)
        self.store, self.runner, self.interval = store, runner, interval
        self.stopped = threading.Event()

    def run(self) -> None:
        import sqlite3

        while not self.stopped.wait(self.interval):
            try:
                self.store.heartbeat(self.runner)
            except sqlite3.Error:
                pass  # the store is busy: the next beat comes before the lease ends


def _spec_source(spec: ExperimentSpec, spec_path: str | None) -> tuple[str, str | None]:
    """How a cell names its specification: the package's by name, or a file's YAML text."""
    if spec_path is None or Path(spec_path).resolve() == (SPECS_DIR / f"{spec.name}.yml").resolve():
        return spec.name, None
    return spec.name, Path(spec_path).read_text()


def run_experiment(spec: ExperimentSpec, budget: str, store: ResultStore, root: str | Path, *, backend: str = "local",
                   n_jobs: int | None = None, address: str | None = None, spec_path: str | None = None,
                   log: Callable[[str], None] = print, lease_seconds: float = LEASE_SECONDS,
                   rerun_stale: bool = False, gather: bool = False, conditions: Sequence[str] | None = None) -> int:
    """Run every cell of ``spec`` at ``budget`` that the store does not hold yet, and record each as it finishes.

    Cells are claimed in the store one by one before they start; cells that other live runners hold are left to
    them, and waited for once nothing else is left (a runner that dies meanwhile has its cells taken over here).

    :param spec: the experiment
    :param budget: ``"quick"`` or ``"full"``
    :param store: where finished cells are recorded (and looked up) and running ones claimed
    :param root: folder of the cells' runs (made absolute here)
    :param backend: ``"local"`` or ``"ray"``
    :param n_jobs: cells at once (default: this machine's cores on the local backend, the cluster's CPUs on Ray)
    :param address: the Ray cluster's address (None: a local Ray instance)
    :param spec_path: the specification's file when it is not one of the package's
    :param log: where progress lines go
    :param lease_seconds: how long after its last heartbeat a claim of a runner on another host stops holding its
        cell (a runner on this host holds its cells exactly as long as its process lives); heartbeats come every
        quarter of it
    :param rerun_stale: run again the cells stored by another version of the package (replacing them)
    :param gather: on Ray, bring the run folders of cells run on other nodes to this machine's ``root``
    :param conditions: run only these conditions' cells (None: every condition); the others stay as they are
    :return: the number of cells run (and recorded) by this runner
    """
    if budget not in spec.budgets:
        raise ValueError(f"budget must be one of {sorted(spec.budgets)}, got {budget!r}")
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {list(BACKENDS)}, got {backend!r}")
    if n_jobs is not None and (isinstance(n_jobs, bool) or not isinstance(n_jobs, int) or n_jobs < 1):
        raise ValueError(f"n_jobs must be an int >= 1, got {n_jobs!r}")
    if isinstance(lease_seconds, bool) or not isinstance(lease_seconds, (int, float)) or not lease_seconds > 0:
        raise ValueError(f"lease_seconds must be a number > 0, got {lease_seconds!r}")
    root = str(Path(root).resolve())
    version = code_version()
    cells = spec.cells(budget, conditions)
    current = version[0] if rerun_stale else None
    done = store.finished(spec.name, budget, current) & set(cells)
    log(f"{spec.name} ({budget}): {len(cells)} cells, {len(done)} finished"
        + (f" by {version[0]}" if rerun_stale else "") + f", {len(cells) - len(done)} to run ({backend})")
    if len(done) == len(cells):
        return 0
    todo = [cell for cell in cells if cell not in done]
    log(time_to_go(store.rows(spec.name, budget), todo, slots_hint(backend, n_jobs)))
    name, text = _spec_source(spec, spec_path)
    start = time.perf_counter()
    with _backend(backend, n_jobs, address, gather) as (slots, submit, wait_any, collect):
        scheduler = _Scheduler(spec, budget, store, cells, (name, text, root), version, lease_seconds, current, log)
        heartbeat = _Heartbeat(store, scheduler.runner, lease_seconds / 4)
        heartbeat.start()
        try:
            with _stopped_by_signals():
                ran = scheduler.run(slots, submit, wait_any, collect)
        finally:
            heartbeat.stopped.set()
            kill_cells()
            store.release(scheduler.runner)
    log(f"{spec.name} ({budget}): {ran} cells in {time.perf_counter() - start:.0f} s")
    return ran


def slots_hint(backend: str, n_jobs: int | None) -> int | None:
    """The cells that will run at once, when known before the backend starts (local: ``n_jobs`` or the cores)."""
    if backend != "local":
        return n_jobs
    return n_jobs or os.cpu_count() or 1


def time_at_medians(rates: dict[str, list[float]], todo: Sequence[tuple[str, float]], slots: int) -> str:
    """How long ``todo`` takes ``slots`` at a time, as ``"H h MM min"``: each ``(kind, amount)`` at the median of its
    kind's ``rates`` (seconds per unit; every kind's, for a kind with none) times its amount (a protocol's runs, an
    experiment's cells: :func:`time_to_go`, ``benchmarks/zone_patrol_value.py``'s estimate).

    :param rates: seconds per unit of each kind, measured (at least one)
    :param todo: what is left, ``(kind, units)``
    :param slots: how many run at once
    """
    every = [rate for values in rates.values() for rate in values]
    seconds = sum(float(np.median(rates.get(kind, every))) * amount for kind, amount in todo)
    hours, minutes = divmod(round(seconds / slots / 60), 60)
    return f"{hours} h {minutes:02d} min"


def time_to_go(rows: list[dict[str, Any]], todo: list[tuple[str, str, int]], slots: int | None) -> str:
    """The cells still to run and their time, before they start: each at the median training seconds of the stored
    cells of its algorithm (any algorithm's, for one with none), ``slots`` at a time (the evaluations not counted).

    :param rows: the stored cells (:meth:`ResultStore.rows`)
    :param todo: the cells to run, ``(algorithm, condition, seed)``
    :param slots: cells at once (None: unknown, the total is given for one at a time)
    """
    seconds: dict[str, list[float]] = {}
    for row in rows:
        if "train_seconds" in row["metrics"]:
            seconds.setdefault(row["algorithm"], []).append(float(row["metrics"]["train_seconds"]))
    if not seconds:
        return f"{len(todo)} cells to run; no stored cell yet to estimate their time from"
    duration = time_at_medians(seconds, [(algorithm, 1.0) for algorithm, _, _ in todo], slots or 1)
    return (f"{len(todo)} cells to run: about {duration} of training at {slots or 1} at a time (each "
            f"at its algorithm's median training seconds over the {len(rows)} stored cells, on the machines and loads "
            "they ran on)")


class _Scheduler:
    """What one runner does with an experiment's cells on a backend's slots: claim free cells while slots are free,
    record each cell as it finishes, and when nothing is left to claim wait for the cells other live runners hold
    (taking over those of a runner that died).

    :param spec: the experiment
    :param budget: its budget
    :param store: the store (claims and results)
    :param cells: the cells to run
    :param source: the specification's name and text (None: the package's own) and the results root, as a cell's
        process is given them
    :param version: the package's version and commit
    :param lease_seconds: how long a claim of a runner on another host holds without a heartbeat
    :param current: the version whose stored cells count as finished (None: any)
    :param log: where progress lines go
    """

    def __init__(self, spec: ExperimentSpec, budget: str, store: ResultStore, cells: list[tuple[str, str, int]],
                 source: tuple[str, str | None, str], version: tuple[str, str], lease_seconds: float,
                 current: str | None, log: Callable[[str], None]) -> None:
        self.spec, self.budget, self.store, self.cells, self.source = spec, budget, store, cells, source
        self.version, self.lease_seconds, self.current, self.log = version, lease_seconds, current, log
        self.runner = RunnerId()
        self.running: dict[Any, tuple[str, str, int]] = {}
        self.waiting_said = False

    def run(self, slots: int, submit: Callable[..., Any], wait_any: Callable[..., Any],
            collect: Callable[[Any], dict[str, Any]]) -> int:
        """Run cells until none is left to this runner or to any other live one; the number this runner recorded."""
        ran = 0
        while True:
            self._fill(slots, submit)
            if not self.running:
                if not self._others_running():
                    return ran
                continue
            for handle in wait_any(list(self.running), POLL_SECONDS):
                ran += self._record(self.running.pop(handle), collect(handle))

    def _fill(self, slots: int, submit: Callable[..., Any]) -> None:
        """Claim and start free cells while a slot is free."""
        name, text, root = self.source
        while len(self.running) < slots:
            claim = self.store.claim(self.spec.name, self.budget, self.cells, self.runner, self.lease_seconds,
                                     self.current)
            if claim is None:
                return
            if claim.previous is not None:
                self.log(f"  taking over {' / '.join(map(str, claim.cell))} from runner {claim.previous[:8]}, "
                         "which is gone")
            self.running[submit((name, text, self.budget, *claim.cell, root), self.version[0])] = claim.cell

    def _others_running(self) -> bool:
        """Whether other live runners hold cells of this experiment (waiting a poll's time if so)."""
        others = self.store.held_by_others(self.spec.name, self.budget, self.runner, self.lease_seconds) \
            & set(self.cells)
        if not others:
            return False
        if not self.waiting_said:
            self.log(f"  waiting for {len(others)} cell(s) that other runners are running")
            self.waiting_said = True
        time.sleep(POLL_SECONDS)
        return True

    def _record(self, cell: tuple[str, str, int], result: dict[str, Any]) -> int:
        """Record a finished cell (1), or drop it if another runner took its claim over (0)."""
        algorithm, condition, seed = cell
        if not self.store.record(self.spec.name, self.budget, cell, result["metrics"], result["episodes"],
                                 result["run_dir"], result["hardware"], runner=self.runner, version=self.version):
            self.log(f"  dropped {algorithm} / {condition} / seed {seed}: its claim was taken over")
            return 0
        self.log(f"  finished {algorithm} / {condition} / seed {seed}: "
                 + ", ".join(f"{k} {v:.3g}" for k, v in result["metrics"].items() if k in self.spec.metrics)
                 + (f" (run folder gathered from node {result['gathered_from'][:12]})"
                    if "gathered_from" in result else ""))
        return 1


@contextmanager
def _backend(backend: str, n_jobs: int | None, address: str | None, gather: bool) -> Iterator[tuple]:
    """``(slots, submit(args, version) -> handle, wait_any(handles, timeout) -> finished handles,
    collect(handle) -> result)`` of a backend, shut down on exit (running cells killed first): ``submit`` runs
    :func:`run_cell_process` with the positional ``args`` and the driver's package ``version``."""
    if backend == "local":
        slots = slots_hint("local", n_jobs) or 1
        pool = ThreadPoolExecutor(max_workers=slots)

        def submit_local(args: tuple, version: str) -> Future:
            return pool.submit(run_cell_process, *args, version=version)

        def wait_local(handles: list[Future], timeout: float) -> set[Future]:
            return wait(handles, timeout=timeout, return_when=FIRST_COMPLETED)[0]

        try:
            yield slots, submit_local, wait_local, Future.result
        finally:
            kill_cells()
            pool.shutdown(wait=True, cancel_futures=True)
        return
    with requires("ray", "ray", "the ray backend"):
        import ray
    started = not ray.is_initialized()
    if started:
        ray.init(address=address, include_dashboard=False, log_to_driver=False)
    refs: set[Any] = set()
    try:
        slots = n_jobs if n_jobs is not None else max(1, int(ray.cluster_resources().get("CPU", 1)))
        # (ray's typed remote functions take positional arguments only; run_cell_process takes two by keyword)
        task: Any = ray.remote(num_cpus=1, max_retries=0)(run_cell_process)
        gather_from = ray.get_runtime_context().get_node_id() if gather else None

        def submit(args: tuple, version: str) -> Any:
            ref = task.remote(*args, version=version, gather_from=gather_from)
            refs.add(ref)
            return ref

        def wait_ray(handles: list[Any], timeout: float) -> list[Any]:
            return ray.wait(handles, num_returns=1, timeout=timeout)[0]

        def collect(ref: Any) -> dict[str, Any]:
            refs.discard(ref)
            try:
                result = ray.get(ref)
            except ray.exceptions.RayTaskError as error:
                raise RuntimeError(str(error.cause)) from None
            archive, node = result.pop("folder_archive", None), result.pop("node", None)
            if archive is not None:
                unpack(archive, Path(result["run_dir"]))
                result["gathered_from"] = node
            return result

        yield slots, submit, wait_ray, collect
    finally:
        for ref in refs:
            ray.cancel(ref, force=True)
        if started:
            ray.shutdown()


def die_with_parent(parent_pid: int) -> None:
    """End this process when ``parent_pid`` (the runner that started it) dies: Linux's parent-death signal (SIGKILL),
    else a thread that polls the parent every second; and at once if the parent is already gone."""
    if sys.platform.startswith("linux"):
        libc = ctypes.CDLL(None, use_errno=True)
        if libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0) != 0:
            raise OSError(ctypes.get_errno(), "prctl(PR_SET_PDEATHSIG) failed")
    else:
        def watch() -> None:
            while os.getppid() == parent_pid:
                time.sleep(1.0)
            os.killpg(os.getpgrp(), signal.SIGKILL)

        threading.Thread(target=watch, name="parent-watch", daemon=True).start()
    if os.getppid() != parent_pid:  # it died before the signal was set
        os._exit(1)


def _cell_main(argv: list[str] | None = None) -> int:
    """One cell in this process: ``SPEC BUDGET ALGORITHM CONDITION SEED ROOT RESULT_FILE [--parent-pid PID]
    [--spec-stdin]``."""
    parser = argparse.ArgumentParser(description="Run one experiment cell (used by the runner).")
    parser.add_argument("spec", help="the package's specification's name, or with --spec-stdin the file's")
    for name in ("budget", "algorithm", "condition"):
        parser.add_argument(name)
    parser.add_argument("seed", type=int)
    parser.add_argument("root")
    parser.add_argument("result_file")
    parser.add_argument("--parent-pid", type=int, default=None, help="die when this process (the runner) dies")
    parser.add_argument("--spec-stdin", action="store_true", help="read the specification's YAML from stdin")
    args = parser.parse_args(argv)
    if args.parent_pid is not None:
        die_with_parent(args.parent_pid)
    spec = spec_from(args.spec, sys.stdin.read() if args.spec_stdin else None)
    from sb3_emmarl.common.trust.atomic_files import write_text

    try:
        result = run_cell(spec, args.budget, args.algorithm, args.condition, args.seed, args.root)
        write_text(args.result_file, json.dumps(result))
    except OSError as error:  # a full disk, a folder it may not write in: one line naming the file
        print(os_error_text(error), file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(_cell_main())
