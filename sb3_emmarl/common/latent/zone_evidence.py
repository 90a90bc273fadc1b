"""ZonePatrol's evidence for the latent model: where tracks lie relative to the zones (a plug-in).

ZonePatrol (``wildlife_reserve.zone_patrol_v0``) hides a zone where intruders strike and a weather that decides
which sensor works; its observation is an egocentric window and the UAV's cell. :class:`ZoneEvidence` gives the
latent model (:mod:`~sb3_emmarl.common.latent.evidence`) :func:`zone_features` of any environment that exposes a
``zone_map``, the visibility and zone readings among them declared as readings (:func:`zone_readings`); it has no
count evidence. Registered when ``sb3_emmarl`` is imported.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from stable_baselines3.common.vec_env import VecEnv

from sb3_emmarl.common.latent.evidence import LatentEvidence, env_attribute, observation_size
from sb3_emmarl.common.latent.features import FeatureFn


def zone_features(zone_map: dict) -> tuple[FeatureFn, int]:
    """Compact features of an observation made of an egocentric window and the UAV's cell, on a map with zones where
    the hidden mode puts its events (ZonePatrol's ``zone_map``): ``2 * zones + 2``, by default 10 (14 with
    ZonePatrol's ``zone_cue``).

    Per zone, the window cells of the zone that hold a track (capped at 5, over 5) and the window cells of the zone
    (over the window's cells, the exposure); then the visibility reading as observed, the window's detection cells
    this step and, when the observation has them (``zone_cue``), the zone readings as observed. The zone is where the
    mode shows, so the features say *where* the tracks were seen, which an egocentric window alone does not; the
    visibility is where the weather shows. How well EM reads the mode from them, against :func:`generic_features`:
    ``docs/lab/2026-12-05/zone_patrol_latent_ceiling.py`` (its figures in that day's lab notebook).

    :param zone_map: plain values: ``grid_size``, ``zone_size``, ``window_radius``, ``zone_origins`` (top-left cells),
        the observation's ``tracks``, ``detections`` and ``own`` parts as ``[start, stop]`` (``own``: row and column
        scaled to [-1, 1]), the index of its ``visibility`` and its ``cues`` as ``[start, stop]`` or None
    """
    g, size, r = int(zone_map["grid_size"]), int(zone_map["zone_size"]), int(zone_map["window_radius"])
    origins = np.asarray(zone_map["zone_origins"], dtype=np.int64).reshape(-1, 2)
    n_zones, side = len(origins), 2 * r + 1
    zone_of = np.full((g, g), -1, dtype=np.int64)
    for z, (top, left) in enumerate(origins):
        zone_of[top:top + size, left:left + size] = z
    # The zone of each window cell, for each cell the UAV can be in: (g, g, side * side), -1 off the zones or the map.
    rows, cols = np.indices((g, g))
    da, db = (np.indices((side, side)).reshape(2, -1) - r)
    at_rows, at_cols = rows[..., None] + da, cols[..., None] + db
    inside = (at_rows >= 0) & (at_rows < g) & (at_cols >= 0) & (at_cols < g)
    window_zones = np.where(inside, zone_of[np.clip(at_rows, 0, g - 1), np.clip(at_cols, 0, g - 1)], -1)
    tracks, detections, own = (slice(*zone_map[part]) for part in ("tracks", "detections", "own"))
    cues = slice(*zone_map["cues"]) if zone_map.get("cues") else slice(0, 0)
    visibility, n_cues = int(zone_map["visibility"]), cues.stop - cues.start
    dim = 2 * n_zones + 2 + n_cues

    def features(obs: np.ndarray) -> np.ndarray:
        obs = np.asarray(obs, dtype=np.float32)
        cell = np.clip(np.rint((obs[:, own] + 1.0) / 2.0 * (g - 1)).astype(np.int64), 0, g - 1)
        zones = window_zones[cell[:, 0], cell[:, 1]]  # (N, side * side)
        marked = obs[:, tracks] > 0
        out = np.empty((len(obs), dim), dtype=np.float32)
        for z in range(n_zones):
            here = zones == z
            out[:, z] = np.minimum((marked & here).sum(1), 5) / 5.0
            out[:, n_zones + z] = here.sum(1) / (side * side)
        out[:, 2 * n_zones] = obs[:, visibility]
        out[:, 2 * n_zones + 1] = (obs[:, detections] > 0).sum(1)
        out[:, 2 * n_zones + 2:] = obs[:, cues]
        return out

    return features, dim


def zone_readings(zone_map: dict) -> tuple[int, ...]:
    """The indices of :func:`zone_features`' readings: the visibility reading and, with ``zone_cue``, the zone readings
    (read afresh each step, independent given the mode; the tracks in view and the detections are not)."""
    n_zones = len(zone_map["zone_origins"])
    n_cues = zone_map["cues"][1] - zone_map["cues"][0] if zone_map.get("cues") else 0
    return (2 * n_zones, *range(2 * n_zones + 2, 2 * n_zones + 2 + n_cues))


class ZoneEvidence(LatentEvidence):
    """:func:`zone_features` of an environment with a ``zone_map`` (ZonePatrol), its readings
    (:func:`zone_readings`) modelled as readings; no counts.

    :param spec: ``kind`` ``"zones"``, ``obs_dim`` and the environment's ``zone_map``
    """

    kind = "zones"

    def __init__(self, spec: dict[str, Any]) -> None:
        super().__init__(spec)
        self._fn, self.feature_dim = zone_features(spec["zone_map"])
        self.readings = zone_readings(spec["zone_map"])

    @classmethod
    def from_env(cls, venv: VecEnv) -> ZoneEvidence | None:
        """ZonePatrol's (an environment whose ``zone_map`` is a dict)."""
        zone_map = env_attribute(venv, "zone_map")
        return cls({"kind": cls.kind, "obs_dim": observation_size(venv), "zone_map": zone_map}) \
            if isinstance(zone_map, dict) else None

    def features(self, observations: np.ndarray) -> np.ndarray:
        return self._fn(observations)
