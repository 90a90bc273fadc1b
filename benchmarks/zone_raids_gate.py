"""The gate of the reserve's zone raids (no training): how much more a scripted team told the hidden mode earns than
the best scripted team that is not told it.

On the reserve with ``scenario="zone_raids"`` (each poacher strategy strikes its own zone; see the environment card)
every team is a :class:`~wildlife_reserve.reserve.scripted.ZoneRaidPatrol`. Every blind plan (where its rings stand
before the team's first catch: one per zone or all around one guessed zone; whether it then converges on the zone of
that catch; the rings' radius) and every told plan (the rings' radius) plays ``--fit`` fitting episodes (seeds from
``FIT_SEED``); the best blind plan and the best told plan then play the same ``--episodes`` held-out episodes (seeds
from ``--eval-seed``: the same modes, maps and starting cells for both, a paired comparison). Printed: each plan's
fitting score, then told against the best blind team on the held-out episodes (mean +- std, the paired difference
with its standard deviation over episodes, the paired t-test and Wilcoxon p-values, how often told is higher), the
same per block of ``--block`` episodes (the spread of the difference between blocks), and per mode.

Example: ``python benchmarks/zone_raids_gate.py`` (about 10 minutes on one core);
``python benchmarks/zone_raids_gate.py --env-kwargs n_poachers:24`` for a variant.
"""

from __future__ import annotations

import argparse
import itertools
import sys
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np
from scipy import stats

from sb3_emmarl.common.trust.arguments import parse_key_values
from wildlife_reserve import reserve_v1
from wildlife_reserve.reserve.modes import MODE_NAMES, N_MODES
from wildlife_reserve.reserve.scripted import ZONE_RAID_PLANS, ZoneRaidPatrol, run_patrol

#: Seed of the first fitting episode (the held-out ones start at ``--eval-seed``, far from these).
FIT_SEED = 0
#: Radii of the rings of stations the plans try.
SPREADS = (4, 7, 10)


def plans() -> list[tuple[bool, str, bool, int]]:
    """Every plan, as ``(told, rings before the first catch, converge, spread)``: the told ones first."""
    told = [(True, "split", False, spread) for spread in SPREADS]
    blind = [(False, plan, converge, spread) for plan, converge, spread in
             itertools.product(ZONE_RAID_PLANS, (True, False), SPREADS)]
    return told + blind


def name(plan: tuple[bool, str, bool, int]) -> str:
    told, rings, converge, spread = plan
    return f"{'told' if told else rings + ('+converge' if converge else '')} r={spread}"


def play(plan: tuple[bool, str, bool, int], episodes: int, seed: int, env_kwargs: dict) -> list[dict]:
    """Each episode's metrics of ``plan`` on ``episodes`` episodes from ``seed`` (a module-level function, so that a
    process pool can run plans side by side)."""
    env = reserve_v1.parallel_env(**{"scenario": "zone_raids", **env_kwargs})
    told, rings, converge, spread = plan
    return run_patrol(env, ZoneRaidPatrol(env, told=told, plan=rings, converge=converge, spread=spread), episodes,
                      seed=seed)


def rewards(records: list[dict]) -> np.ndarray:
    return np.array([record["team_reward"] for record in records])


