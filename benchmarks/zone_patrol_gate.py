"""The gate of ZonePatrol (no training): how much more a scripted team told the hidden mode earns than the best
scripted team that is not told it.

Every blind plan (:func:`~wildlife_reserve.zone_patrol.scripted.blind_plans`: how the team searches before a zone
shows evidence, how it picks its sensor; the team shares everything its UAVs see) plays ``--fit`` fitting episodes
(seed 0); the best of them and the told team then play the same ``--episodes`` held-out episodes (seed 1, the same
modes and starting states for both: a paired comparison). Printed: each plan's fitting score, then told against the
best blind team on the held-out episodes (mean +- std, their ratio, the paired t-test and Wilcoxon p-values, per
mode), and the stepping speed of 16 copies x 4 UAVs with random actions against the reserve's batched vector
environment (agent-steps per second, one process, taking turns).

The held-out lines end with how often the exact posterior of the whole team's zone readings tells the zone at
mid-episode (:func:`~wildlife_reserve.zone_patrol.posterior.zone_posterior`: what a belief that pools the team's
evidence can reach). ZonePatrol's default ``zone_cue`` (``zone_patrol_v1``) was chosen on this gate: the largest of
0.20, 0.21, ..., 0.25 at which the told team earns 1.5 times the best blind team and that posterior is right 0.9 of
the time.

Example: ``python benchmarks/zone_patrol_gate.py`` (about a minute; ``--zone-cue 0``: zone_patrol_v0's task)
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np
from scipy import stats

from wildlife_reserve.zone_patrol.scripted import BlindTeam, ToldTeam, blind_plans, play_and_read
from wildlife_reserve.zone_patrol.world import N_WEATHERS, ZonePatrolConfig, ZonePatrolWorld


def episodes(team, config: ZonePatrolConfig, n: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Team rewards of ``n`` episodes (one batch of copies), their modes, and whether the exact posterior of the whole
    team's zone readings tells each episode's zone at mid-episode (step ``max_cycles // 2``); the modes come from their
    own generator, so every team meets the same modes and starting states."""
    world = ZonePatrolWorld(config, n)
    modes = np.random.default_rng([seed, 1]).integers(config.n_modes, size=n)
    rewards, posterior = play_and_read(team, world, np.random.default_rng(seed), modes, config.max_cycles // 2)
    return rewards, modes, posterior.argmax(1) == modes // N_WEATHERS


def gate(config: ZonePatrolConfig, fit: int = 300, held_out: int = 300) -> str:
    header = "blind plan (search, sensor, confidence)" if config.zone_cue else "blind plan (search, sensor)"
    lines = [f"{header:<40}{'fitting episodes':>20}"]
    scores = {}
    for plan in blind_plans(bool(config.zone_cue)):
        scores[plan] = episodes(BlindTeam(*plan), config, fit, 0)[0].mean()
        lines.append(f"{plan!s:<40}{scores[plan]:>20.3f}")
    best = max(scores, key=scores.get)
    told, modes, right = episodes(ToldTeam(), config, held_out, 1)
    blind = episodes(BlindTeam(*best), config, held_out, 1)[0]
    diff = told - blind
    lines += ["", f"held-out episodes: {held_out} (seed 1); the best blind plan on the fitting episodes: {best}",
              f"told {told.mean():.3f} +- {told.std():.3f}; best blind {blind.mean():.3f} +- {blind.std():.3f}; "
              f"ratio {told.mean() / blind.mean():.3f}; difference {diff.mean():.3f} +- {diff.std():.3f}",
              f"paired t p = {stats.ttest_rel(told, blind).pvalue:.3g}; Wilcoxon p = {stats.wilcoxon(diff).pvalue:.3g}; "
              f"told higher in {int((diff > 0).sum())} of {held_out} episodes",
              f"the exact posterior of the whole team's zone readings tells the zone at step {config.max_cycles // 2} "
              f"of {config.max_cycles} in {right.mean():.3f} of the held-out episodes"
              + ("" if config.zone_cue else " (no zone readings: chance)"),
              f"{'mode (zone, weather)':<24}{'episodes':>9}{'told':>9}{'blind':>9}"]
    for mode in range(config.n_modes):
        mine = modes == mode
        name = f"{mode} ({mode // 2}, {('clear', 'fog')[mode % 2]})"
        if mine.any():
            lines.append(f"{name:<24}{int(mine.sum()):>9}{told[mine].mean():>9.2f}{blind[mine].mean():>9.2f}")
        else:
            lines.append(f"{name:<24}{0:>9}{'-':>9}{'-':>9}")
    return "\n".join(lines)


def speed(seconds: float = 3.0, rounds: int = 3) -> str:
    """Agent-steps per second of 16 copies x 4 UAVs with random actions: ZonePatrol's world (step, observations and
    links) against the reserve's batched vector environment, taking turns."""
    from sb3_emmarl.common.vec_env import make_vec_env

    rng = np.random.default_rng(0)
    world = ZonePatrolWorld(ZonePatrolConfig(), 16)
    world.reset(rng)
    reserve = make_vec_env(16, seed=0, env_kwargs={"n_uavs": 4})
    reserve.reset()

    def zone_patrol_steps() -> int:
        world.step(rng.integers(10, size=(16, 4)), rng)
        world.observations()
        world.links()
        if world.t >= world.config.max_cycles:
            world.reset(rng)
        return 64

    def reserve_steps() -> int:
        reserve.step(rng.integers(reserve.action_space.n, size=reserve.num_envs))
        return reserve.num_envs

    rates: dict[str, list[float]] = {"zone_patrol": [], "reserve": []}
    for _ in range(rounds):
        for name, step in (("zone_patrol", zone_patrol_steps), ("reserve", reserve_steps)):
            start, done = time.perf_counter(), 0
            while time.perf_counter() - start < seconds:
                done += step()
            rates[name].append(done / (time.perf_counter() - start))
    reserve.close()
    zone, res = np.median(rates["zone_patrol"]), np.median(rates["reserve"])
    return (f"16 copies x 4 UAVs, random actions, median of {rounds} turns of {seconds:.0f} s: ZonePatrol {zone:,.0f} "
            f"agent-steps/s, the reserve {res:,.0f} ({zone / res:.1f}x)")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--fit", type=int, default=300, help="fitting episodes per blind plan")
    parser.add_argument("--episodes", type=int, default=300, help="held-out episodes")
    parser.add_argument("--no-speed", action="store_true", help="skip the speed comparison")
    parser.add_argument("--zone-cue", type=float, default=ZonePatrolConfig.zone_cue,
                        help=f"ZonePatrol's zone_cue (default {ZonePatrolConfig.zone_cue}, zone_patrol_v1's; 0: no zone "
                             "readings, as zone_patrol_v0)")
    args = parser.parse_args(argv)
    if args.fit < 1 or args.episodes < 2:
        parser.error(f"--fit must be >= 1 and --episodes >= 2, got {args.fit} and {args.episodes}")
    try:
        config = ZonePatrolConfig(zone_cue=args.zone_cue)
    except ValueError as error:
        parser.error(str(error))
    print(gate(config, args.fit, args.episodes))
    if not args.no_speed:
        print(speed())
    return 0


if __name__ == "__main__":
    sys.exit(main())
