"""Does the hidden mode show in what a team observes? A supervised ceiling, by patrol, source and time.

The UAVs never observe the mode; a latent method can only infer it if the evidence they gather carries
it. This script plays episodes with a scripted patrol (random actions, or the stalest-block sweep),
then trains a classifier *with the true mode as label* and reports its held-out accuracy on the mode,
the poacher strategy and the weather, beside the commonest-class rate of the held-out set, from

- **one UAV**: that UAV's observations so far;
- **the team**: all the team's observations so far;
- **UAV now**: one UAV's observation at that step alone, what a memoryless policy reads (its maps accumulate what
  the UAV knows, so the evidence a history holds can show in one observation; the design asks that it not);

at the first observation (the reset) and after 25 %, 50 % and 100 % of ``max_cycles``.

"Observations so far" are summarised generically, whatever the layout: per UAV, the running mean and the
running maximum over steps ``0..t`` of its observation vector, elementwise (the observation's own maps
already accumulate what the UAV knows); for the team, the mean and the maximum over its UAVs of those.
The classifier is :func:`probe_accuracy` (an MLP with 128 ReLU units on standardised
inputs) predicting the 8-way mode; strategy and weather are read off the predicted mode
(``mode // 2``, ``mode % 2``). One-UAV samples are all the UAVs of every episode (a random subset of
each episode's UAVs when there would be more than ``--max-uav-samples``, as the script then says); team
samples one per episode. Held-out episodes have seeds disjoint from the training ones.

Example: ``python benchmarks/mode_evidence.py`` (or ``make benchmark-mode-evidence``)
"""

from __future__ import annotations

import argparse
import ast
import time

import numpy as np
import torch as th
from torch import nn

from wildlife_reserve import reserve_v1
from wildlife_reserve.reserve.modes import N_MODES, WEATHERS
from wildlife_reserve.reserve.scripted import RandomPatrol, StalestBlockPatrol

#: Points of the episode, as fractions of ``max_cycles`` (0: the reset observation).
POINTS = (0.0, 0.25, 0.5, 1.0)
PATROLS = {"random": lambda env, seed: RandomPatrol(env, seed=seed), "scripted": lambda env, seed: StalestBlockPatrol(env)}
#: Offset of the held-out episodes' seeds.
TEST_SEED_OFFSET = 1_000_000


def probe_accuracy(train_x: np.ndarray, train_y: np.ndarray, test_x: np.ndarray, n_classes: int, epochs: int,
                   seed: int) -> np.ndarray:
    """Predicted classes for ``test_x`` from an MLP (128 ReLU units) trained by cross-entropy on standardised inputs."""
    th.manual_seed(seed)
    x = th.as_tensor(train_x, dtype=th.float32)
    y = th.as_tensor(train_y, dtype=th.long)
    mean, std = x.mean(0), x.std(0) + 1e-6
    net = nn.Sequential(nn.Linear(x.shape[1], 128), nn.ReLU(), nn.Linear(128, n_classes))
    optimizer = th.optim.Adam(net.parameters(), lr=1e-3)
    for _ in range(epochs):
        order = th.randperm(len(x))
        for start in range(0, len(x), 512):
            idx = order[start:start + 512]
            loss = nn.functional.cross_entropy(net((x[idx] - mean) / std), y[idx])
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
    with th.no_grad():
        return net((th.as_tensor(test_x, dtype=th.float32) - mean) / std).argmax(1).numpy()

def summarise(observations: np.ndarray) -> np.ndarray:
    """Per-UAV features of an observation history ``(t + 1, n, d)``: running mean and max over time, ``(n, 2d)``."""
    return np.concatenate([observations.mean(axis=0), observations.max(axis=0)], axis=-1)


def team_features(per_uav: np.ndarray) -> np.ndarray:
    """Team features from per-UAV features ``(n, f)``: their mean and max over UAVs, ``(2f,)``."""
    return np.concatenate([per_uav.mean(axis=0), per_uav.max(axis=0)])


