"""The single-agent (centralised) view of the wildlife reserve (and of ZonePatrol), used by the Centralized PPO
baseline.

One policy sees the global state and picks the joint action of every UAV at once, so any
single-agent Stable-Baselines3 algorithm can train on the reserve:

.. code-block:: python

    from stable_baselines3 import PPO

    from sb3_emmarl.common.centralized import CentralizedReserveEnv

    model = PPO("MlpPolicy", CentralizedReserveEnv(n_uavs=3, grid_size=20)).learn(10_000)

:func:`register_envs` makes the same environment available as ``gymnasium.make("WildlifeReserve-v1", **env_kwargs)``,
and ZonePatrol's (:class:`CentralizedZonePatrolEnv`) as ``gymnasium.make("ZonePatrol-v1", **env_kwargs)`` (its former
version: :class:`CentralizedZonePatrolV0Env`, ``"ZonePatrol-v0"``).
"""

from __future__ import annotations

from typing import Any

import gymnasium
import numpy as np
from gymnasium import spaces

from sb3_emmarl.common.env_ids import ENV_ID, ZONE_PATROL_ID, ZONE_PATROL_V0_ID, check_env_id
from wildlife_reserve import reserve_v1, zone_patrol_v0, zone_patrol_v1
from wildlife_reserve.reserve.reserve import ReserveParallelEnv

#: Values of one UAV's continuous action: ``(d_row, d_col, comm)``.
CONTINUOUS_ACTION_DIM = 3


class CentralizedReserveEnv(gymnasium.Env):
    """The wildlife reserve as one single-agent Gymnasium environment (the Centralized PPO baseline).

    A central controller with one policy over the global state and the joint action: it observes
    ``state()`` of a :class:`~wildlife_reserve.reserve.reserve.ReserveParallelEnv`, acts for every
    UAV at once and receives the team reward.

    - Observation: the global state, ``Box(-1, 1, (4 n_uavs + 4 n_poachers + 3 n_leopards + belief_size^2 + 1,))``.
    - Action: ``MultiDiscrete([n] * n_uavs)`` (one UAV's ``n`` actions each, ``move + 5 * comm`` on the reserve, in
      agent order), or with
      ``continuous_actions=True`` a ``Box(-1, 1, (3 * n_uavs,))`` read as ``(d_row, d_col, comm)`` per UAV.
    - Reward: the mean of the agents' rewards, i.e. the team reward when ``shaping=0`` (the default).
    - ``terminated`` / ``truncated``: the parallel env's (every UAV ends at the same step).
    - Info: the info of agent ``uav_0``: ``"mode"`` (the hidden scenario mode, for evaluation only)
      every step and ``"metrics"`` (:meth:`~wildlife_reserve.reserve.reserve.ReserveParallelEnv.episode_metrics`)
      on the last step.

    :param env_kwargs: arguments of ``reserve_v1.parallel_env`` (see
        :class:`~wildlife_reserve.reserve.config.ReserveConfig`), ``render_mode`` included
    """

    metadata = {
        "render_modes": list(ReserveParallelEnv.metadata["render_modes"]),
        "render_fps": ReserveParallelEnv.metadata["render_fps"],
    }

    #: The parallel environment's constructor (a subclass names another environment's).
    parallel_env_fn = staticmethod(reserve_v1.parallel_env)

    def __init__(self, **env_kwargs: Any) -> None:
        super().__init__()
        self.parallel_env: ReserveParallelEnv = self.parallel_env_fn(**env_kwargs)
        self.possible_agents = list(self.parallel_env.possible_agents)
        self.n_uavs = len(self.possible_agents)
        self.continuous_actions = bool(getattr(self.parallel_env.config, "continuous_actions", False))
        self.render_mode = self.parallel_env.render_mode
        self.observation_space = self.parallel_env.state_space
        if self.continuous_actions:
            self.action_space = spaces.Box(low=-1.0, high=1.0, shape=(CONTINUOUS_ACTION_DIM * self.n_uavs,), dtype=np.float32)
        else:
            action_space = self.parallel_env.action_space(self.possible_agents[0])
            assert isinstance(action_space, spaces.Discrete)  # (the discrete actions)
            self.n_actions = int(action_space.n)
            self.action_space = spaces.MultiDiscrete([self.n_actions] * self.n_uavs)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict]:
        """Start an episode of the parallel env.

        :param seed: passed to the parallel env (seeds the episode and later unseeded resets)
        :param options: passed to the parallel env, e.g. ``{"mode": int}`` or ``{"uav_positions": array (n, 2)}``
        :return: the global state and agent ``uav_0``'s info
        """
        super().reset(seed=seed)
        _, infos = self.parallel_env.reset(seed=seed, options=options)
        return self.parallel_env.state(), dict(infos[self.possible_agents[0]])

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        """Apply the joint action to every UAV.

        :param action: the joint action, of shape ``action_space.shape``
        :return: the global state, the (mean) team reward, terminated, truncated and agent ``uav_0``'s info
        """
        actions = self._split_action(action)
        _, rewards, terminations, truncations, infos = self.parallel_env.step(actions)
        values = np.array([rewards[agent] for agent in self.possible_agents])
        # Identical rewards (shaping=0) are returned as they are: their float mean can be off in the last bit.
        reward = float(values[0]) if np.all(values == values[0]) else float(values.mean())
        terminated = any(terminations[agent] for agent in self.possible_agents)
        truncated = any(truncations[agent] for agent in self.possible_agents)
        info = dict(infos[self.possible_agents[0]])
        return self.parallel_env.state(), reward, bool(terminated), bool(truncated), info

    def _split_action(self, action: np.ndarray) -> dict[str, Any]:
        """Split the joint action into the parallel env's ``{agent: action}`` dict.

        :param action: the joint action, of shape ``action_space.shape``
        :return: one action per UAV
        """
        joint = np.asarray(action)
        expected = self.action_space.shape
        if joint.shape != expected:
            raise ValueError(f"the joint action must have shape {expected} ({self.action_space}), got shape {joint.shape}")
        if self.continuous_actions:
            per_uav = joint.astype(np.float32).reshape(self.n_uavs, CONTINUOUS_ACTION_DIM)
            return {agent: per_uav[i] for i, agent in enumerate(self.possible_agents)}
        if not np.issubdtype(joint.dtype, np.integer):
            if not (np.issubdtype(joint.dtype, np.number) and np.all(np.mod(joint, 1) == 0)):
                raise ValueError(f"the joint action must hold integers in [0, {self.n_actions - 1}], got {joint!r}")
        return {agent: int(joint[i]) for i, agent in enumerate(self.possible_agents)}

    def render(self) -> np.ndarray | None:
        """Render the parallel env (an RGB array in ``"rgb_array"`` mode, a window in ``"human"`` mode)."""
        return self.parallel_env.render()

    def close(self) -> None:
        """Close the parallel env (and its renderer)."""
        self.parallel_env.close()
        super().close()


