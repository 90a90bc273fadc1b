"""``python -m sb3_emmarl.zoo.train``: the same command as ``zoo/train.py``."""

import sys

from sb3_emmarl.cli import os_error_text
from sb3_emmarl.zoo.cli import train_main

if __name__ == "__main__":
    try:
        sys.exit(train_main())
    except OSError as error:  # (as the emmarl command: one line naming the file that could not be written)
        print(f"error: {os_error_text(error)}", file=sys.stderr)
        sys.exit(1)
