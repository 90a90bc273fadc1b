"""Run an experiment's missing cells, in parallel on this machine or as tasks on a Ray cluster.

A cell is one (algorithm, condition, seed) of a specification at a budget. Each runs in a fresh process
(``python -m sb3_emmarl.experiments.runner``, one torch thread): it trains through the zoo (``zoo/train.py``'s own
code, so the run folder is a zoo run: model, config, tensorboard logs, ``run_stats.json``), optionally fine-tunes on
another reserve (``-i``), evaluates the team on the budget's evaluation episodes (the same episodes for every cell)
and writes its result as JSON. The runner records each finished cell in the :class:`ResultStore` as soon as it
finishes, so that a runner killed mid-way and started again runs only the missing cells.

Backends: ``"local"`` (``n_jobs`` cells at once, each a subprocess) and ``"ray"`` (each cell a Ray task with one CPU
running the same subprocess; ``address`` names a running cluster, None starts a local instance). Ray is an optional
extra (``pip install sb3-emmarl[ray]``). On a cluster without a shared file system the run folders (and so the
learning curves) stay on the workers; the store gets every metric.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import time
from collections.abc import Callable
from concurrent.futures import FIRST_COMPLETED, ThreadPoolExecutor, wait
from pathlib import Path
from typing import Any

import numpy as np

from sb3_emmarl.common.environments import ENV_ID
from sb3_emmarl.experiments.spec import EPISODE_METRICS, SPECS_DIR, ExperimentSpec, load_spec
from sb3_emmarl.experiments.store import ResultStore

#: The backends of :func:`run_experiment`.
BACKENDS = ("local", "ray")
#: A cell's trajectory of one evaluation episode (for the trajectory figures), in its folder.
TRAJECTORY_FILE = "trajectory.npz"


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
    shutil.rmtree(folder, ignore_errors=True)  # what a killed attempt left behind
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
    model = ZOO_ALGOS[variant.algo].load(run / f"{spec.env}.zip", device="cpu")
    records = evaluate_team(model, plan.eval_episodes, seed=plan.eval_seed, env_kwargs=cond.eval_kwargs, env_id=spec.env)
    for metric in EPISODE_METRICS:
        if all(metric in r for r in records):
            metrics[metric] = float(np.mean([r[metric] for r in records]))
    if any(output.kind == "trajectories" for output in spec.outputs):
        from sb3_emmarl.common.checkpoints import write_atomic
        from sb3_emmarl.common.recording import record_trajectory

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


def run_cell_process(spec_path: str, budget: str, algorithm: str, condition: str, seed: int,
                     root: str) -> dict[str, Any]:
    """:func:`run_cell` in a fresh process (one torch thread), after :func:`compile_for_condition` in this one;
    returns its result."""
    compile_for_condition(load_spec(spec_path), condition)
    result_file = Path(root) / ".results" / f"{Path(spec_path).stem}-{budget}-{algorithm}-{condition}-{seed}.json"
    result_file.parent.mkdir(parents=True, exist_ok=True)
    result_file.unlink(missing_ok=True)
    command = [sys.executable, "-m", "sb3_emmarl.experiments.runner", spec_path, budget, algorithm, condition,
               str(seed), root, str(result_file)]
    done = subprocess.run(command, capture_output=True, text=True, env={**os.environ, "OMP_NUM_THREADS": "1"})
    if done.returncode != 0 or not result_file.is_file():
        raise RuntimeError(f"cell {algorithm} / {condition} / seed {seed} failed:\n{done.stderr[-3000:]}")
    result = json.loads(result_file.read_text())
    result_file.unlink()
    return result


def _spec_path(spec: ExperimentSpec, spec_path: str | None) -> str:
    return spec_path or str(SPECS_DIR / f"{spec.name}.yml")


def run_experiment(spec: ExperimentSpec, budget: str, store: ResultStore, root: str | Path, backend: str = "local",
                   n_jobs: int | None = None, address: str | None = None, spec_path: str | None = None,
                   log: Callable[[str], None] = print) -> int:
    """Run every cell of ``spec`` at ``budget`` that the store does not hold yet, and record each as it finishes.

    :param spec: the experiment
    :param budget: ``"quick"`` or ``"full"``
    :param store: where finished cells are recorded (and looked up)
    :param root: folder of the cells' runs
    :param backend: ``"local"`` or ``"ray"``
    :param n_jobs: cells at once on the local backend (default: this machine's cores)
    :param address: the Ray cluster's address (None: a local Ray instance)
    :param spec_path: the specification's file when it is not one of the package's
    :param log: where progress lines go
    :return: the number of cells run now
    """
    if budget not in spec.budgets:
        raise ValueError(f"budget must be one of {sorted(spec.budgets)}, got {budget!r}")
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {list(BACKENDS)}, got {backend!r}")
    n_jobs = (os.cpu_count() or 1) if n_jobs is None else n_jobs
    if isinstance(n_jobs, bool) or not isinstance(n_jobs, int) or n_jobs < 1:
        raise ValueError(f"n_jobs must be an int >= 1, got {n_jobs!r}")
    done = store.finished(spec.name, budget)
    cells = [cell for cell in spec.cells(budget) if cell not in done]
    log(f"{spec.name} ({budget}): {len(spec.cells(budget))} cells, {len(done)} finished, {len(cells)} to run "
        f"({backend})")
    if not cells:
        return 0
    path, machine = _spec_path(spec, spec_path), hardware()
    args = [(path, budget, a, c, s, str(root)) for a, c, s in cells]

    def record(cell_args: tuple, result: dict[str, Any]) -> None:
        _, _, algorithm, condition, seed, _ = cell_args
        store.record(spec.name, budget, algorithm, condition, seed, result["metrics"], result["episodes"],
                     result["run_dir"], machine)
        log(f"  finished {algorithm} / {condition} / seed {seed}: "
            + ", ".join(f"{k} {v:.3g}" for k, v in result["metrics"].items() if k in spec.metrics))

    start = time.perf_counter()
    if backend == "local":
        with ThreadPoolExecutor(max_workers=n_jobs) as pool:
            pending = {pool.submit(run_cell_process, *a): a for a in args}
            while pending:
                finished, _ = wait(pending, return_when=FIRST_COMPLETED)
                for future in finished:
                    record(pending.pop(future), future.result())
    else:
        _run_on_ray(args, address, record)
    log(f"{spec.name} ({budget}): {len(cells)} cells in {time.perf_counter() - start:.0f} s")
    return len(cells)


def _run_on_ray(args: list[tuple], address: str | None, record: Callable[[tuple, dict], None]) -> None:
    try:
        import ray
    except ImportError:
        raise ValueError("the ray backend needs Ray: pip install 'sb3-emmarl[ray]'") from None
    started = not ray.is_initialized()
    if started:
        ray.init(address=address, include_dashboard=False, log_to_driver=False)
    try:
        task = ray.remote(num_cpus=1)(run_cell_process)
        pending = {task.remote(*a): a for a in args}
        while pending:
            finished, _ = ray.wait(list(pending), num_returns=1)
            for ref in finished:
                record(pending.pop(ref), ray.get(ref))
    finally:
        if started:
            ray.shutdown()


def _cell_main(argv: list[str] | None = None) -> int:
    """One cell in this process: ``SPEC BUDGET ALGORITHM CONDITION SEED ROOT RESULT_FILE``."""
    parser = argparse.ArgumentParser(description="Run one experiment cell (used by the runner).")
    for name in ("spec", "budget", "algorithm", "condition"):
        parser.add_argument(name)
    parser.add_argument("seed", type=int)
    parser.add_argument("root")
    parser.add_argument("result_file")
    args = parser.parse_args(argv)
    result = run_cell(load_spec(args.spec), args.budget, args.algorithm, args.condition, args.seed, args.root)
    from sb3_emmarl.common.checkpoints import write_text

    write_text(args.result_file, json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(_cell_main())