def gate(fit: int, held_out: int, eval_seed: int, block: int, env_kwargs: dict, n_jobs: int) -> str:
    every = plans()
    with ProcessPoolExecutor(n_jobs) as pool:
        fitted = list(pool.map(play, every, [fit] * len(every), [FIT_SEED] * len(every), [env_kwargs] * len(every)))
    scores = {plan: rewards(records).mean() for plan, records in zip(every, fitted)}
    lines = [f"{'plan (rings before the first catch, radius)':<46}{'fitting episodes':>18}"]
    lines += [f"{name(plan):<46}{score:>18.2f}" for plan, score in scores.items()]
    best_told = max((plan for plan in every if plan[0]), key=scores.__getitem__)
    best_blind = max((plan for plan in every if not plan[0]), key=scores.__getitem__)
    with ProcessPoolExecutor(min(n_jobs, 2)) as pool:
        told_records, blind_records = pool.map(play, (best_told, best_blind), (held_out,) * 2, (eval_seed,) * 2,
                                               (env_kwargs,) * 2)
    told, blind = rewards(told_records), rewards(blind_records)
    modes = np.array([record["mode"] for record in told_records])
    diff = told - blind
    blocks = diff[:len(diff) // block * block].reshape(-1, block).mean(axis=1)
    lines += ["", f"held-out episodes: {held_out} (seeds {eval_seed}-{eval_seed + held_out - 1}); the best told plan "
              f"{name(best_told)!r}, the best blind plan {name(best_blind)!r} (on the fitting episodes)",
              f"told {told.mean():.2f} +- {told.std():.2f}; best blind {blind.mean():.2f} +- {blind.std():.2f}",
              f"difference {diff.mean():.2f}, std over episodes {diff.std(ddof=1):.2f} "
              f"({diff.mean() / diff.std(ddof=1):.2f} std)",
              f"paired t p = {stats.ttest_rel(told, blind).pvalue:.3g}; Wilcoxon p = {stats.wilcoxon(diff).pvalue:.3g}; "
              f"told higher in {int((diff > 0).sum())} of {held_out} episodes, lower in {int((diff < 0).sum())}",
              f"blocks of {block} episodes: differences {' '.join(f'{value:.1f}' for value in blocks)}; "
              f"std {blocks.std(ddof=1):.2f} ({blocks.mean() / blocks.std(ddof=1):.1f} std)",
              f"{'mode':<32}{'episodes':>9}{'told':>9}{'blind':>9}{'caught told':>13}{'caught blind':>14}"]
    for mode in range(N_MODES):
        mine = modes == mode
        if mine.any():
            caught = [np.mean([r["poachers_detected"] for r, m in zip(records, mine) if m])
                      for records in (told_records, blind_records)]
            lines.append(f"{mode} {MODE_NAMES[mode]:<30}{int(mine.sum()):>9}{told[mine].mean():>9.2f}"
                         f"{blind[mine].mean():>9.2f}{caught[0]:>13.2f}{caught[1]:>14.2f}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--fit", type=int, default=100, help="fitting episodes per plan")
    parser.add_argument("--episodes", type=int, default=300, help="held-out episodes")
    parser.add_argument("--eval-seed", type=int, default=100_000, help="seed of the first held-out episode")
    parser.add_argument("--block", type=int, default=60, help="held-out episodes per block (the pilot's seeds)")
    parser.add_argument("--env-kwargs", nargs="*", default=[], metavar="KEY:VALUE",
                        help="arguments of the reserve beyond scenario='zone_raids' (the zoo's format)")
    parser.add_argument("--n-jobs", type=int, default=2, help="processes")
    args = parser.parse_args(argv)
    if args.fit < 1 or args.episodes < 2 or not 2 <= args.block <= args.episodes // 2 or args.n_jobs < 1:
        parser.error(f"--fit must be >= 1, --episodes >= 2, --block in [2, episodes / 2] and --n-jobs >= 1, got "
                     f"{args.fit}, {args.episodes}, {args.block} and {args.n_jobs}")
    try:
        env_kwargs = parse_key_values(args.env_kwargs, "--env-kwargs")
        reserve_v1.parallel_env(**{"scenario": "zone_raids", **env_kwargs})
    except ValueError as error:
        parser.error(str(error))
    start = time.perf_counter()
    print(gate(args.fit, args.episodes, args.eval_seed, args.block, env_kwargs, args.n_jobs))
    print(f"wall time {time.perf_counter() - start:.0f} s; reserve arguments: scenario='zone_raids' {env_kwargs}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
