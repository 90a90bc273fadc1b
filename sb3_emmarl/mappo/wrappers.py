"""The critic's input in SB3's rollout buffer: each entry's observation followed by the global state (and its agent id).

SB3's ``RolloutBuffer`` stores observations only, and bootstraps an episode cut at the time limit from
``infos[i]["terminal_observation"]``. :class:`GlobalStateWrapper` therefore appends to every vector entry's
observation the global state that goes with it (``infos[i]["state"]`` of
:func:`~sb3_emmarl.common.vec_env.make_vec_env` with the state on; after ``reset()``, the reset infos of the
innermost vector environment) and, with ``agent_id``, a one-hot of the entry's agent (entry ``i`` is agent
``i % agents_per_copy``). A terminal observation gets the state its episode ended in
(``infos[i]["terminal_state"]``), so the value it is bootstrapped from is the critic's value of that state.

The augmented observation is ``[observation (obs_dim), state (state_dim), agent one-hot (n_agents, if agent_id)]``
(:class:`StateLayout`); the actor of :class:`~sb3_emmarl.mappo.policies.MAPPOPolicy` reads the first
``obs_dim`` values only, the critic all of them: MAPPO's agent-specific global state.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from gymnasium import spaces
from stable_baselines3.common.vec_env import VecEnv

from sb3_emmarl.common.appended.wrapping import TERMINAL_OBSERVATION, AppendingVecEnvWrapper, ensure_wrapped
from sb3_emmarl.common.vec_env import STATE_KEY, TERMINAL_STATE_KEY, SharedPolicyVecEnv, require_state


@dataclass(frozen=True)
class StateLayout:
    """Where the parts of an augmented observation sit (saved with the policy in ``policy_kwargs``).

    :param obs_dim: size of one agent's (flat) observation, the actor's whole input
    :param state_dim: size of the (flat) global state
    :param n_agents: agents per environment copy (the one-hot's size when ``agent_id``)
    :param agent_id: the augmented observation ends with a one-hot of the entry's agent
    """

    obs_dim: int
    state_dim: int
    n_agents: int
    agent_id: bool = True

    def __post_init__(self) -> None:
        for name in ("obs_dim", "state_dim", "n_agents"):
            value = getattr(self, name)
            if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or value < 1:
                raise ValueError(f"{name} must be an int >= 1, got {value!r}")
            object.__setattr__(self, name, int(value))
        if not isinstance(self.agent_id, (bool, np.bool_)):
            raise ValueError(f"agent_id must be True or False, got {self.agent_id!r}")
        object.__setattr__(self, "agent_id", bool(self.agent_id))

    @property
    def id_dim(self) -> int:
        """Size of the agent one-hot (0 without ``agent_id``)."""
        return self.n_agents if self.agent_id else 0

    @property
    def critic_dim(self) -> int:
        """Size of an augmented observation: the critic's input."""
        return self.obs_dim + self.state_dim + self.id_dim

    def split(self, observations: Any) -> tuple[Any, Any, Any]:
        """Augmented observations ``(..., critic_dim)`` (numpy or torch) -> observation, state, agent one-hot."""
        state_end = self.obs_dim + self.state_dim
        return observations[..., : self.obs_dim], observations[..., self.obs_dim:state_end], observations[..., state_end:]

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> StateLayout:
        return cls(**data)


def _flat_box(space: Any, what: str) -> spaces.Box:
    if not isinstance(space, spaces.Box) or len(space.shape) != 1:
        raise ValueError(f"MAPPO needs a flat Box {what}, got {space}")
    return space


class GlobalStateWrapper(AppendingVecEnvWrapper):
    """Append the global state (and, with ``agent_id``, the agent's one-hot) to every entry's observation.

    Switches the global state on (:func:`~sb3_emmarl.common.vec_env.require_state`) from the next reset.

    :param venv: the parameter-sharing vector environment (:func:`~sb3_emmarl.common.vec_env.make_vec_env`) of a
        PettingZoo environment with ``state()``, flat ``Box`` observations and state
    :param agent_id: append a one-hot of the entry's agent (``agents_per_copy`` floats)
    :param who: the algorithm asking, for the error messages
    :raise ValueError: if the environment has no global state (or it cannot be switched on), or the spaces are not flat
    """

    def __init__(self, venv: VecEnv, agent_id: bool = True, who: str = "MAPPO") -> None:
        if not isinstance(agent_id, (bool, np.bool_)):
            raise ValueError(f"agent_id must be True or False, got {agent_id!r}")
        try:
            state_space = require_state(venv, who)
        except ValueError as error:
            raise ValueError(f"{who} needs the environment's global state: {error}") from None
        observation_space = _flat_box(venv.observation_space, "observation space")
        state_space = _flat_box(state_space, "global state space")
        inner = venv.unwrapped
        assert isinstance(inner, SharedPolicyVecEnv)  # (require_state checked it)
        n_agents = int(inner.agents_per_copy)
        self.layout = StateLayout(int(observation_space.shape[0]), int(state_space.shape[0]), n_agents, bool(agent_id))
        id_low, id_high = np.zeros(self.layout.id_dim, np.float32), np.ones(self.layout.id_dim, np.float32)
        super().__init__(venv, np.concatenate([state_space.low, id_low]), np.concatenate([state_space.high, id_high]))
        eye = np.eye(n_agents, dtype=np.float32)[:, : self.layout.id_dim]
        self.agent_ids = eye[np.arange(self.num_envs) % n_agents]  # (num_envs, id_dim)

    @property
    def agent_id(self) -> bool:
        return self.layout.agent_id

    def _states(self, infos: list[dict[str, Any]], key: str, where: str) -> np.ndarray:
        try:
            return np.stack([np.asarray(info[key], dtype=np.float32).reshape(-1) for info in infos])
        except KeyError:
            raise ValueError(f"the global state is missing from the {where} (infos[i][{key!r}]): reset the "
                             "environment after wrapping it, or build it with make_vec_env(..., with_state=True)") from None

    def _reset_extra(self, observations: np.ndarray) -> np.ndarray:
        self.reset_infos = list(self.venv.unwrapped.reset_infos)  # the outer VecMonitor's own are empty
        return np.concatenate([self._states(self.reset_infos, STATE_KEY, "reset infos"), self.agent_ids], axis=1)

    def _step_extra(self, observations: np.ndarray, dones: np.ndarray, infos: list[dict[str, Any]]
                    ) -> tuple[np.ndarray, dict[int, np.ndarray]]:
        states = self._states(infos, STATE_KEY, "step infos")
        terminal = {int(i): np.concatenate([self._states([infos[i]], TERMINAL_STATE_KEY, "infos of an episode's end")[0],
                                            self.agent_ids[i]])
                    for i in np.flatnonzero(dones) if infos[i].get(TERMINAL_OBSERVATION) is not None}
        return np.concatenate([states, self.agent_ids], axis=1), terminal


def wrap_with_state(env: Any, agent_id: bool, verbose: int = 0, strict: bool = True) -> VecEnv:
    """``env`` with a :class:`GlobalStateWrapper` on top (kept if it already has one).

    :param env: the parameter-sharing vector environment (a Gymnasium env is wrapped as SB3 does, then rejected)
    :param agent_id: append the agent one-hot
    :param verbose: verbosity of SB3's wrapping
    :param strict: reject an existing wrapper with another ``agent_id`` (False while loading: the saved one wins)
    """
    if isinstance(env, str):
        raise ValueError(f"MAPPO needs the parameter-sharing vector environment (make_vec_env), got the id {env!r}")

    def mismatch(wrapper: GlobalStateWrapper) -> str | None:
        if not strict or wrapper.agent_id == bool(agent_id):
            return None
        return f"the environment's GlobalStateWrapper has agent_id={wrapper.agent_id}, but agent_id={agent_id}"

    return ensure_wrapped(env, GlobalStateWrapper, lambda venv: GlobalStateWrapper(venv, agent_id), mismatch, verbose)
