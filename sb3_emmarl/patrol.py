"""``emmarl patrol``: run a scripted patrol on the reserve and print the team metrics (no learning, no extra needed).

Example: ``emmarl patrol --policy stalest_block --episodes 3 --seed 0``
"""

from __future__ import annotations

from sb3_emmarl.common.metrics import format_summary, summarize
from sb3_emmarl.common.trust.arguments import KeyValues, OneLineParser
from sb3_emmarl.common.trust.validation import MAX_EPISODES, MAX_SEED, int_flag
from wildlife_reserve import reserve_v1
from wildlife_reserve.reserve.scripted import SCRIPTED_PATROLS, run_patrol


def patrol_parser() -> OneLineParser:
    """The flags of ``emmarl patrol``."""
    parser = OneLineParser(description="Run a scripted patrol on the reserve and print the team metrics.")
    parser.add_argument("--policy", choices=sorted(SCRIPTED_PATROLS), default="stalest_block", help="scripted patrol")
    parser.add_argument("--episodes", type=int_flag(1, MAX_EPISODES), default=3, help="episodes to play")
    parser.add_argument("--seed", type=int_flag(0, MAX_SEED), default=0,
                        help="seed of the first episode (and of the random patrol)")
    parser.add_argument("--env-kwargs", type=str, nargs="+", action=KeyValues, default={},
                        help="reserve arguments as key:value, e.g. n_uavs:20")
    return parser


def patrol_main(argv: list[str] | None = None) -> int:
    """Play the scripted patrol's episodes and print the mean and std of the team metrics.

    :param argv: the command line's arguments (default: ``sys.argv[1:]``)
    :return: the exit code (argparse exits with 2 on a bad argument)
    """
    parser = patrol_parser()
    args = parser.parse_args(argv)
    try:
        env = reserve_v1.parallel_env(**args.env_kwargs)
    except (TypeError, ValueError) as error:
        parser.error(str(error))
    policy_cls = SCRIPTED_PATROLS[args.policy]
    policy = policy_cls(env, seed=args.seed) if args.policy == "random" else policy_cls(env)
    records = run_patrol(env, policy, args.episodes, seed=args.seed)
    title = f"{args.policy} patrol, {args.episodes} episodes from seed {args.seed} (mean +- std)"
    print(format_summary(summarize(records), title))
    return 0
