"""EM-PPO with default arguments on the two hidden-mode tasks, against PPO told the mode and plain PPO.

The tasks (:mod:`sb3_emmarl.common.envs`): ``cue`` shows the mode only through a weak cue at every step
(right 40% of the time); ``dynamics`` changes only what the actions do. Every run trains on 8 copies
(SB3's ``make_vec_env``) in its own process with one torch thread: ``EMPPO("MlpPolicy", env)`` with its
defaults, and PPO with the same PPO settings (``n_steps`` 128, ``batch_size`` 128) on the plain task and on
the task whose observation ends with the mode's one-hot (``told``). Each is then scored by SB3's
``evaluate_policy`` on the plain task it was trained on (50 episodes, held-out seeds); EM-PPO's aligned
latent accuracy is measured over the second half of 40 held-out episodes (beliefs from its belief
wrapper; components aligned to modes by Hungarian matching).

Example: ``python benchmarks/latent_tasks.py`` (or ``make benchmark-latent-tasks``; about 30 minutes)
"""

from __future__ import annotations

import argparse
import sys
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from sb3_emmarl.zoo.benchmark import paired_p_value
from sb3_emmarl.zoo.cli import KeyValues

#: Budget (agent-steps) of each task's runs: where EM-PPO's defaults reach the targets in our runs (on the dynamics
#: task one seed of three fell short at 300k in two releases, 0.83 and 0.84 of the told return; at 500k none did).
BUDGETS = {"cue": 100_000, "dynamics": 500_000}
VARIANTS = ("em_ppo", "told_ppo", "ppo")
N_ENVS = 8


def make_task(task: str, told: bool = False, n_envs: int = N_ENVS, seed: int = 0):
    from stable_baselines3.common.env_util import make_vec_env

    from sb3_emmarl.common.envs import ModeCueEnv, ModeDynamicsEnv

    env_class = {"cue": ModeCueEnv, "dynamics": ModeDynamicsEnv}[task]
    return make_vec_env(lambda: env_class(told=told), n_envs=n_envs, seed=seed)


