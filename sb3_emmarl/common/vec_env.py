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

import multiprocessing as mp
import os
import pickle
import time
import traceback
from collections.abc import Callable, Sequence
from functools import partial
from typing import Any

import numpy as np
from gymnasium.vector.utils import CloudpickleWrapper
from pettingzoo import ParallelEnv
from stable_baselines3.common.vec_env import VecCheckNan, VecEnv, VecEnvWrapper, VecMonitor
from stable_baselines3.common.vec_env.base_vec_env import VecEnvIndices, VecEnvObs, VecEnvStepReturn
from supersuit.vector import ConcatVecEnv, MakeCPUAsyncConstructor, MarkovVectorEnv, ProcConcatVec

from wildlife_reserve import reserve_v0

#: The two parameter-sharing paths (see :func:`make_vec_env`).
VEC_ENV_TYPES = ("batched", "supersuit")
#: The zoo's --vec-env choices: the two parameter-sharing paths, rl-zoo's "dummy" (SuperSuit in this process, the name
#: rl-zoo gives its in-process choice) and "subproc" (the batched path over worker processes).
ZOO_VEC_ENVS = (*VEC_ENV_TYPES, "dummy", "subproc")

#: Key of the ``reset`` options that carries one seed per reserve copy.
COPY_SEEDS_KEY = "sb3_emmarl_copy_seeds"


#: Info keys of the global state (with ``with_state=True``): the state matching the returned observation (after an
#: automatic reset, the new episode's), and at an episode's end the state it ended in (as ``terminal_observation``).
STATE_KEY, TERMINAL_STATE_KEY = "state", "terminal_state"
#: Info keys of the links: the teammates whose messages reached an agent this step (the reserve's ``heard_from``; none
#: after an automatic reset), and at an episode's end the links of its last step (SuperSuit's automatic reset would
#: otherwise overwrite them with the new episode's empty ones).
LINKS_KEY, TERMINAL_LINKS_KEY = "heard_from", "terminal_heard_from"

