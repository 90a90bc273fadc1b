"""``emmarl compare``: compare variants at the same budget over seeds: by default EM-PPO, PPO, RecurrentPPO (memory
without EM), PPO told the mode (the upper bound) and EM-PPO's no-latent and frozen-E-step ablations, paired against PPO.

Example: ``python zoo/compare.py -n 500000 --seeds 0 1 2 3 4 --eval-episodes 20 --n-jobs 2``
"""

import sys

from sb3_emmarl.cli import main

if __name__ == "__main__":
    sys.exit(main(["compare", *sys.argv[1:]]))
