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
#: mode, how far the policy's actions move when the belief is permuted (``belief_use``) and, on a team with links, how
#: much of the team's evidence is in the beliefs (``evidence_reach_*``).
LATENT_METRICS: tuple[str, ...] = ("latent_accuracy", *(f"latent_accuracy_{fraction_label(f)}" for f in EPISODE_FRACTIONS),
                                   "latent_kl", "latent_nmi", "belief_use",
                                   *(f"evidence_reach_{fraction_label(f)}" for f in EPISODE_FRACTIONS))


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


#: What each metric of an evaluation record is, and which way is better (``"higher"``, ``"lower"`` or ``""`` when
#: neither is): printed beside the numbers by :func:`format_summary`. The reserve's are defined in docs/env.md,
#: ZonePatrol's in its card, the latent ones in docs/em.md.
METRIC_MEANINGS: dict[str, tuple[str, str]] = {
    "team_reward": ("the team reward summed over the episode (unshaped)", "higher"),
    "coverage_efficiency": ("share of the high-risk cells seen at least once", "higher"),
    "detection_rate": ("threats detected over threats that came (poachers; ZonePatrol: intruders)", "higher"),
    "false_alarms": ("spurious poacher readings (sensor noise, decoys), all UAVs", "lower"),
    "poaching_events": ("leopards poached", "lower"),
    "collisions": ("UAV pairs sharing a cell, summed over the steps", "lower"),
    "energy": ("battery spent by the whole team (a full battery is 1)", "lower"),
    "time_to_first_detection": ("steps from the first poacher's entry to its first detection", "lower"),
    "signs_found": ("distinct real signs of poacher activity found", "higher"),
    "detections": ("intruders detected", "higher"),
    "escapes": ("intruders that escaped undetected", "lower"),
    "intruders": ("intruders that appeared (the episode's, not the team's doing)", ""),
    "latent_accuracy": ("share of steps whose belief names the true mode (components matched to modes)", "higher"),
    **{f"latent_accuracy_{fraction_label(f)}": (f"the same, at {f:.0%} of the episode", "higher")
       for f in EPISODE_FRACTIONS},
    "latent_kl": ("KL from the belief to the true mode's one-hot (smoothed), mean over steps", "lower"),
    "latent_nmi": ("mutual information of the belief's choice and the mode, 0 (none) to 1", "higher"),
    "belief_use": ("how far the actions move when the belief is permuted (KL, nats): 0 when the policy ignores its "
                   "belief, higher the more its actions follow it (good only where the belief is right)", ""),
    **{f"evidence_reach_{fraction_label(f)}": (f"share of the team's evidence in a UAV's belief at {f:.0%} of the episode "
                                               "(1: the whole team's, 1/n: its own)", "higher")
       for f in EPISODE_FRACTIONS},
}


def format_summary(summary: dict[str, tuple[float, float]], title: str = "", explain: bool = True) -> str:
    """A plain-text table of ``summarize``'s output, one metric per line.

    :param summary: ``{metric: (mean, std)}``
    :param title: a first line
    :param explain: add what each metric is and which way is better (:data:`METRIC_MEANINGS`)
    """
    width = max(len(k) for k in summary)
    lines = [title] if title else []
    for k, (mean, std) in summary.items():
        line = f"{k:<{width}}  {mean:10.3f} +- {std:<8.3f}"
        meaning, better = METRIC_MEANINGS.get(k, ("", ""))
        if explain and meaning:
            line += f"  {meaning}" + (f" ({better} is better)" if better else "")
        lines.append(line.rstrip())
    return "\n".join(lines)
