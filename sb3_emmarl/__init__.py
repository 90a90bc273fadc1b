"""sb3-emmarl: latent-variable multi-agent reinforcement learning on Stable-Baselines3."""

from sb3_emmarl.version import __version__

__all__ = ["__version__"]
