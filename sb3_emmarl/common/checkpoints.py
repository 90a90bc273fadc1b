"""Files that survive a kill, and training that resumes as if it had not stopped.

- :func:`write_atomic` writes any file to a temporary name beside it and renames it into place, so that
  a kill at any moment leaves the previous complete file; :func:`save_model`, :func:`save_pickle` and
  :func:`write_text` use it for models, replay buffers, ``VecNormalize`` statistics, configs and results.
- :func:`check_model_file` / :func:`load_model` refuse a truncated or corrupt zip with a message naming
  the file, and a zip saved by another algorithm than the one asked for.
- :func:`training_state` / :func:`restore_training_state`: what a model zip does not hold but the next
  steps depend on: the global random generators (torch, numpy, ``random``) and the state of every layer
  of the vector environment (the reserves mid-episode, ``VecMonitor``'s running episodes,
  ``VecNormalize``'s statistics, the EM belief). A layer that keeps state between steps defines
  ``get_state()`` / ``set_state(state)``; SB3's own stateful wrappers are read here by their attributes.
- :class:`ResumableCheckpointCallback`: SB3's ``CheckpointCallback`` that saves at the start of a rollout
  (after the previous update, before any action of the next rollout is drawn), so that a run continued from
  the checkpoint collects exactly the rollouts the uninterrupted run collects;
  :class:`AtomicEvalCallback` and :class:`SaveVecNormalize`: the team-counting ``EvalCallback``
  (:class:`sb3_emmarl.common.callbacks.EvalCallback`) and rl_zoo3's statistics saver with atomic files
  (``evaluations.npz``, ``best_model.zip``, ``vecnormalize.pkl``).

SB3 writes its files in place (``model.save``, ``VecNormalize.save``, ``save_to_pkl``) and has no notion
of the environment's state in a checkpoint; this module adds both without changing SB3's file formats.
"""

from __future__ import annotations

import contextlib
import inspect
import io
import os
import pickle
import random
import re
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch as th
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback, CheckpointCallback
from stable_baselines3.common.monitor import ResultsWriter
from stable_baselines3.common.save_util import load_from_zip_file
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv, VecEnvWrapper, VecMonitor, VecNormalize

from sb3_emmarl.common.callbacks import EvalCallback
from sb3_emmarl.common.pickling import ViewPickler, dumps
from sb3_emmarl.common.safe_pickle import ENV_STATE_MODULES, DataUnpickler, load_data_pickle, loads
from sb3_emmarl.common.safe_zip import check_zip_sizes, pickle_globals, read_data, safe_data_objects

#: Attributes of SB3's vector wrappers that change from step to step (the rest is configuration).
SB3_WRAPPER_STATE: dict[type, tuple[str, ...]] = {
    VecMonitor: ("episode_returns", "episode_lengths", "episode_count"),
    VecNormalize: ("obs_rms", "ret_rms", "returns", "old_obs", "old_reward", "training"),
    DummyVecEnv: ("envs", "buf_obs", "buf_dones", "buf_rews", "buf_infos", "reset_infos"),
}
#: Checkpoint files: ``<prefix>_<steps>_steps.zip`` and its companions ``<prefix>_<kind>_<steps>_steps.pkl``.
CHECKPOINT_PATTERN = re.compile(r"^(?P<prefix>.+)_(?P<steps>\d+)_steps\.zip$")
TRAINING_STATE = "training_state"
REPLAY_BUFFER = "replay_buffer"
VEC_NORMALIZE = "vecnormalize"
#: The file in which a run keeps its final ``VecNormalize`` statistics (rl_zoo3's name).
VEC_NORMALIZE_FILE = f"{VEC_NORMALIZE}.pkl"


def vec_normalize_stats(folder: str | Path) -> str | None:
    """The ``VecNormalize`` statistics a run saved in ``folder`` (its params folder, ``<run>/<env id>``), or None if
    it was not normalised."""
    path = Path(folder) / VEC_NORMALIZE_FILE
    return str(path) if path.is_file() else None


