"""Does the hidden mode show in what a team observes? A supervised ceiling, by patrol, source and time.

The UAVs never observe the mode; a latent method can only infer it if the evidence they gather carries
it. This script plays episodes with a scripted patrol (random actions, or the stalest-block sweep),
then trains a classifier *with the true mode as label* and reports its held-out accuracy on the mode,
the poacher strategy and the weather, beside the commonest-class rate of the held-out set, from

- **one UAV**: that UAV's observations so far;
- **the team**: all the team's observations so far;

at the first observation (the reset) and after 25 %, 50 % and 100 % of ``max_cycles``.

"Observations so far" are summarised generically, whatever the layout: per UAV, the running mean and the
running maximum over steps ``0..t`` of its observation vector, elementwise (the observation's own maps
already accumulate what the UAV knows); for the team, the mean and the maximum over its UAVs of those.
The classifier is :func:`latent_probe.probe_accuracy` (an MLP with 128 ReLU units on standardised
inputs) predicting the 8-way mode; strategy and weather are read off the predicted mode
(``mode // 2``, ``mode % 2``). One-UAV samples are all the UAVs of every episode; team samples one per
episode. Held-out episodes have seeds disjoint from the training ones.

Example: ``python benchmarks/mode_evidence.py`` (or ``make benchmark-mode-evidence``)
"""

from __future__ import annotations

import argparse
import ast
import importlib.util
import time
from pathlib import Path

import numpy as np
import torch as th

from wildlife_reserve import reserve_v0
from wildlife_reserve.reserve.modes import N_MODES, WEATHERS
from wildlife_reserve.reserve.scripted import RandomPatrol, StalestBlockPatrol

#: Points of the episode, as fractions of ``max_cycles`` (0: the reset observation).
POINTS = (0.0, 0.25, 0.5, 1.0)
PATROLS = {"random": lambda env, seed: RandomPatrol(env, seed=seed), "scripted": lambda env, seed: StalestBlockPatrol(env)}
#: Offset of the held-out episodes' seeds.
TEST_SEED_OFFSET = 1_000_000