def parse_env_kwargs(text: str) -> dict:
    """The reserve's arguments from a Python dict literal (``"{'n_uavs': 2}"``) or ``"dict(n_uavs=2)"``, read safely.

    Only literals are evaluated (:func:`ast.literal_eval`); nothing is called, ``dict(...)`` is read as keywords.

    :param text: the literal
    :raises ValueError: if ``text`` is neither
    """
    try:
        tree = ast.parse(text.strip(), mode="eval").body
    except SyntaxError as error:
        raise ValueError(f"not a Python literal ({error.msg})") from None
    if isinstance(tree, ast.Call) and isinstance(tree.func, ast.Name) and tree.func.id == "dict" and not tree.args:
        if any(keyword.arg is None for keyword in tree.keywords):
            raise ValueError("dict(...) takes key=literal pairs only")
        return {keyword.arg: ast.literal_eval(keyword.value) for keyword in tree.keywords}
    value = ast.literal_eval(tree)
    if not isinstance(value, dict):
        raise ValueError(f"not a dict but a {type(value).__name__}")
    return value


def collect_features(env_kwargs: dict, patrol: str, seeds: range, points: tuple[float, ...] = POINTS,
                     patrol_seed: int = 0, uavs_per_episode: int | None = None
                     ) -> tuple[dict[float, np.ndarray], dict[float, np.ndarray], np.ndarray, dict[float, np.ndarray]]:
    """Play one episode per seed with a patrol and summarise the observations at each point.

    Running sums and maxima are kept instead of the whole history (the same numbers, less memory).

    :param env_kwargs: the reserve's arguments
    :param patrol: ``"random"`` or ``"scripted"``
    :param seeds: one episode per seed
    :param points: fractions of ``max_cycles`` (an episode that ends earlier is summarised at its end)
    :param patrol_seed: seed of the random patrol's draws
    :param uavs_per_episode: one-UAV samples kept per episode, a random subset of its UAVs drawn from the
        episode's seed (None: all); the team features always use all of them
    :return: one-UAV features ``{point: (episodes * k, f)}`` (``k`` UAVs per episode, in their order),
        team features ``{point: (episodes, 2f)}``, the modes ``(episodes,)``, and the same ``k`` UAVs' observations
        at each point alone ``{point: (episodes * k, d)}``
    """
    env = reserve_v1.parallel_env(**env_kwargs)
    policy = PATROLS[patrol](env, patrol_seed)
    n = len(env.possible_agents)
    steps = {point: round(point * env.max_cycles) for point in points}
    single: dict[float, list] = {point: [] for point in points}
    team: dict[float, list] = {point: [] for point in points}
    now: dict[float, list] = {point: [] for point in points}
    modes = []
    for seed in seeds:
        observations, infos = env.reset(seed=seed)
        obs = np.stack([observations[a] for a in env.possible_agents]).astype(np.float64)
        total, peak, t = obs.copy(), obs.copy(), 0
        modes.append(infos[env.possible_agents[0]]["mode"])
        kept = slice(None)
        if uavs_per_episode is not None and uavs_per_episode < n:
            kept = np.sort(np.random.default_rng(seed).choice(n, uavs_per_episode, replace=False))
        for point in points:
            while t < steps[point] and env.agents:
                observations, *_ = env.step(policy(observations))
                obs = np.stack([observations[a] for a in env.possible_agents])
                total += obs
                np.maximum(peak, obs, out=peak)
                t += 1
            per_uav = np.concatenate([total / (t + 1), peak], axis=-1)
            single[point].append(per_uav[kept].astype(np.float32))
            team[point].append(team_features(per_uav).astype(np.float32))
            now[point].append(obs[kept].astype(np.float32))
    env.close()
    return ({p: np.concatenate(v) for p, v in single.items()}, {p: np.stack(v) for p, v in team.items()},
            np.array(modes), {p: np.concatenate(v) for p, v in now.items()})


