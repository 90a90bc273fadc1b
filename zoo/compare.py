"""Compare variants (EM-PPO, its no-latent ablation, PPO by default) at the same budget over seeds.

Example (EM-PPO, its ablations and PPO over 3 seeds): ``python zoo/compare.py -n 1000000 --seeds 0 1 2``
"""

import sys

from sb3_emmarl.zoo.benchmark import compare_main

if __name__ == "__main__":
    sys.exit(compare_main())
