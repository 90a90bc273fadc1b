"""What fusing teammates' evidence along the links does to trained EM-PPO teams: the same models, fusion on and off.

Reads the runs that ``zoo/compare.py`` left (``<folder>/<variant>/seed_<s>/``), evaluates each model on the same
episodes with fusion on and with fusion off (``model.latent_config.fusion``; only the beliefs at execution change), and prints
latent accuracy at 25%, 50% and 100% of an episode and the team reward for both, paired over seeds. With
``--all-links``, also with every teammate's message reaching every UAV every step (what the reserve's links cost the
fused belief).

Example: ``python docs/lab/studies/fusion.py -f logs/compare --seeds 0 1 2 3 4`` (after ``zoo/compare.py``)
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch as th
from stable_baselines3.common.vec_env import VecEnvWrapper

from sb3_emmarl.common.centralized import ENV_ID
from sb3_emmarl.common.evaluation import evaluate_team
from sb3_emmarl.common.vec_env import LINKS_KEY
from sb3_emmarl.zoo.algos import ZOO_ALGOS
from sb3_emmarl.zoo.cli import latest_run
from sb3_emmarl.zoo.compare import COMPARISON_EVAL_EPISODES, paired_p_value, run_eval_env, run_settings

METRICS = ("latent_accuracy_25", "latent_accuracy_50", "latent_accuracy_100", "team_reward")


class AllLinks(VecEnvWrapper):
    """Every UAV hears every teammate every step (its ``infos`` list all of them): what the links cost the belief,
    against a team whose every message arrives. A diagnostic: the reserve's own links decide what a team can fuse."""

    def reset(self) -> np.ndarray:
        return self.venv.reset()

    def step_wait(self):
        observations, rewards, dones, infos = self.venv.step_wait()
        per_copy = self.venv.unwrapped.agents_per_copy
        teammates = [tuple(i - i % per_copy + j for j in range(per_copy) if j != i % per_copy) for i in range(len(infos))]
        return observations, rewards, dones, [{**info, LINKS_KEY: heard} for info, heard in zip(infos, teammates)]


def table(title: str, a_name: str, b_name: str, a: list[dict], b: list[dict]) -> str:
    """Mean +- std over seeds of both settings, their difference and the paired t-test's p-value, per metric."""
    lines = [title, f"{'metric':<22}{a_name:>18}{b_name:>18}{'difference':>12}{'p':>10}"]
    for metric in METRICS:
        x, y = [r[metric] for r in a], [r[metric] for r in b]
        lines.append(f"{metric:<22}{np.mean(x):>10.3f} +- {np.std(x):<5.3f}{np.mean(y):>10.3f} +- {np.std(y):<5.3f}"
                     f"{np.mean(x) - np.mean(y):>12.3f}{paired_p_value(x, y):>10.3g}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("-f", "--folder", default="logs/compare", help="the comparison's log folder")
    parser.add_argument("--variant", default="em_ppo", help="the variant whose runs to evaluate")
    parser.add_argument("--algo", default="em_ppo", choices=["em_ppo", "em_ddpg"])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    parser.add_argument("--eval-episodes", type=int, default=COMPARISON_EVAL_EPISODES,
                        help="evaluation episodes per model and setting")
    parser.add_argument("--eval-seed", type=int, default=50_000)
    parser.add_argument("--all-links", action="store_true",
                        help="also evaluate with every teammate's message reaching every UAV every step")
    args = parser.parse_args(argv)
    if args.eval_episodes < 1:
        parser.error(f"--eval-episodes must be >= 1, got {args.eval_episodes}")
    th.set_num_threads(1)
    settings = ["fusion on", "fusion off", *(["all links"] if args.all_links else [])]
    results: dict[str, list[dict]] = {name: [] for name in settings}
    for seed in args.seeds:
        run = latest_run(Path(args.folder) / args.variant / f"seed_{seed}", args.algo)
        if not run.is_dir():
            parser.error(f"no {args.algo} run in {run.parent}")
        run_kwargs = run_settings(run)  # the run's reserve arguments, vec_env_wrapper, VecNormalize
        model = ZOO_ALGOS[args.algo].load(run / f"{ENV_ID}.zip", device="cpu")
        for name in settings:
            model.latent_config = replace(model.latent_config, fusion=name != "fusion off")
            # The same episodes as evaluate_team's own reserve (make_eval_env), with every link up.
            vec_env = AllLinks(run_eval_env(run, args.eval_seed)) if name == "all links" else None
            records = evaluate_team(model, args.eval_episodes, seed=args.eval_seed,
                                    **(run_kwargs if vec_env is None else {}), vec_env=vec_env)
            if vec_env is not None:
                vec_env.close()
            results[name].append({m: float(np.mean([r[m] for r in records])) for m in METRICS})
        print(f"seed {seed}: " + "  ".join(f"{m} " + "/".join(f"{results[name][-1][m]:.3f}" for name in settings)
                                           for m in METRICS), flush=True)
    header = (f"{args.variant}: {len(args.seeds)} trained models, {args.eval_episodes} evaluation episodes from seed "
              f"{args.eval_seed}")
    print("\n" + table(f"{header}, fusion on / off; mean +- std over seeds, paired t-test", "fusion on", "fusion off",
                       results["fusion on"], results["fusion off"]))
    if args.all_links:
        print("\n" + table(f"{header}, fusion on with every link up / with the reserve's links", "all links",
                           "fusion on", results["all links"], results["fusion on"]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
