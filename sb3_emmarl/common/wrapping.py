"""One way for an algorithm to wrap its environment: the algorithms whose environment carries more than the plain
observations (the true mode for OraclePPO, the neighbour messages for MessagePPO, the global state for MAPPO, the
belief for the EM algorithms) wrap it in ``set_env`` and in ``load`` through :class:`WrapsEnv`, and say how in two
methods. Those whose policy acts only on the wrapped observations, and that give them to evaluation through a public
``wrap_env`` (OraclePPO, MessagePPO, the EM algorithms), are :class:`WrapsObservations`.

SB3 has no hook for this: its ``set_env`` and ``load`` take the environment as given, so each algorithm would otherwise
override both (as the five did, each its own way). QMIX and VDN add nothing to their observations (their global state
comes from the infos), so they keep SB3's wrapping; QMIX's ``set_env`` only checks that the teams are the model's.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
from stable_baselines3.common.save_util import load_from_zip_file
from stable_baselines3.common.vec_env import VecEnv

from sb3_emmarl.common.safe_zip import safe_data_objects

if TYPE_CHECKING:  # the type checker sees the SB3 algorithm the mixin is placed before; at run time it is a plain class
    from stable_baselines3.common.base_class import BaseAlgorithm as _AlgorithmBase
else:
    _AlgorithmBase = object


class WrapsEnv(_AlgorithmBase):
    """Mixin placed before the SB3 algorithm class (``class MAPPO(WrapsEnv, PPO)``): ``set_env`` and ``load`` wrap
    a plain parameter-sharing vector environment as training did.

    A subclass implements :meth:`_wrap_own_env` (with the model's own settings) and :meth:`_wrap_saved_env` (from a
    saved model's data, before the model exists).
    """

    def _wrap_own_env(self, env: Any) -> VecEnv:
        """``env`` wrapped as this model's training wrapped it."""
        raise NotImplementedError

    @classmethod
    def _wrap_saved_env(cls, env: Any, data: dict[str, Any]) -> VecEnv:
        """``env`` wrapped as the saved model's training wrapped it.

        :param env: the environment given to ``load``
        :param data: the saved model's data (its constructor arguments and attributes)
        """
        raise NotImplementedError

    def set_env(self, env: Any, force_reset: bool = True) -> None:
        """As SB3's ``set_env``; a plain environment gets the model's wrapper."""
        super().set_env(self._wrap_own_env(env), force_reset=force_reset)

    @classmethod
    def load(cls, path: Any, env: Any = None, device: Any = "auto", custom_objects: dict | None = None,
             print_system_info: bool = False, force_reset: bool = True, **kwargs: Any) -> Any:
        """As SB3's ``load``, the zip's pickled data read as data only
        (:func:`~sb3_emmarl.common.safe_zip.safe_data_objects`: nothing in the file runs); ``env`` (a plain
        environment is fine) gets the wrapper the model was trained with."""
        custom_objects = safe_data_objects(path, custom_objects)
        if env is not None:
            data, _, _ = load_from_zip_file(path, device="cpu", custom_objects=custom_objects)
            env = cls._wrap_saved_env(env, data or {})
        return super().load(path, env=env, device=device, custom_objects=custom_objects,
                            print_system_info=print_system_info, force_reset=force_reset, **kwargs)


class WrapsObservations(WrapsEnv):
    """:class:`WrapsEnv` for an algorithm whose policy reads what its wrapper adds (``class OraclePPO(WrapsObservations,
    PPO)``): the one wrapping is the public :meth:`wrap_env`, which ``set_env`` and ``load`` use and which evaluation
    and recording call (``evaluate_team`` wraps the environment of a model that has it), and :meth:`predict` refuses
    plain observations with one line naming ``model.wrap_env(env)``.

    A subclass implements :meth:`wrap_env` and :meth:`_wrap_saved_env`; one whose ``predict`` acts on plain
    observations too (the EM algorithms, which carry the belief in ``state``) overrides :meth:`predict`.
    """

    def wrap_env(self, venv: VecEnv) -> VecEnv:
        """``venv`` wrapped as this model's training wrapped it (for evaluation and recording).

        :param venv: a parameter-sharing vector environment (one already wrapped is kept when its wrapper matches)
        """
        raise NotImplementedError

    def _wrap_own_env(self, env: Any) -> VecEnv:
        """SB3's wrapping (a Gymnasium environment becomes a vector one), then :meth:`wrap_env`."""
        return self.wrap_env(self._wrap_env(env, self.verbose))

    def predict(self, observation: np.ndarray | dict[str, np.ndarray], state: tuple[np.ndarray, ...] | None = None,
                episode_start: np.ndarray | None = None,
                deterministic: bool = False) -> tuple[np.ndarray, tuple[np.ndarray, ...] | None]:
        """SB3's ``predict`` on the wrapped observations; plain ones (a plain environment's) are refused with one line
        naming ``model.wrap_env(env)``, before SB3's own shape message."""
        shape = getattr(self.observation_space, "shape", None)
        obs = np.asarray(observation) if not isinstance(observation, dict) else None
        if shape and obs is not None and obs.ndim >= 1 and obs.shape[-1] != shape[-1]:
            raise ValueError(f"{type(self).__name__} acts on observations of {shape[-1]} values, got {obs.shape[-1]}: "
                             f"evaluate it on model.wrap_env(env), which adds what training added")
        return super().predict(observation, state, episode_start, deterministic)
