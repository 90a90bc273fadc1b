"""Training that resumes as if it had not stopped: what a model zip does not hold but the next steps depend on.

:func:`training_state` holds the global random generators (torch, numpy, ``random``) and the state of every layer of
the vector environment (the reserves mid-episode, ``VecMonitor``'s running episodes, ``VecNormalize``'s statistics,
the EM belief). A layer that keeps state between steps defines ``get_state()`` / ``set_state(state)``; SB3's own
stateful wrappers are read here by their attributes (:data:`SB3_WRAPPER_STATE`). A training state file is read as data
only (:func:`load_training_state`, :mod:`sb3_emmarl.common.trust.safe_pickle`).
"""

from __future__ import annotations

import functools
import io
import pickle
import random
from pathlib import Path
from typing import Any

import numpy as np
import torch as th
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.monitor import ResultsWriter
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv, VecEnvWrapper, VecMonitor, VecNormalize

from sb3_emmarl.common.trust.pickling import ViewPickler
from sb3_emmarl.common.trust.safe_pickle import ENV_STATE_MODULES, DataUnpickler, load_data_pickle, loads

#: Attributes of SB3's vector wrappers that change from step to step (the rest is configuration).
SB3_WRAPPER_STATE: dict[type, tuple[str, ...]] = {
    VecMonitor: ("episode_returns", "episode_lengths", "episode_count"),
    VecNormalize: ("obs_rms", "ret_rms", "returns", "old_obs", "old_reward", "training"),
    DummyVecEnv: ("envs", "buf_obs", "buf_dones", "buf_rews", "buf_infos", "reset_infos"),
}


class _FileReferencePickler(ViewPickler):
    """:class:`~sb3_emmarl.common.trust.pickling.ViewPickler` that keeps open files (SB3's ``Monitor`` writers inside a
    ``DummyVecEnv``, which hold a file and a csv writer) out of the pickle, by their order of appearance:
    :func:`_loads_with_files` puts back the live environment's in their place, so that a resumed run goes on writing its
    own monitor files."""

    def __init__(self, file: io.BytesIO) -> None:
        super().__init__(file, protocol=pickle.HIGHEST_PROTOCOL)
        self.files: list[Any] = []

    def persistent_id(self, obj: Any) -> int | None:
        if isinstance(obj, (io.IOBase, ResultsWriter)):
            self.files.append(obj)
            return len(self.files) - 1
        return None


def _dumps_with_files(obj: Any) -> tuple[bytes, list[Any]]:
    """``obj`` pickled by :class:`_FileReferencePickler`, and the open files it refers to."""
    buffer = io.BytesIO()
    pickler = _FileReferencePickler(buffer)
    pickler.dump(obj)
    return buffer.getvalue(), pickler.files


class _LiveFilesUnpickler(DataUnpickler):
    """:class:`~sb3_emmarl.common.trust.safe_pickle.DataUnpickler` that puts the live environment's open files in the place
    of the references :class:`_FileReferencePickler` wrote.

    :param files: the live environment's open files, in the order the pickler met them
    """

    def __init__(self, *args: Any, files: list[Any]) -> None:
        super().__init__(*args)
        self.files = files

    def persistent_load(self, pid: Any) -> Any:
        if not isinstance(pid, int) or not 0 <= pid < len(self.files):
            raise ValueError(f"the saved environment refers to open file {pid!r}; this one has {len(self.files)}")
        return self.files[pid]


def _loads_with_files(blob: bytes, files: list[Any]) -> Any:
    """Unpickle :func:`_dumps_with_files`'s bytes as data only (instances of the environments' classes,
    :data:`~sb3_emmarl.common.trust.safe_pickle.ENV_STATE_MODULES`), the open files taken from ``files`` (the live ones,
    same order)."""
    return loads(blob, "the training state's environment wrapper", class_modules=ENV_STATE_MODULES,
                 unpickler=functools.partial(_LiveFilesUnpickler, files=files))


def _layers(venv: VecEnv | None) -> list[Any]:
    layers = [venv]
    while isinstance(venv, VecEnvWrapper):
        venv = venv.venv
        layers.append(venv)
    return layers


def _has_own(layer: Any, method: str) -> bool:
    """Whether ``layer``'s class defines ``method`` (an SB3 ``VecEnvWrapper`` forwards unknown attributes to the
    environment it wraps, so ``hasattr`` would find the inner environment's)."""
    return callable(getattr(type(layer), method, None))


