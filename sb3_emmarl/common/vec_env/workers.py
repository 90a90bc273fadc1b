"""The batched path's copies: stepped in turn in this process (:class:`SteppedCopies`), or split over worker
processes that share their arrays and a doorbell in shared memory (:class:`SplitCopies`)."""

from __future__ import annotations

import multiprocessing as mp
import os
import pickle
import time
import traceback
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np
from gymnasium.vector.utils import CloudpickleWrapper
from pettingzoo import ParallelEnv

from sb3_emmarl.common.trust.pickling import dumps
from sb3_emmarl.common.vec_env.shared_policy import (
    COPY_SEEDS_KEY,
    LINKS_KEY,
    STATE_KEY,
    TERMINAL_LINKS_KEY,
    TERMINAL_STATE_KEY,
    apply_to_env,
)

if TYPE_CHECKING:
    from multiprocessing.context import ForkServerContext, SpawnContext

#: Seconds a waiting side of the split batched path (:class:`SplitCopies`) polls its doorbell in shared memory before
#: it blocks on its pipe: on this project's 2-core virtual machine a blocking pipe round trip took 263 us (each side
#: wakes a halted virtual CPU), a polled one 34 us. Long enough for a worker to wait through the policy's forward pass
#: between two steps; during a gradient update it then sleeps. No polling when the processes outnumber the CPUs.
POLL_SECONDS = 0.02



class SteppedCopies:
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
        assert actions is not None  # (step_async first)
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

    def portable(self) -> SteppedCopies:
        """Itself: the copies, picklable (see :meth:`SplitCopies.portable`)."""
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


def _copies_worker(pipe: Any, env_fn: Any, n_copies: int, action_space: Any, with_state: bool, *, buffers: tuple,
                   shape: tuple[int, int], start: int, bells: Any, index: int, poll_seconds: float) -> None:
    """A worker process of :class:`SplitCopies`: ``n_copies`` reserves stepped through :class:`SteppedCopies`,
    their observations, rewards and dones written to the shared ``buffers`` from entry ``start`` on, their infos
    (or the error that stopped them) sent back through ``pipe``. Its doorbells are row ``index`` of ``bells``
    (see :class:`SplitCopies`): it polls column 0 for commands, for up to ``poll_seconds``, and rings column 1."""
    bell = _bells(bells)[index]

    def send(message: tuple) -> None:
        pipe.send(message)
        bell[1] += 1

    try:
        copies = SteppedCopies([env_fn() for _ in range(n_copies)], action_space, with_state)
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
                reply = dumps(copies.envs)
            elif command == "set_envs":
                copies.close()
                copies.envs, copies.with_state = pickle.loads(data)  # (the parent's live objects: a file's were read
                # as data before, by the training-state loader)
            elif command == "apply":  # get_attr, set_attr, env_method on some of the copies
                kind, name, payload, indices = data
                try:
                    reply = [apply_to_env(copies.envs[i], kind, name, payload) for i in indices]
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
    """The doorbells of :class:`SplitCopies` in the shared ``buffer``: ``(workers, 2)`` int64 counts of the messages
    sent to each worker (column 0) and by it (column 1)."""
    return np.frombuffer(buffer, dtype=np.int64).reshape(-1, 2)


def _shared_views(buffers: tuple, shape: tuple[int, int]) -> tuple[np.ndarray, ...]:
    """Numpy views of :class:`SplitCopies`' shared buffers: observations ``shape``, rewards, terminations and
    truncations (one per vector entry)."""
    observations, rewards, terminations, truncations = buffers
    return (np.frombuffer(observations, dtype=np.float32).reshape(shape), np.frombuffer(rewards, dtype=np.float32),
            np.frombuffer(terminations, dtype=bool), np.frombuffer(truncations, dtype=bool))


class SplitCopies:
    """The reserve copies in ``n_groups`` groups stepped at the same time: the first in this process, each other by a
    worker process (a :class:`SteppedCopies` there) that writes its observations, rewards and dones into shared
    memory and sends its infos through a pipe. The data are those of one :class:`SteppedCopies` over every copy
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
        self.local = SteppedCopies([env_fn() for _ in range(sizes[0])], action_space, with_state)
        self.n, self.obs_dim, self.action_dtype = self.local.n, self.local.obs_dim, self.local.action_dtype
        self.action_space = action_space
        total = n_copies * self.n
        # As SB3's SubprocVecEnv: no fork of a process that holds torch's threads (scripts need the main guard)
        if "forkserver" in mp.get_all_start_methods():
            context: ForkServerContext | SpawnContext = mp.get_context("forkserver")
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
                    target=_copies_worker, daemon=True,
                    args=(child, CloudpickleWrapper(env_fn), sizes[g], action_space, with_state),
                    kwargs={"buffers": buffers, "shape": (total, self.obs_dim), "start": self.bounds[g] * self.n,
                            "bells": bells, "index": g - 1, "poll_seconds": self.poll_seconds},
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
        assert self._actions is not None  # (step_async first)
        self.local.step_async(self._actions[:local])
        infos = self.local.step_wait(tuple(array[:local] for array in out))[4]
        for g in self._groups():
            infos.extend(self._receive(g))
        for array, view in zip(out, self._shared):
            array[local:] = view[local:]
        observations, rewards, terminations, truncations = out
        return observations, rewards, terminations, truncations, infos

    def apply(self, copies: list[int], kind: str, name: str, payload: tuple) -> list[Any]:
        """:func:`apply_to_env` on each of ``copies`` (indices over every copy), wherever it lives, in that order."""
        results: list[Any] = [None] * len(copies)
        remote: dict[int, list[tuple[int, int]]] = {}
        for position, c in enumerate(copies):
            g = int(np.searchsorted(self.bounds, c, side="right")) - 1
            if g == 0:
                results[position] = apply_to_env(self.local.envs[c], kind, name, payload)
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

    def portable(self) -> SteppedCopies:
        """Every copy in one :class:`SteppedCopies` (a checkpoint then restores into any number of processes)."""
        return SteppedCopies(self.all_envs(), self.action_space, self.with_state)

    def adopt(self, copies: SteppedCopies) -> None:
        """Carry on with ``copies`` (every copy, e.g. from a checkpoint), spread over the groups as before."""
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