#: Seconds a waiting side of the split batched path (:class:`_SplitCopies`) polls its doorbell in shared memory before
#: it blocks on its pipe: on this project's 2-core virtual machine a blocking pipe round trip took 263 us (each side
#: wakes a halted virtual CPU), a polled one 34 us. Long enough for a worker to wait through the policy's forward pass
#: between two steps; during a gradient update it then sleeps. No polling when the processes outnumber the CPUs.
POLL_SECONDS = 0.02


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
    return _ReserveCopy(env_fn(), copy_index, with_state)


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
            seed = int(np.random.SeedSequence().entropy % 2**31)
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
        from sb3_emmarl.common.checkpoints import dumps  # keeps the reserves' numpy views views

        return dumps({"venv": self._portable_copies(), "copy_seeds": self._copy_seeds,
                      "never_reset": self._never_reset, "reset_infos": self.reset_infos})

    def set_state(self, state: bytes) -> None:
        """Restore :meth:`get_state` (the copies then continue their episodes)."""
        saved = pickle.loads(state)
        self._adopt_copies(saved["venv"])
        self._copy_seeds = saved["copy_seeds"]
        self._never_reset, self.reset_infos = saved["never_reset"], saved["reset_infos"]

    @property
    def checkpointable(self) -> bool:
        """Whether :meth:`get_state` can read the copies (not in SuperSuit's worker processes)."""
        return not self.multiprocess

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
        """:func:`_apply` ``kind`` (get, set or call) on the reserve copy behind each index, once per index; with
        SuperSuit's worker processes ``get`` reads the local prototype and the others are refused."""
        copies = [i // self.agents_per_copy for i in self._get_indices(indices)]
        if self.multiprocess:
            if kind == "get":
                return [getattr(self.prototype, name) for _ in copies]
            raise NotImplementedError("the environments live in SuperSuit's worker processes (num_cpus > 1); get_attr "
                                      "reads the local prototype, set_attr and env_method need num_cpus <= 1 or the "
                                      "batched path")
        envs = self._par_envs()
        return [_apply(envs[c], kind, name, payload) for c in copies]

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


def _apply(env: Any, kind: str, name: str, payload: tuple) -> Any:
    """``getattr(env, name)`` (kind ``"get"``), ``setattr(env, name, *payload)`` (``"set"``) or
    ``getattr(env, name)(*args, **kwargs)`` with ``payload = (args, kwargs)`` (``"call"``)."""
    if kind == "get":
        return getattr(env, name)
    if kind == "set":
        return setattr(env, name, *payload)
    args, kwargs = payload
    return getattr(env, name)(*args, **kwargs)


class _SteppedCopies:
    """The reserve copies stepped in turn through :meth:`ReserveParallelEnv.step_arrays`, giving what SuperSuit's
    ``ConcatVecEnv`` of :class:`_ReserveCopy` gives (observations, rewards, terminations, truncations, infos,
    automatic resets), without its per-agent dictionaries and copies. Hand-written because SuperSuit's vector
    environments only speak PettingZoo's dictionaries; the dynamics are the reserve's own (``step`` is
    ``step_arrays`` plus the dictionaries)."""

    def __init__(self, envs: list[Any], action_space: Any, with_state: bool) -> None:
        self.envs = envs
        self.n = len(envs[0].possible_agents)
        self.obs_dim = int(envs[0].obs_dim)
        self.action_dtype = action_space.dtype  # SuperSuit casts the actions to the space's dtype: so do we
        self.with_state = with_state
        self._actions: np.ndarray | None = None

    def _state(self, env: Any) -> np.ndarray:
        return np.asarray(env.state(), dtype=np.float32)

    def _reset_copy(self, env: Any, seed: int | None, options: dict | None) -> tuple[np.ndarray, list[dict]]:
        observations, infos = env.reset(seed=seed, options=options)
        agents = env.possible_agents
        return np.stack([observations[a] for a in agents]), [infos.get(a, {}) for a in agents]

    def reset(self, options: dict | None = None) -> tuple[np.ndarray, list[dict]]:
        """Reset every copy; the options' :data:`COPY_SEEDS_KEY` gives each its seed (the rest goes to the reserves)."""
        options = dict(options or {})
        seeds = options.pop(COPY_SEEDS_KEY, None)
        observations = np.empty((len(self.envs) * self.n, self.obs_dim), dtype=np.float32)
        infos: list[dict] = []
        for c, env in enumerate(self.envs):
            copy_seed = None if seeds is None else seeds[c]
            observations[c * self.n:(c + 1) * self.n], copy_infos = self._reset_copy(env, copy_seed, options or None)
            if self.with_state:
                state = self._state(env)
                copy_infos = [{**info, STATE_KEY: state} for info in copy_infos]
            infos.extend(copy_infos)
        return observations, infos

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions).astype(self.action_dtype, copy=False)

    def step_wait(self, out: tuple[np.ndarray, ...] | None = None
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, list[dict]]:
        """Step every copy (see :meth:`step_async`).

        :param out: arrays to fill instead of new ones: observations, rewards, terminations, truncations
        """
        actions, n = self._actions, self.n
        total = len(self.envs) * n
        if out is None:
            out = (np.empty((total, self.obs_dim), dtype=np.float32), np.empty(total, dtype=np.float32),
                   np.empty(total, dtype=bool), np.empty(total, dtype=bool))
        observations, rewards, terminations, truncations = out
        terminations[:], truncations[:] = False, False
        infos: list[dict] = []
        for c, env in enumerate(self.envs):
            lo, hi = c * n, (c + 1) * n
            obs, reward, terminated, truncated, info, heard = env.step_arrays(actions[lo:hi], observations[lo:hi])
            rewards[lo:hi] = reward
            if not (terminated or truncated):
                if self.with_state:
                    info = {**info, STATE_KEY: self._state(env)}
                for senders in heard:  # (copy and set: cheaper than {**info, ...} per entry)
                    entry = info.copy()
                    entry[LINKS_KEY] = senders
                    infos.append(entry)
                continue
            terminations[lo:hi], truncations[lo:hi] = terminated, truncated
            obs = obs.copy()  # the terminal observations: the reset's go where they were written
            ended = {TERMINAL_STATE_KEY: self._state(env)} if self.with_state else {}
            observations[lo:hi], reset_infos = self._reset_copy(env, None, None)  # an automatic reset, unseeded
            if self.with_state:
                ended[STATE_KEY] = self._state(env)  # the new episode's, one array for the copy (as SuperSuit's)
            for k, (senders, reset_info) in enumerate(zip(heard, reset_infos)):
                new = {key: value for key, value in reset_info.items() if key != LINKS_KEY}
                infos.append({**info, "terminal_observation": obs[k], **new, **ended,
                              TERMINAL_LINKS_KEY: senders, LINKS_KEY: ()})
        return observations, rewards, terminations, truncations, infos

    def render(self) -> Any:
        return self.envs[0].render()

    def close(self) -> None:
        for env in self.envs:
            env.close()

    def portable(self) -> _SteppedCopies:
        """Itself: the copies, picklable (see :meth:`_SplitCopies.portable`)."""
        return self


