"""``python -m sb3_emmarl.plots``: the same command as ``emmarl plot``."""

import sys

from sb3_emmarl.plots.command import main

if __name__ == "__main__":
    sys.exit(main())