def accuracies(predicted: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    """Accuracy on the mode, the strategy and the weather, and the commonest-class rate of each in ``truth``."""
    n_weathers = len(WEATHERS)
    out = {}
    for name, part in (("mode", lambda m: m), ("strategy", lambda m: m // n_weathers), ("weather", lambda m: m % n_weathers)):
        out[name] = float(np.mean(part(predicted) == part(truth)))
        out[f"{name}_majority"] = float(np.bincount(part(truth)).max() / len(truth))
    return out


def evaluate(env_kwargs: dict, patrol: str, train_episodes: int, test_episodes: int, seed: int, epochs: int,
             points: tuple[float, ...] = POINTS, uavs_per_episode: int | None = None) -> list[dict]:
    """Held-out accuracies of the supervised probe for one patrol: one row per (source, point).

    :param env_kwargs: the reserve's arguments
    :param patrol: ``"random"`` or ``"scripted"``
    :param train_episodes: training episodes (seeds ``seed, seed + 1, ...``)
    :param test_episodes: held-out episodes (seeds from ``TEST_SEED_OFFSET + seed``)
    :param seed: seed of the first training episode, of the patrol's draws and of the classifier
    :param epochs: classifier epochs
    :param points: fractions of ``max_cycles``
    :param uavs_per_episode: one-UAV samples per episode (None: all its UAVs), see :func:`collect_features`
    :return: rows with the patrol, source, point, training samples and the :func:`accuracies`
    """
    probe = probe_accuracy
    train_single, train_team, train_modes, train_now = collect_features(
        env_kwargs, patrol, range(seed, seed + train_episodes), points, patrol_seed=seed, uavs_per_episode=uavs_per_episode)
    test_seeds = range(TEST_SEED_OFFSET + seed, TEST_SEED_OFFSET + seed + test_episodes)
    test_single, test_team, test_modes, test_now = collect_features(
        env_kwargs, patrol, test_seeds, points, patrol_seed=seed + 1, uavs_per_episode=uavs_per_episode)
    n = len(train_single[points[0]]) // train_episodes
    uav_train, uav_test = np.repeat(train_modes, n), np.repeat(test_modes, n)  # the one-UAV rows' labels
    rows = []
    for source, train, test, y_train, y_test in (
        ("one UAV", train_single, test_single, uav_train, uav_test),
        ("team", train_team, test_team, train_modes, test_modes),
        ("UAV now", train_now, test_now, uav_train, uav_test),
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
    """Parse the flags, play and probe each patrol, print the budget, the table and the wall time."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--episodes", type=int, default=1500, help="training episodes per patrol")
    parser.add_argument("--test-episodes", type=int, default=300, help="held-out episodes per patrol")
    parser.add_argument("--patrols", nargs="+", default=list(PATROLS), help=f"patrols, among {sorted(PATROLS)}")
    parser.add_argument("--seed", type=int, default=0, help="seed of the first training episode")
    parser.add_argument("--epochs", type=int, default=20, help="classifier epochs")
    parser.add_argument("--max-uav-samples", type=int, default=20_000,
                        help="one-UAV training samples at most (beyond: a random subset of each episode's UAVs)")
    parser.add_argument("--env-kwargs", type=str, default="{}",
                        help="the reserve's arguments as a Python dict literal, e.g. \"{'n_uavs': 4}\" or \"dict(n_uavs=4)\"")
    args = parser.parse_args(argv)
    for name in ("episodes", "test_episodes", "epochs", "max_uav_samples"):
        if getattr(args, name) < 1:
            parser.error(f"--{name.replace('_', '-')} must be >= 1, got {getattr(args, name)}")
    if args.seed < 0:
        parser.error(f"--seed must be >= 0, got {args.seed}")
    unknown = [p for p in args.patrols if p not in PATROLS]
    if unknown:
        parser.error(f"--patrols must be among {sorted(PATROLS)}, got {unknown}")
    try:
        env_kwargs = parse_env_kwargs(args.env_kwargs)
    except ValueError as error:
        parser.error(f"--env-kwargs must be a dict literal of the reserve's arguments, got {args.env_kwargs!r}: {error}")
    try:
        env = reserve_v1.parallel_env(**env_kwargs)
        for patrol in args.patrols:
            PATROLS[patrol](env, args.seed)
    except (ValueError, TypeError) as error:
        parser.error(f"--env-kwargs {args.env_kwargs!r} does not suit the reserve or the patrols {args.patrols}: {error}")
    n_uavs = len(env.possible_agents)
    env.close()
    uavs_per_episode = min(n_uavs, max(1, args.max_uav_samples // args.episodes))
    th.set_num_threads(1)
    start = time.perf_counter()
    print(f"Supervised probe of the hidden mode: {args.episodes} training and {args.test_episodes} held-out episodes per "
          f"patrol (seeds {args.seed}.. and {TEST_SEED_OFFSET + args.seed}..), env_kwargs {env_kwargs}, "
          f"{args.epochs} epochs")
    if uavs_per_episode < n_uavs:
        print(f"One-UAV samples: a random {uavs_per_episode} of the {n_uavs} UAVs of each episode "
              f"(--max-uav-samples {args.max_uav_samples}); the team rows use all of them")
    rows = [row for patrol in args.patrols
            for row in evaluate(env_kwargs, patrol, args.episodes, args.test_episodes, args.seed, args.epochs,
                                uavs_per_episode=None if uavs_per_episode == n_uavs else uavs_per_episode)]
    print(format_rows(rows))
    print(f"wall time {time.perf_counter() - start:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
