"""Issue 8's founding figure, repeated on the reserve it was measured on (sb3-emmarl 0.1.0, commit 8044dff).

The value-of-information issue was filed on 0.1.0 with "PPO told the mode against plain PPO, 3 seeds, 20 evaluation
episodes each: team reward 4.0 against -3.0, higher on every seed". Every later reserve was measured with
``benchmarks/mode_value.py``, which 0.1.0 does not have. This script repeats the figure on 0.1.0 itself, with more
seeds and episodes, and asks how often the issue's protocol shows such a gain by chance.

``run`` trains and evaluates one run and must run on the 0.1.0 tree (0.1.0 has no ``oracle_ppo``, so the one-hot is
appended here, by a PettingZoo wrapper around each reserve copy); ``report`` reads the runs' files on any version:

.. code-block:: bash

    git worktree add /tmp/wt_0_1_0 8044dff
    for seed in 0 1 2 3 4 5 6 7 8 9; do for variant in told ppo control; do
        echo "run --variant $variant --seed $seed --folder /tmp/mv010"; done; done |
      PYTHONPATH=/tmp/wt_0_1_0:/tmp/wt_0_1_0/envs xargs -P 2 -L 1 python docs/lab/studies/mode_value_0_1_0.py
    python docs/lab/studies/mode_value_0_1_0.py report --folder /tmp/mv010

The variants: ``told`` (the true mode's one-hot appended to every UAV's observation; also evaluated told the next
strategy, the same weather), ``ppo`` (the plain observation) and ``control`` (the one-hot of a label drawn uniformly
per episode, independent of the mode). Every run: 0.1.0's ``ppo.yml`` (4 copies x 128 steps, batch 1280, 5 epochs,
``ent_coef`` 0.01, ``net_arch`` [128, 128]), 500,000 agent-steps, one torch thread, then 200 episodes of 0.1.0's
``evaluate_team`` from seed 50000 (actions sampled).
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
import time
from pathlib import Path

import numpy as np

#: The variants ``run`` trains.
VARIANTS = ("told", "ppo", "control")
#: The episode metrics the report compares.
METRICS = ("team_reward", "detection_rate", "coverage_efficiency", "collisions")
#: The issue's protocol: seeds, evaluation episodes per seed, and the gain it reported (4.0 against -3.0).
ISSUE_SEEDS, ISSUE_EPISODES, ISSUE_GAIN = 3, 20, 7.0
#: Evaluation: episodes per run and their seed.
EVAL_EPISODES, EVAL_SEED = 200, 50_000
#: The benchmarks' folder (``report`` reads ``benchmarks/mode_value.py``'s table).
BENCHMARKS = Path(__file__).resolve().parents[3] / "benchmarks"


def run(variant: str, seed: int, folder: Path, n_timesteps: int = 500_000) -> None:
    """Train and evaluate one run on the 0.1.0 tree; write ``<folder>/<variant>_<seed>.json``.

    :raises SystemExit: if the ``sb3_emmarl`` imported is not 0.1.0
    """
    import sb3_emmarl

    if sb3_emmarl.__version__ != "0.1.0":
        raise SystemExit(f"run needs sb3-emmarl 0.1.0 on the path (git worktree add <dir> 8044dff; PYTHONPATH=<dir>:"
                         f"<dir>/envs), got {sb3_emmarl.__version__} from {sb3_emmarl.__file__}")
    import torch as th
    from gymnasium import spaces
    from pettingzoo.utils import BaseParallelWrapper
    from stable_baselines3 import PPO

    from sb3_emmarl.common.evaluation import evaluate_team
    from sb3_emmarl.common.vec_env import make_vec_env
    from wildlife_reserve import reserve_v1
    from wildlife_reserve.reserve.modes import N_MODES, WEATHERS

    class OneHot(BaseParallelWrapper):
        """Every UAV's observation ends with a one-hot: of the true mode, the next strategy's, or a random label."""

        def __init__(self, env, label: str) -> None:
            super().__init__(env)
            self.label, self._rng, self._label = label, np.random.default_rng(12345), 0
            box = env.observation_space(env.possible_agents[0])
            self._space = spaces.Box(np.append(box.low, np.zeros(N_MODES, box.dtype)),
                                     np.append(box.high, np.ones(N_MODES, box.dtype)), dtype=box.dtype)

        def observation_space(self, agent):
            return self._space

        def _add(self, observations):
            mode = self.env.unwrapped.mode
            if self.label == "next_strategy":
                mode = (mode + len(WEATHERS)) % N_MODES  # 0.1.0: mode = strategy * len(WEATHERS) + weather
            hot = np.zeros(N_MODES, np.float32)
            hot[self._label if self.label == "random" else mode] = 1.0
            return {agent: np.append(o, hot.astype(o.dtype)) for agent, o in observations.items()}

        def reset(self, seed=None, options=None):
            observations, infos = self.env.reset(seed=seed, options=options)
            if seed is not None:
                self._rng = np.random.default_rng([seed, 777])
            self._label = int(self._rng.integers(N_MODES))
            return self._add(observations), infos

        def step(self, actions):
            observations, *rest = self.env.step(actions)
            return (self._add(observations), *rest)

    def env_fn(label: str | None):
        return reserve_v1.parallel_env if label is None else lambda **kw: OneHot(reserve_v1.parallel_env(**kw), label)

    label = {"told": "mode", "ppo": None, "control": "random"}[variant]
    th.set_num_threads(1)
    start = time.time()
    model = PPO("MlpPolicy", make_vec_env(4, seed=seed, env_fn=env_fn(label)), n_steps=128, batch_size=1280, n_epochs=5,
                gamma=0.99, gae_lambda=0.95, learning_rate=3e-4, ent_coef=0.01, clip_range=0.2,
                policy_kwargs=dict(net_arch=[128, 128]), seed=seed, verbose=0)
    model.learn(n_timesteps)
    out = {"variant": variant, "seed": seed, "n_timesteps": n_timesteps, "train_seconds": time.time() - start}
    for key, episode_label in [("records", label)] + ([("next_strategy_records", "next_strategy")] if label == "mode" else []):
        out[key] = evaluate_team(model, n_episodes=EVAL_EPISODES, seed=EVAL_SEED,
                                 vec_env=make_vec_env(1, seed=EVAL_SEED, env_fn=env_fn(episode_label)))
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{variant}_{seed}.json"
    path.with_suffix(".tmp").write_text(json.dumps(out))
    path.with_suffix(".tmp").replace(path)  # no half-written file if the run is killed
    print(f"{path}: team reward {np.mean([r['team_reward'] for r in out['records']]):.3f}, "
          f"trained in {out['train_seconds']:.0f} s")


def load(folder: Path, variant: str) -> dict[int, dict]:
    """``{seed: run}`` of every run of ``variant`` in ``folder`` (what ``run`` wrote)."""
    runs = {}
    for path in sorted(folder.glob(f"{variant}_*.json")):
        data = json.loads(path.read_text())
        runs[int(data["seed"])] = data
    return runs


def seed_means(runs: dict[int, list[dict]], seeds: list[int], episodes: int | None = None) -> list[dict]:
    """One record per seed: each metric's mean over the first ``episodes`` episodes (all if None)."""
    return [{"seed": seed, **{m: float(np.mean([r[m] for r in runs[seed][:episodes]])) for m in METRICS}}
            for seed in seeds]