class CentralizedZonePatrolEnv(CentralizedReserveEnv):
    """ZonePatrol as one single-agent Gymnasium environment: the global state, the joint action
    ``MultiDiscrete([n_actions] * n_uavs)``, the team reward (see :class:`CentralizedReserveEnv`).

    :param env_kwargs: arguments of ``zone_patrol_v1.parallel_env``
    """

    parallel_env_fn = staticmethod(zone_patrol_v1.parallel_env)


class CentralizedZonePatrolV0Env(CentralizedZonePatrolEnv):
    """ZonePatrol's former version (``zone_patrol_v0``) as :class:`CentralizedZonePatrolEnv`.

    :param env_kwargs: arguments of ``zone_patrol_v0.parallel_env``
    """

    parallel_env_fn = staticmethod(zone_patrol_v0.parallel_env)


#: The centralised view of each environment id.
CENTRALIZED_ENVS: dict[str, type[CentralizedReserveEnv]] = {ENV_ID: CentralizedReserveEnv,
                                                            ZONE_PATROL_ID: CentralizedZonePatrolEnv,
                                                            ZONE_PATROL_V0_ID: CentralizedZonePatrolV0Env}


def centralized_env(env_id: str = ENV_ID, **env_kwargs: Any) -> CentralizedReserveEnv:
    """The centralised view of ``env_id`` built with ``env_kwargs``.

    :raise ValueError: for an unknown id
    """
    return CENTRALIZED_ENVS[check_env_id(env_id)](**env_kwargs)


def register_envs() -> None:
    """Register the centralised views with Gymnasium (``"WildlifeReserve-v1"``, ``"ZonePatrol-v1"``, ``"ZonePatrol-v0"``).

    Idempotent: calling it again does nothing. There is no ``max_episode_steps``: the environments
    truncate themselves after their episode length.
    """
    for env_id, env_class in CENTRALIZED_ENVS.items():
        if env_id not in gymnasium.registry:
            gymnasium.register(id=env_id, entry_point=f"{__name__}:{env_class.__name__}")
