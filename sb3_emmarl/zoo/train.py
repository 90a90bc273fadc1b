"""``python -m sb3_emmarl.zoo.train``: the same command as ``zoo/train.py``."""

import sys

from sb3_emmarl.zoo.cli import train_main

if __name__ == "__main__":
    sys.exit(train_main())
