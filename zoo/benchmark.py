"""``emmarl benchmark``: train algorithms on the reserve and compare each with the random team on the same
evaluation episodes.

Example (trained PPO against the random team, about 10 minutes): ``python zoo/benchmark.py --algos ppo -n 3000000 --seeds 0``
"""

import sys

from sb3_emmarl.cli import main

if __name__ == "__main__":
    sys.exit(main(["benchmark", *sys.argv[1:]]))
