"""``emmarl enjoy``: watch a trained team, print its team metrics and record an animated GIF (or MP4) of its patrol.

Example: ``python zoo/enjoy.py --algo ppo --env WildlifeReserve-v1 -f logs/ --episodes 5``
"""

import sys

from sb3_emmarl.cli import main

if __name__ == "__main__":
    sys.exit(main(["enjoy", *sys.argv[1:]]))
