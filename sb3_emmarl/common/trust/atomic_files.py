"""Files that survive a kill: each is written to a hidden temporary name beside it, flushed to disk and renamed into
place, so that a kill, a full disk or a read-only folder leaves the previous complete file and no partial one.

SB3 writes its files in place (``model.save``, ``VecNormalize.save``, ``save_to_pkl``); :func:`save_model`,
:func:`save_pickle` and :func:`write_text` write the same formats through :func:`write_atomic` (models, checkpoints,
replay buffers, ``VecNormalize`` statistics, configs, results, recordings and figures).
"""

from __future__ import annotations

import contextlib
import io
import os
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sb3_emmarl.common.trust.pickling import dumps

if TYPE_CHECKING:
    from stable_baselines3.common.base_class import BaseAlgorithm


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
    except BaseException as error:
        with contextlib.suppress(OSError):  # (nothing to remove in a read-only folder, which refuses even that)
            tmp.unlink(missing_ok=True)
        # a write on a full disk names no file, a read-only folder the temporary one: say which
        if isinstance(error, OSError) and error.errno is not None and error.filename in (None, str(tmp), tmp):
            raise OSError(error.errno, error.strerror, str(path)) from error
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