_yield = getattr(os, "sched_yield", lambda: None)


def _receive_polled(pipe: Any, bell: np.ndarray, side: int, received: int, seconds: float) -> Any:
    """``pipe.recv()``, after polling for up to ``seconds`` until the doorbell ``bell[side]`` (the count of messages the
    other side sent, rung after each send) passes ``received`` (the messages read so far). The doorbell only tells
    when to read: the pipe carries every message, and a reader that stopped polling blocks on it as before."""
    if seconds > 0 and bell[side] <= received:
        deadline = time.perf_counter() + seconds
        while bell[side] <= received and time.perf_counter() < deadline:
            _yield()  # other processes ready to run get the CPU; alone, this returns at once
    return pipe.recv()


def _copies_worker(pipe: Any, env_fn: Any, n_copies: int, action_space: Any, with_state: bool, buffers: tuple,
                   shape: tuple[int, int], start: int, bells: Any, index: int, poll_seconds: float) -> None:
    """A worker process of :class:`_SplitCopies`: ``n_copies`` reserves stepped through :class:`_SteppedCopies`,
    their observations, rewards and dones written to the shared ``buffers`` from entry ``start`` on, their infos
    (or the error that stopped them) sent back through ``pipe``. Its doorbells are row ``index`` of ``bells``
    (see :class:`_SplitCopies`): it polls column 0 for commands, for up to ``poll_seconds``, and rings column 1."""
    bell = _bells(bells)[index]

    def send(message: tuple) -> None:
        pipe.send(message)
        bell[1] += 1

    try:
        copies = _SteppedCopies([env_fn() for _ in range(n_copies)], action_space, with_state)
        entries = slice(start, start + n_copies * copies.n)
        out = tuple(view[entries] for view in _shared_views(buffers, shape))
        send(("ok", None))
        received = 0
        while True:
            command, data = _receive_polled(pipe, bell, 0, received, poll_seconds)
            received += 1
            reply: Any = None
            if command == "step":
                copies.step_async(data)
                reply = copies.step_wait(out)[4]
            elif command == "reset":
                out[0][:], reply = copies.reset(data)
            elif command == "state_on":
                copies.with_state = True
            elif command == "get_envs":
                from sb3_emmarl.common.checkpoints import dumps

                reply = dumps(copies.envs)
            elif command == "set_envs":
                copies.close()
                copies.envs, copies.with_state = pickle.loads(data)
            elif command == "apply":  # get_attr, set_attr, env_method on some of the copies
                kind, name, payload, indices = data
                try:
                    reply = [_apply(copies.envs[i], kind, name, payload) for i in indices]
                except Exception as error:  # the caller's to handle (an AttributeError, say); the copies carry on
                    send(("raise", error))
                    continue
            elif command == "render":
                reply = copies.render()
            elif command == "close":
                copies.close()
                send(("ok", None))
                return
            send(("ok", reply))
    except KeyboardInterrupt:  # Ctrl-C reaches the whole process group: the main process reports it
        return
    except BaseException:  # anything that stops the worker goes back to the main process
        try:
            send(("error", traceback.format_exc()))
        except (BrokenPipeError, EOFError, OSError):
            pass


def _bells(buffer: Any) -> np.ndarray:
    """The doorbells of :class:`_SplitCopies` in the shared ``buffer``: ``(workers, 2)`` int64 counts of the messages
    sent to each worker (column 0) and by it (column 1)."""
    return np.frombuffer(buffer, dtype=np.int64).reshape(-1, 2)


