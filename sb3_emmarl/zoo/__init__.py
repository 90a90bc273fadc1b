"""The rl-zoo layer: algorithm registry, experiment manager and the command lines behind ``emmarl train|enjoy|compare|
benchmark`` (and ``zoo/*.py``).

It is the ``[zoo]`` extra (rl_zoo3, optuna, pandas): without rl_zoo3, importing this package fails with one line naming
the extra to install.
"""

from sb3_emmarl.common.trust.extras import requires

with requires("rl_zoo3", "zoo", "the zoo"):
    import rl_zoo3  # noqa: F401
