"""The joint replay buffer: SB3's per-entry transitions regrouped into the team transitions QMIX and VDN learn from.

SB3's ``OffPolicyAlgorithm`` stores one vector step at a time with ``add(obs, next_obs, action, reward, done,
infos)``, for all ``n_envs`` entries at once, after substituting each finished entry's ``terminal_observation``.
On the parameter-sharing vector environment (:func:`~sb3_emmarl.common.vec_env.make_vec_env`) entry ``i`` is agent
``i % n_agents`` of copy ``i // n_agents``, so one stored row of ``n_envs`` entries is ``n_copies`` joint
transitions of ``n_agents`` agents each. :class:`JointReplayBuffer` keeps SB3's per-entry arrays (and its
``add``), adds one global state per copy and row (and the next one), and samples ``(row, copy)`` pairs: whole
team transitions, never single agents.

The global states come from the infos (``make_vec_env(..., with_state=True)`` puts them there): the next state
is ``infos[i]["state"]``, or ``infos[i]["terminal_state"]`` at an episode's end (the new episode's state then is
``infos[i]["state"]``, as the new observation is the returned one); the state the observations were made in is
the one the previous ``add`` read, or after a reset the one :meth:`JointReplayBuffer.observe_reset` read from
the reset infos.

The team reward is the mean of the copy's agents' rewards (the team reward itself on the reserve, where every agent
gets it with the default ``shaping=0``); a copy's transition is terminal if an agent's episode terminated (not
truncated: after a truncation the target bootstraps from the terminal state, as SB3's ``TimeLimit.truncated``).

:class:`RecurrentJointReplayBuffer` (QMIX's and VDN's ``recurrent=True``) also keeps each row's episode-start flags
and the hidden states the agent network acted from (``rnn_hidden_dim`` floats per agent-transition), and samples
stretches of ``sequence_length`` consecutive rows of one copy that never cross the write position.
"""

from __future__ import annotations

from typing import Any, NamedTuple, cast

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.vec_env import VecNormalize

from sb3_emmarl.common.vec_env import STATE_KEY, TERMINAL_STATE_KEY


class JointReplaySamples(NamedTuple):
    """A batch of ``batch_size`` team transitions of ``n_agents`` agents."""

    observations: th.Tensor  # (batch, n_agents, *obs_shape)
    actions: th.Tensor  # (batch, n_agents), long
    next_observations: th.Tensor  # (batch, n_agents, *obs_shape)
    dones: th.Tensor  # (batch,): 1 if the episode terminated (a truncation bootstraps)
    rewards: th.Tensor  # (batch,): the team reward (the mean of the agents')
    states: th.Tensor | None  # (batch, *state_shape), or None without states
    next_states: th.Tensor | None  # (batch, *state_shape): the terminal state at an episode's end