def _shared_views(buffers: tuple, shape: tuple[int, int]) -> tuple[np.ndarray, ...]:
    """Numpy views of :class:`_SplitCopies`' shared buffers: observations ``shape``, rewards, terminations and
    truncations (one per vector entry)."""
    observations, rewards, terminations, truncations = buffers
    return (np.frombuffer(observations, dtype=np.float32).reshape(shape), np.frombuffer(rewards, dtype=np.float32),
            np.frombuffer(terminations, dtype=bool), np.frombuffer(truncations, dtype=bool))


class _SplitCopies:
    """The reserve copies in ``n_groups`` groups stepped at the same time: the first in this process, each other by a
    worker process (a :class:`_SteppedCopies` there) that writes its observations, rewards and dones into shared
    memory and sends its infos through a pipe. The data are those of one :class:`_SteppedCopies` over every copy
    (each copy draws from its own generators). Hand-written because SuperSuit's ``ProcConcatVec`` writes the
    observations entry by entry and deep-copies every info dict (together more than the stepping itself at 10
    UAVs) and cannot hand its copies to a checkpoint.

    Beside each pipe, two doorbells in shared memory count the messages each side sent; a side that waits for a
    message polls its doorbell for up to :data:`POLL_SECONDS` before it blocks on the pipe (a hand-off without the
    wake-up of a sleeping process; SB3's ``SubprocVecEnv`` blocks).

    :param env_fn: builds one reserve (picklable with cloudpickle: the workers are started as SB3's
        ``SubprocVecEnv`` starts them, with ``forkserver`` or ``spawn``, so scripts need ``if __name__ == "__main__":``)
    :param n_copies: number of copies
    :param n_groups: number of groups (this process and ``n_groups - 1`` workers), at most ``n_copies``
    :param action_space: one agent's action space
    :param with_state: the global state in the infos
    :param poll_seconds: how long a waiting side polls its doorbell (0: block on the pipe at once, as SB3's
        ``SubprocVecEnv``); None: :data:`POLL_SECONDS`, or 0 when the processes outnumber the CPUs
    """

    def __init__(self, env_fn: Callable[[], ParallelEnv], n_copies: int, n_groups: int, action_space: Any,
                 with_state: bool, poll_seconds: float | None = None) -> None:
        sizes = [len(group) for group in np.array_split(np.arange(n_copies), n_groups)]
        self.bounds = np.cumsum([0, *sizes]).tolist()  # copies [bounds[g], bounds[g + 1]) form group g
        self.local = _SteppedCopies([env_fn() for _ in range(sizes[0])], action_space, with_state)
        self.n, self.obs_dim, self.action_dtype = self.local.n, self.local.obs_dim, self.local.action_dtype
        self.action_space = action_space
        total = n_copies * self.n
        # As SB3's SubprocVecEnv: no fork of a process that holds torch's threads (scripts need the main guard)
        if "forkserver" in mp.get_all_start_methods():
            context = mp.get_context("forkserver")
            # Workers then start in milliseconds, not seconds of imports; added to whatever the program preloads.
            from multiprocessing import forkserver

            preload = list(getattr(forkserver._forkserver, "_preload_modules", None) or [])
            if __name__ not in preload:
                context.set_forkserver_preload([*preload, __name__])
        else:
            context = mp.get_context("spawn")
        buffers = (context.RawArray("b", total * self.obs_dim * 4), context.RawArray("b", total * 4),
                   context.RawArray("b", total), context.RawArray("b", total))
        self._shared = _shared_views(buffers, (total, self.obs_dim))
        bells = context.RawArray("b", 16 * max(n_groups - 1, 1))
        self._bells = _bells(bells)
        self._received = [0] * (n_groups - 1)  # the replies read from each worker
        if poll_seconds is None:
            cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
            poll_seconds = POLL_SECONDS if n_groups <= cpus else 0.0  # polling beside a busy CPU would slow it
        self.poll_seconds = float(poll_seconds)
        self.pipes: list[Any] = []
        self.processes: list[Any] = []
        try:
            for g in range(1, n_groups):
                parent, child = context.Pipe()
                process = context.Process(
                    target=_copies_worker, daemon=True, args=(child, CloudpickleWrapper(env_fn), sizes[g], action_space,
                                                              with_state, buffers, (total, self.obs_dim),
                                                              self.bounds[g] * self.n, bells, g - 1,
                                                              self.poll_seconds),
                    name=f"reserve-copies-{self.bounds[g]}-{self.bounds[g + 1] - 1}")
                self.pipes.append(parent)
                self.processes.append(process)
                process.start()
                child.close()
            for g in self._groups():
                self._receive(g)
        except BaseException:
            self.close()
            raise
        self._actions: np.ndarray | None = None

    @property
    def with_state(self) -> bool:
        return self.local.with_state

    @with_state.setter
    def with_state(self, value: bool) -> None:
        if value:
            self._broadcast("state_on")
        self.local.with_state = value

    def _died(self, g: int) -> RuntimeError:
        process = self.processes[g - 1]
        process.join(1.0)
        return RuntimeError(f"the worker process of reserve copies {self.bounds[g]}-{self.bounds[g + 1] - 1} died "
                            f"(exit code {process.exitcode})")

    def _send(self, g: int, command: str, data: Any = None) -> None:
        """Send a command to group ``g``'s worker; a :class:`RuntimeError` naming its copies if it died."""
        try:
            self.pipes[g - 1].send((command, data))
        except OSError as error:  # BrokenPipeError among them
            raise self._died(g) from error
        self._bells[g - 1, 0] += 1

    def _receive(self, g: int) -> Any:
        """The reply of group ``g``'s worker; a :class:`RuntimeError` naming its copies if it failed or died."""
        try:
            status, reply = _receive_polled(self.pipes[g - 1], self._bells[g - 1], 1, self._received[g - 1],
                                            self.poll_seconds)
        except (EOFError, OSError) as error:
            raise self._died(g) from error
        self._received[g - 1] += 1
        if status == "error":
            raise RuntimeError(f"the worker process of reserve copies {self.bounds[g]}-{self.bounds[g + 1] - 1} "
                               f"failed:\n{reply}")
        if status == "raise":
            raise reply
        return reply

    def _groups(self) -> range:
        """The groups stepped by workers."""
        return range(1, len(self.bounds) - 1)

    def _broadcast(self, command: str, data: Any = None) -> list[Any]:
        for g in self._groups():
            self._send(g, command, data)
        return [self._receive(g) for g in self._groups()]

    def reset(self, options: dict | None = None) -> tuple[np.ndarray, list[dict]]:
        """Reset every copy (each group gets its copies' seeds)."""
        options = dict(options or {})
        seeds = options.pop(COPY_SEEDS_KEY, None)
        for g in self._groups():
            group = dict(options)
            if seeds is not None:
                group[COPY_SEEDS_KEY] = seeds[self.bounds[g]:self.bounds[g + 1]]
            self._send(g, "reset", group)
        if seeds is not None:
            options[COPY_SEEDS_KEY] = seeds[:self.bounds[1]]
        local_observations, infos = self.local.reset(options)
        for g in self._groups():
            infos.extend(self._receive(g))
        observations = self._shared[0].copy()
        observations[:len(local_observations)] = local_observations
        return observations, infos

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = actions = np.asarray(actions).astype(self.action_dtype, copy=False)
        for g in self._groups():
            self._send(g, "step", actions[self.bounds[g] * self.n:self.bounds[g + 1] * self.n])

    def step_wait(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, list[dict]]:
        """This process steps its copies while the workers step theirs."""
        local = self.bounds[1] * self.n
        out = tuple(np.empty_like(view) for view in self._shared)
        self.local.step_async(self._actions[:local])
        infos = self.local.step_wait(tuple(array[:local] for array in out))[4]
        for g in self._groups():
            infos.extend(self._receive(g))
        for array, view in zip(out, self._shared):
            array[local:] = view[local:]
        return (*out, infos)

    def apply(self, copies: list[int], kind: str, name: str, payload: tuple) -> list[Any]:
        """:func:`_apply` on each of ``copies`` (indices over every copy), wherever it lives, in that order."""
        results: list[Any] = [None] * len(copies)
        remote: dict[int, list[tuple[int, int]]] = {}
        for position, c in enumerate(copies):
            g = int(np.searchsorted(self.bounds, c, side="right")) - 1
            if g == 0:
                results[position] = _apply(self.local.envs[c], kind, name, payload)
            else:
                remote.setdefault(g, []).append((position, c - self.bounds[g]))
        for g, items in remote.items():
            self._send(g, "apply", (kind, name, payload, [index for _, index in items]))
        raised: BaseException | None = None
        for g, items in remote.items():  # every reply is read, so that none is left in a pipe
            try:
                values = self._receive(g)
            except Exception as error:
                raised = raised or error
                continue
            for (position, _), value in zip(items, values):
                results[position] = value
        if raised is not None:
            raise raised
        return results

    def all_envs(self) -> list[Any]:
        """Every copy, those of the workers as pickled copies."""
        return self.local.envs + [env for reply in self._broadcast("get_envs") for env in pickle.loads(reply)]

    def portable(self) -> _SteppedCopies:
        """Every copy in one :class:`_SteppedCopies` (a checkpoint then restores into any number of processes)."""
        return _SteppedCopies(self.all_envs(), self.action_space, self.with_state)

    def adopt(self, copies: _SteppedCopies) -> None:
        """Carry on with ``copies`` (every copy, e.g. from a checkpoint), spread over the groups as before."""
        from sb3_emmarl.common.checkpoints import dumps

        envs = copies.envs
        if len(envs) != self.bounds[-1]:
            raise ValueError(f"the checkpoint holds {len(envs)} reserve copies, this environment {self.bounds[-1]}")
        for g in self._groups():
            self._send(g, "set_envs", dumps((envs[self.bounds[g]:self.bounds[g + 1]], copies.with_state)))
        self.local.close()
        self.local.envs, self.local.with_state = envs[:self.bounds[1]], copies.with_state
        for g in self._groups():
            self._receive(g)

    def render(self) -> Any:
        return self.local.render()

    def close(self) -> None:
        """Close the copies and stop the workers (killed if they do not stop within 10 s)."""
        for pipe, process, bell in zip(self.pipes, self.processes, self._bells):
            try:
                if process.is_alive():
                    pipe.send(("close", None))
                    bell[0] += 1
                    if pipe.poll(10.0):
                        pipe.recv()
            except (BrokenPipeError, EOFError, OSError):
                pass
            if process.pid is not None:  # started
                process.join(1.0)
                if process.is_alive():
                    process.kill()
            pipe.close()
        self.pipes, self.processes = [], []
        self.local.close()


