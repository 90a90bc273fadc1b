"""The training environment's guard against non-finite values (:class:`FiniteCheck`)."""

from __future__ import annotations

from typing import Any

import numpy as np
from stable_baselines3.common.vec_env import VecCheckNan, VecEnv
from stable_baselines3.common.vec_env.base_vec_env import VecEnvStepReturn


class FiniteCheck(VecCheckNan):
    """SB3's ``VecCheckNan`` that stops at the first NaN or inf with a short message naming the quantity
    (observations, rewards or actions), the step of the vector environment, the entries and where it came from.

    :param venv: the vector environment to guard
    """

    SOURCES = {"reset": "the environment, at reset", "step_wait": "the environment",
               "step_async": "the policy (the actions it chose)"}

    def __init__(self, venv: VecEnv) -> None:
        super().__init__(venv, raise_exception=True, check_inf=True)
        self.n_steps = 0

    def step_wait(self) -> VecEnvStepReturn:
        self.n_steps += 1
        return super().step_wait()

    def _check_val(self, event: str, **kwargs: Any) -> None:
        for name, value in kwargs.items():
            parts = value.items() if isinstance(value, dict) else [("", value)]
            for key, part in parts:
                array = np.asarray(part)
                if array.dtype.kind not in "fc":
                    continue
                bad = ~np.isfinite(array)
                if bad.any():
                    kinds = sorted({"nan" if np.isnan(v) else "inf" for v in array[bad].ravel()[:100]})
                    entries = np.unique(np.nonzero(bad)[0])[:10].tolist()
                    raise ValueError(f"non-finite {name}{'.' + key if key else ''} ({' and '.join(kinds)}) at step "
                                     f"{self.n_steps} of the vector environment, entries {entries}; they come from "
                                     f"{self.SOURCES[event]}")
