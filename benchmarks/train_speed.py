"""Training speed on the reserve through the two parameter-sharing paths, against a zero-cost environment.

Four parts, all printed as figures measured in this run:

1. **Training**: PPO and EM-PPO with their zoo YAMLs (4 copies x 10 UAVs, one torch thread unless
   ``--num-threads`` says otherwise) train ``-n``
   agent-steps on the reserve through the batched path (``ReserveVecEnv``), through SuperSuit
   (``SharedPolicyVecEnv``) and on a zero-cost vector environment with the same spaces, entries and episode length
   (constant observations, zero rewards: only the networks and SB3 cost anything). The configurations take turns,
   ``--rounds`` times; the table gives medians, and the share of training time spent outside the networks,
   ``1 - t(zero-cost) / t(path)`` (the environment plus the vector environment).
2. **Raw stepping** of the batched path with random actions: 1, 4, 16 and 64 copies of 10 UAVs, and 50 and 200
   UAVs (one copy, 200 x 200 cells), beside the SuperSuit path at the same sizes and, from 2 copies, the batched
   copies split over this process and a worker, polling (``subproc``) and blocking; the paths take turns
   (``--step-turns``, medians); peak memory that tracemalloc
   saw while the vector environment was built and stepped (a separate pass: tracing slows every allocation).
3. **Team size through the zoo** (``--team-sizes``): ``zoo/train.py --algo ppo`` for the same agent-steps with 10,
   50 and 200 UAVs, each in its own process: its training time (``run_stats.json``), cost per agent-step against
   10 UAVs and the process's peak resident memory.
4. **The networks' floor** (``--floor-threads``): PPO's gradient epochs alone, ``model.train()`` on one full rollout
   of the zero-cost environment with ``ppo.yml``'s settings, timed with 1 and 2 torch threads taking turns; per
   agent-step and for the paper's 10M agent-steps. EM-PPO trains the same networks (its policy reads the belief too)
   and adds its E-step, so no environment makes a 10M EM-PPO run faster than this.

Example: ``python benchmarks/train_speed.py`` (or ``make benchmark-train-speed``; about 15 minutes)
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
import tracemalloc
from functools import partial
from pathlib import Path

import numpy as np
import torch as th
from em_speed import build, zoo_settings
from gymnasium import spaces
from stable_baselines3.common.vec_env import VecEnv, VecMonitor

from sb3_emmarl.common.phases import PhaseTimes, median_phase_table
from sb3_emmarl.common.vec_env import ReserveVecEnv, compile_reserve, make_vec_env
from wildlife_reserve import reserve_v1

ROOT = Path(__file__).resolve().parents[1]


class ZeroCostVecEnv(VecEnv):
    """A vector environment with the reserve's spaces and entries that costs nothing: the same observation every
    step, zero rewards, every entry's episode ending after ``max_cycles`` steps (as the reserve's do)."""

    def __init__(self, observation_space: spaces.Box, action_space: spaces.Space, n_copies: int, agents_per_copy: int,
                 max_cycles: int) -> None:
        super().__init__(n_copies * agents_per_copy, observation_space, action_space)
        self.agents_per_copy, self.max_cycles = agents_per_copy, max_cycles
        self._obs = np.random.default_rng(0).random((self.num_envs, *observation_space.shape)).astype(np.float32)
        self._t = 0

    def reset(self):
        self._t = 0
        return self._obs.copy()

    def step_async(self, actions):
        pass

    def step_wait(self):
        self._t += 1
        dones = np.full(self.num_envs, self._t >= self.max_cycles)
        infos = [{} for _ in range(self.num_envs)]
        if self._t >= self.max_cycles:
            self._t = 0
            for info in infos:
                info.update({"terminal_observation": self._obs[0], "TimeLimit.truncated": True})
        return self._obs.copy(), np.zeros(self.num_envs, dtype=np.float32), dones, infos

    def close(self):
        pass

    def get_attr(self, attr_name, indices=None):
        if attr_name == "render_mode":  # (as the reserve's: no rendering; SB3 warns on an environment without one)
            return [None] * self.num_envs
        raise AttributeError(attr_name)

    def set_attr(self, attr_name, value, indices=None):
        pass

    def env_method(self, method_name, *args, indices=None, **kwargs):
        raise AttributeError(method_name)

    def env_is_wrapped(self, wrapper_class, indices=None):
        return [False] * self.num_envs


def zero_cost_like(algo: str, n_copies: int | None = None) -> VecEnv:
    settings = zoo_settings(algo)
    reserve = make_vec_env(1, seed=0, env_kwargs=settings.get("env_kwargs") or {})
    inner = reserve.unwrapped
    env = ZeroCostVecEnv(reserve.observation_space, reserve.action_space, int(n_copies or settings["n_envs"]),
                         inner.agents_per_copy, inner.prototype.max_cycles)
    reserve.close()
    return VecMonitor(env)


#: The training paths: name -> (make_vec_env's vec_env_type, num_cpus); "subproc" is the zoo's name for the batched
#: path with its copies split over this process and a worker.
PATHS = {"batched": ("batched", 0), "subproc": ("batched", 2), "supersuit": ("supersuit", 0)}


def training(algos: list[str], n: int, rounds: int, n_copies: int | None = None) -> None:
    paths = [*PATHS, "zero-cost"]
    seconds = {(algo, path): [] for algo in algos for path in paths}
    phases: dict[str, list[dict[str, float]]] = {f"{algo} {path}": [] for algo in algos for path in paths}
    for round_ in range(rounds):
        for algo in algos:
            for path in paths:
                env = zero_cost_like(algo, n_copies) if path == "zero-cost" else None
                vec_env_type, num_cpus = PATHS.get(path, (None, 0))
                model = build(algo, seed=round_, env=env, vec_env_type=vec_env_type, num_cpus=num_cpus,
                              n_copies=n_copies)
                times = PhaseTimes()
                start = time.perf_counter()
                model.learn(n, callback=times)
                seconds[algo, path].append(time.perf_counter() - start)
                phases[f"{algo} {path}"].append(times.seconds)
                model.get_env().close()
                print(f"  round {round_} {algo:<7} {path:<10} {seconds[algo, path][-1]:6.1f} s", flush=True)
    copies = f", {n_copies} copies" if n_copies else ""
    threads = th.get_num_threads()
    print(f"\nTraining: {n:,} agent-steps per turn, {rounds} turns each (median), zoo YAML settings{copies}, "
          f"{'one torch thread' if threads == 1 else f'{threads} torch threads'} (subproc: the batched path's copies "
          "split over this process and one worker)")
    print(f"{'algo':<8}{'path':<11}{'seconds':>9}{'agent-steps/s':>15}{'outside networks':>18}")
    for algo in algos:
        zero = np.median(seconds[algo, "zero-cost"])
        for path in paths:
            t = np.median(seconds[algo, path])
            share = "" if path == "zero-cost" else f"{1 - zero / t:.0%}"
            print(f"{algo:<8}{path:<11}{t:>9.1f}{n / t:>15,.0f}{share:>18}")
    print("\n" + median_phase_table(phases, {f"{algo} {path}": seconds[algo, path] for algo, path in seconds}))


def _step_rate(vec_env_type: str, n_copies: int, env_kwargs: dict, steps: int, trace: bool = False,
               num_cpus: int = 0, poll_seconds: float | None = None) -> float:
    if trace:
        tracemalloc.start()
    if poll_seconds is None:
        venv = make_vec_env(n_copies, seed=0, env_kwargs=env_kwargs, vec_env_type=vec_env_type, num_cpus=num_cpus)
    else:  # the batched path with the given polling (make_vec_env leaves it at its default)
        venv = VecMonitor(ReserveVecEnv(partial(reserve_v1.parallel_env, **env_kwargs), n_copies=n_copies,
                                        num_cpus=num_cpus, poll_seconds=poll_seconds))
        venv.seed(0)
    venv.reset()
    rng = np.random.default_rng(0)
    actions = rng.integers(0, venv.action_space.n, (64, venv.num_envs))
    for k in range(min(20, steps)):  # warm-up (numba's compiled kernels, first allocations)
        venv.step(actions[k % 64])
    start = time.perf_counter()
    for k in range(steps):
        venv.step(actions[k % 64])
    elapsed = time.perf_counter() - start
    venv.close()
    if trace:
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        return peak / 2**20
    return steps * venv.num_envs / elapsed


def stepping(agent_steps: int, copies: list[int], large_teams: list[int], turns: int = 3) -> None:
    sizes = [(c, 10, {}) for c in copies] + [(1, u, {"n_uavs": u, "grid_size": 200}) for u in large_teams]
    print(f"\nRaw stepping, random actions, about {agent_steps:,} agent-steps each (median of {turns} turns, the paths "
          "taking turns); batched and supersuit in one process, subproc: the batched copies split over this process "
          "and one worker (two cores; blocking: the same without polling, poll_seconds=0; memory: this process's "
          "allocations only)")
    print(f"{'copies':>7}{'UAVs':>6}{'batched /s':>13}{'subproc /s':>13}{'blocking /s':>13}{'supersuit /s':>15}"
          f"{'ratio':>7}{'batched MiB':>13}{'supersuit MiB':>15}")
    for copies, uavs, kwargs in sizes:
        steps = max(50, agent_steps // (copies * uavs))
        # The paths take turns, `turns` times (the load on the machine moves): (vec_env_type, num_cpus, poll_seconds)
        paths = {"batched": ("batched", 0, None), "supersuit": ("supersuit", 0, None)}
        if copies > 1:
            paths.update(subproc=("batched", 2, None), blocking=("batched", 2, 0.0))
        measured: dict[str, list[float]] = {path: [] for path in paths}
        for _ in range(turns):
            for path, (vec_env_type, num_cpus, poll) in paths.items():
                measured[path].append(_step_rate(vec_env_type, copies, kwargs, steps, num_cpus=num_cpus,
                                                 poll_seconds=poll))
        rates = {path: float(np.median(measured[path])) if path in measured else float("nan")
                 for path in ("batched", "supersuit", "subproc", "blocking")}
        split, blocking = rates["subproc"], rates["blocking"]
        memory = {path: _step_rate(path, copies, kwargs, 50, trace=True) for path in ("batched", "supersuit")}
        print(f"{copies:>7}{uavs:>6}{rates['batched']:>13,.0f}{split:>13,.0f}{blocking:>13,.0f}"
              f"{rates['supersuit']:>15,.0f}"
              f"{rates['batched'] / rates['supersuit']:>7.2f}{memory['batched']:>13.1f}{memory['supersuit']:>15.1f}",
              flush=True)


def team_sizes(n: int, sizes: list[int], vec_env: str, threads: int = 1) -> None:
    print(f"\nTeam size through the zoo: zoo/train.py --algo ppo -n {n:,} --vec-env {vec_env} --num-threads {threads} "
          "(ppo.yml: 4 copies), "
          "each in its own process; the training time and peak memory the zoo writes in run_stats.json")
    print(f"{'UAVs':>6}{'seconds':>9}{'us/agent-step':>15}{'x 10 UAVs':>11}{'peak RSS MiB':>14}")
    first = None
    with tempfile.TemporaryDirectory() as folder:
        for uavs in sizes:
            compile_reserve({"n_uavs": uavs})  # so that no run's time or peak memory counts numba compiling the kernels
            cmd = [sys.executable, "zoo/train.py", "--algo", "ppo", "-n", str(n), "--seed", "0", "-f", folder,
                   "--eval-freq", "-1", "--team-eval-episodes", "0", "--verbose", "0", "--vec-env", vec_env,
                   "--num-threads", str(threads), "--env-kwargs", f"n_uavs:{uavs}"]
            out = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True,
                                 env={**os.environ, "OMP_NUM_THREADS": str(threads)})
            if out.returncode:
                raise RuntimeError(f"zoo run with {uavs} UAVs failed:\n{out.stderr[-2000:]}")
            stats = json.loads(max(Path(folder).glob("ppo/*/run_stats.json"), key=os.path.getmtime).read_text())
            cost = stats["train_seconds"] / stats["n_timesteps"] * 1e6
            first = first or cost
            print(f"{uavs:>6}{stats['train_seconds']:>9.1f}{cost:>15.1f}{cost / first:>11.2f}"
                  f"{stats['peak_rss_mib']:>14.0f}", flush=True)


def network_floor(threads: list[int], turns: int, total: int = 10_000_000) -> None:
    """PPO's gradient epochs on one rollout, timed per thread count (the counts take turns; medians)."""
    env = zero_cost_like("ppo")
    model = build("ppo", seed=0, env=env)
    rollout = model.n_steps * env.num_envs
    model.learn(rollout)  # one rollout collected and trained on: the buffer is full, the logger set up
    seconds: dict[int, list[float]] = {count: [] for count in threads}
    before = th.get_num_threads()
    for _ in range(turns):
        for count in threads:
            th.set_num_threads(count)
            start = time.perf_counter()
            model.train()
            seconds[count].append(time.perf_counter() - start)
    th.set_num_threads(before)
    env.close()
    print(f"\nThe networks' floor: PPO's gradient epochs on one rollout of {rollout:,} agent-steps (ppo.yml: "
          f"{model.n_epochs} epochs, batches of {model.batch_size}, net_arch "
          f"{model.policy.net_arch}), model.train() on the zero-cost environment, {turns} turns (median), the thread "
          f"counts taking turns; minutes: the gradient epochs alone of {total:,} agent-steps")
    print(f"{'threads':>8}{'s per rollout':>15}{'us/agent-step':>15}{f'min per {total / 1e6:g}M':>14}")
    for count in threads:
        t = float(np.median(seconds[count]))
        print(f"{count:>8}{t:>15.3f}{t / rollout * 1e6:>15.1f}{t / rollout * total / 60:>14.1f}", flush=True)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("-n", "--n-timesteps", type=int, default=100_000, help="agent-steps per training turn")
    parser.add_argument("--rounds", type=int, default=3, help="turns of each training configuration")
    parser.add_argument("--algos", nargs="+", default=["ppo", "em_ppo"], choices=["ppo", "em_ppo"])
    parser.add_argument("--n-copies", type=int, default=None,
                        help="reserve copies of the training part (default: the zoo YAML's n_envs, 4)")
    parser.add_argument("--step-agent-steps", type=int, default=100_000, help="agent-steps per raw stepping measure")
    parser.add_argument("--step-turns", type=int, default=3, help="turns of each path in raw stepping (median)")
    parser.add_argument("--copies", type=int, nargs="*", default=[1, 4, 16, 64], help="copies of 10 UAVs stepped raw")
    parser.add_argument("--large-teams", type=int, nargs="*", default=[50, 200],
                        help="UAVs of the one-copy raw stepping runs on 200 x 200 cells")
    parser.add_argument("--team-sizes", type=int, nargs="*", default=[10, 50, 200],
                        help="UAVs of the zoo runs (none: skip that part)")
    parser.add_argument("--team-n", type=int, default=204_800, help="agent-steps of each zoo run")
    parser.add_argument("--vec-env", default="batched", choices=["batched", "subproc", "supersuit"],
                        help="path of the zoo runs")
    parser.add_argument("--floor-threads", type=int, nargs="*", default=[1, 2],
                        help="torch thread counts of the networks' floor (none: skip that part)")
    parser.add_argument("--floor-turns", type=int, default=5, help="turns of each thread count in the networks' floor")
    parser.add_argument("--skip", nargs="*", default=[], choices=["training", "stepping"], help="parts to skip")
    parser.add_argument("--num-threads", type=int, default=1,
                        help="torch threads of the training part and the zoo runs (the zoo's --num-threads; default 1)")
    args = parser.parse_args(argv)
    for name in ("n_timesteps", "rounds", "step_agent_steps", "step_turns", "team_n", "floor_turns"):
        if getattr(args, name) < 1:
            parser.error(f"--{name.replace('_', '-')} must be >= 1, got {getattr(args, name)}")
    for name in ("copies", "large_teams", "team_sizes", "floor_threads"):
        if any(value < 1 for value in getattr(args, name)):
            parser.error(f"--{name.replace('_', '-')} must be >= 1, got {getattr(args, name)}")
    if args.n_copies is not None and args.n_copies < 1:
        parser.error(f"--n-copies must be >= 1, got {args.n_copies}")
    if args.num_threads < 1:
        parser.error(f"--num-threads must be >= 1, got {args.num_threads}")
    th.set_num_threads(args.num_threads)
    if "training" not in args.skip:
        training(args.algos, args.n_timesteps, args.rounds, args.n_copies)
    if "stepping" not in args.skip:
        stepping(args.step_agent_steps, args.copies, args.large_teams, args.step_turns)
    if args.team_sizes:
        team_sizes(args.team_n, args.team_sizes, args.vec_env, args.num_threads)
    if args.floor_threads:
        network_floor(args.floor_threads, args.floor_turns)
    return 0


if __name__ == "__main__":
    sys.exit(main())