class ReserveVecEnv(SharedPolicyVecEnv):
    """The fast parameter-sharing vector environment of the reserve: :class:`SharedPolicyVecEnv` (same entry order,
    seeds, observations, rewards, dones, infos, terminal observations and automatic resets, tested equal step for
    step) whose copies are stepped through the reserve's array API (``step_arrays``) instead of SuperSuit's
    per-agent dictionaries. With ``num_cpus > 1`` the copies are split into ``num_cpus`` groups stepped at the same
    time, one in this process and the others in worker processes; the data do not depend on the split, checkpoints
    (:meth:`get_state`) hold every copy, so they restore into any number of processes, and ``get_attr``,
    ``set_attr`` and ``env_method`` reach every copy wherever it lives.

    :param env_fn: builds one reserve (``reserve_v0.parallel_env`` with its arguments)
    :param n_copies: number of independent copies
    :param with_state: the global state in the infos (see :class:`SharedPolicyVecEnv`)
    :param num_cpus: processes stepping the copies (0 or 1: this one alone; at most one per copy)
    :param poll_seconds: with ``num_cpus > 1``, how long this process and the workers poll for each other's messages
        in shared memory before they block on their pipes (0: block at once); None: :data:`POLL_SECONDS`, or 0 when
        the processes outnumber the CPUs
    """

    def __init__(self, env_fn: Callable[[], ParallelEnv], n_copies: int = 1, with_state: bool = False,
                 num_cpus: int = 0, poll_seconds: float | None = None) -> None:
        if poll_seconds is not None and (isinstance(poll_seconds, bool) or not isinstance(poll_seconds, (int, float))
                                         or not 0 <= poll_seconds < float("inf")):
            raise ValueError(f"poll_seconds must be None or a finite number >= 0, got {poll_seconds!r}")
        self.poll_seconds = poll_seconds
        super().__init__(env_fn, n_copies=n_copies, num_cpus=num_cpus, with_state=with_state)

    def _check_batchable(self) -> None:
        if not callable(getattr(self.prototype, "step_arrays", None)):
            raise ValueError(f"the batched vector environment needs the reserve's step_arrays(); "
                             f"{type(self.prototype).__name__} has none: use vec_env_type='supersuit'")

    def _local_copies(self, env_fn: Callable[[], ParallelEnv], observation_space: Any, action_space: Any) -> Any:
        self._check_batchable()
        return _SteppedCopies([env_fn() for _ in range(self.n_copies)], action_space, self.with_state)

    def _worker_copies(self, env_fn: Callable[[], ParallelEnv], num_cpus: int, observation_space: Any,
                       action_space: Any) -> Any:
        self._check_batchable()
        return _SplitCopies(env_fn, self.n_copies, num_cpus, action_space, self.with_state, self.poll_seconds)

    def _par_envs(self) -> list[ParallelEnv]:
        return list(self.venv.envs)

    def _on_copies(self, indices: VecEnvIndices, kind: str, name: str, payload: tuple = ()) -> list[Any]:
        if isinstance(self.venv, _SplitCopies):  # the workers answer for their copies
            return self.venv.apply([i // self.agents_per_copy for i in self._get_indices(indices)], kind, name,
                                   payload)
        return super()._on_copies(indices, kind, name, payload)

    def _switch_state_on(self) -> None:
        self.venv.with_state = True

    @property
    def checkpointable(self) -> bool:
        """Always: worker processes hand their copies over."""
        return True

    def _portable_copies(self) -> Any:
        return self.venv.portable()

    def _adopt_copies(self, copies: Any) -> None:
        if isinstance(self.venv, _SplitCopies):
            self.venv.adopt(copies)
        else:
            self.venv.close()
            self.venv = copies


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


class FiniteCheck(VecCheckNan):
    """SB3's ``VecCheckNan`` that stops at the first NaN or inf with a short message naming the quantity
    (observations, rewards or actions), the step of the vector environment, the entries and where it came from.

    :param venv: the vector environment to guard
    """

    SOURCES = {"reset": "the environment, at reset", "step_wait": "the environment",
               "step_async": "the policy (the actions it chose)"}

    def __init__(self, venv: VecEnv) -> None:
        super().__init__(venv, raise_exception=True, check_inf=True)
        self.n_steps = 0

    def step_wait(self) -> VecEnvStepReturn:
        self.n_steps += 1
        return super().step_wait()

    def _check_val(self, event: str, **kwargs: Any) -> None:
        for name, value in kwargs.items():
            parts = value.items() if isinstance(value, dict) else [("", value)]
            for key, part in parts:
                array = np.asarray(part)
                if array.dtype.kind not in "fc":
                    continue
                bad = ~np.isfinite(array)
                if bad.any():
                    kinds = sorted({"nan" if np.isnan(v) else "inf" for v in array[bad].ravel()[:100]})
                    entries = np.unique(np.nonzero(bad)[0])[:10].tolist()
                    raise ValueError(f"non-finite {name}{'.' + key if key else ''} ({' and '.join(kinds)}) at step "
                                     f"{self.n_steps} of the vector environment, entries {entries}; they come from "
                                     f"{self.SOURCES[event]}")


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
    num_cpus: int = 0,
    monitor_dir: str | None = None,
    vec_env_wrapper: Callable[[VecEnv], VecEnvWrapper] | None = None,
    env_fn: Callable[..., ParallelEnv] = reserve_v0.parallel_env,
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
        vec_env_type = "batched" if env_fn is reserve_v0.parallel_env else "supersuit"
    if vec_env_type == "batched":
        venv: VecEnv = ReserveVecEnv(build, n_copies=n_copies, with_state=with_state, num_cpus=num_cpus)
    else:
        venv = SharedPolicyVecEnv(build, n_copies=n_copies, num_cpus=num_cpus, with_state=with_state)
    venv = VecMonitor(venv, filename=monitor_dir)
    if vec_env_wrapper is not None:
        venv = vec_env_wrapper(venv)
    venv.seed(seed)
    return venv
