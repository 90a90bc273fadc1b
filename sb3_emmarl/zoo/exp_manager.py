"""rl_zoo3's ``ExperimentManager``, taught to build the reserve's vector environments.

rl_zoo3 reads the YAML hyperparameters, builds schedules, callbacks and action noise, saves runs in
its folder layout and tunes with optuna; all of that is reused. What changes:

- ``create_envs`` builds :func:`~sb3_emmarl.common.vec_env.make_vec_env` (``n_envs`` reserve copies,
  one vector entry per UAV) instead of ``gym.make`` copies, with the true mode for ``oracle_ppo`` (the EM
  algorithms add their belief wrapper themselves, and evaluate on plain environments through
  ``predict(obs, state, episode_start)``); the centralised algorithms keep rl_zoo3's own path
  through the Gymnasium id ``WildlifeReserve-v0``;
- ``oracle_ppo`` reads ``ppo.yml``: the same settings as PPO by construction;
- ``n_envs`` is counted in vector entries (copies x UAVs) once the YAML is read, so that rl_zoo3's
  ``--eval-freq`` / ``--save-freq`` / optuna arithmetic, which divides by ``n_envs``, stays right;
- the environment's arguments are validated before any folder is written;
- :class:`~sb3_emmarl.common.callbacks.TeamMetricsCallback` is added to the training callbacks (and
  :class:`~sb3_emmarl.common.callbacks.LatentMetricsCallback` for the EM algorithms).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import yaml
from rl_zoo3.exp_manager import ExperimentManager
from stable_baselines3.common.vec_env import VecEnv

from sb3_emmarl.common.callbacks import LatentMetricsCallback, TeamMetricsCallback
from sb3_emmarl.common.centralized import ENV_ID, register_envs
from sb3_emmarl.common.mode_aware import wrap_with_mode
from sb3_emmarl.common.vec_env import make_vec_env
from sb3_emmarl.oracle_ppo import OraclePPO
from sb3_emmarl.zoo.algos import CENTRALIZED_ALGOS, LATENT_ALGOS, SHARED_HYPERPARAMS, ZOO_ALGOS, register_algorithms
from wildlife_reserve import reserve_v0

#: The YAML files of the zoo (``zoo/hyperparams/<algo>.yml`` in a checkout).
HYPERPARAMS_DIR = Path(__file__).resolve().parents[2] / "zoo" / "hyperparams"
#: Offset between the training seed and the seed of the evaluation environment.
EVAL_SEED_OFFSET = 10_000


class ReserveExperimentManager(ExperimentManager):
    """rl_zoo3's experiment manager on the wildlife reserve (see the module docstring for what differs).

    Takes rl_zoo3's arguments; ``config`` defaults to ``zoo/hyperparams/<algo>.yml``.
    """

    def __init__(self, args: Any, algo: str, env_id: str, *posargs: Any, **kwargs: Any) -> None:
        register_envs()
        register_algorithms()
        if algo not in ZOO_ALGOS:
            raise ValueError(f"unknown algorithm {algo!r}; the zoo trains {sorted(ZOO_ALGOS)}")
        if env_id != ENV_ID:
            raise ValueError(f"the zoo trains on {ENV_ID!r}, got env {env_id!r}")
        if kwargs.get("config") is None:
            kwargs["config"] = str(HYPERPARAMS_DIR / f"{SHARED_HYPERPARAMS.get(algo, algo)}.yml")
        if not Path(kwargs["config"]).is_file():
            raise ValueError(f"no hyperparameter file {kwargs['config']!r} for algorithm {algo!r}")
        self.num_cpus = 0
        super().__init__(args, algo, env_id, *posargs, **kwargs)
        self.centralized = algo in CENTRALIZED_ALGOS
        self.agents_per_copy = 1
        # Periodic evaluations sample actions, as evaluate_team does (argmax locks identical UAVs together).
        self.deterministic_eval = self.centralized

    def read_hyperparameters(self) -> tuple[dict[str, Any], dict[str, Any]]:
        """rl_zoo3's reading, except that ``--env-kwargs`` update the YAML's ``env_kwargs`` instead of replacing them
        (so ``ddpg.yml``'s ``continuous_actions: true`` survives ``--env-kwargs n_uavs:20``)."""
        cli_env_kwargs = self.env_kwargs
        if cli_env_kwargs:
            with open(self.config) as file:
                yaml_env_kwargs = (yaml.safe_load(file) or {}).get(self.env_name.gym_id, {}).get("env_kwargs") or {}
            self.env_kwargs = {**yaml_env_kwargs, **cli_env_kwargs}
        return super().read_hyperparameters()

    def _preprocess_hyperparams(self, hyperparams: dict[str, Any]):
        processed = super()._preprocess_hyperparams(hyperparams)
        if self._eval_env_kwargs_args is None:  # rl_zoo3 only copies them when --env-kwargs is given
            self.eval_env_kwargs = self.env_kwargs
        # Validate the environment's arguments now, before any folder or process exists.
        prototype = reserve_v0.parallel_env(**self.env_kwargs)
        reserve_v0.parallel_env(**self.eval_env_kwargs)
        if not self.centralized:
            self.agents_per_copy = len(prototype.possible_agents)
            self.n_envs *= self.agents_per_copy  # rl_zoo3 divides step counts by n_envs: count vector entries
        if self.vec_env_class.__name__ == "SubprocVecEnv":
            self.num_cpus = min(os.cpu_count() or 1, max(1, self.n_envs // self.agents_per_copy))
        return processed

    def create_envs(self, n_envs: int, eval_env: bool = False, no_log: bool = False) -> VecEnv:
        """The parameter-sharing vector environment (``n_envs`` entries, rounded up to whole reserve copies).

        :param n_envs: vector entries wanted (copies x UAVs)
        :param eval_env: build the evaluation environment (its own seed, frozen normalisation)
        :param no_log: no monitor file
        """
        if self.centralized:
            return super().create_envs(n_envs, eval_env=eval_env, no_log=no_log)
        n_copies = max(1, -(-n_envs // self.agents_per_copy))
        env = make_vec_env(
            n_copies=n_copies,
            seed=self.seed + EVAL_SEED_OFFSET if eval_env else self.seed,
            env_kwargs=self.eval_env_kwargs if eval_env else self.env_kwargs,
            num_cpus=0 if eval_env else self.num_cpus,
            monitor_dir=None if eval_env or no_log else self.save_path,
            vec_env_wrapper=self.vec_env_wrapper,
        )
        env = self._maybe_normalize(env, eval_env)
        if ZOO_ALGOS[self.algo] is OraclePPO:
            env = wrap_with_mode(env)
        return env

    def create_callbacks(self) -> None:
        super().create_callbacks()
        self.callbacks.append(TeamMetricsCallback())
        if self.algo in LATENT_ALGOS:
            self.callbacks.append(LatentMetricsCallback())
