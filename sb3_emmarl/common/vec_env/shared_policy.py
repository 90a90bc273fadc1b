"""SuperSuit's parameter-sharing conversion presented to Stable-Baselines3 (:class:`SharedPolicyVecEnv`: any
PettingZoo parallel environment, one vector entry per agent of each copy), the info keys it fills, and
:func:`require_state`."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from functools import partial
from typing import Any, cast

import numpy as np
from pettingzoo import ParallelEnv
from stable_baselines3.common.vec_env import VecEnv
from stable_baselines3.common.vec_env.base_vec_env import VecEnvIndices, VecEnvObs, VecEnvStepReturn
from supersuit.vector import ConcatVecEnv, MakeCPUAsyncConstructor, MarkovVectorEnv, ProcConcatVec

from sb3_emmarl.common.trust.pickling import dumps
from sb3_emmarl.common.trust.safe_pickle import ENV_STATE_MODULES, loads
from sb3_emmarl.common.vec_env.memory import check_copies_fit

#: Key of the ``reset`` options that carries one seed per reserve copy.
COPY_SEEDS_KEY = "sb3_emmarl_copy_seeds"


#: Info keys of the global state (with ``with_state=True``): the state matching the returned observation (after an
#: automatic reset, the new episode's), and at an episode's end the state it ended in (as ``terminal_observation``).
STATE_KEY, TERMINAL_STATE_KEY = "state", "terminal_state"
#: Info keys of the links: the teammates whose messages reached an agent this step (the reserve's ``heard_from``; none
#: after an automatic reset), and at an episode's end the links of its last step (SuperSuit's automatic reset would
#: otherwise overwrite them with the new episode's empty ones).
LINKS_KEY, TERMINAL_LINKS_KEY = "heard_from", "terminal_heard_from"


def apply_to_env(env: Any, kind: str, name: str, payload: tuple) -> Any:
    """``getattr(env, name)`` (kind ``"get"``), ``setattr(env, name, *payload)`` (``"set"``) or
    ``getattr(env, name)(*args, **kwargs)`` with ``payload = (args, kwargs)`` (``"call"``)."""
    if kind == "get":
        return getattr(env, name)
    if kind == "set":
        return setattr(env, name, *payload)
    args, kwargs = payload
    return getattr(env, name)(*args, **kwargs)


class _ReserveCopy(MarkovVectorEnv):
    """SuperSuit's ``MarkovVectorEnv`` for one reserve copy, which takes its seed from the reset options and, with
    ``with_state``, puts the environment's global ``state()`` in every agent's infos."""

    def __init__(self, par_env: ParallelEnv, copy_index: int, with_state: bool = False) -> None:
        super().__init__(par_env)
        self.copy_index = copy_index
        self.with_state = with_state
        self._in_step = self._auto_reset = False

    def reset(self, seed: int | None = None, options: dict | None = None):
        options = dict(options or {})
        seeds = options.pop(COPY_SEEDS_KEY, None)
        if seeds is not None:
            seed = seeds[self.copy_index]
        extra: dict[str, Any] = {}
        if self.with_state and self._in_step:  # an automatic reset: keep the state the episode ended in
            extra[TERMINAL_STATE_KEY] = np.asarray(self.par_env.state(), dtype=np.float32)
        observations, infos = super().reset(seed=seed, options=options or None)
        if self.with_state:
            extra[STATE_KEY] = np.asarray(self.par_env.state(), dtype=np.float32)
            infos = [{**info, **extra} for info in infos]
        if self._in_step:  # SuperSuit merges these into the last step's infos: leave that step's links in place
            self._auto_reset = True
            infos = [{k: v for k, v in info.items() if k != LINKS_KEY} for info in infos]
        return observations, infos

    def step(self, actions):
        self._in_step, self._auto_reset = True, False
        try:
            observations, rewards, terminations, truncations, infos = super().step(actions)
        finally:
            self._in_step = False
        if self._auto_reset:  # the last step's links move to their terminal key; the new episode has heard nobody
            infos = [{**info, TERMINAL_LINKS_KEY: info[LINKS_KEY], LINKS_KEY: ()} if LINKS_KEY in info else info
                     for info in infos]
        if self.with_state and (not infos or STATE_KEY not in infos[0]):  # no automatic reset: the current state
            state = np.asarray(self.par_env.state(), dtype=np.float32)
            infos = [{**info, STATE_KEY: state} for info in infos]
        return observations, rewards, terminations, truncations, infos


def _build_copy(env_fn: Callable[[], ParallelEnv], copy_index: int, with_state: bool = False) -> _ReserveCopy:
    env = env_fn()
    if not hasattr(env.unwrapped, "render_mode"):  # PettingZoo does not require it; SuperSuit reads it
        env.unwrapped.render_mode = None
    return _ReserveCopy(env, copy_index, with_state)


class SharedPolicyVecEnv(VecEnv):
    """SB3 ``VecEnv`` over ``n_copies`` parallel PettingZoo environments, one entry per (copy, agent).

    :param env_fn: builds one parallel environment (all agents with the same spaces; none leaves early)
    :param n_copies: number of independent copies
    :param num_cpus: worker processes (0 or 1: all copies in this process)
    :param with_state: put the environment's global ``state()`` in every entry's infos (``infos[i]["state"]``, and
        ``infos[i]["terminal_state"]`` at an episode's end) and its ``state_space`` in :attr:`state_space`
    """

    def __init__(self, env_fn: Callable[[], ParallelEnv], n_copies: int = 1, num_cpus: int = 0,
                 with_state: bool = False) -> None:
        if isinstance(n_copies, bool) or not isinstance(n_copies, (int, np.integer)) or n_copies < 1:
            raise ValueError(f"n_copies must be an int >= 1, got {n_copies!r}")
        if isinstance(num_cpus, bool) or not isinstance(num_cpus, (int, np.integer)) or num_cpus < 0:
            raise ValueError(f"num_cpus must be an int >= 0, got {num_cpus!r}")
        self.prototype = env_fn()  # also validates the environment's arguments, here and now
        check_copies_fit(self.prototype, int(n_copies))
        self.possible_agents = list(self.prototype.possible_agents)
        self.agents_per_copy = len(self.possible_agents)
        self.n_copies = int(n_copies)
        self.multiprocess = min(num_cpus, n_copies) > 1
        agent = self.possible_agents[0]
        observation_space = self.prototype.observation_space(agent)
        action_space = self.prototype.action_space(agent)
        self.with_state = bool(with_state)
        self.state_space = self._state_space() if self.with_state else None
        if self.multiprocess:
            self.venv = self._worker_copies(env_fn, min(num_cpus, self.n_copies), observation_space, action_space)
        else:
            self.venv = self._local_copies(env_fn, observation_space, action_space)
        super().__init__(self.n_copies * self.agents_per_copy, observation_space, action_space)
        self._copy_seeds: list[int] | None = None
        self._never_reset = True

    def _local_copies(self, env_fn: Callable[[], ParallelEnv], observation_space: Any, action_space: Any) -> Any:
        """The copies in this process: SuperSuit's ``ConcatVecEnv`` of ``MarkovVectorEnv`` s."""
        return ConcatVecEnv(self._copy_builders(env_fn), observation_space, action_space)

    def _worker_copies(self, env_fn: Callable[[], ParallelEnv], num_cpus: int, observation_space: Any,
                       action_space: Any) -> Any:
        """The copies in ``num_cpus`` worker processes: SuperSuit's ``ProcConcatVec``."""
        return MakeCPUAsyncConstructor(num_cpus)(self._copy_builders(env_fn), observation_space, action_space)

    def _copy_builders(self, env_fn: Callable[[], ParallelEnv]) -> list[Callable[[], _ReserveCopy]]:
        """One builder of a :class:`_ReserveCopy` per copy (SuperSuit's vector environments call them)."""
        return [partial(_build_copy, env_fn, c, self.with_state) for c in range(self.n_copies)]

    def _par_envs(self) -> list[ParallelEnv]:
        """The copies' environments (in this process)."""
        return [copy.par_env for copy in self.venv.vec_envs]

    def _switch_state_on(self) -> None:
        """Have the copies put the global state in their infos (each :class:`_ReserveCopy`, in this process)."""
        if self.multiprocess:
            raise ValueError("the copies live in SuperSuit's worker processes: build the environment with "
                             "make_vec_env(..., with_state=True) to have the global state")
        for copy in self.venv.vec_envs:
            copy.with_state = True

    # -------------------------------------------------------------- seeding and reset
    def seed(self, seed: int | None = None) -> Sequence[int | None]:
        """Seed the next reset: copy ``c`` gets ``seed + c`` (a fresh random ``seed`` if None).

        :return: the seed of each vector entry (entries of one copy share it)
        """
        if seed is None:
            seed = int(cast(int, np.random.SeedSequence().entropy) % 2**31)  # (a fresh sequence's entropy is an int)
        self._copy_seeds = [int(seed) + c for c in range(self.n_copies)]
        return [s for s in self._copy_seeds for _ in range(self.agents_per_copy)]

    def reset(self) -> VecEnvObs:
        if self._copy_seeds is None and self._never_reset:
            self.seed(None)  # unseeded: still a different episode in every copy
        options = dict(self._options[0]) if self._options and self._options[0] else {}
        if self._copy_seeds is not None:
            options[COPY_SEEDS_KEY] = self._copy_seeds
        observations, infos = self.venv.reset(options=options or None)
        self.reset_infos = self._decompress_infos(infos) if isinstance(self.venv, ProcConcatVec) else list(infos)
        self._copy_seeds = None
        self._never_reset = False
        self._reset_options()
        return observations

    def _decompress_infos(self, compressed: list[list[tuple[int, dict]]]) -> list[dict]:
        """One info dict per vector entry from ``ProcConcatVec``'s per-worker ``(index, info)`` pairs."""
        infos: list[dict] = [{} for _ in range(self.num_envs)]
        for start, pairs in zip(self.venv.idx_starts, compressed):
            for index, info in pairs:
                infos[start + index] = info
        return infos

    # -------------------------------------------------------------- the global state
    def _state_space(self) -> Any:
        space = getattr(self.prototype, "state_space", None)
        if not callable(getattr(self.prototype, "state", None)) or space is None:
            raise ValueError(f"the global state is needed (with_state=True), but {type(self.prototype).__name__} has no "
                             "state() and state_space")
        return space

    def enable_state(self) -> None:
        """Put the global state in the infos from the next reset on (as ``with_state=True`` does at construction).

        :raise ValueError: if the environment has no ``state()``, or its copies live in SuperSuit's worker processes
            (then build it with ``make_vec_env(..., with_state=True)``)
        """
        if self.with_state:
            return
        space = self._state_space()
        self._switch_state_on()
        self.with_state, self.state_space = True, space

    # -------------------------------------------------------------- state, for checkpoints
    def get_state(self) -> bytes:
        """The copies mid-episode (their reserves and random generators), pickled, for checkpoints that resume
        exactly where a run stopped.

        :raise ValueError: with SuperSuit's worker processes (``num_cpus > 1``), whose copies this process cannot read
        """
        return dumps({"venv": self._portable_copies(), "copy_seeds": self._copy_seeds,
                      "never_reset": self._never_reset, "reset_infos": self.reset_infos})

    def set_state(self, state: bytes) -> None:
        """Restore :meth:`get_state` (the copies then continue their episodes), read as data only: a checkpoint may
        hold instances of the environments' own classes (:data:`~sb3_emmarl.common.trust.safe_pickle.ENV_STATE_MODULES`)
        and nothing else.

        :raise ValueError: if the state is not this environment's (other copies, a foreign or unsafe pickle)
        """
        saved = loads(state, "the training state's environment copies", class_modules=ENV_STATE_MODULES)
        if not isinstance(saved, dict) or set(saved) != {"venv", "copy_seeds", "never_reset", "reset_infos"} \
                or type(saved["venv"]) is not self._copies_type():
            held = type(saved.get("venv") if isinstance(saved, dict) else saved).__name__
            raise ValueError(f"the training state holds {held} copies, this environment {self._copies_type().__name__}:"
                             " build it as the run did")
        self._adopt_copies(saved["venv"])
        self._copy_seeds = saved["copy_seeds"]
        self._never_reset, self.reset_infos = saved["never_reset"], saved["reset_infos"]

    @property
    def checkpointable(self) -> bool:
        """Whether :meth:`get_state` can read the copies (not in SuperSuit's worker processes)."""
        return not self.multiprocess

    def _copies_type(self) -> type:
        """The class of :meth:`_portable_copies`'s object (what :meth:`set_state` accepts)."""
        return type(self.venv)

    def _portable_copies(self) -> Any:
        """The copies as one picklable object (for :meth:`get_state`)."""
        if self.multiprocess:
            raise ValueError("the reserve copies live in SuperSuit's worker processes and cannot be checkpointed; "
                             "use the batched path (the zoo's --vec-env batched or subproc) to resume runs exactly")
        return self.venv

    def _adopt_copies(self, copies: Any) -> None:
        """Carry on with the copies of a checkpoint (from :meth:`_portable_copies`)."""
        if self.multiprocess:
            raise ValueError("cannot restore reserve copies into SuperSuit's worker processes (num_cpus > 1)")
        self.venv.close()
        self.venv = copies

    # -------------------------------------------------------------- stepping
    def step_async(self, actions: np.ndarray) -> None:
        self.venv.step_async(actions)

    def step_wait(self) -> VecEnvStepReturn:
        observations, rewards, terminations, truncations, infos = self.venv.step_wait()
        terminations = np.asarray(terminations, dtype=bool)
        truncations = np.asarray(truncations, dtype=bool)
        dones = terminations | truncations
        infos = list(infos)
        for i in np.flatnonzero(dones):
            infos[i] = dict(infos[i])
            infos[i]["TimeLimit.truncated"] = bool(truncations[i] and not terminations[i])
        return observations, np.asarray(rewards, dtype=np.float32), dones, infos

    def close(self) -> None:
        self.venv.close()
        self.prototype.close()

    # -------------------------------------------------------------- access to the copies
    def _on_copies(self, indices: VecEnvIndices, kind: str, name: str, payload: tuple = ()) -> list[Any]:
        """:func:`apply_to_env` ``kind`` (get, set or call) on the reserve copy behind each index, once per index; with
        SuperSuit's worker processes ``get`` reads the local prototype and the others are refused."""
        copies = [i // self.agents_per_copy for i in self._get_indices(indices)]
        if self.multiprocess:
            if kind == "get":
                return [getattr(self.prototype, name) for _ in copies]
            raise NotImplementedError("the environments live in SuperSuit's worker processes (num_cpus > 1); get_attr "
                                      "reads the local prototype, set_attr and env_method need num_cpus <= 1 or the "
                                      "batched path")
        envs = self._par_envs()
        return [apply_to_env(envs[c], kind, name, payload) for c in copies]

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        """Attribute of the reserve copy behind each index (of the local prototype with SuperSuit's workers)."""
        return self._on_copies(indices, "get", attr_name)

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        """Set an attribute on the reserve copy behind each index."""
        self._on_copies(indices, "set", attr_name, (value,))

    def env_method(self, method_name: str, *method_args, indices: VecEnvIndices = None, **method_kwargs) -> list[Any]:
        """Call a method of the reserve copy behind each index (once per index)."""
        return self._on_copies(indices, "call", method_name, (method_args, method_kwargs))

    def env_is_wrapped(self, wrapper_class: type, indices: VecEnvIndices = None) -> list[bool]:
        return [False for _ in self._get_indices(indices)]

    def get_images(self) -> Sequence[np.ndarray | None]:
        return [self.venv.render()]

    def render(self, mode: str | None = None) -> np.ndarray | None:
        """Render reserve copy 0 (its ``render_mode`` is set when the environment is built)."""
        return self.venv.render()


def require_state(venv: VecEnv, who: str) -> Any:
    """Switch on the global state of a parameter-sharing vector environment (see
    :meth:`SharedPolicyVecEnv.enable_state`) and return its ``state_space``.

    :param venv: the vector environment (any wrappers around a :class:`SharedPolicyVecEnv`)
    :param who: the algorithm asking, for the message
    :raise ValueError: if ``venv`` is not a parameter-sharing vector environment over an environment with ``state()``
    """
    inner = venv.unwrapped if isinstance(venv, VecEnv) else None
    if not isinstance(inner, SharedPolicyVecEnv):
        raise ValueError(f"{who} needs the global state: give it the parameter-sharing vector environment "
                         f"(sb3_emmarl.common.vec_env.make_vec_env) of a PettingZoo environment with state(), "
                         f"got {type(venv).__name__}")
    inner.enable_state()
    return inner.state_space