def latent_accuracy(model, task: str, seed: int, episodes: int = 40) -> float:
    """Aligned accuracy of the belief's most likely component over the second half of held-out episodes."""
    from sb3_emmarl.common.latent.metrics import align_components

    venv = model.wrap_env(make_task(task, n_envs=4, seed=seed))
    length = venv.get_attr("length", indices=[0])[0]
    obs, steps = venv.reset(), np.zeros(4, dtype=np.int64)
    modes_now = np.array(venv.get_attr("mode"))
    beliefs, modes = [], []
    for _ in range(episodes // 4 * length):
        if (steps >= length // 2).any():
            late = steps >= length // 2
            beliefs.append(model.posterior(obs)[late])
            modes.append(modes_now[late])
        obs, _, dones, _ = venv.step(model.predict(obs, deterministic=True)[0])
        steps = np.where(dones, 0, steps + 1)
        modes_now = np.array(venv.get_attr("mode"))
    beliefs, modes = np.concatenate(beliefs), np.concatenate(modes)
    mapping = align_components(beliefs, modes)
    return float((mapping[beliefs.argmax(1)] == modes).mean())


def run(task: str, variant: str, seed: int, budget: int, eval_episodes: int) -> dict:
    """Train one variant on one task and seed, then evaluate it with SB3's ``evaluate_policy``."""
    import torch as th
    from stable_baselines3 import PPO
    from stable_baselines3.common.evaluation import evaluate_policy

    from sb3_emmarl import EMPPO

    th.set_num_threads(1)
    told = variant == "told_ppo"
    env = make_task(task, told=told, seed=seed)
    start = time.perf_counter()
    if variant == "em_ppo":
        model = EMPPO("MlpPolicy", env, seed=seed)
    else:
        model = PPO("MlpPolicy", env, n_steps=128, batch_size=128, seed=seed)
    model.learn(budget)
    seconds = time.perf_counter() - start
    mean, _ = evaluate_policy(model, make_task(task, told=told, n_envs=5, seed=10_000 + seed), n_eval_episodes=eval_episodes)
    record = {"task": task, "variant": variant, "seed": seed, "return": float(mean), "seconds": seconds}
    if variant == "em_ppo":
        record["latent_accuracy"] = latent_accuracy(model, task, 20_000 + seed)
    return record


def table(records: list[dict]) -> str:
    lines = [f"{'task':<10}{'variant':<10}{'return':>18}{'/ told':>8}{'latent acc (2nd half)':>24}{'seconds':>9}"]
    for task in dict.fromkeys(r["task"] for r in records):
        mine = {v: sorted((r for r in records if r["task"] == task and r["variant"] == v), key=lambda r: r["seed"])
                for v in VARIANTS}
        told = np.mean([r["return"] for r in mine["told_ppo"]])
        for variant in VARIANTS:
            returns = np.array([r["return"] for r in mine[variant]])
            accuracy = [r["latent_accuracy"] for r in mine[variant] if "latent_accuracy" in r]
            acc = f"{np.mean(accuracy):.3f} +- {np.std(accuracy):.3f}" if accuracy else "-"
            lines.append(f"{task:<10}{variant:<10}{returns.mean():>10.2f} +- {returns.std():<4.2f}"
                         f"{returns.mean() / told:>8.3f}{acc:>24}{np.mean([r['seconds'] for r in mine[variant]]):>9.0f}")
        em = [r["return"] for r in mine["em_ppo"]]
        for other in ("ppo", "told_ppo"):
            lines.append(f"{'':<10}em_ppo - {other}: {np.mean(em) - np.mean([r['return'] for r in mine[other]]):+.2f}, "
                         f"p (paired t over seeds) {paired_p_value(em, [r['return'] for r in mine[other]]):.3g}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tasks", nargs="+", default=list(BUDGETS), choices=list(BUDGETS))
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--eval-episodes", type=int, default=50)
    parser.add_argument("--n-jobs", type=int, default=2, help="runs at once, each in its own process")
    parser.add_argument("--budgets", nargs="+", action=KeyValues, default={}, metavar="TASK:N",
                        help=f"agent-steps per run of a task, for every variant alike (default {BUDGETS})")
    args = parser.parse_args(argv)
    if args.eval_episodes < 1 or args.n_jobs < 1 or len(set(args.seeds)) != len(args.seeds):
        parser.error("--eval-episodes and --n-jobs must be >= 1 and --seeds distinct")
    for task, steps in args.budgets.items():
        if task not in BUDGETS or isinstance(steps, bool) or not isinstance(steps, int) or steps < 1:
            parser.error(f"--budgets takes TASK:N with TASK one of {list(BUDGETS)} and N an integer >= 1, "
                         f"got {task}:{steps!r}")
    budgets = {**BUDGETS, **args.budgets}
    tasks = [(t, v, s, budgets[t], args.eval_episodes) for t in args.tasks for s in args.seeds for v in VARIANTS]
    with ProcessPoolExecutor(max_workers=args.n_jobs) as pool:
        records = []
        for record in pool.map(run, *zip(*tasks)):
            print(f"{record['task']} {record['variant']} seed {record['seed']}: return {record['return']:.2f}"
                  + (f", latent accuracy {record['latent_accuracy']:.3f}" if "latent_accuracy" in record else ""),
                  flush=True)
            records.append(record)
    used = {t: budgets[t] for t in args.tasks}
    print(f"\nDefault arguments; budgets {used} agent-steps; {N_ENVS} envs; {len(args.seeds)} seeds; "
          f"{args.eval_episodes} evaluation episodes (evaluate_policy on the plain task, deterministic actions); "
          "mean +- std over seeds")
    print(table(records))
    return 0


if __name__ == "__main__":
    sys.exit(main())
