"""``python -m sb3_emmarl <command>``: the ``emmarl`` command (:mod:`sb3_emmarl.cli`) without its console script."""

import sys

from sb3_emmarl.cli import main

if __name__ == "__main__":
    sys.exit(main(prog="python -m sb3_emmarl"))
