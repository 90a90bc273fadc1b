"""Where a ZonePatrol team's evidence goes (no training): how much of it reaches each UAV's belief, step by step,
under the links, and what that is worth.

Scripted teams play held-out episodes of ZonePatrol (a uniformly random team; the blind scripted teams that search
``together`` or ``split`` over the four zones, :class:`~wildlife_reserve.zone_patrol.scripted.BlindTeam`) at several
``comm_range`` values. Each UAV's evidence is the exact log-likelihood of each mode from its readings
(:func:`~wildlife_reserve.zone_patrol.posterior.reading_log_likelihoods`), fused along the ``heard_from`` links by the
belief's own mechanism (:class:`~sb3_emmarl.common.latent.belief.BeliefTracker`: each teammate's newest version, relayed
one hop per step, counted once). Printed per team, range and step: the **evidence reach** (the share of the team's
transitions in a UAV's belief, :meth:`~sb3_emmarl.common.latent.belief.BeliefTracker.evidence_reach`; 1: the whole
team's) and how often the zone is told by the exact posterior of one UAV's readings, of the readings that reached it,
and of the whole team's. ZonePatrol has no message loss: its links are the range alone.

Example: ``python benchmarks/zone_patrol_reach.py`` (about a minute)
"""

from __future__ import annotations

import argparse
import sys

import numpy as np
from scipy.special import logsumexp

from sb3_emmarl.common.latent.belief import BeliefTracker
from wildlife_reserve.zone_patrol.posterior import reading_log_likelihoods
from wildlife_reserve.zone_patrol.scripted import BlindTeam
from wildlife_reserve.zone_patrol.world import N_WEATHERS, N_ZONES, ZonePatrolConfig, ZonePatrolWorld

TEAMS = ("random", "together", "split")


def zone_right(evidence: np.ndarray, zones: np.ndarray) -> np.ndarray:
    """Whether the zone marginal of mode evidence ``(..., 8)`` names ``zones`` ``(...)``."""
    by_zone = logsumexp(evidence.reshape(*evidence.shape[:-1], N_ZONES, N_WEATHERS), axis=-1)
    return by_zone.argmax(-1) == zones


def measure(team: str, comm_range: int, episodes: int, seed: int, steps: tuple[int, ...]) -> dict[int, tuple]:
    """``{step: (reach, one UAV right, along the links right, whole team right)}``, means over UAVs and episodes."""
    config = ZonePatrolConfig(comm_range=comm_range)
    world, rng, n = ZonePatrolWorld(config, episodes), np.random.default_rng(seed), config.n_uavs
    world.reset(rng)
    scripted = BlindTeam(team, "estimate") if team != "random" else None
    if scripted is not None:
        scripted.reset(world)
    tracker = BeliefTracker(episodes * n, N_ZONES * N_WEATHERS, 1, 1, agents_per_copy=n)
    tracker.start(np.arange(episodes * n), np.zeros((episodes * n, 1)))
    zones = np.repeat(world.zones, n)
    out = {}
    for t in range(config.max_cycles + 1):
        evidence = reading_log_likelihoods(config, world.observations().reshape(episodes * n, -1))
        tracker.evidence += evidence
        if t:  # (the reset's readings are each UAV's own until the first messages)
            links = world.links()
            tracker.fuse([{"heard_from": links[c][u]} for c in range(episodes) for u in range(n)])
        if t in steps:
            team_evidence = tracker.evidence.reshape(episodes, n, -1).sum(1)
            out[t] = (float(tracker.evidence_reach().mean()), float(zone_right(tracker.evidence, zones).mean()),
                      float(zone_right(tracker.log_beliefs(), zones).mean()),
                      float(zone_right(team_evidence, world.zones).mean()))
        if t < config.max_cycles:
            actions = scripted.act(world) if scripted is not None else rng.integers(10, size=(episodes, n))
            world.step(actions, rng)
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--teams", nargs="+", default=list(TEAMS), choices=TEAMS)
    parser.add_argument("--ranges", type=int, nargs="+", default=[4, 8, 14, 28], help="comm_range values")
    parser.add_argument("--episodes", type=int, default=1000)
    parser.add_argument("--steps", type=int, nargs="+", default=[15, 30, 60])
    args = parser.parse_args(argv)
    if args.episodes < 1 or min(args.ranges) < 0 or not all(1 <= s <= ZonePatrolConfig.max_cycles for s in args.steps):
        parser.error(f"--episodes must be >= 1, --ranges >= 0 and --steps in [1, {ZonePatrolConfig.max_cycles}]")
    print(f"ZonePatrol (zone_patrol_v1's defaults but comm_range), {args.episodes} episodes (seed 1) per team and range; "
          "per step: the evidence reach, and the share of UAVs whose exact posterior tells the zone from its own "
          "readings / the readings that reached it / the whole team's")
    print(f"{'team':<10}{'range':>6}{'step':>6}{'reach':>8}{'one UAV':>9}{'links':>8}{'team':>8}")
    for team in args.teams:
        for comm_range in args.ranges:
            for step, (reach, one, links, whole) in measure(team, comm_range, args.episodes, 1,
                                                            tuple(args.steps)).items():
                print(f"{team:<10}{comm_range:>6}{step:>6}{reach:>8.3f}{one:>9.3f}{links:>8.3f}{whole:>8.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
