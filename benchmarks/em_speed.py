"""Wall time of EM-PPO against PPO and RecurrentPPO at equal agent-steps, taking turns in one process.

Each algorithm is built from its zoo YAML (``em_ppo.yml``, ``ppo.yml``, ``ppo_lstm.yml``: the same PPO
settings) on the default reserve and trains ``-n`` agent-steps; the algorithms take turns, ``--rounds``
times (fresh models, seeds 0, 1, ...), with one torch thread, so that the machine's load drifts hit all
of them alike. The table gives the median seconds and agent-steps per second of each, and the ratios of
EM-PPO's median to the others'.

Example: ``python benchmarks/em_speed.py`` (or ``make benchmark-em-speed``; about 15 minutes)
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np
import torch as th

from sb3_emmarl.common.centralized import ENV_ID
from sb3_emmarl.common.vec_env import make_vec_env
from sb3_emmarl.zoo.algos import ZOO_ALGOS
from sb3_emmarl.zoo.exp_manager import zoo_hyperparams, zoo_model


def zoo_settings(algo: str) -> dict:
    """The zoo YAML's settings of ``algo`` on the reserve."""
    settings = zoo_hyperparams(algo, ENV_ID)
    if settings.get("normalize"):
        raise ValueError(f"{algo}.yml normalizes observations; this benchmark does not")
    return settings


def build(algo: str, seed: int, env=None, vec_env_type: str | None = None, num_cpus: int = 0,
          n_copies: int | None = None):
    """The algorithm with its zoo YAML's settings on ``n_envs`` (or ``n_copies``) default reserves (through
    ``vec_env_type``, in ``num_cpus`` processes), or on ``env``."""
    settings = zoo_settings(algo)
    if env is None:
        env = make_vec_env(n_copies=int(n_copies or settings["n_envs"]), seed=seed,
                           env_kwargs=settings.get("env_kwargs") or {}, vec_env_type=vec_env_type, num_cpus=num_cpus)
    return zoo_model(algo, env, seed)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("-n", "--n-timesteps", type=int, default=100_000, help="agent-steps per turn")
    parser.add_argument("--rounds", type=int, default=3, help="turns of each algorithm")
    parser.add_argument("--algos", nargs="+", default=["em_ppo", "ppo", "ppo_lstm"], choices=sorted(ZOO_ALGOS))
    args = parser.parse_args(argv)
    if args.n_timesteps < 1 or args.rounds < 1:
        parser.error(f"-n and --rounds must be >= 1, got {args.n_timesteps} and {args.rounds}")
    th.set_num_threads(1)
    seconds: dict[str, list[float]] = {algo: [] for algo in args.algos}
    for round_ in range(args.rounds):
        for algo in args.algos:
            model = build(algo, seed=round_)
            start = time.perf_counter()
            model.learn(args.n_timesteps)
            seconds[algo].append(time.perf_counter() - start)
            print(f"round {round_} {algo}: {seconds[algo][-1]:.1f} s", flush=True)
    print(f"\n{args.n_timesteps:,} agent-steps per turn, {args.rounds} turns each, one process, one torch thread")
    print(f"{'algo':<10}{'median s':>10}{'agent-steps/s':>15}")
    for algo, values in seconds.items():
        print(f"{algo:<10}{np.median(values):>10.1f}{args.n_timesteps / np.median(values):>15,.0f}")
    if "em_ppo" in seconds:
        for other in (a for a in seconds if a != "em_ppo"):
            print(f"em_ppo / {other}: {np.median(seconds['em_ppo']) / np.median(seconds[other]):.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
