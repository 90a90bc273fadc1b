"""Command lines of the zoo: ``zoo/train.py`` and ``zoo/enjoy.py`` call :func:`train_main` / :func:`enjoy_main`.

The flags are rl-baselines3-zoo's (``--algo --env -n --seed --tensorboard-log --eval-freq --env-kwargs
--hyperparams -f -i -optimize --storage --study-name --n-trials``...), plus ``--resume`` to continue a
stopped run. Every input is checked before any training starts (flags by their argparse types, the
hyperparameters by :mod:`sb3_emmarl.common.trust.validation`, the reserve's arguments by the reserve): a bad one
ends with exit code 2 and an ``error:`` line naming it, and leaves no folder behind. A run that fails
while training (e.g. at a non-finite value) says why and where its checkpoints are.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import resource
import shutil
import sys
import threading
import time
import uuid
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import numpy as np
import yaml

from sb3_emmarl.cli import os_error_text
from sb3_emmarl.common.checkpoints import (
    TRAINING_STATE,
    check_checkpoint,
    companion,
    list_checkpoints,
    vec_normalize_stats,
)
from sb3_emmarl.common.env_ids import ENV_ID, ENV_MODULES, current_env_id, folder_ids, parallel_env_fn
from sb3_emmarl.common.evaluation import evaluate_team
from sb3_emmarl.common.metrics import format_summary, summarize
from sb3_emmarl.common.model_files import check_model_file, check_saved_algorithm, network_shapes
from sb3_emmarl.common.phases import phase_table
from sb3_emmarl.common.trust.arguments import KeyValues, OneLineParser
from sb3_emmarl.common.trust.arguments import parse_key_values as parse_key_values
from sb3_emmarl.common.trust.atomic_files import write_text
from sb3_emmarl.common.trust.safe_config import wrapper_from_config
from sb3_emmarl.common.trust.validation import MAX_EPISODES, MAX_SEED, MAX_TIMESTEPS, device_flag, int_flag
from sb3_emmarl.common.vec_env import ZOO_VEC_ENVS, compile_reserve
from sb3_emmarl.zoo.algos import ZOO_ALGOS

if TYPE_CHECKING:
    from collections.abc import Callable

    from stable_baselines3.common.vec_env import VecEnv

#: Seed offset of the team evaluation printed at the end of training (episodes unseen in training).
TEAM_EVAL_SEED_OFFSET = 20_000


def peak_rss_mib() -> float:
    """This process's peak resident memory in MiB: Linux's ``VmHWM`` (``ru_maxrss`` of a process started by a large
    one, e.g. a benchmark, starts from its parent's peak inherited at fork), else ``ru_maxrss``."""
    try:
        with open("/proc/self/status") as status:
            return next(int(line.split()[1]) for line in status if line.startswith("VmHWM")) / 1024
    except (OSError, StopIteration, ValueError):
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def saved_as(log_folder: str | Path, algo: str, env_id: str = ENV_ID, exp_id: int = 0) -> str:
    """The id under which the run ``exp_id`` (0: the latest) of ``algo`` on ``env_id`` is saved in ``log_folder``:
    ``env_id`` when it has such a run, else the first former id that does (:func:`folder_ids`), else ``env_id``."""
    from rl_zoo3.utils import get_latest_run_id

    algo_folder = Path(log_folder) / algo
    for name in folder_ids(env_id):
        if (algo_folder / f"{name}_{exp_id or get_latest_run_id(str(algo_folder), name)}").is_dir():
            return name
    return env_id


def latest_run(log_folder: str | Path, algo: str, env_id: str = ENV_ID) -> Path:
    """The folder of the newest run of ``algo`` on ``env_id`` in the zoo's ``log_folder`` (rl-zoo's
    ``<log>/<algo>/<env>_<n>``, highest ``n``); ``<env>_0``, which does not exist, when there is none."""
    from rl_zoo3.utils import get_latest_run_id

    algo_folder = Path(log_folder) / algo
    return algo_folder / f"{env_id}_{get_latest_run_id(str(algo_folder), env_id)}"


def run_env_id(run: str | Path) -> str:
    """The environment id of a zoo run folder (``<env>_<n>``; the reserve's for a folder not named so)."""
    name = Path(run).name.rsplit("_", 1)[0]
    return name if name in ENV_MODULES else ENV_ID


def train_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(description="Train an agent on the wildlife reserve or ZonePatrol "
                                                 "(rl-baselines3-zoo flags).")
    parser.add_argument("--algo", default="ppo", choices=sorted(ZOO_ALGOS), help="algorithm")
    parser.add_argument("--env", default=ENV_ID, type=current_env_id, choices=sorted(ENV_MODULES),
                        help="environment id (a former id gives its current one, with a warning)")
    parser.add_argument("-n", "--n-timesteps", type=int_flag(1, MAX_TIMESTEPS, extra=(-1,)), default=-1,
                        help="overwrite the YAML's n_timesteps (-1: the YAML's)")
    parser.add_argument("--seed", type=int_flag(0, MAX_SEED, extra=(-1,)), default=-1, help="random seed (-1: draw one)")
    parser.add_argument("-tb", "--tensorboard-log", default="", help="tensorboard log folder")
    parser.add_argument("-f", "--log-folder", default="logs", help="where runs are saved (logs/<algo>/<env>_<n>/)")
    parser.add_argument("-i", "--trained-agent", default="",
                        help="continue training from this model or checkpoint zip (its replay buffer and VecNormalize "
                             "statistics are loaded when saved beside it), in a new run folder, for -n more steps")
    parser.add_argument("--resume", nargs="?", const="", default=None, metavar="RUN_FOLDER",
                        help="continue a stopped run (default: the latest run of --log-folder/--algo) in its own folder "
                             "from its newest checkpoint, with the run's own settings, up to its n_timesteps")
    parser.add_argument("--eval-freq", type=int_flag(-1, MAX_TIMESTEPS), default=25000,
                        help="evaluate every n steps (0 or -1: never)")
    parser.add_argument("--eval-episodes", type=int_flag(1, MAX_EPISODES), default=5, help="episodes per periodic evaluation")
    parser.add_argument("--n-eval-envs", type=int_flag(1, 64), default=1, help="environments for periodic evaluation")
    parser.add_argument("--save-freq", type=int_flag(-1, MAX_TIMESTEPS), default=-1,
                        help="checkpoint every n agent-steps, as -n counts them (0 or -1: never); checkpoints are atomic "
                             "and resumable")
    parser.add_argument("--save-replay-buffer", action="store_true",
                        help="save the replay buffer with the final model and every checkpoint (off-policy algorithms)")
    parser.add_argument("--team-eval-episodes", type=int_flag(0, MAX_EPISODES), default=5,
                        help="evaluation episodes whose team metrics are printed after training (0: none)")
    parser.add_argument("--env-kwargs", type=str, nargs="+", action=KeyValues, help="environment arguments, key:value")
    parser.add_argument("--eval-env-kwargs", type=str, nargs="+", action=KeyValues, help="evaluation environment arguments")
    parser.add_argument("-params", "--hyperparams", type=str, nargs="+", action=KeyValues,
                        help="overwrite hyperparameters, e.g. learning_rate:0.01")
    parser.add_argument("-conf", "--conf-file", default=None,
                        help="YAML file instead of sb3_emmarl/zoo/hyperparams/<algo>.yml")
    parser.add_argument("-P", "--progress", action="store_true", help="show a progress bar")
    parser.add_argument("--vec-env", default="batched", choices=list(ZOO_VEC_ENVS),
                        help="batched: the reserve's array API in this process; subproc: the same with the reserve "
                             "copies split over this process and worker processes, one per core (pays from about 16 "
                             "copies); supersuit (or rl-zoo's dummy): SuperSuit's conversion in this process")
    parser.add_argument("--num-threads", type=int_flag(1, 1024, extra=(-1,)), default=1,
                        help="torch threads (default 1: fastest for these small networks on a small CPU; -1: torch's default)")
    parser.add_argument("--log-interval", type=int_flag(-2, 10**6), default=-1,
                        help="override the log interval (-1: default, -2: none)")
    parser.add_argument("--device", type=usable_device, default="auto",
                        help="torch device: auto, cpu, or a cuda/mps device this machine has")
    parser.add_argument("--verbose", type=int_flag(0, 2), default=1, help="0: quiet, 1: info")
    parser.add_argument("-uuid", "--uuid", action="store_true", help="unique run folder name")
    parser.add_argument("-optimize", "--optimize-hyperparameters", action="store_true", help="optuna search")
    parser.add_argument("--n-trials", type=int_flag(1, 10**5), default=10, help="optuna trials")
    parser.add_argument("--max-total-trials", type=int_flag(1, 10**5), default=None, help="optuna trials over all workers")
    parser.add_argument("--n-jobs", type=int_flag(1, 64), default=1, help="parallel optuna jobs")
    parser.add_argument("--sampler", default="tpe", choices=["random", "tpe", "auto"], help="optuna sampler")
    parser.add_argument("--pruner", default="median", choices=["halving", "median", "none"], help="optuna pruner")
    parser.add_argument("--n-startup-trials", type=int_flag(0, 10**5), default=10, help="random trials before the sampler")
    parser.add_argument("--n-evaluations", type=int_flag(1, 10**4), default=None, help="evaluations per optuna trial")
    parser.add_argument("--storage", default=None, help="optuna storage (default SQLite file; an RDB URL for many machines)")
    parser.add_argument("--study-name", default=None, help="optuna study name")
    parser.add_argument("--optimization-log-path", default=None, help="where optuna trials log")
    parser.add_argument("--no-optim-plots", action="store_true", help="no optuna plots")
    return parser


def usable_device(text: str) -> str:
    """An argparse ``type`` for ``--device``: ``auto`` or a torch device this machine has (SB3 would train a missing
    ``cuda:N`` on the CPU without a word, and fail mid-run on a device type torch was not built with).

    :param text: the flag's value
    """
    import torch as th

    device = device_flag(text)
    if device == "auto":
        return device
    parsed = th.device(device)
    count = th.cuda.device_count() if th.cuda.is_available() else 0
    if parsed.type == "cpu" or (parsed.type == "cuda" and (parsed.index or 0) < count) \
            or (parsed.type == "mps" and th.backends.mps.is_available()):
        return device
    has = ["auto", "cpu", *(["cuda", *(f"cuda:{i}" for i in range(count))] if count else []),
           *(["mps"] if th.backends.mps.is_available() else [])]
    raise argparse.ArgumentTypeError(f"must be a device this machine has ({', '.join(has)}), got {text!r}")


#: Flags that may be given with ``--resume`` whatever the run's own are (they find the run or only change output).
RESUME_FREE_FLAGS = ("resume", "log_folder", "progress", "verbose")


def explicit_flags(argv: list[str]) -> dict[str, Any]:
    """The flags given on the command line ``argv`` (not the defaults), with their parsed values.

    :param argv: the command line's arguments
    """
    parser = train_parser()
    for action in parser._actions:  # argparse leaves out of the namespace a flag whose default is SUPPRESS
        action.default = argparse.SUPPRESS
    return vars(parser.parse_args(argv))


def newest_loadable_checkpoint(checkpoints: list[tuple[int, Path]]) -> tuple[int, Path, list[str]]:
    """The newest checkpoint whose zip and companions (training state, replay buffer, ``VecNormalize`` statistics) are
    complete and safe to load (:func:`~sb3_emmarl.common.checkpoints.check_checkpoint`), and why each newer one is not.

    :param checkpoints: ``(steps, zip)`` oldest first (:func:`~sb3_emmarl.common.checkpoints.list_checkpoints`)
    :raise ValueError: if none loads, naming the newest and why
    """
    skipped, complete = [], []
    for steps, path in reversed(checkpoints):
        try:
            check_checkpoint(path)
            complete.append((steps, path, network_shapes(path)))
        except ValueError as error:
            skipped.append(f"{path.name}: {error}")
    if not complete:
        raise ValueError(f"none of the run's {len(checkpoints)} checkpoints loads (the newest, {skipped[0]})")
    # A checkpoint of another run (a valid zip whose networks differ from the run's other checkpoints) is passed over.
    counts = Counter(shapes for _, _, shapes in complete)
    usual = max(counts, key=lambda shapes: (counts[shapes], shapes == complete[-1][2]))  # (a tie: the oldest's)
    for steps, path, shapes in complete:
        if shapes == usual:
            return steps, path, skipped
        skipped.append(f"{path.name}: its networks' shapes differ from the run's other checkpoints (another run's?)")
    raise AssertionError("unreachable: the usual shapes are some checkpoint's")


def _check_train_args(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    if args.conf_file is not None and not Path(args.conf_file).is_file():
        parser.error(f"--conf-file {args.conf_file!r} does not exist")
    if args.trained_agent:
        try:
            check_model_file(args.trained_agent)
            check_saved_algorithm(args.trained_agent, ZOO_ALGOS[args.algo], ZOO_ALGOS)
        except ValueError as error:
            parser.error(f"-i/--trained-agent: {error}")


def _resume_args(parser: argparse.ArgumentParser, args: argparse.Namespace,
                 given: dict[str, Any]) -> tuple[argparse.Namespace, Path] | None:
    """The stopped run's own arguments and its newest checkpoint that loads (None if the run already finished).

    :param parser: the train parser (its errors end the command)
    :param args: the command line's arguments
    :param given: the flags given explicitly (:func:`explicit_flags`): any but :data:`RESUME_FREE_FLAGS` must equal
        the run's own (``--algo a2c --resume <a PPO run>`` is refused, not trained as PPO)
    """
    from sb3_emmarl.zoo.exp_manager import plain, read_yaml

    if args.resume:
        run = Path(args.resume)
    else:
        runs = sorted(Path(args.log_folder, args.algo).glob(f"{args.env}_*"),
                      key=lambda path: int(path.name.rsplit("_", 1)[-1]) if path.name.rsplit("_", 1)[-1].isdigit() else -1)
        if not runs:
            parser.error(f"--resume: no run of {args.algo} on {args.env} in {Path(args.log_folder, args.algo)}")
        run = runs[-1]
    env_id = run_env_id(run)
    args_file = run / env_id / "args.yml"
    if not args_file.is_file():
        parser.error(f"--resume: {run} is not a run folder of the zoo (no {env_id}/args.yml)")
    try:
        saved = read_yaml(args_file, "the run's arguments")
    except ValueError as error:
        parser.error(f"--resume: {error}")
    if not isinstance(saved, dict) or saved.get("algo") not in ZOO_ALGOS:
        parser.error(f"--resume: {args_file} does not hold a zoo run's arguments")
    differ = [f"--{key.replace('_', '-')} {value!r} (the run's: {saved.get(key)!r})" for key, value in given.items()
              if key not in RESUME_FREE_FLAGS and plain(value) != saved.get(key, parser.get_default(key))]
    if differ:
        parser.error(f"--resume continues {run} with its own settings, and these differ from them: {'; '.join(differ)} "
                     "(to train on from one of its checkpoints with other settings, give it with -i: a new run)")
    final = run / f"{env_id}.zip"
    if final.exists():
        try:
            check_model_file(final)
        except ValueError as error:  # a final model cut short or damaged: the run is resumed, and writes a new one
            print(f"warning: {final.name} does not load ({error}); resuming {run} from its checkpoints",
                  file=sys.stderr)
        else:
            print(f"{run} has finished (its final model {env_id}.zip exists): nothing to resume")
            return None
    for leftover in run.rglob(".*.tmp"):  # a file being written when the run stopped (its previous version is intact)
        leftover.unlink()
    checkpoints = list_checkpoints(run)
    if not checkpoints:
        parser.error(f"--resume: {run} has no checkpoint (train with --save-freq to make runs resumable)")
    try:
        steps, checkpoint, skipped = newest_loadable_checkpoint(checkpoints)
    except ValueError as error:
        parser.error(f"--resume: {run}: {error}")
    resumed = {**vars(parser.parse_args([])), **{k: v for k, v in saved.items() if k in vars(args)}}
    resumed.update(resume=str(run), trained_agent=str(checkpoint), progress=args.progress, verbose=args.verbose)
    state = companion(checkpoint, TRAINING_STATE)
    print(f"Resuming {run} from {checkpoint.name} (step {steps}"
          f"{', with its training state' if state is not None and state.is_file() else ', without training state'})"
          + (f"; newer checkpoints that do not load: {'; '.join(skipped)}" if skipped else ""))
    return argparse.Namespace(**resumed), run


def _files(folder: Path | None) -> set[Path]:
    return set(folder.rglob("*")) if folder is not None and folder.is_dir() else set()


def _remove_new_files(folder: Path | None, before: set[Path]) -> None:
    """Remove what appeared in ``folder`` since ``before`` (a resumed run's folder after a failed start: its new
    monitor file), deepest first."""
    for path in sorted(_files(folder) - before, key=lambda p: len(p.parts), reverse=True):
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path, ignore_errors=True)
        else:
            path.unlink(missing_ok=True)


def _remove_tensorboard_run(model: Any, tensorboard_log: str) -> None:
    """Remove the tensorboard folder SB3 made for ``model``'s run under ``tensorboard_log`` (a run that failed before
    its first checkpoint), and ``tensorboard_log`` if that leaves it empty."""
    folder = model.logger.get_dir() if tensorboard_log and getattr(model, "_logger", None) is not None else None
    root = Path(tensorboard_log).resolve() if tensorboard_log else None
    if folder is None or root is None or root not in Path(folder).resolve().parents:
        return
    shutil.rmtree(folder, ignore_errors=True)
    if root.is_dir() and not any(root.iterdir()):
        root.rmdir()


def _after_failed_training(manager: Any, model: Any, tensorboard_log: str) -> str:
    """Tidy a run whose training failed and say where it stands: its checkpoints are kept; a new run without any is
    removed with its tensorboard folder; a resumed one is left as it was.

    :param manager: the run's experiment manager
    :param model: the model that was training
    :param tensorboard_log: ``-tb``'s folder
    """
    checkpoints = list_checkpoints(manager.save_path)
    if checkpoints:
        return (f"the run folder {manager.save_path} keeps its checkpoints up to step {checkpoints[-1][0]} "
                f"and no final model; continue with --resume {manager.save_path}")
    if manager.resume_run is None:
        manager.remove_created_folders()
        _remove_tensorboard_run(model, tensorboard_log)
        return f"no checkpoint had been written, so the run folder {manager.save_path} was removed"
    return f"the run folder {manager.save_path} is left as it was"


def make_manager(args: argparse.Namespace, resume_run: Path | None = None) -> Any:
    """The experiment manager of the train command's arguments (nothing is read or written yet).

    :param args: :func:`train_parser`'s arguments
    :param resume_run: the run folder to continue (``--resume``), if any
    """
    from sb3_emmarl.zoo.exp_manager import ReserveExperimentManager

    return ReserveExperimentManager(
        args, args.algo, args.env, args.log_folder, args.tensorboard_log, args.n_timesteps, args.eval_freq,
        args.eval_episodes, args.save_freq, args.hyperparams, args.env_kwargs, args.eval_env_kwargs,
        args.trained_agent, args.optimize_hyperparameters, args.storage, args.study_name, args.n_trials,
        args.max_total_trials, args.n_jobs, args.sampler, args.pruner, args.optimization_log_path,
        n_startup_trials=args.n_startup_trials, n_evaluations=args.n_evaluations,
        uuid_str=f"_{uuid.uuid4()}" if args.uuid else "", seed=args.seed, log_interval=args.log_interval,
        save_replay_buffer=args.save_replay_buffer, verbose=args.verbose, vec_env_type=args.vec_env,
        n_eval_envs=args.n_eval_envs, no_optim_plots=args.no_optim_plots, device=args.device,
        config=args.conf_file, show_progress=args.progress, resume_run=resume_run,
    )


@contextlib.contextmanager
def _writer_thread_failures_quiet() -> Iterator[None]:
    """Leave unprinted the traceback of tensorboard's writer thread when a write fails (a full disk): the thread hands
    the error to the training thread at its next write, which reports it in one line."""
    previous = threading.excepthook

    def hook(args: Any) -> None:
        if not (isinstance(args.exc_value, OSError) and type(args.thread).__name__ == "_AsyncWriterThread"):
            previous(args)

    threading.excepthook = hook
    try:
        yield
    finally:
        threading.excepthook = previous


def train_main(argv: list[str] | None = None) -> int:
    """Train, save the run in rl-zoo's layout, and print the team metrics of an evaluation on seeded episodes
    (actions sampled, as ``evaluate_team`` does)."""
    import torch as th
    from stable_baselines3.common.utils import set_random_seed

    parser = train_parser()
    args = parser.parse_args(argv)
    resume_run = None
    if args.resume is not None:
        if args.trained_agent:
            parser.error("give -i/--trained-agent or --resume, not both")
        resumed = _resume_args(parser, args, explicit_flags(sys.argv[1:] if argv is None else argv))
        if resumed is None:
            return 0
        args, resume_run = resumed
    _check_train_args(parser, args)
    if args.seed < 0:
        args.seed = int(np.random.randint(2**31 - 1))
    set_random_seed(args.seed)
    if args.num_threads > 0:
        th.set_num_threads(args.num_threads)
    default_storage = args.optimize_hyperparameters and args.storage is None
    if default_storage:  # its folder is made once the settings are checked
        args.storage = f"sqlite:///{Path(args.log_folder) / 'optuna.db'}"
        args.study_name = args.study_name or f"{args.algo}-{args.env}"

    manager = None
    resumed_files = _files(resume_run)
    try:
        manager = make_manager(args, resume_run)
        results = manager.setup_experiment()
    except (ValueError, TypeError, KeyError, AssertionError, yaml.YAMLError, OSError, RuntimeError,
            NotImplementedError) as error:
        if manager is not None:  # nothing half-written is left behind
            manager.remove_created_folders()
        _remove_new_files(resume_run, resumed_files)
        text = os_error_text(error) if isinstance(error, OSError) else str(error)
        print(f"error: {' '.join(text.split())}", file=sys.stderr)
        return 2
    if results is None:
        if default_storage:
            Path(args.log_folder).mkdir(parents=True, exist_ok=True)
        manager.hyperparameters_optimization()
        return 0
    model, _ = results
    for env_kwargs in (manager.env_kwargs, manager.eval_env_kwargs) if args.env == ENV_ID else ():  # each played once
        compile_reserve(env_kwargs)  # numba compiles (or loads) the reserve's kernels here, not in the timed training
    start, cpu_start = time.perf_counter(), time.process_time()
    try:
        with _writer_thread_failures_quiet():
            manager.learn(model)
    except (ValueError, RuntimeError, FloatingPointError, OSError) as error:  # OSError: a checkpoint on a full disk
        reason = os_error_text(error) if isinstance(error, OSError) else error
        if isinstance(error, OSError) and not error.filename:  # (tensorboard's and SB3's log writers name no file)
            logs = " or ".join(str(path) for path in (args.tensorboard_log, manager.save_path) if path)
            reason = f"{reason} (writing the logs under {logs})"
        print(f"error: training stopped at step {model.num_timesteps}: {reason}\n"
              f"{_after_failed_training(manager, model, args.tensorboard_log)}", file=sys.stderr)
        return 1
    return _finish_run(args, manager, model, time.perf_counter() - start, time.process_time() - cpu_start)


def _finish_run(args: argparse.Namespace, manager: Any, model: Any, train_seconds: float, cpu_seconds: float) -> int:
    """Save a trained run (model, ``run_stats.json``, the team's evaluation) and say what to do next; 1 (with one
    line) if the model cannot be saved."""
    try:
        manager.save_trained_model(model)
    except OSError as error:  # (each file is written whole or not at all)
        print(f"error: the trained model was not saved: {os_error_text(error)}\n"
              f"{_after_failed_training(manager, model, args.tensorboard_log)}", file=sys.stderr)
        return 1
    stats = {"train_seconds": train_seconds, "cpu_seconds": cpu_seconds, "n_timesteps": int(model.num_timesteps),
             "peak_rss_mib": peak_rss_mib()}
    phases = getattr(manager, "phase_times", None)
    if phases is not None and phases.wall > 0:
        stats["phase_seconds"] = phases.seconds
        print(phase_table(phases.seconds, train_seconds, f"where the training's {train_seconds:.1f} s went (the "
                                                         f"phases sum to {sum(phases.seconds.values()):.1f} s; the rest "
                                                         "is SB3's set-up of the run)"))
    write_text(Path(manager.save_path) / "run_stats.json", json.dumps(stats, indent=1))
    if args.team_eval_episodes:
        records = evaluate_team(model, n_episodes=args.team_eval_episodes, seed=args.seed + TEAM_EVAL_SEED_OFFSET,
                                env_kwargs=manager.eval_env_kwargs,
                                vec_normalize_path=vec_normalize_stats(manager.params_path),
                                vec_env_wrapper=manager.vec_env_wrapper, env_id=args.env)
        write_text(Path(manager.save_path) / "team_eval.json", json.dumps(records, indent=1))
        eval_seed = args.seed + TEAM_EVAL_SEED_OFFSET
        title = f"{args.algo} on {args.env}: {len(records)} evaluation episodes, seed {eval_seed} (mean +- std)"
        print(format_summary(summarize(records), title))
    print(next_steps(args, str(manager.save_path), int(model.num_timesteps)))
    return 0


def next_steps(args: argparse.Namespace, save_path: str, n_timesteps: int) -> str:
    """What a finished ``train`` tells a newcomer: where the run and its curves are, and what to run next.

    :param args: the train command's arguments
    :param save_path: the run's folder
    :param n_timesteps: the agent-steps the run trained
    """
    lines = ["", f"the run: {save_path} (the model, checkpoints, config.yml, team_eval.json)"]
    if args.tensorboard_log:
        lines.append(f"the learning curves (rollout/, train/, and the team's metrics): tensorboard --logdir "
                     f"{args.tensorboard_log}")
    lines += [f"watch the team (metrics and a GIF in the run folder): emmarl enjoy --algo {args.algo} "
              f"--env {args.env} -f {args.log_folder}",
              (f"compare with PPO over seeds: emmarl compare --variants {args.algo}={args.algo} ppo=ppo "
               f"--seeds 0 1 2 -n {n_timesteps}" if args.env == ENV_ID else
               "compare with PPO, PPO told the mode and EM-PPO over seeds: python benchmarks/zone_patrol_value.py run "
               "--seeds 0 1 2 --folder zp"),
              "the paper's experiments: emmarl experiment --list"]
    return "\n".join(lines)


def enjoy_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(description="Watch a trained team: team metrics and an animation of its patrol.")
    parser.add_argument("--algo", default="ppo", choices=sorted(ZOO_ALGOS), help="algorithm")
    parser.add_argument("--env", default=ENV_ID, type=current_env_id, choices=sorted(ENV_MODULES),
                        help="environment id (a former id gives its current one, with a warning)")
    parser.add_argument("-f", "--folder", default="logs", help="log folder of the runs")
    parser.add_argument("--exp-id", type=int_flag(0, 10**6), default=0, help="run number (0: the latest)")
    parser.add_argument("--load-best", action="store_true", help="the best model of the periodic evaluations")
    parser.add_argument("--load-checkpoint", type=int_flag(1, MAX_TIMESTEPS), default=None,
                        help="the checkpoint of this step")
    parser.add_argument("--episodes", type=int_flag(1, MAX_EPISODES), default=3, help="evaluation episodes")
    parser.add_argument("--seed", type=int_flag(0, MAX_SEED), default=0, help="evaluation seed")
    parser.add_argument("--deterministic", action="store_true",
                        help="the most likely actions instead of sampled ones (identical UAVs then tend to move in lockstep)")
    parser.add_argument("--env-kwargs", type=str, nargs="+", action=KeyValues,
                        help="override the run's environment arguments")
    parser.add_argument("-o", "--output", default=None, help="animation file, .gif or .mp4 (default: <run>/patrol.gif)")
    parser.add_argument("--no-record", action="store_true", help="print the metrics only")
    parser.add_argument("--fps", type=int_flag(1, 120), default=10, help="animation frames per second")
    parser.add_argument("--frame-skip", type=int_flag(1, 10**4), default=1, help="keep one frame in this many")
    return parser


def enjoy_main(argv: list[str] | None = None) -> int:
    """Load a saved run, print its team metrics on evaluation episodes and record one episode."""
    from rl_zoo3.utils import EnvironmentName, get_model_path

    from sb3_emmarl.common.recording import record_episode

    parser = enjoy_parser()
    args = parser.parse_args(argv)
    if args.output is not None and Path(args.output).suffix not in (".gif", ".mp4"):
        parser.error(f"--output must end in .gif or .mp4, got {args.output!r}")
    from sb3_emmarl.common.model_files import load_model
    from sb3_emmarl.zoo.exp_manager import read_yaml

    try:
        checkpoint = None if args.load_checkpoint is None else str(args.load_checkpoint)
        saved = saved_as(args.folder, args.algo, args.env, args.exp_id)  # a former id's runs play on the current id
        _, model_path, log_path = get_model_path(args.exp_id, args.folder, args.algo, EnvironmentName(saved),
                                                 args.load_best, checkpoint)
        params_path = Path(log_path) / saved
        config_file = params_path / "config.yml"
        config = read_yaml(config_file, "the run's config") if config_file.exists() else {}  # (a folder is refused)
        if not isinstance(config, dict):
            raise ValueError(f"{config_file} must hold a mapping of hyperparameters, got {type(config).__name__}")
        env_kwargs = {**dict(config.get("env_kwargs") or {}), **(args.env_kwargs or {})}
        parallel_env_fn(args.env)(**env_kwargs).close()  # checked before anything runs
        vec_normalize_path = vec_normalize_stats(params_path)
        # What the run was trained under (rl_zoo3 annotates get_wrapper_class for gym.Env wrappers only)
        vec_env_wrapper = cast("Callable[[VecEnv], VecEnv] | None", wrapper_from_config(config, "vec_env_wrapper"))
        model = load_model(ZOO_ALGOS[args.algo], model_path, candidates=ZOO_ALGOS, device="cpu")
    except (AssertionError, ValueError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    records = evaluate_team(model, n_episodes=args.episodes, seed=args.seed, env_kwargs=env_kwargs,
                            deterministic=args.deterministic, vec_normalize_path=vec_normalize_path,
                            vec_env_wrapper=vec_env_wrapper, env_id=args.env)
    print(format_summary(summarize(records), f"{model_path}: {len(records)} episodes from seed {args.seed} (mean +- std)"))
    if not args.no_record:
        output = Path(args.output) if args.output else Path(log_path) / "patrol.gif"
        record_episode(model, output, seed=args.seed, env_kwargs=env_kwargs, deterministic=args.deterministic,
                       vec_normalize_path=vec_normalize_path, fps=args.fps, frame_skip=args.frame_skip,
                       vec_env_wrapper=vec_env_wrapper, env_id=args.env)
        print(f"Recorded one episode to {output}")
    return 0
