"""The reserve's batched parameter-sharing vector environment (:class:`ReserveVecEnv`): SharedPolicyVecEnv's data
through the environments' array API (``step_arrays``)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from pettingzoo import ParallelEnv
from stable_baselines3.common.vec_env.base_vec_env import VecEnvIndices

from sb3_emmarl.common.vec_env.shared_policy import SharedPolicyVecEnv
from sb3_emmarl.common.vec_env.workers import SplitCopies, SteppedCopies


class ReserveVecEnv(SharedPolicyVecEnv):
    """The fast parameter-sharing vector environment of the reserve: :class:`SharedPolicyVecEnv` (same entry order,
    seeds, observations, rewards, dones, infos, terminal observations and automatic resets, tested equal step for
    step) whose copies are stepped through the reserve's array API (``step_arrays``) instead of SuperSuit's
    per-agent dictionaries. With ``num_cpus > 1`` the copies are split into ``num_cpus`` groups stepped at the same
    time, one in this process and the others in worker processes; the data do not depend on the split, checkpoints
    (:meth:`get_state`) hold every copy, so they restore into any number of processes, and ``get_attr``,
    ``set_attr`` and ``env_method`` reach every copy wherever it lives.

    :param env_fn: builds one reserve (``reserve_v1.parallel_env`` with its arguments)
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
        return SteppedCopies([env_fn() for _ in range(self.n_copies)], action_space, self.with_state)

    def _worker_copies(self, env_fn: Callable[[], ParallelEnv], num_cpus: int, observation_space: Any,
                       action_space: Any) -> Any:
        self._check_batchable()
        return SplitCopies(env_fn, self.n_copies, num_cpus, action_space, self.with_state, self.poll_seconds)

    def _par_envs(self) -> list[ParallelEnv]:
        return list(self.venv.envs)

    def _on_copies(self, indices: VecEnvIndices, kind: str, name: str, payload: tuple = ()) -> list[Any]:
        if isinstance(self.venv, SplitCopies):  # the workers answer for their copies
            return self.venv.apply([i // self.agents_per_copy for i in self._get_indices(indices)], kind, name,
                                   payload)
        return super()._on_copies(indices, kind, name, payload)

    def _switch_state_on(self) -> None:
        self.venv.with_state = True

    @property
    def checkpointable(self) -> bool:
        """Always: worker processes hand their copies over."""
        return True

    def _copies_type(self) -> type:
        return SteppedCopies

    def _portable_copies(self) -> Any:
        return self.venv.portable()

    def _adopt_copies(self, copies: Any) -> None:
        if isinstance(self.venv, SplitCopies):
            self.venv.adopt(copies)
        else:
            self.venv.close()
            self.venv = copies
