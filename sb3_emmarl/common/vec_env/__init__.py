"""Parameter-sharing vector environments: SuperSuit's (any PettingZoo environment) and the reserve's batched one.

``make_vec_env(n_copies, seed, env_kwargs)`` builds ``n_copies`` independent reserves. SuperSuit's
``pettingzoo_env_to_vec_env_v1`` (``MarkovVectorEnv``) turns each reserve's agents into vector
entries and its ``ConcatVecEnv`` / ``ProcConcatVec`` concatenates the copies; :class:`SharedPolicyVecEnv`
then presents them to Stable-Baselines3. Vector index ``i`` belongs to reserve copy
``i // agents_per_copy`` and to agent ``possible_agents[i % agents_per_copy]`` of that copy (e.g. with
10 UAVs, indices 0-9 are ``uav_0`` ... ``uav_9`` of copy 0, indices 10-19 those of copy 1).

The adapter replaces SuperSuit's ``SB3VecEnvWrapper`` and mends its faults:

- ``seed()`` exists (``PPO(..., seed=s)`` and ``reset()`` after ``seed(s)`` work): copy ``c`` gets
  seed ``s + c``, delivered through ``reset`` options so that it holds in- and multi-process alike
  (SuperSuit offsets seeds by process *and* by copy, so copies in different processes collided);
- every copy is built fresh (not cloned) and an unseeded first reset draws one fresh base seed, so
  copies never replay the same episode;
- an episode cut at ``max_cycles`` sets ``infos[i]["TimeLimit.truncated"]`` (SB3 then bootstraps);
- ``dones`` are booleans, and ``get_attr`` / ``set_attr`` / ``env_method`` reach the reserves;
- the reset infos are one dict per vector entry with worker processes too (``ProcConcatVec.reset``
  returned each worker's compressed ``(index, info)`` pairs).

:class:`ReserveVecEnv` is the same adapter over the reserve's array API (``ReserveParallelEnv.step_arrays``)
instead of SuperSuit: the same data, step for step and seed for seed, without the per-agent dictionaries. It is
``make_vec_env``'s default for the reserve, in this process or split over worker processes (``num_cpus``);
``vec_env_type="supersuit"`` keeps the SuperSuit path (the reference, and the path of other PettingZoo environments).
"""


from __future__ import annotations

from collections.abc import Callable
from functools import partial
from typing import Any

from pettingzoo import ParallelEnv
from stable_baselines3.common.vec_env import VecEnv, VecMonitor

from sb3_emmarl.common.vec_env.batched import ReserveVecEnv
from sb3_emmarl.common.vec_env.finite import FiniteCheck
from sb3_emmarl.common.vec_env.shared_policy import (
    COPY_SEEDS_KEY,
    LINKS_KEY,
    STATE_KEY,
    TERMINAL_LINKS_KEY,
    TERMINAL_STATE_KEY,
    SharedPolicyVecEnv,
    require_state,
)
from wildlife_reserve import reserve_v1

__all__ = ["COPY_SEEDS_KEY", "LINKS_KEY", "STATE_KEY", "TERMINAL_LINKS_KEY", "TERMINAL_STATE_KEY", "VEC_ENV_TYPES",
           "ZOO_VEC_ENVS", "FiniteCheck", "ReserveVecEnv", "SharedPolicyVecEnv", "compile_reserve", "make_vec_env",
           "require_state"]

#: The two parameter-sharing paths (see :func:`make_vec_env`).
VEC_ENV_TYPES = ("batched", "supersuit")
#: The zoo's --vec-env choices: the two parameter-sharing paths, rl-zoo's "dummy" (SuperSuit in this process, the name
#: rl-zoo gives its in-process choice) and "subproc" (the batched path over worker processes).
ZOO_VEC_ENVS = (*VEC_ENV_TYPES, "dummy", "subproc")


def compile_reserve(env_kwargs: dict[str, Any] | None = None) -> None:
    """Compile the reserve's numba kernels in this process for training runs on ``env_kwargs``, with discrete and with
    continuous actions (an algorithm's YAML may ask for either), so that runs started afterwards in fresh processes
    load them from numba's cache instead of compiling them inside their timed training
    (:func:`wildlife_reserve.reserve.reserve.compile_kernels`, once per process and arguments).

    :param env_kwargs: the reserve's arguments, as ``--env-kwargs`` gives them
    """
    from wildlife_reserve.reserve.reserve import compile_kernels

    for continuous in (False, True):
        compile_kernels(**{**(env_kwargs or {}), "continuous_actions": continuous})


def make_vec_env(
    n_copies: int = 1,
    seed: int | None = None,
    env_kwargs: dict[str, Any] | None = None,
    *,
    num_cpus: int = 0,
    monitor_dir: str | None = None,
    vec_env_wrapper: Callable[[VecEnv], VecEnv] | None = None,
    env_fn: Callable[..., ParallelEnv] = reserve_v1.parallel_env,
    with_state: bool = False,
    vec_env_type: str | None = None,
) -> VecEnv:
    """The parameter-sharing vector environment: ``n_copies`` reserves, one vector entry per UAV.

    :param n_copies: independent reserve copies (rl-zoo's ``n_envs``)
    :param seed: seeds the first reset (copy ``c`` gets ``seed + c``); None draws a fresh seed
    :param env_kwargs: keyword arguments of the environment (validated here, before anything runs)
    :param num_cpus: processes stepping the copies (0 or 1: this one alone; batched: this one and ``num_cpus - 1``
        workers; supersuit: ``num_cpus`` workers)
    :param monitor_dir: folder for ``VecMonitor``'s ``monitor.csv`` (one row per agent-episode); None: no file
    :param vec_env_wrapper: optional wrapper applied last (e.g. the EM history wrapper)
    :param env_fn: environment constructor taking ``env_kwargs`` (default: the reserve)
    :param with_state: the global state in the infos (see :class:`SharedPolicyVecEnv`; MAPPO and QMIX need it)
    :param vec_env_type: ``"batched"`` (:class:`ReserveVecEnv`: the reserve's array API) or ``"supersuit"``
        (:class:`SharedPolicyVecEnv`: SuperSuit's conversion, any PettingZoo environment); both give the same data.
        None: ``"batched"`` for the reserve (``env_fn`` left at its default), else ``"supersuit"``
    :return: ``VecMonitor(ReserveVecEnv or SharedPolicyVecEnv)``, wrapped by ``vec_env_wrapper`` if given
    """
    if vec_env_type not in (*VEC_ENV_TYPES, None):
        raise ValueError(f"vec_env_type must be one of {list(VEC_ENV_TYPES)} or None, got {vec_env_type!r}")
    env_kwargs = dict(env_kwargs or {})
    build = partial(env_fn, **env_kwargs)
    if vec_env_type is None:
        vec_env_type = "batched" if env_fn is reserve_v1.parallel_env else "supersuit"
    if vec_env_type == "batched":
        venv: VecEnv = ReserveVecEnv(build, n_copies=n_copies, with_state=with_state, num_cpus=num_cpus)
    else:
        venv = SharedPolicyVecEnv(build, n_copies=n_copies, num_cpus=num_cpus, with_state=with_state)
    venv = VecMonitor(venv, filename=monitor_dir)
    if vec_env_wrapper is not None:
        venv = vec_env_wrapper(venv)
    venv.seed(seed)
    return venv
