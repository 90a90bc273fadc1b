"""Peak memory of an EM-DDPG run on the reserve with a given E-step window (one run per process).

Trains ``em_ddpg.yml`` through the zoo's own training command (every setting the YAML's: DDPG's, the latent ones,
the reserve's) for ``-n`` agent-steps, with only the E-step's schedule overridden: every ``--interval`` ``train()``
calls on the last ``--window``. Prints the process's peak resident memory (the zoo's ``peak_rss_mib``). The run goes
to a temporary folder that is removed afterwards. Compare windows in separate processes, and with
``MALLOC_MMAP_THRESHOLD_=131072`` set in the environment to see how much of the difference is the C allocator's
(docs/lab/results-history.md, EM-DDPG against DDPG).

Example: ``python benchmarks/e_step_memory.py --window 800 --interval 200`` then ``--window 20 --interval 20``
"""

from __future__ import annotations

import argparse
import sys
import tempfile

from sb3_emmarl.zoo.cli import peak_rss_mib, train_main

ALGO = "em_ddpg"


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
    latent = {"e_step_interval": args.interval, "e_step_kwargs": {"window": args.window}}  # (the YAML's others kept)
    with tempfile.TemporaryDirectory(prefix="e_step_memory_") as folder:
        code = train_main(["--algo", ALGO, "-n", str(args.n_timesteps), "--seed", str(args.seed), "-f", folder,
                           "--eval-freq", "-1", "--team-eval-episodes", "0", "--verbose", "0", "--num-threads", "1",
                           "-params", f"latent_kwargs:{latent!r}"])
    if code:
        return code
    print(f"EM-DDPG ({ALGO}.yml), {args.n_timesteps:,} agent-steps, E-step every {args.interval} train() calls on the "
          f"last {args.window}: peak resident memory {peak_rss_mib():,.0f} MiB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
