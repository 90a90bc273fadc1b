"""Parts of the reserve's observation hidden from the policy: what a team would do without that evidence.

:class:`HideObservationParts` zeroes named parts of every entry's observation (an ablation of the observation,
not of the environment: the reserve runs as before, and its rewards and infos are untouched). For example,
``benchmarks/mode_value.py --hide signs window.sign`` measures what knowing the hidden mode pays to a team that
cannot see the signs of poacher activity, where the poacher strategy shows. In the zoo it is a ``vec_env_wrapper``
(rl-zoo's YAML key, or ``-params``), which the comparisons apply again when they evaluate the run.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper
from stable_baselines3.common.vec_env.base_vec_env import VecEnvObs, VecEnvStepReturn

from wildlife_reserve.reserve.kernels.constants import CHANNEL_NAMES


def hidden_indices(layout: dict[str, tuple[slice, tuple[int, ...]]], parts: Sequence[str]) -> np.ndarray:
    """The flat observation indices of ``parts``: names of the observation layout (``signs``, ``belief``, ...) or
    ``window.<channel>`` for one channel of the window (``window.sign``, ``window.poacher``, ...).

    :param layout: the reserve's ``observation_layout`` (name -> (slice, shape))
    :raises ValueError: naming a part that is neither, and listing the allowed names
    """
    allowed = [*layout, *(f"window.{name}" for name in CHANNEL_NAMES)]
    if isinstance(parts, str) or not len(parts):
        raise ValueError(f"parts must be a non-empty list of names from {allowed}, got {parts!r}")
    indices = []
    for part in parts:
        if part in layout:
            indices.append(np.arange(layout[part][0].start, layout[part][0].stop))
        elif part in allowed:
            window, (_, w, _) = layout["window"]
            channel = CHANNEL_NAMES.index(part.split(".", 1)[1])
            indices.append(window.start + channel * w * w + np.arange(w * w))
        else:
            raise ValueError(f"unknown observation part {part!r}: allowed are {allowed}")
    return np.unique(np.concatenate(indices))


class HideObservationParts(VecEnvWrapper):
    """Zeroes the named parts of a parameter-sharing reserve vector environment's observations (terminal
    observations included). The observation space is unchanged (0 lies inside every part's bounds).

    :param venv: the reserve's parameter-sharing vector environment (``make_vec_env``), batched or SuperSuit
    :param parts: what to hide, as :func:`hidden_indices` reads them
    """

    def __init__(self, venv: VecEnv, parts: Sequence[str]) -> None:
        self.hidden = hidden_indices(venv.get_attr("observation_layout", [0])[0], parts)
        self.parts = tuple(parts)
        super().__init__(venv)

    def reset(self) -> VecEnvObs:
        observations = np.array(self.venv.reset(), copy=True)  # (never the inner environment's own buffer)
        observations[:, self.hidden] = 0.0
        return observations

    def step_wait(self) -> VecEnvStepReturn:
        observations, rewards, dones, infos = self.venv.step_wait()
        observations = np.array(observations, copy=True)
        observations[:, self.hidden] = 0.0
        for i in np.flatnonzero(dones):
            if "terminal_observation" in infos[i]:
                terminal = np.array(infos[i]["terminal_observation"], copy=True)
                terminal[self.hidden] = 0.0
                infos[i]["terminal_observation"] = terminal
        return observations, rewards, dones, infos
