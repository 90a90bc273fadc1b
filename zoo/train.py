"""``emmarl train``: train an agent on the wildlife reserve with rl-baselines3-zoo's flags.

Example: ``python zoo/train.py --algo ppo --env WildlifeReserve-v1 -n 200000 --seed 0 -tb runs/ -f logs/``
"""

import sys

from sb3_emmarl.cli import main

if __name__ == "__main__":
    sys.exit(main(["train", *sys.argv[1:]]))