class JointReplayBuffer(ReplayBuffer):
    """SB3's ``ReplayBuffer`` over the parameter-sharing vector environment, sampled as team transitions.

    ``buffer_size`` counts agent-transitions, as SB3's (rows of ``n_envs`` entries: ``buffer_size // n_envs`` rows);
    ``sample(batch_size)`` returns ``batch_size`` team transitions (:class:`JointReplaySamples`).

    :param buffer_size: agent-transitions kept
    :param observation_space: one agent's observation space
    :param action_space: one agent's action space (``Discrete``)
    :param device: torch device of the samples
    :param n_envs: vector entries (``n_copies * n_agents``)
    :param optimize_memory_usage: must be False (the next observations are kept)
    :param handle_timeout_termination: a truncated episode's last transition bootstraps (SB3's option)
    :param n_agents: agents per copy (``venv.unwrapped.agents_per_copy``)
    :param state_shape: shape of the global state; None keeps no state (VDN)
    """

    def __init__(self, buffer_size: int, observation_space: spaces.Space, action_space: spaces.Space,
                 device: th.device | str = "auto", n_envs: int = 1, optimize_memory_usage: bool = False,
                 handle_timeout_termination: bool = True, n_agents: int = 1,
                 state_shape: tuple[int, ...] | None = None) -> None:
        if isinstance(n_agents, bool) or not isinstance(n_agents, (int, np.integer)) or n_agents < 1:
            raise ValueError(f"n_agents must be an int >= 1, got {n_agents!r}")
        if n_envs % n_agents:
            raise ValueError(f"the vector environment's {n_envs} entries are not whole teams of n_agents={n_agents}")
        if optimize_memory_usage:
            raise ValueError("optimize_memory_usage=True is not supported by the joint replay buffer (it keeps the next "
                             "observations and states)")
        if not isinstance(action_space, spaces.Discrete):
            raise ValueError(f"the joint replay buffer needs Discrete actions, got {action_space}")
        super().__init__(buffer_size, observation_space, action_space, device=device, n_envs=n_envs,
                         optimize_memory_usage=False, handle_timeout_termination=handle_timeout_termination)
        self.n_agents = int(n_agents)
        self.n_copies = n_envs // self.n_agents
        self.state_shape = None if state_shape is None else tuple(int(d) for d in state_shape)
        if self.state_shape is not None:
            self.states = np.zeros((self.buffer_size, self.n_copies, *self.state_shape), dtype=np.float32)
            self.next_states = np.zeros_like(self.states)
        #: ``(n_copies, *state_shape)``: the states the next ``add``'s observations were made in
        self.last_states: np.ndarray | None = None

    # ------------------------------------------------------------------ the states, from the infos
    def _states(self, infos: list[dict[str, Any]], keys: list[str]) -> np.ndarray:
        """One state per copy: ``infos[first entry of the copy][key]`` for each copy's key."""
        assert self.state_shape is not None  # (a buffer that keeps the states)
        states = np.empty((self.n_copies, *self.state_shape), dtype=np.float32)
        for copy, key in enumerate(keys):
            info = infos[copy * self.n_agents]
            if key not in info:
                raise ValueError(f"infos[{copy * self.n_agents}] has no {key!r}: the joint replay buffer needs the global "
                                 "state in the infos (build the environment with make_vec_env(..., with_state=True))")
            states[copy] = np.asarray(info[key], dtype=np.float32).reshape(self.state_shape)
        return states

    def observe_reset(self, reset_infos: list[dict[str, Any]]) -> None:
        """Read the copies' states after a reset of the vector environment (``venv.unwrapped.reset_infos``)."""
        if self.state_shape is not None:
            self.last_states = self._states(reset_infos, [STATE_KEY] * self.n_copies)

    # ------------------------------------------------------------------ storing and sampling
    def add(self, obs: np.ndarray, next_obs: np.ndarray, action: np.ndarray, reward: np.ndarray, done: np.ndarray,
            infos: list[dict[str, Any]]) -> None:
        """Store one vector step (SB3's arguments; ``next_obs`` already holds the terminal observations), with the
        copies' states and next states read from ``infos``."""
        if self.state_shape is not None:
            if self.last_states is None:
                raise RuntimeError("the joint replay buffer does not know the states of the observations: call "
                                   "observe_reset(venv.unwrapped.reset_infos) after every reset of the environment")
            ended = cast(np.ndarray, np.asarray(done, dtype=bool).reshape(self.n_copies, self.n_agents).any(axis=1))
            next_keys = [TERMINAL_STATE_KEY if end else STATE_KEY for end in ended]
            self.states[self.pos] = self.last_states
            self.next_states[self.pos] = self._states(infos, next_keys)
            self.last_states = self._states(infos, [STATE_KEY] * self.n_copies)
        super().add(obs, next_obs, action, reward, done, infos)

    def _get_samples(  # type: ignore[override]  # team transitions in place of SB3's samples (QMIX reads them)
        self, batch_inds: np.ndarray, env: VecNormalize | None = None,
    ) -> JointReplaySamples:
        copies = np.random.randint(0, self.n_copies, size=len(batch_inds))
        entries = copies[:, None] * self.n_agents + np.arange(self.n_agents)  # (batch, n_agents)
        return self._team_batch(batch_inds[:, None], entries, batch_inds, copies, env)

    def _team_batch(self, rows: np.ndarray, entries: np.ndarray, state_rows: np.ndarray, state_copies: np.ndarray,
                    env: VecNormalize | None = None) -> JointReplaySamples:
        """Team transitions at the fancy indices ``[rows, entries]`` (the agents on the last axis) and the states at
        ``[state_rows, state_copies]``: what single transitions and stretches of them share."""
        dones = self.dones[rows, entries]
        if self.handle_timeout_termination:
            dones = dones * (1 - self.timeouts[rows, entries])
        rewards = self._normalize_reward(self.rewards[rows, entries], env).mean(axis=-1)
        states = next_states = None
        if self.state_shape is not None:
            states = self.to_torch(self.states[state_rows, state_copies], copy=False)
            next_states = self.to_torch(self.next_states[state_rows, state_copies], copy=False)
        # (SB3 annotates _normalize_obs for dict observations too; these are arrays)
        observations = cast(np.ndarray, self._normalize_obs(self.observations[rows, entries], env))
        next_observations = cast(np.ndarray, self._normalize_obs(self.next_observations[rows, entries], env))
        return JointReplaySamples(  # the fancy indexing copied every array already
            observations=self.to_torch(observations, copy=False),
            actions=self.to_torch(self.actions[rows, entries, 0], copy=False).long(),
            next_observations=self.to_torch(next_observations, copy=False),
            dones=self.to_torch(dones.max(axis=-1).astype(np.float32), copy=False),
            rewards=self.to_torch(rewards.astype(np.float32), copy=False),
            states=states,
            next_states=next_states,
        )