def supports_training_state(venv: VecEnv | None) -> bool:
    """Whether :func:`vec_env_state` can read ``venv``: its innermost environment is SB3's ``DummyVecEnv`` or gives
    its state (the reserve's parameter-sharing vector environments, except SuperSuit's with worker processes)."""
    if venv is None:
        return False
    inner = _layers(venv)[-1]
    if isinstance(inner, DummyVecEnv):
        return True
    return _has_own(inner, "get_state") and getattr(inner, "checkpointable", True)


def vec_env_state(venv: VecEnv | None) -> list[Any]:
    """The step-to-step state of every layer of a vector environment, outermost first (None for stateless layers).

    :raise ValueError: if a layer cannot give its state (e.g. reserves in worker processes)
    """
    if not supports_training_state(venv):
        raise ValueError(f"the state of {type(_layers(venv)[-1]).__name__} cannot be saved (environments in worker "
                         "processes): a run resumed from its checkpoints starts new episodes")
    states: list[Any] = []
    for layer in _layers(venv):
        if _has_own(layer, "get_state"):
            states.append(layer.get_state())
        else:
            names = next((attrs for cls, attrs in SB3_WRAPPER_STATE.items() if isinstance(layer, cls)), ())
            states.append(_dumps_with_files({name: getattr(layer, name) for name in names})[0] if names else None)
    return states


def set_vec_env_state(venv: VecEnv | None, states: list[Any]) -> None:
    """Restore :func:`vec_env_state` into a vector environment built the same way."""
    layers = _layers(venv)
    if len(layers) != len(states):
        raise ValueError(f"the saved environment has {len(states)} layers, this one {len(layers)} "
                         f"({[type(layer).__name__ for layer in layers]}): build it as the run did")
    for index, (layer, state) in enumerate(zip(layers, states)):
        if _has_own(layer, "set_state"):
            layer.set_state(state)
        elif state is None or (index < len(layers) - 1 and isinstance(state, bytes) and state == states[-1]):
            continue  # stateless, or (checkpoints before 0.22.1) the inner environment's state forwarded: set last
        else:  # the layer's open files (monitor files) stay this environment's own
            names = next(attrs for cls, attrs in SB3_WRAPPER_STATE.items() if isinstance(layer, cls))
            _, files = _dumps_with_files({name: getattr(layer, name) for name in names})
            for name, value in _loads_with_files(state, files).items():
                setattr(layer, name, value)


#: What :func:`training_state` holds.
TRAINING_STATE_KEYS = frozenset({"num_timesteps", "torch_rng", "numpy_rng", "python_rng", "env"})


def training_state(model: BaseAlgorithm) -> dict[str, Any]:
    """The random generators and the environment's state: with the model zip, everything the next steps depend on."""
    return {
        "num_timesteps": int(model.num_timesteps),
        "torch_rng": th.get_rng_state(),
        "numpy_rng": np.random.get_state(),
        "python_rng": random.getstate(),
        "env": vec_env_state(model.get_env()),
    }


def load_training_state(path: str | Path) -> dict[str, Any]:
    """Read a :func:`training_state` file as data only (its environments' states stay pickles, read as data by the
    layers they belong to, :func:`set_vec_env_state`).

    :raise ValueError: one line naming the file: cut short, not a training state, or naming, calling or allocating
        what data does not
    """
    state = load_data_pickle(path)
    if not isinstance(state, dict) or not TRAINING_STATE_KEYS <= set(state):
        raise ValueError(f"{path} is not a training state (it holds a {type(state).__name__} without "
                         f"{sorted(TRAINING_STATE_KEYS)})")
    return state


def restore_training_state(model: BaseAlgorithm, state: dict[str, Any]) -> None:
    """Restore :func:`training_state` into a model loaded from the checkpoint saved with it (call it last, right
    before ``learn``: building and loading a model draws from the random generators)."""
    restore_environment_state(model, state)
    restore_random_generators(state)


def restore_environment_state(model: BaseAlgorithm, state: dict[str, Any]) -> None:
    """The environment's part of :func:`restore_training_state` (the zoo calls it as soon as the checkpoint is loaded,
    so that a state that is not this run's is refused before anything else starts).

    :raise ValueError: if the state is of another step than the model, or not this environment's
    """
    if int(state["num_timesteps"]) != model.num_timesteps:
        raise ValueError(f"the training state is of step {state['num_timesteps']}, the model of step "
                         f"{model.num_timesteps}: they come from different checkpoints")
    set_vec_env_state(model.get_env(), state["env"])


def restore_random_generators(state: dict[str, Any]) -> None:
    """The random generators' part of :func:`restore_training_state` (right before ``learn``)."""
    th.set_rng_state(state["torch_rng"])
    np.random.set_state(state["numpy_rng"])
    random.setstate(state["python_rng"])
