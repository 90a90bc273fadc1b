"""Checkpoints: SB3's ``CheckpointCallback`` files, written whole and at the start of a rollout so that a run resumes
exactly.

- :class:`ResumableCheckpointCallback` saves at the start of a rollout (after the previous update, before any action
  of the next rollout is drawn), so that a run continued from the checkpoint collects exactly the rollouts the
  uninterrupted run collects; beside the zip, its companions (training state, replay buffer, ``VecNormalize``
  statistics) are named as rl_zoo3 names them (:func:`checkpoint_path`, :func:`companion`).
- :class:`SaveVecNormalize`: rl_zoo3's statistics saver with an atomic file.
- :func:`check_checkpoint`: a checkpoint and its companions complete and safe to load.
"""

from __future__ import annotations

import re
from pathlib import Path

from stable_baselines3.common.callbacks import BaseCallback, CheckpointCallback

from sb3_emmarl.common.model_files import check_model_file, check_pickle_file
from sb3_emmarl.common.training_state import supports_training_state, training_state
from sb3_emmarl.common.trust.atomic_files import save_model, save_pickle

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
