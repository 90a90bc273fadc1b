"""Callbacks: the reserve's team metrics (and the policy entropy) and the latent metrics in tensorboard; SB3's
``EvalCallback`` counting team episodes."""

from __future__ import annotations

import os
from typing import TYPE_CHECKING

import gymnasium as gym
import numpy as np
from stable_baselines3.common import callbacks as sb3_callbacks
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import VecEnv, sync_envs_normalization

from sb3_emmarl.common.evaluation import check_episode_count, evaluate_policy
from sb3_emmarl.common.metrics import team_metric_keys

if TYPE_CHECKING:
    from sb3_emmarl.common.latent.algorithm import LatentAlgorithmMixin

#: Tensorboard prefix of every reserve metric.
METRICS_PREFIX = "reserve"


class TeamMetricsCallback(BaseCallback):
    """Log every reserve episode metric under ``reserve/`` (mean over the episodes that ended since the last dump).

    With the parameter-sharing vector environment every agent of a copy reports the same episode, so
    only the first agent of each copy is counted (``agents_per_copy`` of the vector environment; 1 for a
    single-agent environment such as the centralised view). For on-policy algorithms it also logs
    ``reserve/policy_entropy``: the mean entropy of the policy over the last update's minibatches
    (``-train/entropy_loss``), so it appears from the second rollout on.

    :param metrics: which episode metrics to log (None: the episode's team metrics,
        :func:`~sb3_emmarl.common.metrics.team_metric_keys`: the reserve's, or another environment's own, e.g. ZonePatrol's)
    :param verbose: verbosity
    """

    def __init__(self, metrics: tuple[str, ...] | None = None, verbose: int = 0) -> None:
        super().__init__(verbose)
        self.metrics = metrics
        self.agents_per_copy = 1

    def _init_callback(self) -> None:
        self.agents_per_copy = int(getattr(self.training_env, "agents_per_copy", 1))

    def _on_step(self) -> bool:
        for i, done in enumerate(self.locals["dones"]):
            if done and i % self.agents_per_copy == 0:
                metrics = self.locals["infos"][i].get("metrics")
                if metrics is not None:
                    for key in self.metrics or team_metric_keys(metrics):
                        self.logger.record_mean(f"{METRICS_PREFIX}/{key}", float(metrics[key]))
        return True

    def _on_rollout_end(self) -> None:
        entropy_loss = self.logger.name_to_value.get("train/entropy_loss")
        if entropy_loss is not None:
            self.logger.record(f"{METRICS_PREFIX}/policy_entropy", -float(entropy_loss))


class LatentMetricsCallback(BaseCallback):
    """Log how well the beliefs of an EM model tell the true mode during training: ``latent/accuracy_25``,
    ``latent/accuracy_50`` and ``latent/accuracy_100`` (aligned accuracy at the step a quarter, half and all of
    the way through each episode that ended in the rollout) and ``latent/nmi``; on a team with links (more than one
    agent per copy), also ``latent/evidence_reach_25``, ``_50`` and ``_100``: the share of the team's evidence in the
    beliefs at those steps (:meth:`~sb3_emmarl.common.latent.belief.BeliefTracker.evidence_reach`).

    Needs an environment whose infos carry ``"mode"`` (the reserve, the tasks of :mod:`sb3_emmarl.common.envs`);
    components are aligned to modes over the rollout's finished episodes (Hungarian matching).

    :param verbose: verbosity
    """

    model: LatentAlgorithmMixin  # (an EM algorithm)

    def _init_callback(self) -> None:
        from sb3_emmarl.common.latent.belief import find_belief_wrapper

        #: (belief, mode, evidence reach) of every step of each entry's running episode, and of the episodes finished
        #: this rollout
        self.current: list[list[tuple[np.ndarray, int, float]]] = [[] for _ in range(self.training_env.num_envs)]
        self.finished: list[list[tuple[np.ndarray, int, float]]] = []
        wrapper = find_belief_wrapper(self.training_env)
        self.tracker = wrapper.tracker if wrapper is not None and wrapper.tracker.agents_per_copy > 1 else None

    def _on_rollout_start(self) -> None:
        self.finished = []

    def _on_step(self) -> bool:
        beliefs = self.model.posterior(self.locals["new_obs"])
        reach = self.tracker.evidence_reach() if self.tracker is not None else np.ones(len(beliefs))
        for i, (done, info) in enumerate(zip(self.locals["dones"], self.locals["infos"])):
            if done:
                if self.current[i]:
                    self.finished.append(self.current[i])
                self.current[i] = []
            elif "mode" in info:
                self.current[i].append((beliefs[i], int(info["mode"]), float(reach[i])))
        return True

    def _on_rollout_end(self) -> None:
        from sb3_emmarl.common.latent.metrics import (
            EPISODE_FRACTIONS,
            align_components,
            fraction_label,
            fraction_step,
            normalized_mutual_information,
        )

        episodes = [e for e in self.finished if len(e) >= 2]
        if not episodes:
            return
        beliefs = np.array([b for e in episodes for b, _, _ in e])
        modes = np.array([m for e in episodes for _, m, _ in e])
        mapping = align_components(beliefs, modes)
        self.logger.record("latent/nmi", normalized_mutual_information(beliefs.argmax(1), modes))
        for fraction in EPISODE_FRACTIONS:
            picks = [e[fraction_step(fraction, len(e))] for e in episodes]
            correct = [mapping[int(np.argmax(b))] == m for b, m, _ in picks]
            self.logger.record(f"latent/accuracy_{fraction_label(fraction)}", float(np.mean(correct)))
            if self.tracker is not None:
                self.logger.record(f"latent/evidence_reach_{fraction_label(fraction)}",
                                   float(np.mean([reach for _, _, reach in picks])))


