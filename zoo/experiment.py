"""``emmarl experiment``: run the paper's experiments (only the cells the store lacks) and regenerate their tables
and figures.

Example: ``python zoo/experiment.py table2_robustness --budget quick`` (``--list`` names them all)
"""

import sys

from sb3_emmarl.cli import main

if __name__ == "__main__":
    sys.exit(main(["experiment", *sys.argv[1:]]))
