"""Callbacks: the reserve's team metrics (and the policy entropy) and the latent metrics in tensorboard; SB3's
``EvalCallback`` counting team episodes, and the same with its files written atomically (:class:`AtomicEvalCallback`).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING

import gymnasium as gym
import numpy as np
from stable_baselines3.common import callbacks as sb3_callbacks
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import VecEnv

from sb3_emmarl.common.appended.wrapping import find_wrapper
from sb3_emmarl.common.evaluation import check_episode_count, evaluate_policy
from sb3_emmarl.common.metrics import team_metric_keys
from sb3_emmarl.common.trust.atomic_files import save_model

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

    Needs an environment whose infos carry ``"mode"`` (the reserve, the tasks of :mod:`sb3_emmarl.common.mode_tasks`);
    components are aligned to modes over the rollout's finished episodes (Hungarian matching).

    :param verbose: verbosity
    """

    model: LatentAlgorithmMixin  # (an EM algorithm)

    def _init_callback(self) -> None:
        from sb3_emmarl.common.latent.belief import BeliefWrapper

        #: (belief, mode, evidence reach) of every step of each entry's running episode, and of the episodes finished
        #: this rollout
        self.current: list[list[tuple[np.ndarray, int, float]]] = [[] for _ in range(self.training_env.num_envs)]
        self.finished: list[list[tuple[np.ndarray, int, float]]] = []
        wrapper = find_wrapper(self.training_env, BeliefWrapper)
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
        """SB3's ``EvalCallback._on_step``, its evaluation this package's ``evaluate_policy`` (team episodes): SB3's
        method calls the ``evaluate_policy`` of its module, which is this package's while the method runs."""
        sb3_evaluate = sb3_callbacks.evaluate_policy
        sb3_callbacks.evaluate_policy = evaluate_policy  # type: ignore[assignment]
        try:
            return super()._on_step()
        finally:
            sb3_callbacks.evaluate_policy = sb3_evaluate


class AtomicEvalCallback(EvalCallback):
    """The team-counting ``EvalCallback`` (:class:`sb3_emmarl.common.callbacks.EvalCallback`: SB3's, whose evaluations
    are team episodes) whose ``evaluations.npz`` and ``best_model.zip`` are written atomically (same arguments).

    SB3 writes both in place; here the evaluations go to a hidden temporary file renamed over
    ``evaluations.npz``, and the best model is saved with :func:`save_model`.
    """

    def _init_callback(self) -> None:
        super()._init_callback()
        self._best_folder, self.best_model_save_path = self.best_model_save_path, None
        self._log_file = None
        if self.log_path is not None:
            self._log_file = Path(self.log_path).with_suffix(".npz")
            self.log_path = str(self._log_file.with_name(f".{self._log_file.stem}.{os.getpid()}.tmp"))

    def _on_step(self) -> bool:
        best = self.best_mean_reward
        result = super()._on_step()
        if self._log_file is not None:
            written = Path(f"{self.log_path}.npz")  # numpy's savez adds the suffix
            if written.is_file():
                os.replace(written, self._log_file)
        if self._best_folder is not None and self.best_mean_reward > best:
            save_model(self.model, Path(self._best_folder) / "best_model.zip")
        return result