class EvalCallback(sb3_callbacks.EvalCallback):
    """SB3's ``EvalCallback`` (same arguments, files and logs) whose evaluations count team episodes: it calls
    :func:`~sb3_emmarl.common.evaluation.evaluate_policy`, so on a parameter-sharing vector environment
    ``n_eval_episodes`` are episodes of the team (one team reward each), not the UAVs of one episode as with SB3's; on
    any other environment it is SB3's. A model with ``wrap_env`` (the EM algorithms, OraclePPO, MessagePPO) has the
    evaluation environment wrapped as its training environment is, once, when training starts.

    :param eval_env: the evaluation environment (the plain parameter-sharing vector environment is fine)
    :param callback_on_new_best: callback triggered when the mean team reward is a new best
    :param callback_after_eval: callback triggered after every evaluation
    :param n_eval_episodes: team episodes per evaluation (a whole number >= 1)
    :param eval_freq: evaluate every ``eval_freq`` calls of the callback (vector steps)
    :param log_path: folder of ``evaluations.npz`` (updated at each evaluation)
    :param best_model_save_path: folder of ``best_model.zip``
    :param deterministic: the most likely actions
    :param render: render the environment during evaluation
    :param verbose: 1: print each evaluation's result
    :param warn: passed to ``evaluate_policy`` (warns when the environment has no Monitor wrapper)
    """

    def __init__(
        self,
        eval_env: gym.Env | VecEnv,
        callback_on_new_best: BaseCallback | None = None,
        callback_after_eval: BaseCallback | None = None,
        n_eval_episodes: int = 5,
        eval_freq: int = 10000,
        log_path: str | None = None,
        best_model_save_path: str | None = None,
        deterministic: bool = True,
        render: bool = False,
        verbose: int = 1,
        warn: bool = True,
    ) -> None:
        super().__init__(eval_env, callback_on_new_best, callback_after_eval, check_episode_count(n_eval_episodes),
                         eval_freq, log_path, best_model_save_path, deterministic, render, verbose, warn)

    def _init_callback(self) -> None:
        wrap = getattr(self.model, "wrap_env", None)
        if wrap is not None:  # as training's (also what sync_envs_normalization walks in step with it)
            self.eval_env = wrap(self.eval_env)
        super()._init_callback()

    def _on_step(self) -> bool:
        """SB3's ``EvalCallback._on_step`` (stable-baselines3 2.x) with one change: the evaluation is this package's
        ``evaluate_policy``."""
        continue_training = True

        if self.eval_freq > 0 and self.n_calls % self.eval_freq == 0:
            # Sync training and eval env if there is VecNormalize
            if self.model.get_vec_normalize_env() is not None:
                try:
                    sync_envs_normalization(self.training_env, self.eval_env)
                except AttributeError as e:
                    raise AssertionError(
                        "Training and eval env are not wrapped the same way, "
                        "see https://stable-baselines3.readthedocs.io/en/master/guide/callbacks.html#evalcallback "
                        "and warning above."
                    ) from e

            # Reset success rate buffer
            self._is_success_buffer = []

            episode_rewards, episode_lengths = evaluate_policy(
                self.model,
                self.eval_env,
                n_eval_episodes=self.n_eval_episodes,
                render=self.render,
                deterministic=self.deterministic,
                return_episode_rewards=True,
                warn=self.warn,
                callback=self._log_success_callback,
            )

            if self.log_path is not None:
                assert isinstance(episode_rewards, list)
                assert isinstance(episode_lengths, list)
                self.evaluations_timesteps.append(self.num_timesteps)
                self.evaluations_results.append(episode_rewards)
                self.evaluations_length.append(episode_lengths)

                kwargs = {}
                # Save success log if present
                if len(self._is_success_buffer) > 0:
                    self.evaluations_successes.append(self._is_success_buffer)
                    kwargs = dict(successes=self.evaluations_successes)

                np.savez(
                    self.log_path,
                    timesteps=self.evaluations_timesteps,
                    results=self.evaluations_results,
                    ep_lengths=self.evaluations_length,
                    **kwargs,  # type: ignore[arg-type]
                )

            mean_reward, std_reward = np.mean(episode_rewards), np.std(episode_rewards)
            mean_ep_length, std_ep_length = np.mean(episode_lengths), np.std(episode_lengths)
            self.last_mean_reward = float(mean_reward)

            if self.verbose >= 1:
                print(f"Eval num_timesteps={self.num_timesteps}, episode_reward={mean_reward:.2f} +/- {std_reward:.2f}")
                print(f"Episode length: {mean_ep_length:.2f} +/- {std_ep_length:.2f}")
            # Add to current Logger
            self.logger.record("eval/mean_reward", float(mean_reward))
            self.logger.record("eval/mean_ep_length", mean_ep_length)

            if len(self._is_success_buffer) > 0:
                success_rate = np.mean(self._is_success_buffer)
                if self.verbose >= 1:
                    print(f"Success rate: {100 * success_rate:.2f}%")
                self.logger.record("eval/success_rate", success_rate)

            # Dump log so the evaluation results are printed with the correct timestep
            self.logger.record("time/total_timesteps", self.num_timesteps, exclude="tensorboard")
            self.logger.dump(self.num_timesteps)

            if mean_reward > self.best_mean_reward:
                if self.verbose >= 1:
                    print("New best mean reward!")
                if self.best_model_save_path is not None:
                    self.model.save(os.path.join(self.best_model_save_path, "best_model"))
                self.best_mean_reward = float(mean_reward)
                # Trigger callback on new best model, if needed
                if self.callback_on_new_best is not None:
                    continue_training = self.callback_on_new_best.on_step()

            # Trigger callback after every evaluation, if needed
            if self.callback is not None:
                continue_training = continue_training and self._on_event()

        return continue_training
