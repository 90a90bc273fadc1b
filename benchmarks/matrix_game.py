"""QMIX and VDN on QMIX's two-step matrix game (Rashid et al. 2018, section 5): the greedy joint policy's return.

The optimum is 8 (agent 0 picks state 2B, then both play B); VDN's sum cannot represent 2B's payoffs
``[[0, 1], [1, 8]]`` (its best additive fit values 2B's best joint action at about 6.5 < 7) and settles for 7.
Each seed trains one model and prints the return of its greedy joint policy (the game is deterministic).

Settings, the paper's (appendix B.1) where they apply: full exploration (epsilon = 1 throughout), agent networks
with one hidden layer of 64 units told the agent's index, a mixing network of 8 units with linear hypernetworks,
gamma 0.99, a buffer of the last 500 episodes, batches of 32 episodes (64 team transitions), one update every
episode (two steps), target updates every 100 episodes, learning rate 5e-4 (Adam here, RMSprop there), and 10k
team steps (20k agent-steps), the paper's budget.

Command (about 3 minutes on one core; 10 runs)::

    OMP_NUM_THREADS=1 python benchmarks/matrix_game.py            # 5 seeds, 20000 agent-steps
    OMP_NUM_THREADS=1 python benchmarks/matrix_game.py --seeds 0 1 -n 10000 --eps 0.05

``--eps`` sets epsilon's final value (annealed from 1 over the first half of the run) instead of full exploration.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from matrix_game import TwoStepGame, greedy_return

from sb3_emmarl.common.phases import PhaseTimes, PhaseTotals
from sb3_emmarl.common.vec_env import make_vec_env
from sb3_emmarl.qmix import QMIX
from sb3_emmarl.vdn import VDN

#: Agent-steps per run: the paper's 10k team steps of two agents.
BUDGET = 20_000
SEEDS = (0, 1, 2, 3, 4)


def settings(final_eps: float = 1.0) -> dict[str, Any]:
    """The paper's settings in this library's units (agent-steps for the buffer, start and target interval)."""
    return dict(
        learning_rate=5e-4,
        buffer_size=2000,  # 500 episodes x 2 steps x 2 agents
        learning_starts=200,  # 50 episodes of random play first
        batch_size=64,  # 32 episodes of 2 team transitions
        train_freq=2,  # one update per episode, as PyMARL's episode runner
        gradient_steps=1,
        target_update_interval=400,  # every 100 episodes
        gamma=0.99,
        exploration_initial_eps=1.0,
        exploration_final_eps=final_eps,
        exploration_fraction=0.5,
        agent_id=True,
        policy_kwargs=dict(net_arch=[64]),
    )


def run(algo: str, seed: int, n_timesteps: int = BUDGET, final_eps: float = 1.0, totals: PhaseTotals | None = None
        ) -> float:
    """Train ``algo`` (``"qmix"`` or ``"vdn"``) on one copy of the game; the greedy joint policy's return. The
    training's phases are added to ``totals``."""
    env = make_vec_env(1, seed=seed, env_fn=TwoStepGame)
    if algo == "qmix":
        model = QMIX("MlpPolicy", env, mixing_embed_dim=8, hypernet_layers=1, seed=seed, **settings(final_eps))
    else:
        model = VDN("MlpPolicy", env, seed=seed, **settings(final_eps))
    times = PhaseTimes()
    model.learn(n_timesteps, callback=times)
    if totals is not None:
        totals.add(times)
    env.close()
    return greedy_return(model)


def main(argv: list[str] | None = None) -> dict[str, list[float]]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=list(SEEDS))
    parser.add_argument("-n", "--n-timesteps", type=int, default=BUDGET, help="agent-steps per run")
    parser.add_argument("--eps", type=float, default=1.0, help="final epsilon (1: full exploration, the paper's)")
    args = parser.parse_args(argv)
    results: dict[str, list[float]] = {}
    totals = PhaseTotals()
    print(f"two-step game, {args.n_timesteps} agent-steps per run, final epsilon {args.eps}")
    for algo, target in (("qmix", 8.0), ("vdn", 7.0)):
        results[algo] = []
        for seed in args.seeds:
            start = time.time()
            value = run(algo, seed, args.n_timesteps, args.eps, totals)
            results[algo].append(value)
            print(f"{algo:4s} seed {seed}: greedy return {value:g}  ({time.time() - start:.0f} s)", flush=True)
        hits = sum(value == target for value in results[algo])
        print(f"{algo:4s}: {hits}/{len(args.seeds)} seeds reach {target:g}", flush=True)
    print(totals.table())
    return results


if __name__ == "__main__":
    main()
