"""How trained teams spread out: whether a policy shared by identical UAVs sends them all the same way.

Reads the runs that ``zoo/compare.py`` left (``<folder>/<variant>/seed_<s>/``), evaluates each model on the same
episodes as the comparison (``evaluate_team``, the run's own reserve arguments) and prints, per variant and seed, the
team reward and collisions per episode beside three measures of how the team spreads, read from what the UAVs
observe and do (a :class:`SpreadMonitor` between the model and the reserve):

- ``edge``: the share of UAV-steps on the reserve's boundary (an own position of 0 or 1 on some axis; flying
  against the boundary leaves a UAV there);
- ``corner``: the share of UAV-steps in a corner (0 or 1 on both axes);
- ``alignment``: the mean cosine between two teammates' moves (1: every UAV flies the same way; about 0: the moves
  are unrelated), over every pair of moving UAVs and every step.

A deterministic actor shared by every UAV (DDPG, EM-DDPG) gives two UAVs that observe the same thing the same move
for good: docs/lab/results-history.md ("EM-DDPG against DDPG") uses these figures to tell a team that piles up at the boundary
from one that collides in the open.

Example: ``python docs/lab/studies/team_spread.py -f logs/compare --variants em_ddpg ddpg --seeds 0 1 2`` (a variant as
compare.py was given it, ``--variants nofusion=em_ddpg:fusion=False``, is read the same way)
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch as th
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper

from sb3_emmarl.common.centralized import ENV_ID
from sb3_emmarl.common.evaluation import evaluate_team
from sb3_emmarl.zoo.algos import ZOO_ALGOS
from sb3_emmarl.zoo.cli import latest_run
from sb3_emmarl.zoo.compare import parse_variant, run_eval_env, run_settings
from wildlife_reserve import reserve_v1
from wildlife_reserve.reserve.actors import STEPS
from wildlife_reserve.reserve.kernels.constants import N_MOVES


class SpreadMonitor(VecEnvWrapper):
    """Counts, as the team plays, the UAV-steps on the boundary and in a corner (from the own position in each UAV's
    observation) and the cosines between teammates' moves (from the actions), over every copy of the reserve.

    :param venv: the parameter-sharing reserve (plain observations)
    :param own: the slice of the own features in an observation (position scaled to [0, 1] first)
    :param agents_per_copy: UAVs per reserve copy (consecutive vector entries)
    :param continuous: ``(d_row, d_col, comm)`` actions; else discrete ``move + N_MOVES * comm``
    """

    def __init__(self, venv: VecEnv, own: slice, agents_per_copy: int, continuous: bool) -> None:
        super().__init__(venv)
        self.own, self.n, self.continuous = own, agents_per_copy, continuous
        self.steps = self.edge = self.corner = 0
        self.cosines: list[float] = []
        self._observations: np.ndarray | None = None

    def reset(self) -> np.ndarray:
        self._observations = self.venv.reset()
        return self._observations

    def step_async(self, actions: np.ndarray) -> None:
        self._record(np.asarray(actions))
        self.venv.step_async(actions)

    def step_wait(self):
        self._observations, rewards, dones, infos = self.venv.step_wait()
        return self._observations, rewards, dones, infos

    def _moves(self, actions: np.ndarray) -> np.ndarray:
        if self.continuous:
            return actions.reshape(len(actions), -1)[:, :2].astype(float)
        return STEPS[actions.reshape(-1).astype(np.int64) % N_MOVES].astype(float)  # discrete: move + N_MOVES * comm

    def _record(self, actions: np.ndarray) -> None:
        position = self._observations[:, self.own][:, :2]
        at_bound = (position <= 0.0) | (position >= 1.0)
        self.steps += len(position)
        self.edge += int(at_bound.any(1).sum())
        self.corner += int(at_bound.all(1).sum())
        moves = self._moves(actions)
        norms = np.linalg.norm(moves, axis=1)
        for start in range(0, len(moves), self.n):
            team, moving = moves[start:start + self.n], norms[start:start + self.n] > 1e-9
            unit = team[moving] / norms[start:start + self.n][moving, None]
            m = len(unit)
            if m > 1:
                cosine = unit @ unit.T
                self.cosines.append(float((cosine.sum() - m) / (m * (m - 1))))

    def summary(self) -> dict[str, float]:
        return {"edge": self.edge / max(self.steps, 1), "corner": self.corner / max(self.steps, 1),
                "alignment": float(np.mean(self.cosines)) if self.cosines else float("nan")}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("-f", "--folder", required=True, help="zoo/compare.py's log folder")
    parser.add_argument("--variants", nargs="+", default=["em_ddpg", "ddpg"],
                        help="variants to read: ALGO, or NAME=ALGO for a variant compare.py named (NAME=ALGO:...)")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--eval-episodes", type=int, default=20, help="evaluation episodes per model")
    parser.add_argument("--eval-seed", type=int, default=50_000)
    args = parser.parse_args(argv)
    if args.eval_episodes < 1:
        parser.error(f"--eval-episodes must be >= 1, got {args.eval_episodes}")
    th.set_num_threads(1)
    print(f"{args.eval_episodes} evaluation episodes from seed {args.eval_seed} per model; per episode: team reward, "
          f"collisions; per UAV-step: at the boundary, in a corner; mean cosine of two teammates' moves")
    print(f"{'variant':<10} {'seed':>4} {'team_reward':>12} {'collisions':>11} {'edge':>7} {'corner':>7} "
          f"{'alignment':>10}")
    for item in args.variants:
        try:
            variant, algo, _ = parse_variant(item)  # compare.py's own reading of a variant
        except ValueError as error:
            parser.error(f"--variants: {error}")
        for seed in args.seeds:
            run = latest_run(Path(args.folder) / variant / f"seed_{seed}", algo)
            if not run.is_dir():
                parser.error(f"no {variant} run in {run.parent}")
            settings = run_settings(run)
            if settings["vec_normalize_path"] is not None:  # the monitor reads positions from plain observations
                parser.error(f"{run} was trained with VecNormalize: its observations do not hold plain positions")
            env_kwargs = settings["env_kwargs"]
            probe = reserve_v1.parallel_env(**env_kwargs)
            own, n, continuous = probe.observation_layout["own"][0], probe.n, probe.config.continuous_actions
            probe.close()
            model = ZOO_ALGOS[algo].load(run / f"{ENV_ID}.zip", device="cpu")
            monitor = SpreadMonitor(run_eval_env(run, args.eval_seed), own, n, continuous)
            records = evaluate_team(model, args.eval_episodes, seed=args.eval_seed, vec_env=monitor)
            monitor.close()
            spread = monitor.summary()
            print(f"{variant:<10} {seed:>4} {np.mean([r['team_reward'] for r in records]):>12.1f} "
                  f"{np.mean([r['collisions'] for r in records]):>11.1f} {spread['edge']:>7.3f} "
                  f"{spread['corner']:>7.3f} {spread['alignment']:>10.3f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
