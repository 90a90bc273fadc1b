"""Scripted teams for ZonePatrol: one told the hidden mode, and blind ones that act on what the team has seen.

A scripted team acts on a :class:`~wildlife_reserve.zone_patrol.world.ZonePatrolWorld` (every copy at once). The
told team flies every UAV to its post in the mode's zone (posts that tile the zone with the narrow sensor's reach)
and uses the weather's sensor. A blind team knows what any of its UAVs has seen so far (tracks in the windows,
detections, visibility readings: the team shares everything, as no learned team can), never the mode: it flies to
zones by its ``search`` plan until a zone shows a track or a detection, then the whole team goes there, and picks
its sensor by ``sensor`` (``"estimate"``: wide while the team's mean visibility reading is above one half, i.e.
clear). With ZonePatrol's zone readings (``zone_cue``) the team also sums every UAV's readings and, once the
posterior of a zone (the readings' exact Bayes posterior) passes ``confidence``, goes there as on a track.
:func:`blind_plans` lists the plans; the best is chosen on fitting episodes and compared on held-out ones
(``benchmarks/zone_patrol_gate.py``).
"""

from __future__ import annotations

from itertools import product

import numpy as np

from wildlife_reserve.zone_patrol.posterior import zone_posterior
from wildlife_reserve.zone_patrol.world import CLEAR, N_MOVES, N_ZONES, NARROW, WIDE, ZonePatrolWorld

#: How a blind team searches before a zone shows evidence: each UAV to its own zone (``"split"``), or the whole team
#: through the zones one after another (``"together"``).
SEARCHES = ("split", "together")
SENSORS = ("estimate", "wide", "narrow")
#: How sure of a zone the zone readings must make a blind team before it goes there (with ``zone_cue`` only).
CONFIDENCES = (0.6, 0.9, 0.99)


def blind_plans(cues: bool = False) -> list[tuple]:
    """Every ``(search, sensor)`` plan of a blind team; with ``cues`` (ZonePatrol's ``zone_cue``), every
    ``(search, sensor, confidence)``."""
    return list(product(SEARCHES, SENSORS, CONFIDENCES)) if cues else list(product(SEARCHES, SENSORS))


def posts(world: ZonePatrolWorld) -> np.ndarray:
    """``(4, n_uavs, 2)``: each UAV's post in each zone, spread so that the posts tile the zone."""
    cfg = world.config
    reach = max(cfg.narrow_radius, 0)
    step = 2 * reach + 1
    spots = np.arange(reach, cfg.zone_size, step).clip(max=cfg.zone_size - 1)
    grid = np.stack(np.meshgrid(spots, spots, indexing="ij"), -1).reshape(-1, 2)
    chosen = grid[np.arange(cfg.n_uavs) % len(grid)]
    return cfg.zone_origins()[:, None, :] + chosen[None]


