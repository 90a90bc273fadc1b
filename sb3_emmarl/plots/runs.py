"""Finding runs: the zoo's run folders (``<log-folder>/<algo>/<env>_<n>/``, one per seed) and their tensorboard logs."""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any


@dataclass(frozen=True)
class Run:
    """One training run (one seed) of an algorithm.

    :param algo: the zoo algorithm (``ppo``, ``em_ppo``...)
    :param env_id: the environment id
    :param folder: the zoo run folder (``<log-folder>/<algo>/<env>_<n>``), or its tensorboard folder
    :param agents_per_copy: the vector entries of one environment copy (its UAVs; 1 on the centralised view): the
        monitor rows of one team episode
    :param team_size: the team's UAVs (``n_uavs``)
    """

    algo: str
    env_id: str
    folder: Path
    agents_per_copy: int
    team_size: int

    @property
    def uav_steps_per_timestep(self) -> int:
        """Agent-steps (one per UAV per step) in one of SB3's timesteps: 1 on the parameter-sharing view (a timestep
        is a vector entry's step), the team's UAVs on the centralised one (a timestep moves the whole team)."""
        return self.team_size // self.agents_per_copy


def _run_number(folder: Path, prefix: str) -> int | None:
    """``n`` of a folder named ``<prefix>_<n>``, else None."""
    match = re.fullmatch(re.escape(prefix) + r"_(\d+)", folder.name)
    return int(match.group(1)) if match and folder.is_dir() else None


def make_run(algo: str, env_id: str, folder: Path, env_kwargs: Mapping[str, Any]) -> Run:
    """A run of ``algo`` on ``env_id``: its team's UAVs (``n_uavs`` of the environment's configuration, built from
    ``env_kwargs`` without building the environment), each a vector entry on the parameter-sharing view, the team one
    entry on the centralised one.

    :param algo: the zoo algorithm
    :param env_id: the environment id
    :param folder: the run's folder
    :param env_kwargs: the environment's arguments the run was trained with
    """
    import importlib

    from sb3_emmarl.common.env_ids import ENV_CONFIGS
    from sb3_emmarl.zoo.algos import CENTRALIZED_ALGOS

    module, name = ENV_CONFIGS[env_id].split(":")
    team_size = int(getattr(importlib.import_module(module), name).from_kwargs(**env_kwargs).n_uavs)
    return Run(algo, env_id, folder, 1 if algo in CENTRALIZED_ALGOS else team_size, team_size)


def _run_env_kwargs(folder: Path, env_id: str) -> dict[str, Any]:
    """The environment's arguments of a zoo run, from its ``config.yml`` (empty when it has none)."""
    from sb3_emmarl.common.trust.safe_config import load_yaml

    config_file = folder / env_id / "config.yml"
    if not config_file.is_file():
        return {}
    return dict(load_yaml(config_file, "the run's config").get("env_kwargs") or {})


def zoo_runs(log_folders: Sequence[str | Path], algos: Sequence[str] | None = None,
             env_id: str | None = None) -> list[Run]:
    """The runs of the zoo's log folders, in the zoo's layout ``<log-folder>/<algo>/<env>_<n>/``.

    :param log_folders: the folders given to ``train -f``
    :param algos: the algorithms (None: every zoo algorithm that has a folder)
    :param env_id: the environment (None: every known environment); the runs saved under its former ids
        (:func:`~sb3_emmarl.common.env_ids.folder_ids`) count as its own
    :return: the runs, by algorithm (in ``algos``' order), environment and run number
    """
    from sb3_emmarl.common.env_ids import ENV_MODULES, folder_ids
    from sb3_emmarl.zoo.algos import ZOO_ALGOS

    names = list(algos) if algos is not None else sorted(ZOO_ALGOS)
    env_ids = [env_id] if env_id is not None else sorted(ENV_MODULES)
    runs = []
    for algo in names:
        for env in env_ids:
            for name in folder_ids(env):  # runs saved under a former id count as the current id's
                for log_folder in log_folders:
                    algo_folder = Path(log_folder) / algo
                    found = sorted((n, f) for f in (algo_folder.iterdir() if algo_folder.is_dir() else [])
                                   if (n := _run_number(f, name)) is not None)
                    runs += [make_run(algo, env, folder, _run_env_kwargs(folder, name)) for _, folder in found]
    return runs


def tensorboard_name(algo: str) -> str:
    """The name SB3 gives the tensorboard runs of ``algo`` (``learn``'s ``tb_log_name``: ``PPO``, ``EMPPO``...), under
    which the zoo writes them (``<tb>/<env>/<name>_<n>``)."""
    import inspect

    from sb3_emmarl.zoo.algos import ZOO_ALGOS

    return str(inspect.signature(ZOO_ALGOS[algo].learn).parameters["tb_log_name"].default)


def tensorboard_runs(tensorboard_log: str | Path, zoo: Sequence[Run]) -> list[Run]:
    """The tensorboard runs the zoo wrote with ``train -tb <tensorboard_log>`` beside the zoo runs ``zoo``:
    ``<tensorboard_log>/<env>/<name>_<n>``, ``name`` the algorithm's :func:`tensorboard_name`. A tensorboard folder does
    not say its team's size: each algorithm's runs take its zoo runs' (which must agree on the centralised view, where
    it converts SB3's timesteps to agent-steps).

    :param tensorboard_log: the folder given to ``train -tb``
    :param zoo: the zoo runs (one environment's) whose algorithms to look for
    :raise ValueError: when two of the algorithms write runs of one name (PPO's variants), which cannot be told apart,
        or a centralised algorithm's zoo runs have teams of several sizes
    """
    env_id = zoo[0].env_id
    like: dict[str, Run] = {}
    for run in zoo:
        known = like.setdefault(run.algo, run)
        if known.uav_steps_per_timestep != run.uav_steps_per_timestep:
            raise ValueError(f"{run.algo}'s runs have teams of {known.team_size} and {run.team_size} UAVs, and its "
                             "tensorboard runs do not say which is which: plot its scalars from its run folders")
    names: dict[str, str] = {}
    for algo in like:
        name = tensorboard_name(algo)
        if name in names:
            raise ValueError(f"{names[name]} and {algo} both write their tensorboard runs as {name}_<n>, which cannot "
                             f"be told apart: plot them one at a time, each from the -tb folder it was trained with")
        names[name] = algo
    from sb3_emmarl.common.env_ids import folder_ids

    runs = []
    for name, algo in names.items():
        for folder in (Path(tensorboard_log) / saved for saved in folder_ids(env_id)):
            found = sorted((n, f) for f in (folder.iterdir() if folder.is_dir() else [])
                           if (n := _run_number(f, name)) is not None)
            runs += [Run(algo, env_id, run_folder, like[algo].agents_per_copy, like[algo].team_size)
                     for _, run_folder in found]
    return runs
