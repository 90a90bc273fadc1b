"""How right must a belief be to pay? Told PPO (ZonePatrol, zone_cue 0.2) evaluated told a label right with probability p.

``python docs/lab/2026-12-06/zone_patrol_label_value.py SEED [ZIP]`` from the repository root: trains (or loads) told PPO
with the zoo's ZonePatrol settings and zone_cue 0.2 for 1M agent-steps, then scores it on 200 held-out team episodes
told, per copy and episode, the true mode with probability p and else one of the seven others"""
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch as th

sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "benchmarks"))
import zone_patrol_value as bench
from stable_baselines3.common.vec_env import VecEnvWrapper

CUE = {"zone_cue": 0.2}


class Noisy(VecEnvWrapper):
    """The told one-hot replaced, per copy and episode, by the true mode w.p. p, else one of the 7 others."""

    def __init__(self, venv, p, seed):
        super().__init__(venv)
        self.p, self.rng = p, np.random.default_rng(seed)
        self.per = int(getattr(venv, "agents_per_copy", 1))
        self.labels = None

    def _draw(self, obs, copies):
        for c in copies:
            true = int(obs[c * self.per, -8:].argmax())
            if self.rng.random() < self.p:
                self.labels[c] = true
            else:
                self.labels[c] = (true + self.rng.integers(1, 8)) % 8

    def _apply(self, obs):
        obs = obs.copy()
        obs[:, -8:] = np.eye(8, dtype=obs.dtype)[np.repeat(self.labels, self.per)]
        return obs

    def reset(self):
        obs = self.venv.reset()
        self.labels = np.zeros(self.num_envs // self.per, dtype=int)
        self._draw(obs, range(len(self.labels)))
        return self._apply(obs)

    def step_wait(self):
        obs, rewards, dones, infos = self.venv.step_wait()
        starts = [c for c in range(len(self.labels)) if dones[c * self.per]]
        self._draw(obs, starts)
        return self._apply(obs), rewards, dones, infos


def main():
    seed = int(sys.argv[1])
    th.set_num_threads(1)
    from sb3_emmarl import OraclePPO
    if len(sys.argv) > 2:
        model = OraclePPO.load(sys.argv[2], device="cpu")
    else:
        model = bench.build("told", seed, CUE)
        start = time.time()
        model.learn(1_000_000)
        model.save(f"told_cue_{seed}.zip")
        print("trained", time.time() - start, flush=True)
    for p in (1.0, 0.86, 0.68, 0.43, 0.125):
        venv = Noisy(model.wrap_env(bench.make_env(bench.EVAL_SEED, env_kwargs=CUE)), p, 0)
        rewards, _ = bench.play(model, venv, 200, bench.EVAL_SEED)
        print(json.dumps({"seed": seed, "p": p, "team_reward": float(np.mean(rewards))}), flush=True)


if __name__ == "__main__":
    main()