# ---------------------------------------------------------------------------------------------- pickling
class _FileReferencePickler(ViewPickler):
    """:class:`~sb3_emmarl.common.pickling.ViewPickler` that keeps open files (SB3's ``Monitor`` writers inside a
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
    """:class:`~sb3_emmarl.common.safe_pickle.DataUnpickler` that puts the live environment's open files in the place
    of the references :class:`_FileReferencePickler` wrote (``files``, set by :func:`_loads_with_files`)."""

    files: list[Any] = []

    def persistent_load(self, pid: Any) -> Any:
        if not isinstance(pid, int) or not 0 <= pid < len(self.files):
            raise ValueError(f"the saved environment refers to open file {pid!r}; this one has {len(self.files)}")
        return self.files[pid]


def _loads_with_files(blob: bytes, files: list[Any]) -> Any:
    """Unpickle :func:`_dumps_with_files`'s bytes as data only (instances of the environments' classes,
    :data:`~sb3_emmarl.common.safe_pickle.ENV_STATE_MODULES`), the open files taken from ``files`` (the live ones,
    same order)."""
    unpickler = type("_Unpickler", (_LiveFilesUnpickler,), {"files": files})
    return loads(blob, "the training state's environment wrapper", class_modules=ENV_STATE_MODULES,
                 unpickler=unpickler)


# ---------------------------------------------------------------------------------------------- atomic files
def write_atomic(path: str | Path, write: Callable[[io.BufferedWriter], Any]) -> Path:
    """Call ``write(file)`` on a temporary file beside ``path``, flush it to disk, then rename it to ``path``.

    A kill before the rename leaves the previous ``path`` untouched (and at most a hidden ``.tmp`` file).

    :param path: the file to write
    :param write: writes the content into the open binary file
    :return: ``path``
    :raise OSError: naming ``path`` when it cannot be written (a full disk, a folder it may not write in)
    """
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "wb") as file:
            write(file)
            file.flush()
            os.fsync(file.fileno())
        os.replace(tmp, path)
    except OSError as error:  # (a write on a full disk names no file, a read-only folder the temporary one: say which)
        with contextlib.suppress(OSError):  # (nothing to remove in a read-only folder, which refuses even that)
            tmp.unlink(missing_ok=True)
        if (error.filename is None or str(error.filename) == str(tmp)) and error.errno is not None:
            raise OSError(error.errno, error.strerror, str(path)) from error
        raise
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path


def write_text(path: str | Path, text: str) -> Path:
    """Write a text file atomically (see :func:`write_atomic`)."""
    return write_atomic(path, lambda file: file.write(text.encode()))


def save_pickle(path: str | Path, obj: Any) -> Path:
    """Pickle ``obj`` atomically (replay buffers, ``VecNormalize``, training states)."""
    return write_atomic(path, lambda file: file.write(dumps(obj)))


def save_model(model: BaseAlgorithm, path: str | Path) -> Path:
    """``model.save`` into ``path`` (``.zip`` added if missing), atomically."""
    path = Path(path)
    if path.suffix != ".zip":
        path = path.with_name(path.name + ".zip")
    return write_atomic(path, model.save)


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


# ---------------------------------------------------------------------------------------------- checked loading
def check_model_file(path: str | Path) -> Path:
    """Check that ``path`` is a complete SB3 model zip whose pickles name only allowed globals and read as data only
    (:func:`~sb3_emmarl.common.safe_zip.safe_data_objects`).

    :raise ValueError: naming the file when it is missing, truncated, corrupt, not a model, or names a foreign global
    """
    _checked_data_objects(path)
    return Path(path)


def _checked_data_objects(path: str | Path) -> dict[str, Any]:
    """:func:`check_model_file`'s checks, returning the zip's pickled data read as data only (SB3's ``custom_objects``,
    :func:`~sb3_emmarl.common.safe_zip.safe_data_objects`)."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"no model file {str(path)!r}")
    try:
        with zipfile.ZipFile(path) as archive:
            check_zip_sizes(archive, path)  # before the checksums read every member
            names = set(archive.namelist())
            bad = archive.testzip()
    except (zipfile.BadZipFile, OSError, EOFError) as error:
        raise ValueError(f"{path} is incomplete or corrupt ({error}); it may have been cut short by a crash: "
                         "use an earlier checkpoint") from None
    if bad is not None:
        raise ValueError(f"{path} is corrupt (member {bad!r} fails its checksum): use an earlier checkpoint")
    if "data" not in names:
        raise ValueError(f"{path} is not a Stable-Baselines3 model (no 'data' in the zip)")
    return safe_data_objects(path)  # its names checked, then its pickles read as data only (a zip from anywhere is code)


def check_pickle_file(path: str | Path) -> Path:
    """Check that ``path`` is a complete pickle (its opcodes read to the end without running anything: a file cut short
    by a crash fails).

    :raise ValueError: naming the file
    """
    try:
        pickle_globals(Path(path).read_bytes())
    except (OSError, ValueError) as error:
        raise ValueError(f"{path} is incomplete or corrupt ({error}); it may have been cut short by a crash") from None
    return Path(path)


