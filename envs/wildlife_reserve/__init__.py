"""PettingZoo environments for UAV-based wildlife protection."""

__version__ = "0.1.0"
