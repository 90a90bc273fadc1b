"""What knowing the hidden mode pays a learned team on ZonePatrol, and how much of it EM-PPO recovers.

Four variants train with the same PPO settings (:data:`PPO_SETTINGS`) on 8 copies of ZonePatrol through the batched
vector environment, each run in its own process with one torch thread: PPO told the mode (``told``:
``OraclePPO``, the one-hot of the mode appended to every observation), plain PPO (``ppo``), the control told a random
label per episode instead (``control``: ``OraclePPO(random_label=True)``, the same input without the information) and
EM-PPO (``em_ppo``: its generic latent model, 8 components, fusion along the links). Each run then plays the same
``--eval-episodes`` held-out team episodes (8 copies from seed 50,000; actions sampled, torch seeded), scored as team
episodes (one team reward per episode of a copy). ``told`` runs play them again told a wrong zone (the next one, the
same weather) and a wrong weather; ``em_ppo`` runs with their belief permuted between components. Told, control and
EM-PPO runs report how far their actions move when the one-hot or the belief is permuted over the visited
observations (:func:`~sb3_emmarl.common.latent.diagnostics.belief_use`: the swap KL). A run is *collapsed* when its
mean team reward is below the random team's on the same episodes (rule fixed before any run).

``run`` writes one JSON file per run into ``--folder`` (atomically; an existing run is kept, so a killed sweep
resumes); ``report`` prints the paired tables (told against PPO, told against the control, the control against PPO,
told right against told wrong, EM-PPO against PPO) with paired t and Wilcoxon p-values, seeds higher, medians, the
share of the told gain EM-PPO recovers with a 90% bootstrap interval over seeds, and the collapsed runs.

Example: ``python benchmarks/zone_patrol_value.py run --seeds 0 1 2 3 4 5 6 7 8 9 --folder logs/zone_patrol_value``,
then ``python benchmarks/zone_patrol_value.py report --folder logs/zone_patrol_value``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
from scipy import stats

VARIANTS = ("told", "ppo", "control", "em_ppo")
#: PPO settings of every variant (32 entries x 128 steps = 4,096 agent-steps per rollout).
PPO_SETTINGS = {"n_steps": 128, "batch_size": 1024, "n_epochs": 10, "learning_rate": 3e-4, "gamma": 0.99,
                "gae_lambda": 0.95, "ent_coef": 0.01, "clip_range": 0.2, "policy_kwargs": {"net_arch": [128, 128]}}
N_COPIES = 8
EVAL_SEED = 50_000
#: Agent-steps per run unless ``-n`` says otherwise.
BUDGET = 1_000_000


def make_env(seed: int, n_copies: int = N_COPIES):
    from sb3_emmarl.common.vec_env import make_vec_env
    from wildlife_reserve import zone_patrol_v0

    return make_vec_env(n_copies, seed=seed, env_fn=zone_patrol_v0.parallel_env, vec_env_type="batched")


def build(variant: str, seed: int):
    from stable_baselines3 import PPO

    from sb3_emmarl import EMPPO, OraclePPO

    env = make_env(seed)
    if variant == "ppo":
        return PPO("MlpPolicy", env, seed=seed, **PPO_SETTINGS)
    if variant == "em_ppo":
        return EMPPO("MlpPolicy", env, seed=seed, n_components=8, **PPO_SETTINGS)
    return OraclePPO("MlpPolicy", env, seed=seed, random_label=variant == "control", **PPO_SETTINGS)


def play(model, venv, episodes: int, seed: int, random: bool = False) -> tuple[list[float], np.ndarray]:
    """Team rewards of ``episodes`` team episodes (the first agent of each copy reports its copy's), and one visited
    observation per step (as the model saw it); ``random`` plays uniformly random actions instead."""
    import torch as th

    per_copy = int(getattr(venv, "agents_per_copy", 1))
    rewards: list[float] = []
    visited = []
    rng = np.random.default_rng(seed)
    with th.random.fork_rng():
        th.manual_seed(seed)
        obs = venv.reset()
        state, starts = None, np.ones(venv.num_envs, dtype=bool)
        while len(rewards) < episodes:
            if len(visited) < 1024:
                visited.append(np.array(obs[0]))
            if random:
                actions = rng.integers(venv.action_space.n, size=venv.num_envs)
            else:
                actions, state = model.predict(obs, state=state, episode_start=starts, deterministic=False)
            obs, _, starts, infos = venv.step(actions)
            for i in np.flatnonzero(starts):
                if i % per_copy == 0:
                    rewards.append(float(infos[i]["metrics"]["team_reward"]))
    venv.close()
    return rewards[:episodes], np.stack(visited)


def wrong(relabel: list[int]):
    """A vector environment maker whose observations end with the one-hot of ``relabel[mode]``."""
    from sb3_emmarl.common.mode_aware import ModeObservationWrapper

    return lambda: ModeObservationWrapper(make_env(EVAL_SEED), relabel=relabel)


#: Told a wrong zone (the next one, the same weather), or a wrong weather (the same zone). Modes are 2 * zone + weather.
WRONG = {"wrong_zone": [(2 * ((m // 2 + 1) % 4)) + m % 2 for m in range(8)],
         "wrong_weather": [2 * (m // 2) + 1 - m % 2 for m in range(8)]}


def run(variant: str, seed: int, budget: int, episodes: int) -> dict:
    import torch as th

    from sb3_emmarl.common.latent.diagnostics import belief_use, permute_beliefs

    th.set_num_threads(1)
    model = build(variant, seed)
    start = time.perf_counter()
    model.learn(budget)
    record = {"variant": variant, "seed": seed, "budget": budget, "seconds": time.perf_counter() - start}
    wrap = getattr(model, "wrap_env", lambda v: v)
    record["team_reward"], visited = play(model, wrap(make_env(EVAL_SEED)), episodes, EVAL_SEED)
    if variant != "ppo":
        record["swap_kl"] = belief_use(model.policy, visited, 8)
    if variant == "told":
        for name, relabel in WRONG.items():
            record[name] = play(model, wrong(relabel)(), episodes, EVAL_SEED)[0]
    if variant == "em_ppo":
        from stable_baselines3.common.vec_env import VecEnvWrapper

        class Permuted(VecEnvWrapper):
            def reset(self):
                return permute_beliefs(self.venv.reset(), 8)

            def step_wait(self):
                obs, rewards, dones, infos = self.venv.step_wait()
                return permute_beliefs(obs, 8), rewards, dones, infos

        record["permuted"] = play(model, Permuted(wrap(make_env(EVAL_SEED))), episodes, EVAL_SEED)[0]
    return record


def run_and_save(folder: str, variant: str, seed: int, budget: int, episodes: int) -> str:
    path = Path(folder) / f"{variant}_{seed}.json"
    if path.exists():
        return f"{path.name}: kept"
    record = run(variant, seed, budget, episodes)
    from sb3_emmarl.common.checkpoints import write_text
    from sb3_emmarl.version import __version__

    write_text(path, json.dumps({**record, "version": __version__}))
    return f"{path.name}: team reward {np.mean(record['team_reward']):.3f} ({record['seconds']:.0f} s)"


def paired(name_a: str, a: np.ndarray, name_b: str, b: np.ndarray) -> str:
    diff = a - b
    wilcoxon = float(stats.wilcoxon(diff).pvalue) if np.any(diff != 0) else 1.0
    t = float(stats.ttest_rel(a, b).pvalue) if len(a) > 1 and np.any(diff != 0) else 1.0
    return (f"{name_a} {a.mean():.3f} +- {a.std():.3f} (median {np.median(a):.3f}) against {name_b} {b.mean():.3f} +- "
            f"{b.std():.3f} (median {np.median(b):.3f}): difference {diff.mean():+.3f} +- {diff.std():.3f}, paired t p "
            f"{t:.3g}, Wilcoxon p {wilcoxon:.3g}, higher on {int((diff > 0).sum())} of {len(diff)}")


def report(runs: list[dict], random_team: float | None = None) -> str:
    by = {v: {r["seed"]: r for r in runs if r["variant"] == v} for v in VARIANTS}
    budgets = {r["budget"] for r in runs}
    if len(budgets) != 1:
        raise SystemExit(f"runs of different budgets {sorted(budgets)}: report one budget at a time")
    lines = [f"ZonePatrol, {budgets.pop():,} agent-steps per run; mean team reward over each run's evaluation episodes"]

    def means(variant: str, key: str = "team_reward", seeds: list[int] | None = None) -> np.ndarray:
        return np.array([np.mean(by[variant][s][key]) for s in seeds])

    for a, b in (("told", "ppo"), ("told", "control"), ("control", "ppo"), ("em_ppo", "ppo"), ("told", "em_ppo")):
        seeds = sorted(set(by[a]) & set(by[b]))
        if len(seeds) >= 2:
            lines.append(paired(a, means(a, seeds=seeds), b, means(b, seeds=seeds)) + f" (seeds {seeds})")
    told_seeds = sorted(by["told"])
    if len(told_seeds) >= 2:
        for name in WRONG:
            lines.append(paired("told right", means("told", seeds=told_seeds), f"told a {name.replace('_', ' ')}",
                                means("told", name, told_seeds)))
    seeds = sorted(set(by["told"]) & set(by["ppo"]) & set(by["em_ppo"]))
    if len(seeds) >= 2:
        em, told, ppo = means("em_ppo", seeds=seeds), means("told", seeds=seeds), means("ppo", seeds=seeds)
        if (told - ppo).mean() == 0:
            lines.append("(em_ppo - ppo) / (told - ppo): undefined, told and ppo score alike")
        else:
            draws = np.random.default_rng(0).integers(len(seeds), size=(10_000, len(seeds)))
            with np.errstate(divide="ignore", invalid="ignore"):
                boot = (em[draws] - ppo[draws]).mean(1) / (told[draws] - ppo[draws]).mean(1)
            low, high = np.nanpercentile(boot, [5, 95])
            lines.append(f"(em_ppo - ppo) / (told - ppo) = {(em - ppo).mean() / (told - ppo).mean():.3f}, 90% bootstrap "
                         f"interval over seeds [{low:.3f}, {high:.3f}]")
        lines.append(paired("em_ppo", em, "em_ppo, belief permuted", means("em_ppo", "permuted", seeds)))
    for variant in ("told", "control", "em_ppo"):
        if by[variant]:
            kl = np.array([by[variant][s]["swap_kl"] for s in sorted(by[variant])])
            lines.append(f"{variant}: swap KL {kl.mean():.4f} +- {kl.std():.4f}")
    if random_team is not None:
        collapsed = [f"{r['variant']} seed {r['seed']}" for r in runs if np.mean(r["team_reward"]) < random_team]
        lines.append(f"random team {random_team:.3f}; collapsed runs (below it): {', '.join(collapsed) or 'none'}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    commands = parser.add_subparsers(dest="command", required=True)
    run_parser = commands.add_parser("run", help="train and evaluate the runs missing from --folder")
    run_parser.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    run_parser.add_argument("--seeds", type=int, nargs="+", default=list(range(10)))
    run_parser.add_argument("-n", type=int, default=BUDGET, help="agent-steps per run")
    run_parser.add_argument("--eval-episodes", type=int, default=200)
    run_parser.add_argument("--n-jobs", type=int, default=2, help="runs at once, each in its own process (1: here)")
    run_parser.add_argument("--folder", required=True)
    report_parser = commands.add_parser("report", help="the tables of the runs in --folder")
    report_parser.add_argument("--folder", required=True)
    args = parser.parse_args(argv)
    folder = Path(args.folder)
    if args.command == "report":
        runs = [json.loads(p.read_text()) for p in sorted(folder.glob("*.json"))]
        if not runs:
            raise SystemExit(f"no runs in {folder}: run `zone_patrol_value.py run --folder {folder}` first")
        episodes = len(runs[0]["team_reward"])
        random_team = float(np.mean(play(None, make_env(EVAL_SEED), episodes, EVAL_SEED, random=True)[0]))
        print(report(runs, random_team))
        return 0
    if args.n < 1 or args.eval_episodes < 2 or args.n_jobs < 1 or len(set(args.seeds)) != len(args.seeds):
        parser.error("-n and --n-jobs must be >= 1, --eval-episodes >= 2 and --seeds distinct")
    folder.mkdir(parents=True, exist_ok=True)
    jobs = [(str(folder), v, s, args.n, args.eval_episodes) for s in args.seeds for v in args.variants]
    if args.n_jobs == 1:  # in this process (each run sets torch to one thread, as the workers do)
        for job in jobs:
            print(run_and_save(*job), flush=True)
        return 0
    with ProcessPoolExecutor(max_workers=args.n_jobs) as pool:
        for line in pool.map(run_and_save, *zip(*jobs)):
            print(line, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