def network_shapes(path: str | Path) -> tuple[tuple[str, tuple[int, ...]], ...]:
    """The names and shapes of a model zip's parameters (read with ``torch.load(weights_only=True)``): what tells a
    checkpoint of another run apart from a run's own.

    :raise ValueError: naming the file if its parameters do not load
    """
    try:
        _, params, _ = load_from_zip_file(path, device="cpu", load_data=False)
    except Exception as error:  # torch and zipfile raise many kinds on a broken member
        raise ValueError(f"{path}: its parameters do not load ({type(error).__name__})") from None
    states: dict[str, Any] = params
    return tuple(sorted((f"{part}.{name}", tuple(value.shape)) for part, state in states.items()
                        for name, value in state.items() if hasattr(value, "shape")))


def check_checkpoint(path: str | Path) -> Path:
    """Check a checkpoint: its zip (:func:`check_model_file`) and the companions saved with it (training state,
    replay buffer, ``VecNormalize`` statistics: :func:`check_pickle_file`).

    :raise ValueError: naming the file that does not load
    """
    check_model_file(path)
    for kind in (TRAINING_STATE, REPLAY_BUFFER, VEC_NORMALIZE):
        file = companion(path, kind)
        if file is not None and file.is_file():
            check_pickle_file(file)
    return Path(path)


def _own_parameters(algo: type) -> set[str]:
    init = algo.__dict__.get("__init__")
    if init is None:
        return set()
    return set(inspect.signature(init).parameters) - {"self", "args", "kwargs"}


def _stored_parameters(algo: type) -> set[str]:
    """The arguments of ``algo``'s own constructor that it keeps as attributes of the same name (``self.n_epochs =``),
    so that a zip it saved holds them (read from its source; none if the source cannot be read)."""
    try:
        source = inspect.getsource(algo.__dict__["__init__"])
    except (KeyError, OSError, TypeError):
        return set()
    return set(re.findall(r"self\.(\w+)\s*=", source)) & _own_parameters(algo)


def _parameters(algo: type) -> set[str]:
    """Constructor arguments of ``algo`` and of its base classes."""
    return set().union(*(_own_parameters(cls) for cls in algo.__mro__))


def fitting_algorithms(data: dict[str, Any], candidates: dict[str, type[BaseAlgorithm]]) -> list[str]:
    """Names of the ``candidates`` that could have saved ``data`` (a model zip's data).

    SB3 zips do not name their class; a class is recognised by the constructor arguments it keeps as
    attributes: it fits if it takes every such argument the zip holds (a PPO zip holds ``n_epochs``, which A2C
    does not take), if its own constructor adds arguments to its base class's, the zip holds one of them
    (EM-PPO's ``e_step_interval``, which a PPO zip lacks), and the zip's policy is one of its ``policy_aliases``
    (a PPO zip's ``ActorCriticPolicy`` is not RecurrentPPO's); of two that fit and do not derive from each other, one
    whose constructor stores an argument the other does not take fits only if the zip holds it (an A2C zip lacks
    PPO's ``n_epochs``). Algorithms that differ only in defaults (DDPG and TD3) are not told apart.
    """
    known = set().union(*(_parameters(algo) for algo in candidates.values()))
    saved = {key for key, value in data.items() if value is not None} & known  # None: an attribute never set
    fits = []
    for name, algo in candidates.items():
        own = _own_parameters(algo) - set().union(*(_parameters(base) for base in algo.__bases__))
        policy_class = data.get("policy_class")
        policy_fits = not isinstance(policy_class, type) or any(
            issubclass(policy_class, alias) for alias in getattr(algo, "policy_aliases", {}).values())
        if saved <= _parameters(algo) and (not own or own & saved) and policy_fits:
            fits.append(name)
    present = set(data) & known  # attributes the zip holds, None or not
    # Between two fitting algorithms that do not derive from each other, one whose constructor stores an attribute the
    # other does not take must find it in the zip: an A2C zip lacks PPO's n_epochs, so it is A2C's alone.
    return [name for name in fits if all(
        _stored_parameters(candidates[name]) - _parameters(candidates[other]) <= present for other in fits
        if not issubclass(candidates[name], candidates[other]) and not issubclass(candidates[other], candidates[name]))]


