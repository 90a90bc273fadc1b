"""Run the paper's experiments (only the cells the store lacks) and regenerate their tables and figures.

Example: ``python zoo/experiment.py table2_robustness --budget quick`` (``--list`` names them all)
"""

import sys

from sb3_emmarl.experiments.cli import experiment_main

if __name__ == "__main__":
    sys.exit(experiment_main())