def move_towards(positions: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """The move (0-4) that shortens the longer of the row and column gaps to ``targets`` (0: there)."""
    gap = targets - positions
    rows_first = np.abs(gap[..., 0]) >= np.abs(gap[..., 1])
    move = np.where(rows_first, np.where(gap[..., 0] < 0, 1, 2), np.where(gap[..., 1] < 0, 3, 4))
    return np.where((gap == 0).all(-1), 0, move)


class ToldTeam:
    """Every UAV to its post in the mode's zone, with the weather's sensor."""

    def reset(self, world: ZonePatrolWorld) -> None:
        self.posts = posts(world)

    def act(self, world: ZonePatrolWorld) -> np.ndarray:
        targets = self.posts[world.zones]
        sensor = np.where(world.weathers == CLEAR, WIDE, NARROW)[:, None]
        return move_towards(world.positions, targets) + N_MOVES * sensor


class BlindTeam:
    """A team that does not know the mode (see the module's text).

    :param search: ``"split"`` or ``"together"``
    :param sensor: ``"estimate"``, ``"wide"`` or ``"narrow"``
    :param confidence: the posterior of a zone, from the zone readings, at which the team goes there (in (0, 1))
    """

    def __init__(self, search: str = "split", sensor: str = "estimate", confidence: float = 0.9) -> None:
        if search not in SEARCHES or sensor not in SENSORS:
            raise ValueError(f"search must be one of {list(SEARCHES)} and sensor one of {list(SENSORS)}, "
                             f"got {search!r} and {sensor!r}")
        if not 0 < confidence < 1:
            raise ValueError(f"confidence must be in (0, 1), got {confidence!r}")
        self.search, self.sensor, self.confidence = search, sensor, float(confidence)

    def reset(self, world: ZonePatrolWorld) -> None:
        c = world.n_copies
        self.posts = posts(world)
        self.evidence = np.zeros((c, N_ZONES))
        self.visited = np.zeros((c, N_ZONES), dtype=bool)
        self.readings = np.zeros(c)
        self.n_readings = 0
        self.cue_sums = np.zeros((c, N_ZONES))

    def _observe(self, world: ZonePatrolWorld) -> None:
        cfg = world.config
        r, g = cfg.window_radius, cfg.grid_size
        rows, cols = np.indices((g, g))
        seen = np.zeros((world.n_copies, g, g), dtype=bool)
        for u in range(cfg.n_uavs):
            pos = world.positions[:, u]
            seen |= (np.abs(rows[None] - pos[:, :1, None]) <= r) & (np.abs(cols[None] - pos[:, 1:, None]) <= r)
        marks = (world.tracks > 0) & seen
        origins = cfg.zone_origins()
        for z, (top, left) in enumerate(origins):
            block = marks[:, top:top + cfg.zone_size, left:left + cfg.zone_size]
            self.evidence[:, z] += block.any((1, 2))
            here = (world.positions[:, :, None, :] == self.posts[z][None]).all(-1).any(-1)  # (c, n)
            self.visited[:, z] |= here.any(1)
        self.readings += world.visibility.mean(1)
        self.n_readings += 1
        if world.cues.shape[-1]:
            self.cue_sums += world.cues.sum(1)

    def zone_posterior(self, world: ZonePatrolWorld) -> np.ndarray:
        """``(c, 4)``: each zone's posterior from the team's zone readings so far (:func:`zone_posterior`)."""
        return zone_posterior(world.config.zone_cue, self.cue_sums)

    def act(self, world: ZonePatrolWorld) -> np.ndarray:
        self._observe(world)
        n = world.config.n_uavs
        tracked = self.evidence.max(1) > 0
        posterior = self.zone_posterior(world)
        known = tracked | (posterior.max(1) >= self.confidence)
        best = np.where(tracked, self.evidence.argmax(1), posterior.argmax(1))
        if self.search == "split":
            zones = np.broadcast_to(np.arange(n) % N_ZONES, (world.n_copies, n))
        else:  # together: the first zone not yet visited
            nxt = np.where(self.visited.all(1), 0, (~self.visited).argmax(1))
            zones = np.broadcast_to(nxt[:, None], (world.n_copies, n))
        zones = np.where(known[:, None], best[:, None], zones)
        targets = self.posts[zones, np.arange(n)[None, :]]
        if self.sensor == "estimate":
            clear = self.readings / max(self.n_readings, 1) > 0.5
            sensor = np.where(clear, WIDE, NARROW)[:, None]
        else:
            sensor = np.full((world.n_copies, 1), WIDE if self.sensor == "wide" else NARROW)
        return move_towards(world.positions, targets) + N_MOVES * sensor


def play(team, world: ZonePatrolWorld, rng: np.random.Generator, modes: np.ndarray | None = None) -> np.ndarray:
    """One episode in every copy of ``world`` with ``team``; returns each copy's team reward."""
    return play_and_read(team, world, rng, modes)[0]


def play_and_read(team, world: ZonePatrolWorld, rng: np.random.Generator, modes: np.ndarray | None = None,
                  posterior_at: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """:func:`play`, also returning, per copy, the exact zone posterior ``(c, 4)`` of the whole team's zone readings of
    the observations up to step ``posterior_at`` (the one after reset included; :func:`zone_posterior`), whatever the
    team does (None, the default: uniform)."""
    world.reset(rng, modes)
    team.reset(world)
    cue_sums = world.cues.sum(1)
    posterior = np.full((world.n_copies, N_ZONES), 1.0 / N_ZONES)
    if posterior_at is not None and not 1 <= posterior_at <= world.config.max_cycles:
        raise ValueError(f"posterior_at must be a step in [1, {world.config.max_cycles}], got {posterior_at!r}")
    for t in range(1, world.config.max_cycles + 1):
        world.step(team.act(world), rng)
        if posterior_at is not None and t <= posterior_at:
            cue_sums = cue_sums + world.cues.sum(1)
            if t == posterior_at:
                posterior = zone_posterior(world.config.zone_cue, cue_sums)
    return world.team_reward.copy(), posterior
