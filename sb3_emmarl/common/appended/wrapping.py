"""One way for an algorithm to wrap its environment: the algorithms whose environment carries more than the plain
observations (the true mode for OraclePPO, the neighbour messages for MessagePPO, the global state for MAPPO, the
belief for the EM algorithms) wrap it in ``set_env`` and in ``load`` through :class:`WrapsEnv`, and say how in two
methods. Those whose policy acts only on the wrapped observations, and that give them to evaluation through a public
``wrap_env`` (OraclePPO, MessagePPO, the EM algorithms), are :class:`WrapsObservations`.

SB3 has no hook for this: its ``set_env`` and ``load`` take the environment as given, so each algorithm would otherwise
override both (as the five did, each its own way). QMIX and VDN add nothing to their observations (their global state
comes from the infos), so they keep SB3's wrapping; QMIX's ``set_env`` only checks that the teams are the model's.

The wrappers themselves are one family: :class:`AppendingVecEnvWrapper` widens a flat ``Box`` by the values a
subclass appends to every entry's observation (the mode, the messages, the global state, the belief), at reset, at
each step and to each finished episode's ``terminal_observation``; :func:`ensure_wrapped` gives an environment a wrapper
of a kind once (keeping one that is already there when it matches), and :func:`find_wrapper` finds it.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any, TypeVar

import numpy as np
from gymnasium import spaces
from stable_baselines3.common.save_util import load_from_zip_file
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper, unwrap_vec_wrapper
from stable_baselines3.common.vec_env.base_vec_env import VecEnvObs, VecEnvStepReturn

from sb3_emmarl.common.trust.safe_zip import safe_data_objects

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
        (:func:`~sb3_emmarl.common.trust.safe_zip.safe_data_objects`: nothing in the file runs); ``env`` (a plain
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


# ---------------------------------------------------------------------------------------------- the wrappers
#: The key of a finished episode's last observation in a vector environment's step infos (SB3's).
TERMINAL_OBSERVATION = "terminal_observation"


class AppendingVecEnvWrapper(VecEnvWrapper):
    """A vector wrapper that appends values to every entry's flat observation: the observation space is the inner one
    widened by ``extra_low``/``extra_high``; a subclass says what it appends at reset (:meth:`_reset_extra`) and at each
    step, for the current observations and for the terminal observations of the episodes that ended
    (:meth:`_step_extra`).

    :param venv: the vector environment (flat ``Box`` observations)
    :param extra_low: the lower bounds of the appended values
    :param extra_high: their upper bounds
    :param dtype: the widened space's dtype (default: float32)
    :raise ValueError: if the observations are not a flat ``Box``
    """

    def __init__(self, venv: VecEnv, extra_low: np.ndarray, extra_high: np.ndarray, dtype: Any = np.float32) -> None:
        space = venv.observation_space
        if not isinstance(space, spaces.Box) or len(space.shape) != 1:
            raise ValueError(f"{type(self).__name__} needs flat Box observations, got {space}")
        low = np.concatenate([space.low, extra_low]).astype(dtype)
        high = np.concatenate([space.high, extra_high]).astype(dtype)
        super().__init__(venv, observation_space=spaces.Box(low, high, dtype=dtype))

    def _reset_extra(self, observations: np.ndarray) -> np.ndarray:
        """What to append to the observations of a reset, one row per entry."""
        raise NotImplementedError

    def _step_extra(self, observations: np.ndarray, dones: np.ndarray, infos: list[dict[str, Any]]
                    ) -> tuple[np.ndarray, dict[int, np.ndarray]]:
        """What to append to a step's observations (one row per entry), and to the terminal observations of the entries
        whose episode ended (by entry; an entry left out keeps its terminal observation as it is)."""
        raise NotImplementedError

    def _join(self, observations: Any, extra: np.ndarray) -> np.ndarray:
        """Observations (as rows of the widened space's dtype) followed by ``extra``."""
        rows = np.asarray(observations, dtype=self.observation_space.dtype)
        return np.concatenate([rows.reshape(len(rows), -1), extra], axis=1)

    def reset(self) -> VecEnvObs:
        observations = self.venv.reset()
        assert isinstance(observations, np.ndarray)  # (flat Box observations)
        return self._join(observations, self._reset_extra(observations))

    def step_wait(self) -> VecEnvStepReturn:
        observations, rewards, dones, infos = self.venv.step_wait()
        assert isinstance(observations, np.ndarray)  # (flat Box observations)
        infos = list(infos)
        extra, terminal = self._step_extra(observations, dones, infos)
        for i, values in terminal.items():
            infos[i] = {**infos[i], TERMINAL_OBSERVATION: self._join(
                np.asarray(infos[i][TERMINAL_OBSERVATION])[None], values[None])[0]}
        return self._join(observations, extra), rewards, dones, infos


W = TypeVar("W", bound=VecEnvWrapper)


def find_wrapper(venv: Any, kind: type[W]) -> W | None:
    """The wrapper of class ``kind`` in a stack of vector wrappers (None if there is none, or ``venv`` is no vector
    environment)."""
    return unwrap_vec_wrapper(venv, kind) if isinstance(venv, VecEnv) else None  # type: ignore[return-value]


def ensure_wrapped(env: Any, kind: type[W], build: Callable[[VecEnv], W], mismatch: Callable[[W], str | None],
                   verbose: int = 0) -> VecEnv:
    """``env`` as a vector environment (SB3's wrapping) with a ``kind`` wrapper: ``build(venv)`` if it has none; the
    one it has if ``mismatch(wrapper)`` finds nothing wrong with it.

    :param env: an environment (a Gymnasium one is wrapped as SB3 does)
    :param kind: the wrapper's class
    :param build: wraps a vector environment that has none
    :param mismatch: why an existing wrapper does not do what is asked (None: it does)
    :param verbose: SB3's wrapping's verbosity
    :raise ValueError: with ``mismatch``'s reason
    """
    from stable_baselines3.common.base_class import BaseAlgorithm

    venv = env if isinstance(env, VecEnv) else BaseAlgorithm._wrap_env(env, verbose)
    wrapper = find_wrapper(venv, kind)
    if wrapper is None:
        return build(venv)
    problem = mismatch(wrapper)
    if problem:
        raise ValueError(problem)
    return venv
