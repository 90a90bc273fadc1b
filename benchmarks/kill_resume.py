"""Kill zoo training runs with SIGKILL at random moments, resume them, and compare with uninterrupted runs.

For each algorithm (PPO and EM-PPO by default) one uninterrupted ``zoo/train.py`` run is the reference;
then ``--kills`` runs of the same command (same seed, same checkpoint schedule) are killed with SIGKILL
at a moment drawn uniformly over the reference run's wall time. After each kill the script checks that
the newest checkpoint on disk loads (``check_model_file`` and the algorithm's ``load``) and that no
half-written file remains beside it, then continues the run with ``zoo/train.py --resume`` and compares
the final model's parameters with the reference's (maximum absolute difference; 0 means identical).
A kill before the first checkpoint leaves nothing to resume: the command is then run again from the
start, and the count is reported.

Every run trains on a small reserve (2 UAVs, 20 x 20, 50-step episodes) so that a trial takes seconds.

Example: ``python benchmarks/kill_resume.py --kills 20`` (about 15 minutes; ``make benchmark-kill-resume``)
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

TRAIN = str(Path(__file__).resolve().parents[1] / "zoo" / "train.py")
ENV_KWARGS = ["n_uavs:2", "grid_size:20", "max_cycles:50"]


def command(algo: str, folder: Path, n_timesteps: int, save_freq: int, seed: int, vec_env: str = "batched") -> list[str]:
    return [sys.executable, TRAIN, "--algo", algo, "-n", str(n_timesteps), "--seed", str(seed), "--save-freq",
            str(save_freq), "--eval-freq", "-1", "--team-eval-episodes", "0", "--verbose", "0", "-f", str(folder),
            "--vec-env", vec_env, "--env-kwargs", *ENV_KWARGS]


def run(cmd: list[str], timeout: float = 600) -> float:
    start = time.perf_counter()
    result = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout,
                            env={**os.environ, "OMP_NUM_THREADS": "1"})
    if result.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed ({result.returncode}):\n{result.stderr[-2000:]}")
    return time.perf_counter() - start


def parameters(path: Path) -> dict[str, np.ndarray]:
    from stable_baselines3.common.save_util import load_from_zip_file

    _, params, _ = load_from_zip_file(path, device="cpu")
    return {f"{group}.{key}": value.numpy() for group, state in params.items() if not group.endswith("optimizer")
            for key, value in state.items()}


def max_difference(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> float:
    if a.keys() != b.keys():
        return float("inf")
    return max(float(np.abs(a[k].astype(np.float64) - b[k].astype(np.float64)).max()) for k in a)


def trial(algo: str, root: Path, reference: dict[str, np.ndarray], duration: float, rng: np.random.Generator,
          args: argparse.Namespace) -> dict:
    from sb3_emmarl.common.checkpoints import list_checkpoints
    from sb3_emmarl.common.model_files import load_model
    from sb3_emmarl.zoo.algos import ZOO_ALGOS

    folder = root / "trial"
    shutil.rmtree(folder, ignore_errors=True)
    cmd = command(algo, folder, args.n_timesteps, args.save_freq, args.seed, args.vec_env)
    delay = float(rng.uniform(0.0, duration))
    process = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                               env={**os.environ, "OMP_NUM_THREADS": "1"})
    try:
        process.wait(timeout=delay)
        finished_before_kill = True
    except subprocess.TimeoutExpired:
        process.send_signal(signal.SIGKILL)
        process.wait()
        finished_before_kill = False
    runs = sorted((folder / algo).glob("WildlifeReserve-v1_*")) if (folder / algo).is_dir() else []
    outcome = {"delay": delay, "finished_before_kill": finished_before_kill, "checkpoint": None,
               "loads": None, "leftover_tmp": 0, "restarted": False}
    if runs:
        run_folder = runs[-1]
        outcome["leftover_tmp"] = len(list(run_folder.glob(".*.tmp")))
        checkpoints = list_checkpoints(run_folder)
        if checkpoints:
            steps, newest = checkpoints[-1]
            outcome["checkpoint"] = steps
            try:
                load_model(ZOO_ALGOS[algo], newest, device="cpu")
                outcome["loads"] = True
            except Exception as error:
                outcome["loads"] = f"{type(error).__name__}: {error}"
    if outcome["checkpoint"] is None and not finished_before_kill:
        shutil.rmtree(folder, ignore_errors=True)  # nothing to resume from: start again
        run(cmd)
        outcome["restarted"] = True
    else:
        run([sys.executable, TRAIN, "--algo", algo, "--resume", "-f", str(folder), "--verbose", "0"])
    final = sorted((folder / algo).glob("WildlifeReserve-v1_*"))[-1] / "WildlifeReserve-v1.zip"
    outcome["difference"] = max_difference(parameters(final), reference)
    return outcome


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--algos", nargs="+", default=["ppo", "em_ppo"])
    parser.add_argument("--kills", type=int, default=20, help="killed runs per algorithm")
    parser.add_argument("-n", "--n-timesteps", type=int, default=8192)
    parser.add_argument("--save-freq", type=int, default=1024)
    parser.add_argument("--seed", type=int, default=3)
    parser.add_argument("--draw-seed", type=int, default=0, help="seed of the kill moments")
    parser.add_argument("--vec-env", default="batched", choices=["batched", "subproc", "supersuit"],
                        help="the zoo's --vec-env of every run (subproc: reserves in worker processes too)")
    args = parser.parse_args()
    rng = np.random.default_rng(args.draw_seed)
    failures = 0
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        for algo in args.algos:
            ref_folder = root / "reference"
            shutil.rmtree(ref_folder, ignore_errors=True)
            duration = run(command(algo, ref_folder, args.n_timesteps, args.save_freq, args.seed, args.vec_env))
            reference = parameters(sorted((ref_folder / algo).glob("WildlifeReserve-v1_*"))[-1] / "WildlifeReserve-v1.zip")
            print(f"\n{algo} (--vec-env {args.vec_env}): reference run {duration:.1f} s, {args.n_timesteps} steps, "
                  f"a checkpoint every {args.save_freq} steps; {args.kills} runs killed at uniform random moments in "
                  f"[0, {duration:.1f}] s")
            print(f"{'kill':>4} {'at s':>6} {'newest ckpt':>11} {'loads':>5} {'.tmp':>4} {'then':>9} {'max |diff|':>10}")
            counts = {"loads": 0, "with_checkpoint": 0, "restarted": 0, "finished": 0, "identical": 0, "tmp": 0}
            for k in range(args.kills):
                out = trial(algo, root, reference, duration, rng, args)
                then = "restarted" if out["restarted"] else ("finished" if out["finished_before_kill"] else "resumed")
                loads = out["loads"] is True
                counts["loads"] += loads
                counts["with_checkpoint"] += out["checkpoint"] is not None
                counts["restarted"] += out["restarted"]
                counts["finished"] += out["finished_before_kill"]
                counts["identical"] += out["difference"] == 0.0
                counts["tmp"] += out["leftover_tmp"]
                if out["checkpoint"] is not None and not loads:
                    failures += 1
                    print(f"     checkpoint failed to load: {out['loads']}")
                failures += out["difference"] != 0.0
                print(f"{k:>4} {out['delay']:>6.1f} {out['checkpoint']!s:>11} {str(loads) if out['checkpoint'] else '-':>5} "
                      f"{out['leftover_tmp']:>4} {then:>9} {out['difference']:>10.3g}")
            left = counts["with_checkpoint"]
            print(f"{algo}: the newest checkpoint loaded after {counts['loads']} of the {left} kills that left one; "
                  f"{counts['restarted']} kills came before the first checkpoint (run again from the start), "
                  f"{counts['finished']} after the run had finished; the final model is identical to the "
                  f"uninterrupted run's in {counts['identical']} of {args.kills}; half-written .tmp files left by "
                  f"the kills: {counts['tmp']} (removed by --resume)")
    print(f"\nfailures: {failures}")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
