"""``emmarl patrol``: run a scripted patrol on the reserve and print the team metrics.

Example: ``python zoo/patrol.py --policy stalest_block --episodes 3 --seed 0``
"""

import sys

from sb3_emmarl.cli import main

if __name__ == "__main__":
    sys.exit(main(["patrol", *sys.argv[1:]]))
