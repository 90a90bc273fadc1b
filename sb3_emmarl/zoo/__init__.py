"""The rl-zoo layer: algorithm registry, experiment manager and command lines behind ``zoo/*.py``."""
