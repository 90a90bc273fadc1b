"""Summaries of per-episode team metrics (mean and standard deviation over episodes)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from sb3_emmarl.common.latent.metrics import EPISODE_FRACTIONS, fraction_label

#: The reserve's episode metrics in the order tables show them.
TEAM_METRICS: tuple[str, ...] = (
    "team_reward",
    "coverage_efficiency",
    "detection_rate",
    "false_alarms",
    "poaching_events",
    "collisions",
    "energy",
    "time_to_first_detection",
    "signs_found",
)
#: What ``evaluate_team`` adds for a model with a latent belief (see ``LatentTracker``): how well the belief tells the
#: mode, and how far the policy's actions move when the belief is permuted (``belief_use``).
LATENT_METRICS: tuple[str, ...] = ("latent_accuracy", *(f"latent_accuracy_{fraction_label(f)}" for f in EPISODE_FRACTIONS),
                                   "latent_kl", "latent_nmi", "belief_use")


#: Keys of an evaluation record that describe the episode rather than measure it.
RECORD_KEYS: tuple[str, ...] = ("mode", "episode", "seed")


def team_metric_keys(record: Mapping[str, object]) -> tuple[str, ...]:
    """The team metrics of an episode record: :data:`TEAM_METRICS` when it holds most of them or lacks ``team_reward``
    (so that a reserve record with a metric missing is refused by name), else its own numeric metrics in their order
    (another environment's, e.g. ZonePatrol's), leaving out :data:`RECORD_KEYS` and :data:`LATENT_METRICS`."""
    if "team_reward" not in record or sum(key in record for key in TEAM_METRICS) > len(TEAM_METRICS) // 2:
        return TEAM_METRICS
    return tuple(key for key, value in record.items() if key not in RECORD_KEYS and key not in LATENT_METRICS
                 and isinstance(value, (int, float, np.number)) and not isinstance(value, bool))


def summarize(records: Sequence[dict[str, float]], keys: Sequence[str] | None = None) -> dict[str, tuple[float, float]]:
    """Mean and (population) standard deviation of each metric over episodes.

    :param records: one metrics dict per episode
    :param keys: which metrics to summarise (None: the records' team metrics (:func:`team_metric_keys`), then the
        :data:`LATENT_METRICS` they hold)
    :return: ``{metric: (mean, std)}``
    """
    if not records:
        raise ValueError("summarize needs at least one episode record")
    if keys is None:
        keys = (*team_metric_keys(records[0]), *(k for k in LATENT_METRICS if k in records[0]))
    missing = [k for k in keys if k not in records[0]]
    if missing:
        raise ValueError(f"episode records lack the metrics {missing}; they have {sorted(records[0])}")
    return {k: (float(np.mean([r[k] for r in records])), float(np.std([r[k] for r in records]))) for k in keys}


def format_summary(summary: dict[str, tuple[float, float]], title: str = "") -> str:
    """A plain-text table of ``summarize``'s output, one metric per line."""
    width = max(len(k) for k in summary)
    lines = [title] if title else []
    lines += [f"{k:<{width}}  {mean:10.3f} +- {std:.3f}" for k, (mean, std) in summary.items()]
    return "\n".join(lines)
