"""The true hidden mode as part of the observation: what a policy that is *told* the mode sees.

A policy told the mode is the upper bound every latent method is measured against (how much knowing
the mode pays). :class:`ModeObservationWrapper` appends a one-hot of the episode's true mode to every
entry's observation, read from the reserve's infos (``infos[i]["mode"]``), which no UAV observes.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from stable_baselines3.common.vec_env import VecEnv

from sb3_emmarl.common.appended.wrapping import TERMINAL_OBSERVATION, AppendingVecEnvWrapper, ensure_wrapped
from sb3_emmarl.common.trust.validation import boolean
from wildlife_reserve.reserve.modes import N_MODES


class ModeObservationWrapper(AppendingVecEnvWrapper):
    """Appends a one-hot of the true hidden mode (``n_modes`` floats) to each entry's observation.

    The mode comes from the infos: the reset infos of the innermost vector environment, and each step's
    ``infos[i]["mode"]``, which after an automatic reset is already the new episode's mode (SuperSuit
    merges the reset's infos into the last step's). The terminal observation of a finished episode gets
    that episode's mode, from ``infos[i]["metrics"]["mode"]``.

    With ``relabel``, the one-hot is that of ``relabel[mode]`` instead: a policy told a wrong mode. A policy that
    acts on the mode scores less when told a wrong one, and one that ignores it scores the same; this tells whether
    a told policy uses what it is told, run by run (``benchmarks/mode_value.py``'s mode-use table).

    With ``random_labels``, the one-hot is that of a label drawn uniformly at random at each episode's start,
    independently of the mode, and shared by the entries of one reserve copy (``agents_per_copy`` of the vector
    environment; 1 if it has none), as the mode is: an input of the same form, constant over an episode, that
    carries no information. A policy trained on it measures what such an input costs PPO by itself, so that told
    PPO against it measures what the mode's information is worth (``benchmarks/mode_value.py``'s control).

    :param venv: a parameter-sharing vector environment of the reserve (flat ``Box`` observations)
    :param n_modes: number of modes (the one-hot's length)
    :param relabel: the mode told for each true mode (``n_modes`` ints in ``[0, n_modes)``, e.g.
        ``[next_strategy(m) for m in range(N_MODES)]``); None tells the true mode
    :param random_labels: tell a random label per episode instead of the mode (not with ``relabel``)
    :param seed: seed of the random labels (``seed()`` seeds them again, as SB3 seeds its environment)
    """

    def __init__(self, venv: VecEnv, n_modes: int = N_MODES, relabel: Sequence[int] | None = None,
                 random_labels: bool = False, seed: int = 0) -> None:
        space = venv.observation_space
        if isinstance(n_modes, bool) or not isinstance(n_modes, (int, np.integer)) or n_modes < 1:
            raise ValueError(f"n_modes must be an int >= 1, got {n_modes!r}")
        self.n_modes = int(n_modes)
        self.relabel = None if relabel is None else self._check_relabel(relabel)
        self.random_labels = boolean()("random_labels", random_labels)
        if self.random_labels and relabel is not None:
            raise ValueError("give relabel or random_labels, not both: a random label replaces every mode")
        dtype = getattr(space, "dtype", np.float32)
        super().__init__(venv, *self._bounds(dtype), dtype)
        self.modes = np.zeros(venv.num_envs, dtype=np.int64)
        self.per_copy = max(1, int(getattr(venv, "agents_per_copy", 1)))
        self.labels = np.zeros(venv.num_envs, dtype=np.int64)  # with random_labels: each entry's label this episode
        self._label_rng = np.random.default_rng(seed)

    def seed(self, seed: int | None = None) -> Sequence[int | None]:
        """Seed the environment, and the random labels with the same seed (when it is not None)."""
        if seed is not None:
            self._label_rng = np.random.default_rng(seed)
        return self.venv.seed(seed)

    def _draw_labels(self, entries: np.ndarray) -> None:
        """New random labels for the copies of ``entries`` (one per copy, shared by its entries)."""
        for copy in np.unique(entries // self.per_copy):
            self.labels[copy * self.per_copy:(copy + 1) * self.per_copy] = self._label_rng.integers(self.n_modes)

    def _check_relabel(self, relabel: Sequence[int]) -> np.ndarray:
        values = list(relabel) if not isinstance(relabel, (str, bytes, dict)) else None
        if (values is None or len(values) != self.n_modes
                or not all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) for v in values)
                or not all(0 <= v < self.n_modes for v in values)):
            raise ValueError(f"relabel must be {self.n_modes} ints in [0, {self.n_modes - 1}] (the mode told for each "
                             f"true mode), got {relabel!r}")
        return np.asarray(values, dtype=np.int64)

    def _bounds(self, dtype: Any) -> tuple[np.ndarray, np.ndarray]:
        """The bounds of what :meth:`_append` appends: the one-hot's (a subclass that appends another form of the told
        mode gives its own)."""
        return np.zeros(self.n_modes, dtype=dtype), np.ones(self.n_modes, dtype=dtype)

    def _append(self, observations: np.ndarray, told: np.ndarray) -> np.ndarray:
        """What is appended to each row of ``observations`` told the mode ``told``: its one-hot. A subclass may append
        another form of the told mode (for example a direction read from the observations); which mode is told (the
        true one, ``relabel``'s, a random label) and when (resets, steps, terminal observations) stays this class's."""
        return np.eye(self.n_modes, dtype=self.observation_space.dtype)[told]

    def _told(self, observations: np.ndarray, modes: np.ndarray, labels: np.ndarray | None = None) -> np.ndarray:
        """:meth:`_append` of the mode told for each row whose true mode is ``modes``."""
        if modes.min() < 0 or modes.max() >= self.n_modes:
            raise ValueError(f"modes must be in [0, {self.n_modes - 1}], got {modes}")
        if self.random_labels:
            told = self.labels if labels is None else labels
        else:
            told = modes if self.relabel is None else self.relabel[modes]
        return self._append(observations, told)

    def _read_modes(self, infos: list[dict[str, Any]]) -> np.ndarray:
        try:
            return np.array([info["mode"] for info in infos], dtype=np.int64)
        except KeyError as error:
            raise KeyError("ModeObservationWrapper needs infos[i]['mode'] (the wildlife reserve's infos)") from error

    def _reset_extra(self, observations: np.ndarray) -> np.ndarray:
        self.modes = self._read_modes(self.venv.unwrapped.reset_infos)
        if self.random_labels:
            self._draw_labels(np.arange(self.num_envs))
        return self._told(observations, self.modes)

    def _step_extra(self, observations: np.ndarray, dones: np.ndarray, infos: list[dict[str, Any]]
                    ) -> tuple[np.ndarray, dict[int, np.ndarray]]:
        done = np.flatnonzero(dones)
        terminal = {int(i): self._told(np.asarray(infos[i][TERMINAL_OBSERVATION])[None],
                                       np.array([infos[i]["metrics"]["mode"]]), self.labels[i:i + 1])[0]
                    for i in done if TERMINAL_OBSERVATION in infos[i]}  # (the finished episode's mode)
        if self.random_labels and len(done):
            self._draw_labels(done)
        self.modes = self._read_modes(infos)
        return self._told(observations, self.modes), terminal


def wrap_with_mode(env: Any, verbose: int = 0, random_labels: bool = False) -> VecEnv:
    """``env`` as a vector environment whose observations end with the true mode, or with a random label per episode
    (``random_labels``; see :class:`ModeObservationWrapper`).

    A vector environment already wrapped is kept if its wrapper tells what is asked (the mode, or random labels), and
    refused otherwise: a model built to be told one would silently be trained or evaluated on the other.
    """
    told = {True: "a random label per episode", False: "the mode"}

    def mismatch(wrapper: ModeObservationWrapper) -> str | None:
        if wrapper.random_labels == bool(random_labels):
            return None
        return (f"the environment is already wrapped to tell {told[wrapper.random_labels]}, but "
                f"random_labels={bool(random_labels)} asks for {told[bool(random_labels)]}: give the "
                f"environment without its ModeObservationWrapper, or one that tells what is asked")

    return ensure_wrapped(env, ModeObservationWrapper,
                          lambda venv: ModeObservationWrapper(venv, random_labels=random_labels), mismatch, verbose)