def check_saved_algorithm(path: str | Path, algo: type[BaseAlgorithm], candidates: dict[str, type[BaseAlgorithm]],
                          data_objects: dict[str, Any] | None = None) -> None:
    """Refuse a model zip that ``algo`` did not save, judged by :func:`fitting_algorithms` over ``candidates``.

    :param data_objects: the zip's pickled data already read as data only (default: read here)
    :raise ValueError: naming the file, the algorithm asked for and the ones that fit
    """
    objects = safe_data_objects(path) if data_objects is None else data_objects
    data = {key: objects.get(key, value) for key, value in (read_data(path) or {}).items()}  # (as SB3 reads it)
    fits = fitting_algorithms(data, candidates)
    if not any(candidates[name] is algo for name in fits):
        raise ValueError(f"{path} was not saved by {algo.__name__}: its settings fit "
                         f"{', '.join(sorted(fits)) or 'none of ' + str(sorted(candidates))}")


def load_model(algo: type[BaseAlgorithm], path: str | Path, candidates: dict[str, type[BaseAlgorithm]] | None = None,
               **kwargs: Any) -> BaseAlgorithm:
    """``algo.load(path, **kwargs)`` after :func:`check_model_file` (and :func:`check_saved_algorithm` if
    ``candidates`` are given), the zip's pickled data read as data only
    (:func:`~sb3_emmarl.common.safe_zip.safe_data_objects`, given to SB3 as ``custom_objects``)."""
    custom_objects = {**_checked_data_objects(path), **(kwargs.pop("custom_objects", None) or {})}
    if candidates:
        check_saved_algorithm(path, algo, candidates, custom_objects)
    try:
        return algo.load(path, custom_objects=custom_objects, **kwargs)
    except (RuntimeError, KeyError, TypeError, EOFError, pickle.UnpicklingError, zipfile.BadZipFile) as error:
        # weights that are not the model's (another model's shapes, garbage in policy.pth), said in one line
        if isinstance(error, pickle.UnpicklingError):
            why = "its weights are not tensors only: torch.load(weights_only=True) refuses them"
        elif isinstance(error, RuntimeError) and "state_dict" in str(error):
            why = "its weights do not fit the networks its settings build (another model's weights?)"
        else:
            why = f"{type(error).__name__}: {(str(error).strip().splitlines() or [''])[0][:300]}"
        raise ValueError(f"{path} does not load into {algo.__name__} ({why})") from None


# ---------------------------------------------------------------------------------------------- training state
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


# ---------------------------------------------------------------------------------------------- checkpoints
def checkpoint_path(folder: str | Path, prefix: str, steps: int, kind: str | None = None) -> Path:
    """``<folder>/<prefix>_<steps>_steps.zip``, or the companion ``<prefix>_<kind>_<steps>_steps.pkl``
    (SB3's ``CheckpointCallback`` names)."""
    if kind is None:
        return Path(folder) / f"{prefix}_{steps}_steps.zip"
    return Path(folder) / f"{prefix}_{kind}_{steps}_steps.pkl"


def companion(model_path: str | Path, kind: str) -> Path | None:
    """The ``kind`` file saved with a checkpoint zip (None if ``model_path`` is not named as a checkpoint)."""
    model_path = Path(model_path)
    match = CHECKPOINT_PATTERN.match(model_path.name)
    if match is None:
        return None
    return checkpoint_path(model_path.parent, match["prefix"], int(match["steps"]), kind)


def list_checkpoints(folder: str | Path, prefix: str = "rl_model") -> list[tuple[int, Path]]:
    """``(steps, zip)`` of the checkpoints in ``folder``, oldest first."""
    found = []
    for path in Path(folder).glob(f"{prefix}_*_steps.zip"):
        match = CHECKPOINT_PATTERN.match(path.name)
        if match and match["prefix"] == prefix:
            found.append((int(match["steps"]), path))
    return sorted(found)