class JointSequenceSamples(NamedTuple):
    """A batch of ``batch_size`` stretches of ``length`` consecutive team transitions of one copy each."""

    observations: th.Tensor  # (batch, length, n_agents, *obs_shape)
    actions: th.Tensor  # (batch, length, n_agents), long
    next_observations: th.Tensor  # (batch, length, n_agents, *obs_shape): the terminal observation at an episode's end
    dones: th.Tensor  # (batch, length): 1 if the episode terminated (a truncation bootstraps)
    rewards: th.Tensor  # (batch, length): the team reward
    states: th.Tensor | None  # (batch, length, *state_shape), or None without states
    next_states: th.Tensor | None  # (batch, length, *state_shape)
    episode_starts: th.Tensor  # (batch, length, n_agents): 1 where the observation is an episode's first
    hidden: th.Tensor  # (batch, n_agents, rnn_hidden_dim): the stored hidden state entering the stretch's first step


class RecurrentJointReplayBuffer(JointReplayBuffer):
    """:class:`JointReplayBuffer` for the recurrent agent network: ``sample`` returns stretches of rows.

    Besides the joint buffer's arrays it keeps, per row and entry, whether the observation is an episode's first
    (``episode_starts``) and the hidden state the agent network had when it acted on it (``hidden``, already zeroed at
    an episode's start). The algorithm hands both over before each ``add`` (:meth:`set_recurrent_inputs`), as it hands
    over the reset states. ``sample(batch_size)`` draws ``batch_size`` (start row, copy) pairs and returns the
    ``sequence_length`` consecutive rows from each (:class:`JointSequenceSamples`), never across the write position
    (a stretch holds rows written one after another: when full, it never runs from the newest row into the oldest).

    :param sequence_length: rows per stretch
    :param rnn_hidden_dim: size of the stored hidden states
    :param kwargs: :class:`JointReplayBuffer`'s arguments
    """

    def __init__(self, buffer_size: int, observation_space: spaces.Space, action_space: spaces.Space,
                 device: th.device | str = "auto", n_envs: int = 1, optimize_memory_usage: bool = False,
                 handle_timeout_termination: bool = True, n_agents: int = 1,
                 state_shape: tuple[int, ...] | None = None, sequence_length: int = 16, rnn_hidden_dim: int = 64) -> None:
        super().__init__(buffer_size, observation_space, action_space, device=device, n_envs=n_envs,
                         optimize_memory_usage=optimize_memory_usage,
                         handle_timeout_termination=handle_timeout_termination, n_agents=n_agents,
                         state_shape=state_shape)
        for name, value in (("sequence_length", sequence_length), ("rnn_hidden_dim", rnn_hidden_dim)):
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                raise ValueError(f"{name} must be an int >= 1, got {value!r}")
        if sequence_length > self.buffer_size:
            raise ValueError(f"sequence_length={sequence_length} is longer than the buffer's {self.buffer_size} rows "
                             f"(buffer_size / n_envs): raise buffer_size or shorten the stretches")
        self.sequence_length, self.rnn_hidden_dim = int(sequence_length), int(rnn_hidden_dim)
        self.episode_starts = np.zeros((self.buffer_size, self.n_envs), dtype=bool)
        self.hidden = np.zeros((self.buffer_size, self.n_envs, self.rnn_hidden_dim), dtype=np.float32)
        self._pending: tuple[np.ndarray, np.ndarray] | None = None

    def set_recurrent_inputs(self, hidden: np.ndarray, episode_starts: np.ndarray) -> None:
        """The hidden states ``(n_envs, rnn_hidden_dim)`` and episode-start flags ``(n_envs,)`` of the next ``add``'s
        observations."""
        hidden = np.asarray(hidden, dtype=np.float32)
        if hidden.shape != (self.n_envs, self.rnn_hidden_dim):
            raise ValueError(f"hidden must have shape ({self.n_envs}, {self.rnn_hidden_dim}), got {hidden.shape}")
        self._pending = (hidden.copy(), np.asarray(episode_starts, dtype=bool).reshape(self.n_envs).copy())

    def add(self, obs: np.ndarray, next_obs: np.ndarray, action: np.ndarray, reward: np.ndarray, done: np.ndarray,
            infos: list[dict[str, Any]]) -> None:
        """:class:`JointReplayBuffer`'s ``add``, with the hidden states and episode starts :meth:`set_recurrent_inputs`
        gave (each used once)."""
        if self._pending is None:
            raise RuntimeError("the recurrent joint replay buffer needs the hidden states and episode starts of the "
                               "observations: call set_recurrent_inputs(hidden, episode_starts) before every add")
        self.hidden[self.pos], self.episode_starts[self.pos] = self._pending
        self._pending = None
        super().add(obs, next_obs, action, reward, done, infos)

    def n_rows(self) -> int:
        """Rows stored (at most ``buffer_size``)."""
        return self.buffer_size if self.full else self.pos

    def can_sample(self) -> bool:
        """Whether one stretch of ``sequence_length`` rows is stored."""
        return self.n_rows() >= self.sequence_length

    def sequence_starts(self, offsets: np.ndarray) -> np.ndarray:
        """The first rows of stretches number ``offsets`` in ``[0, n_rows - sequence_length]``, counted from the oldest
        row: every stretch of consecutive rows that does not cross the write position."""
        return (offsets + (self.pos if self.full else 0)) % self.buffer_size

    def sample(  # type: ignore[override]  # stretches of team transitions in place of SB3's samples (QMIX reads them)
        self, batch_size: int, env: VecNormalize | None = None,
    ) -> JointSequenceSamples:
        """``batch_size`` stretches of ``sequence_length`` rows, uniformly over the valid first rows and copies."""
        if not self.can_sample():
            raise ValueError(f"the buffer holds {self.n_rows()} rows, fewer than sequence_length={self.sequence_length}")
        offsets = np.random.randint(0, self.n_rows() - self.sequence_length + 1, size=batch_size)
        copies = np.random.randint(0, self.n_copies, size=batch_size)
        return self._get_sequences(self.sequence_starts(offsets), copies, env)

    def _get_sequences(self, first_rows: np.ndarray, copies: np.ndarray,
                       env: VecNormalize | None = None) -> JointSequenceSamples:
        """The stretches beginning at rows ``first_rows`` ``(batch,)`` of copies ``copies`` ``(batch,)``."""
        rows = ((first_rows[:, None] + np.arange(self.sequence_length)) % self.buffer_size)[:, :, None]  # (batch, L, 1)
        entries = (copies[:, None] * self.n_agents + np.arange(self.n_agents))[:, None, :]  # (batch, 1, n_agents)
        team = self._team_batch(rows, entries, rows[:, :, 0], copies[:, None], env)
        return JointSequenceSamples(
            *team,
            episode_starts=self.to_torch(self.episode_starts[rows, entries].astype(np.float32)),
            hidden=self.to_torch(self.hidden[first_rows[:, None], entries[:, 0]]),
        )
