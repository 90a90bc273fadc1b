"""The exact posterior of ZonePatrol's hidden mode from the readings its UAVs observe.

Every step each UAV reads the weather (visibility: 1 in clear weather, 0 in fog, plus Gaussian noise of deviation
``visibility_noise``) and, with ``zone_cue``, the zone (per zone, ``zone_cue`` on the mode's zone plus standard
normal noise), independently of everything else given the mode. The log-likelihood of each mode from one
observation's readings is therefore a sum of two Gaussian terms, and the posterior from any set of observations
(one UAV's, the evidence that reached it along the links, the whole team's) is the softmax of their sum under the
uniform prior: the reference against which a learned belief is scored (docs/zone_patrol.md). The tracks in view and
the detections also carry evidence of the zone, which these posteriors leave out; they depend on where the team flies.
"""

from __future__ import annotations

import numpy as np

from wildlife_reserve.zone_patrol.world import CLEAR, FOG, N_CHANNELS, N_WEATHERS, N_ZONES, ZonePatrolConfig


def zone_posterior(zone_cue: float, cue_sums: np.ndarray) -> np.ndarray:
    """``(..., 4)``: each zone's exact posterior (uniform prior) from sums ``(..., 4)`` of zone readings (uniform without
    them): unit-variance Gaussian readings with mean ``zone_cue`` on the mode's zone, so the log-odds are ``zone_cue``
    times the sums."""
    cue_sums = np.asarray(cue_sums, dtype=np.float64)
    if cue_sums.shape[-1] == 0:  # (no zone readings)
        return np.full((*cue_sums.shape[:-1], N_ZONES), 1.0 / N_ZONES)
    logits = zone_cue * cue_sums
    logits = logits - logits.max(-1, keepdims=True)
    weights = np.exp(logits)
    return weights / weights.sum(-1, keepdims=True)


def reading_log_likelihoods(config: ZonePatrolConfig, observations: np.ndarray) -> np.ndarray:
    """``(n, n_modes)``: the log-likelihood of each mode (``2 * zone + weather``) from the readings of each observation
    ``(n, d)`` (the environment's own first ``obs_dim`` values; more columns, a belief or a one-hot appended, are
    ignored), up to a constant per observation. The observations hold the readings clipped (visibility to [-3, 4],
    zone readings to [-4, 4]: beyond 3 deviations, rare) and scaled by 1/4, which is undone here."""
    observations = np.asarray(observations, dtype=np.float64)
    at = N_CHANNELS * config.window_cells + 2
    visibility = 4.0 * observations[:, at]
    if config.visibility_noise > 0:
        var = config.visibility_noise ** 2
        weather = np.stack([-(visibility - 1.0) ** 2, -visibility ** 2], axis=1) / (2 * var)  # (clear, fog)
    else:  # (a noiseless reading tells the weather)
        weather = np.where(np.stack([visibility > 0.5, visibility <= 0.5], axis=1), 0.0, -np.inf)
    assert (CLEAR, FOG) == (0, 1)
    zone = config.zone_cue * 4.0 * observations[:, at + 2:at + 2 + N_ZONES] if config.zone_cue else \
        np.zeros((len(observations), N_ZONES))
    return (zone[:, :, None] + weather[:, None, :]).reshape(len(observations), N_ZONES * N_WEATHERS)
