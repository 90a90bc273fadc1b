"""PettingZoo environments for UAV-based wildlife protection."""

__version__ = "0.2.0"
