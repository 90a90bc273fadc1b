"""Callbacks: the reserve's team metrics (and the policy entropy) and the latent metrics in tensorboard."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback

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
    the way through each episode that ended in the rollout) and ``latent/nmi``.

    Needs an environment whose infos carry ``"mode"`` (the reserve, the tasks of :mod:`sb3_emmarl.common.envs`);
    components are aligned to modes over the rollout's finished episodes (Hungarian matching).

    :param verbose: verbosity
    """

    model: LatentAlgorithmMixin  # (an EM algorithm)

    def _init_callback(self) -> None:
        #: (belief, mode) of every step of each entry's running episode, and of the episodes finished this rollout
        self.current: list[list[tuple[np.ndarray, int]]] = [[] for _ in range(self.training_env.num_envs)]
        self.finished: list[list[tuple[np.ndarray, int]]] = []

    def _on_rollout_start(self) -> None:
        self.finished = []

    def _on_step(self) -> bool:
        beliefs = self.model.posterior(self.locals["new_obs"])
        for i, (done, info) in enumerate(zip(self.locals["dones"], self.locals["infos"])):
            if done:
                if self.current[i]:
                    self.finished.append(self.current[i])
                self.current[i] = []
            elif "mode" in info:
                self.current[i].append((beliefs[i], int(info["mode"])))
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
        beliefs = np.array([b for e in episodes for b, _ in e])
        modes = np.array([m for e in episodes for _, m in e])
        mapping = align_components(beliefs, modes)
        self.logger.record("latent/nmi", normalized_mutual_information(beliefs.argmax(1), modes))
        for fraction in EPISODE_FRACTIONS:
            picks = [e[fraction_step(fraction, len(e))] for e in episodes]
            correct = [mapping[int(np.argmax(b))] == m for b, m in picks]
            self.logger.record(f"latent/accuracy_{fraction_label(fraction)}", float(np.mean(correct)))
