"""Model zips checked before they are loaded: complete, read as data only, and saved by the algorithm asked for.

:func:`check_model_file` / :func:`load_model` refuse a truncated or corrupt zip with a message naming the file, a zip
whose pickles name, call or allocate what data does not (:mod:`sb3_emmarl.common.trust.safe_zip`), and a zip saved by
another algorithm than the one asked for (:func:`fitting_algorithms`); :func:`network_shapes` tells one run's
checkpoint from another's.
"""

from __future__ import annotations

import inspect
import io
import pickle
import re
import zipfile
from pathlib import Path
from typing import Any

from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.save_util import load_from_zip_file

from sb3_emmarl.common.trust.safe_zip import check_zip_sizes, pickle_globals, read_data, safe_data_objects


def check_model_file(path: str | Path) -> Path:
    """Check that ``path`` is a complete SB3 model zip whose pickles name only allowed globals and read as data only
    (:func:`~sb3_emmarl.common.trust.safe_zip.safe_data_objects`).

    :raise ValueError: naming the file when it is missing, truncated, corrupt, not a model, or names a foreign global
    """
    _checked_data_objects(path)
    return Path(path)


def _checked_data_objects(path: str | Path) -> dict[str, Any]:
    """:func:`check_model_file`'s checks, returning the zip's pickled data read as data only (SB3's ``custom_objects``,
    :func:`~sb3_emmarl.common.trust.safe_zip.safe_data_objects`)."""
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
    (:func:`~sb3_emmarl.common.trust.safe_zip.safe_data_objects`, given to SB3 as ``custom_objects``)."""
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


def model_bytes(model: BaseAlgorithm) -> bytes:
    """The model's zip in memory (for comparisons and tests)."""
    buffer = io.BytesIO()
    model.save(buffer)
    return buffer.getvalue()
