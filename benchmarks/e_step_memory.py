"""Peak memory of an EM-DDPG run on the reserve with a given E-step window (one run per process).

Trains ``EMDDPG`` with ``em_ddpg.yml``'s latent settings (8 components, factored counts, likelihood temperature 0.1,
team pooling, the E-step's epochs and batches) for ``-n`` agent-steps on one reserve copy, with the E-step every
``--interval`` ``train()`` calls on the last ``--window``, and prints the process's peak resident memory
(``ru_maxrss``). Compare windows in separate processes, and with ``MALLOC_MMAP_THRESHOLD_=131072`` set in the
environment to see how much of the difference is the C allocator's (docs/results.md, EM-DDPG against DDPG).

Example: ``python benchmarks/e_step_memory.py --window 800 --interval 200`` then ``--window 20 --interval 20``
"""

from __future__ import annotations

import argparse
import resource
import sys

import torch as th

from sb3_emmarl import EMDDPG
from sb3_emmarl.common.vec_env import make_vec_env
from sb3_emmarl.zoo.exp_manager import zoo_hyperparams


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("-n", "--n-timesteps", type=int, default=100_000, help="agent-steps")
    parser.add_argument("--window", type=int, default=800, help="train() calls of transitions the E-step keeps")
    parser.add_argument("--interval", type=int, default=200, help="train() calls between E-steps")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    for name in ("n_timesteps", "window", "interval"):
        if getattr(args, name) < 1:
            parser.error(f"--{name.replace('_', '-')} must be >= 1, got {getattr(args, name)}")
    th.set_num_threads(1)
    settings = zoo_hyperparams("em_ddpg")
    env = make_vec_env(1, seed=args.seed, env_kwargs=settings["env_kwargs"])
    model = EMDDPG("MlpPolicy", env, n_components=settings["n_components"],
                   count_factors=tuple(settings["count_factors"]),
                   likelihood_temperature=settings["likelihood_temperature"], team_pooling=settings["team_pooling"],
                   fusion=settings["fusion"], learning_starts=settings["learning_starts"],
                   buffer_size=settings["buffer_size"], e_step_interval=args.interval,
                   e_step_kwargs={**settings["e_step_kwargs"], "window": args.window}, seed=args.seed)
    model.learn(args.n_timesteps)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # kB on Linux
    print(f"EM-DDPG, {args.n_timesteps:,} agent-steps, E-step every {args.interval} train() calls on the last "
          f"{args.window}: peak resident memory {peak:,.0f} MiB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
