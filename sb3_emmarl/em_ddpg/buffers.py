"""The replay buffer of EM-DDPG: samples that can carry the latent posterior of their observations."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch as th
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.type_aliases import ReplayBufferSamples
from stable_baselines3.common.vec_env import VecNormalize


class LatentReplayBuffer(ReplayBuffer):
    """SB3's ``ReplayBuffer``; while ``on_sample`` is set, it is called on every sampled batch of observations
    and of next observations (copies, never the stored data) before the batch is returned.

    EM-DDPG sets it during its update to write each observation's posterior into the sample once, so that the
    actor, the critic and their targets read it instead of running the encoder up to five times per gradient step.
    Takes ``ReplayBuffer``'s arguments.
    """

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.on_sample: Callable[[th.Tensor], None] | None = None

    def _get_samples(self, batch_inds: np.ndarray, env: VecNormalize | None = None) -> ReplayBufferSamples:
        samples = super()._get_samples(batch_inds, env)
        if self.on_sample is not None:
            self.on_sample(samples.observations)
            self.on_sample(samples.next_observations)
        return samples

    def __getstate__(self) -> dict:
        state = self.__dict__.copy()
        state["on_sample"] = None  # a bound method of the model: not part of the buffer's data
        return state