def protocol_draws(told: dict[int, np.ndarray], ppo: dict[int, np.ndarray], n_seeds: int = ISSUE_SEEDS,
                   block: int = ISSUE_EPISODES, gain: float = ISSUE_GAIN) -> tuple[int, int]:
    """How often the issue's protocol, drawn from these runs, shows what the issue reported.

    Every set of ``n_seeds`` seeds x every block of ``block`` consecutive evaluation episodes (the same block for both
    variants: they play the same episodes) is one draw; a hit is told higher on every seed of the draw and at least
    ``gain`` higher on average.

    :param told: ``{seed: team reward per evaluation episode}`` of the told runs
    :param ppo: the same for the plain runs (the same seeds)
    :return: ``(hits, draws)``
    """
    hits = draws = 0
    n_episodes = min(len(v) for v in (*told.values(), *ppo.values()))
    for seeds in itertools.combinations(sorted(told), n_seeds):
        for start in range(0, n_episodes - block + 1, block):
            gains = np.array([told[s][start:start + block].mean() - ppo[s][start:start + block].mean() for s in seeds])
            draws += 1
            hits += bool((gains > 0).all() and gains.mean() >= gain)
    return hits, draws


def report(folder: Path) -> None:
    """Print the tables of the runs in ``folder`` (paired by seed; every variant must have the same seeds)."""
    sys.path.insert(0, str(BENCHMARKS))
    from mode_value import paired_table  # the value-of-information benchmark's table
    from scipy import stats

    loaded = {variant: load(folder, variant) for variant in VARIANTS}
    seeds = sorted(loaded["told"])
    if not seeds or any(sorted(r) != seeds for r in loaded.values()):
        raise SystemExit(f"{folder} must hold runs of {', '.join(VARIANTS)} for the same seeds; has "
                         + ", ".join(f"{v}: {sorted(r)}" for v, r in loaded.items()))
    budgets = {run["n_timesteps"] for r in loaded.values() for run in r.values()}
    if len(budgets) != 1:
        raise SystemExit(f"{folder} holds runs of different budgets {sorted(budgets)}: they do not pair")
    runs = {variant: {seed: run["records"] for seed, run in r.items()} for variant, r in loaded.items()}
    means = {variant: seed_means(r, seeds) for variant, r in runs.items()}
    header = (f"{len(seeds)} seeds x {budgets.pop():,} agent-steps per run on sb3-emmarl 0.1.0 (0.1.0's ppo.yml); "
              f"{EVAL_EPISODES} evaluation episodes from seed {EVAL_SEED} per run (actions sampled); mean +- std over seeds")
    for title, a, b in [("PPO told the mode or not", "told", "ppo"),
                        ("Told the mode or a random label (the same input without the information)", "told", "control"),
                        ("A random label or nothing", "control", "ppo")]:
        print(f"{title}: {header}\n{paired_table({a: means[a], b: means[b]}, METRICS)}\n")
    wrong = seed_means({seed: run["next_strategy_records"] for seed, run in loaded["told"].items()}, seeds)
    print(f"The told runs told the true mode or the next strategy (the same weather), on the same episodes\n"
          f"{paired_table({'true_mode': means['told'], 'next_strategy': wrong}, METRICS)}\n")
    issue = seeds[:ISSUE_SEEDS]
    print(f"The issue's protocol: seeds {issue}, the first {ISSUE_EPISODES} evaluation episodes\n"
          + paired_table({"told": seed_means(runs["told"], issue, ISSUE_EPISODES),
                          "ppo": seed_means(runs["ppo"], issue, ISSUE_EPISODES)}, METRICS) + "\n")
    rewards = {v: {s: np.array([r["team_reward"] for r in runs[v][s]]) for s in seeds} for v in ("told", "ppo")}
    hits, draws = protocol_draws(rewards["told"], rewards["ppo"])
    spread = {v: np.array([m["team_reward"] for m in means[v]]) for v in VARIANTS}
    gains = spread["told"] - spread["ppo"]
    print(f"Told minus PPO per seed: {np.array2string(gains, precision=3)}; median {np.median(gains):.3f}; "
          f"Wilcoxon signed-rank p = {stats.wilcoxon(gains).pvalue:.3g}\n"
          f"Team reward's spread over seeds (std): " + ", ".join(f"{v} {np.std(spread[v]):.3f}" for v in VARIANTS)
          + "; Brown-Forsythe p, told against ppo "
          f"{stats.levene(spread['told'], spread['ppo'], center='median').pvalue:.3g}, against control "
          f"{stats.levene(spread['told'], spread['control'], center='median').pvalue:.3g}\n"
          f"The issue's protocol drawn from these runs ({ISSUE_SEEDS} of the {len(seeds)} seeds x a block of "
          f"{ISSUE_EPISODES} of the {EVAL_EPISODES} episodes): told higher on every seed and >= {ISSUE_GAIN:g} higher "
          f"on average in {hits} of {draws} draws ({hits / draws:.1%})")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    commands = parser.add_subparsers(dest="command", required=True)
    run_parser = commands.add_parser("run", help="train and evaluate one run (on the 0.1.0 tree)")
    run_parser.add_argument("--variant", choices=VARIANTS, required=True)
    run_parser.add_argument("--seed", type=int, required=True)
    run_parser.add_argument("--folder", type=Path, required=True)
    run_parser.add_argument("-n", "--n-timesteps", type=int, default=500_000)
    report_parser = commands.add_parser("report", help="print the tables of the runs in a folder")
    report_parser.add_argument("--folder", type=Path, required=True)
    args = parser.parse_args(argv)
    if args.command == "run":
        run(args.variant, args.seed, args.folder, args.n_timesteps)
    else:
        report(args.folder)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