class ResumableCheckpointCallback(CheckpointCallback):
    """SB3's ``CheckpointCallback``, atomic and resumable.

    Every ``save_freq`` calls (as SB3 counts them: steps of the vector environment) a checkpoint is due; it
    is written at the start of the next rollout, after the update that ended the previous one: the
    replay buffer (if asked), the ``VecNormalize`` statistics (if any), the training state
    (:func:`training_state`) and, last, the model zip, each atomically. A zip on disk therefore always has
    its companions, and the newest zip is the checkpoint to resume from.

    :param save_freq: calls between checkpoints
    :param save_path: folder of the checkpoints
    :param name_prefix: file name prefix
    :param save_replay_buffer: also save the replay buffer (off-policy algorithms)
    :param save_vecnormalize: also save the ``VecNormalize`` statistics
    :param save_training_state: also save the training state (None: when :func:`supports_training_state`; without
        it, e.g. with reserves in worker processes, a resumed run starts new episodes)
    :param verbose: 1: print each checkpoint's path
    """

    def __init__(self, save_freq: int, save_path: str, name_prefix: str = "rl_model", save_replay_buffer: bool = False,
                 save_vecnormalize: bool = False, save_training_state: bool | None = None, verbose: int = 0) -> None:
        super().__init__(save_freq, save_path, name_prefix, save_replay_buffer, save_vecnormalize, verbose)
        self.save_training_state = save_training_state
        self._due_index = 0

    def _init_callback(self) -> None:
        super()._init_callback()
        if self.save_training_state is None:
            self.save_training_state = supports_training_state(self.model.get_env())
        # A resumed run does not save again the checkpoint it started from.
        self._due_index = self.model.num_timesteps // (self.save_freq * self.model.n_envs)

    def _on_step(self) -> bool:
        return True

    def _on_rollout_start(self) -> None:
        index = self.model.num_timesteps // (self.save_freq * self.model.n_envs)
        if index > self._due_index:
            self._due_index = index
            self.save_checkpoint()

    def save_checkpoint(self) -> Path:
        """Write the checkpoint of the current step now (companions first, the zip last); if a write fails (a full
        disk) the step's companions already written are removed, so that no step is left half saved.

        :raise OSError: naming the file that could not be written
        """
        steps = self.model.num_timesteps
        folder, prefix = self.save_path, self.name_prefix
        replay_buffer = getattr(self.model, "replay_buffer", None)
        vec_normalize = self.model.get_vec_normalize_env()
        companions = {REPLAY_BUFFER: self.save_replay_buffer and replay_buffer is not None,
                      VEC_NORMALIZE: self.save_vecnormalize and vec_normalize is not None,
                      TRAINING_STATE: self.save_training_state}
        written: list[Path] = []
        try:
            for kind in (kind for kind, wanted in companions.items() if wanted):
                obj = {REPLAY_BUFFER: replay_buffer, VEC_NORMALIZE: vec_normalize}.get(kind)
                written.append(save_pickle(checkpoint_path(folder, prefix, steps, kind),
                                           training_state(self.model) if kind == TRAINING_STATE else obj))
            path = save_model(self.model, checkpoint_path(folder, prefix, steps))
        except BaseException:
            for file in written:
                file.unlink(missing_ok=True)
            raise
        if self.verbose >= 1:
            print(f"Saving model checkpoint to {path}")
        return path


class SaveVecNormalize(BaseCallback):
    """Save the ``VecNormalize`` statistics atomically to ``<folder>/vecnormalize.pkl`` (rl_zoo3's
    ``SaveVecNormalizeCallback``, called by the evaluation on each new best model).

    :param folder: where to save
    """

    def __init__(self, folder: str) -> None:
        super().__init__()
        self.folder = folder

    def _on_step(self) -> bool:
        vec_normalize = self.model.get_vec_normalize_env()
        if vec_normalize is not None:
            save_pickle(Path(self.folder) / VEC_NORMALIZE_FILE, vec_normalize)
        return True


class AtomicEvalCallback(EvalCallback):
    """The team-counting ``EvalCallback`` (:class:`sb3_emmarl.common.callbacks.EvalCallback`: SB3's, whose evaluations
    are team episodes) whose ``evaluations.npz`` and ``best_model.zip`` are written atomically (same arguments).

    SB3 writes both in place; here the evaluations go to a hidden temporary file renamed over
    ``evaluations.npz``, and the best model is saved with :func:`save_model`.
    """

    def _init_callback(self) -> None:
        super()._init_callback()
        self._best_folder, self.best_model_save_path = self.best_model_save_path, None
        self._log_file = None
        if self.log_path is not None:
            self._log_file = Path(self.log_path).with_suffix(".npz")
            self.log_path = str(self._log_file.with_name(f".{self._log_file.stem}.{os.getpid()}.tmp"))

    def _on_step(self) -> bool:
        best = self.best_mean_reward
        result = super()._on_step()
        if self._log_file is not None:
            written = Path(f"{self.log_path}.npz")  # numpy's savez adds the suffix
            if written.is_file():
                os.replace(written, self._log_file)
        if self._best_folder is not None and self.best_mean_reward > best:
            save_model(self.model, Path(self._best_folder) / "best_model.zip")
        return result


def model_bytes(model: BaseAlgorithm) -> bytes:
    """The model's zip in memory (for comparisons and tests)."""
    buffer = io.BytesIO()
    model.save(buffer)
    return buffer.getvalue()