def _probe_accuracy():
    """``probe_accuracy`` of the sibling ``latent_probe.py`` (benchmarks are scripts, not a package)."""
    path = Path(__file__).resolve().parent / "latent_probe.py"
    spec = importlib.util.spec_from_file_location("latent_probe", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.probe_accuracy


def summarise(observations: np.ndarray) -> np.ndarray:
    """Per-UAV features of an observation history ``(t + 1, n, d)``: running mean and max over time, ``(n, 2d)``."""
    return np.concatenate([observations.mean(axis=0), observations.max(axis=0)], axis=-1)


def team_features(per_uav: np.ndarray) -> np.ndarray:
    """Team features from per-UAV features ``(n, f)``: their mean and max over UAVs, ``(2f,)``."""
    return np.concatenate([per_uav.mean(axis=0), per_uav.max(axis=0)])


def collect_features(env_kwargs: dict, patrol: str, seeds: range, points: tuple[float, ...] = POINTS,
                     patrol_seed: int = 0) -> tuple[dict[float, np.ndarray], dict[float, np.ndarray], np.ndarray]:
    """Play one episode per seed with a patrol and summarise the observations at each point.

    Running sums and maxima are kept instead of the whole history (the same numbers, less memory).

    :param env_kwargs: the reserve's arguments
    :param patrol: ``"random"`` or ``"scripted"``
    :param seeds: one episode per seed
    :param points: fractions of ``max_cycles`` (an episode that ends earlier is summarised at its end)
    :param patrol_seed: seed of the random patrol's draws
    :return: one-UAV features ``{point: (episodes * n, f)}``, team features ``{point: (episodes, 2f)}``, and the
        modes ``(episodes,)``
    """
    env = reserve_v0.parallel_env(**env_kwargs)
    policy = PATROLS[patrol](env, patrol_seed)
    steps = {point: round(point * env.max_cycles) for point in points}
    single: dict[float, list] = {point: [] for point in points}
    team: dict[float, list] = {point: [] for point in points}
    modes = []
    for seed in seeds:
        observations, infos = env.reset(seed=seed)
        obs = np.stack([observations[a] for a in env.possible_agents]).astype(np.float64)
        total, peak, t = obs.copy(), obs.copy(), 0
        modes.append(infos[env.possible_agents[0]]["mode"])
        for point in points:
            while t < steps[point] and env.agents:
                observations, *_ = env.step(policy(observations))
                obs = np.stack([observations[a] for a in env.possible_agents])
                total += obs
                np.maximum(peak, obs, out=peak)
                t += 1
            per_uav = np.concatenate([total / (t + 1), peak], axis=-1)
            single[point].append(per_uav)
            team[point].append(team_features(per_uav))
    env.close()
    return ({p: np.concatenate(v).astype(np.float32) for p, v in single.items()},
            {p: np.stack(v).astype(np.float32) for p, v in team.items()}, np.array(modes))


def accuracies(predicted: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    """Accuracy on the mode, the strategy and the weather, and the commonest-class rate of each in ``truth``."""
    n_weathers = len(WEATHERS)
    out = {}
    for name, part in (("mode", lambda m: m), ("strategy", lambda m: m // n_weathers), ("weather", lambda m: m % n_weathers)):
        out[name] = float(np.mean(part(predicted) == part(truth)))
        out[f"{name}_majority"] = float(np.bincount(part(truth)).max() / len(truth))
    return out


def evaluate(env_kwargs: dict, patrol: str, train_episodes: int, test_episodes: int, seed: int, epochs: int,
             points: tuple[float, ...] = POINTS) -> list[dict]:
    """Held-out accuracies of the supervised probe for one patrol: one row per (source, point)."""
    probe = _probe_accuracy()
    train_single, train_team, train_modes = collect_features(env_kwargs, patrol, range(seed, seed + train_episodes),
                                                             points, patrol_seed=seed)
    test_seeds = range(TEST_SEED_OFFSET + seed, TEST_SEED_OFFSET + seed + test_episodes)
    test_single, test_team, test_modes = collect_features(env_kwargs, patrol, test_seeds, points, patrol_seed=seed + 1)
    n = len(train_single[points[0]]) // train_episodes
    rows = []
    for source, train, test, y_train, y_test in (
        ("one UAV", train_single, test_single, np.repeat(train_modes, n), np.repeat(test_modes, n)),
        ("team", train_team, test_team, train_modes, test_modes),
    ):
        for point in points:
            predicted = probe(train[point], y_train, test[point], N_MODES, epochs, seed)
            rows.append({"patrol": patrol, "source": source, "point": point, "samples": len(y_train),
                         **accuracies(predicted, y_test)})
    return rows


def format_rows(rows: list[dict]) -> str:
    """The table: one line per (patrol, source, point)."""
    header = (f"{'patrol':<9}{'source':<9}{'point':>6}{'mode':>7}{'strategy':>10}{'weather':>9}"
              f"{'commonest: mode':>17}{'strategy':>10}{'weather':>9}{'train samples':>15}")
    lines = [header]
    for r in rows:
        point = "first" if r["point"] == 0 else f"{r['point']:.0%}"
        lines.append(f"{r['patrol']:<9}{r['source']:<9}{point:>6}{r['mode']:>7.3f}{r['strategy']:>10.3f}{r['weather']:>9.3f}"
                     f"{r['mode_majority']:>17.3f}{r['strategy_majority']:>10.3f}{r['weather_majority']:>9.3f}"
                     f"{r['samples']:>15,}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--episodes", type=int, default=1500, help="training episodes per patrol")
    parser.add_argument("--test-episodes", type=int, default=300, help="held-out episodes per patrol")
    parser.add_argument("--patrols", nargs="+", default=list(PATROLS), help=f"patrols, among {sorted(PATROLS)}")
    parser.add_argument("--seed", type=int, default=0, help="seed of the first training episode")
    parser.add_argument("--epochs", type=int, default=20, help="classifier epochs")
    parser.add_argument("--env-kwargs", type=str, default="{}", help="the reserve's arguments as a Python dict literal")
    args = parser.parse_args(argv)
    for name in ("episodes", "test_episodes", "epochs"):
        if getattr(args, name) < 1:
            parser.error(f"--{name.replace('_', '-')} must be >= 1, got {getattr(args, name)}")
    if args.seed < 0:
        parser.error(f"--seed must be >= 0, got {args.seed}")
    unknown = [p for p in args.patrols if p not in PATROLS]
    if unknown:
        parser.error(f"--patrols must be among {sorted(PATROLS)}, got {unknown}")
    try:
        env_kwargs = ast.literal_eval(args.env_kwargs)
        if not isinstance(env_kwargs, dict):
            raise ValueError("not a dict")
        reserve_v0.parallel_env(**env_kwargs)
    except (ValueError, SyntaxError, TypeError) as error:
        parser.error(f"--env-kwargs must be a dict literal of the reserve's arguments, got {args.env_kwargs!r}: {error}")
    th.set_num_threads(1)
    start = time.perf_counter()
    print(f"Supervised probe of the hidden mode: {args.episodes} training and {args.test_episodes} held-out episodes per "
          f"patrol (seeds {args.seed}.. and {TEST_SEED_OFFSET + args.seed}..), env_kwargs {env_kwargs}, "
          f"{args.epochs} epochs")
    rows = [row for patrol in args.patrols
            for row in evaluate(env_kwargs, patrol, args.episodes, args.test_episodes, args.seed, args.epochs)]
    print(format_rows(rows))
    print(f"wall time {time.perf_counter() - start:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
