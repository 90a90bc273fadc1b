"""Run a scripted patrol on the reserve and print the team metrics.

Example: ``python zoo/patrol.py --policy stalest_block --episodes 3 --seed 0``
"""

from __future__ import annotations

import argparse
import sys

from sb3_emmarl.common.metrics import format_summary, summarize
from sb3_emmarl.zoo.cli import KeyValues
from wildlife_reserve import reserve_v0
from wildlife_reserve.reserve.scripted import SCRIPTED_PATROLS, run_patrol


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--policy", choices=sorted(SCRIPTED_PATROLS), default="stalest_block")
    parser.add_argument("--episodes", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--env-kwargs", type=str, nargs="+", action=KeyValues, default={},
                        help="reserve arguments as key:value, e.g. n_uavs:20")
    args = parser.parse_args(argv)
    if args.episodes < 1:
        parser.error(f"--episodes must be >= 1, got {args.episodes}")
    try:
        env = reserve_v0.parallel_env(**args.env_kwargs)
    except (TypeError, ValueError) as error:
        parser.error(str(error))
    policy_cls = SCRIPTED_PATROLS[args.policy]
    policy = policy_cls(env, seed=args.seed) if args.policy == "random" else policy_cls(env)
    records = run_patrol(env, policy, args.episodes, seed=args.seed)
    title = f"{args.policy} patrol, {args.episodes} episodes from seed {args.seed} (mean +- std)"
    print(format_summary(summarize(records), title))
    return 0


if __name__ == "__main__":
    sys.exit(main())
