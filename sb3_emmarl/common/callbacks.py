"""Callbacks: the reserve's team metrics (and the policy entropy) in tensorboard."""

from __future__ import annotations

from stable_baselines3.common.callbacks import BaseCallback

from sb3_emmarl.common.metrics import TEAM_METRICS

#: Tensorboard prefix of every reserve metric.
METRICS_PREFIX = "reserve"


class TeamMetricsCallback(BaseCallback):
    """Log every reserve episode metric under ``reserve/`` (mean over the episodes that ended since the last dump).

    With the parameter-sharing vector environment every agent of a copy reports the same episode, so
    only the first agent of each copy is counted (``agents_per_copy`` of the vector environment; 1 for a
    single-agent environment such as the centralised view). For on-policy algorithms it also logs
    ``reserve/policy_entropy``: the mean entropy of the policy over the last update's minibatches
    (``-train/entropy_loss``), so it appears from the second rollout on.

    :param metrics: which episode metrics to log
    :param verbose: verbosity
    """

    def __init__(self, metrics: tuple[str, ...] = TEAM_METRICS, verbose: int = 0) -> None:
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
                    for key in self.metrics:
                        self.logger.record_mean(f"{METRICS_PREFIX}/{key}", float(metrics[key]))
        return True

    def _on_rollout_end(self) -> None:
        entropy_loss = self.logger.name_to_value.get("train/entropy_loss")
        if entropy_loss is not None:
            self.logger.record(f"{METRICS_PREFIX}/policy_entropy", -float(entropy_loss))
