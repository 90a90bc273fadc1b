"""EM-PPO's belief on ZonePatrol under a few latent settings (the zoo's ZonePatrol settings otherwise):
``python docs/lab/2026-12-05/zone_patrol_em_settings.py NAME SEED STEPS [ENV_KWARGS]`` from the repository root
(``ENV_KWARGS``: ZonePatrol's arguments as JSON, e.g. '{"zone_cue": 0.2}'); prints one JSON line (team reward and the
belief's aligned accuracy at step 30 of 50 held-out episodes)."""

import json
import sys
import time
from pathlib import Path

import numpy as np
import torch as th

sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "benchmarks"))
import zone_patrol_value as bench

from sb3_emmarl.common.env_ids import ZONE_PATROL_ID
from sb3_emmarl.common.latent.metrics import align_components, latent_accuracy
from sb3_emmarl.zoo.exp_manager import zoo_model

CONFIGS = {
    "default": {},
    "pool": {"team_pooling": True},
    "pool_t01": {"team_pooling": True, "likelihood_temperature": 0.1},
    "pool_t01_i4": {"team_pooling": True, "likelihood_temperature": 0.1, "e_step_interval": 4,
                    "e_step_kwargs": {"window": 8, "n_epochs": 2, "batch_size": 1024, "max_transitions": 8192}},
}


def main(name: str, seed: int, steps: int, env_kwargs: dict | None = None) -> None:
    th.set_num_threads(1)
    model = zoo_model("em_ppo", bench.make_env(seed, env_kwargs=env_kwargs), seed, ZONE_PATROL_ID, **CONFIGS[name])
    start = time.time()
    model.learn(steps)
    beliefs: list = []
    venv = model.wrap_env(bench.make_env(bench.EVAL_SEED, env_kwargs=env_kwargs))
    rewards, _ = bench.play(model, venv, 50, bench.EVAL_SEED, beliefs=beliefs)
    posteriors, modes = np.stack([b for b, _ in beliefs]), np.array([m for _, m in beliefs])
    accuracy = latent_accuracy(posteriors, modes, align_components(posteriors, modes, 8))
    print(json.dumps({"name": name, "seed": seed, "env_kwargs": env_kwargs or {}, "steps": steps,
                      "seconds": time.time() - start,
                      "team_reward": float(np.mean(rewards)), "belief_accuracy": accuracy}), flush=True)


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), json.loads(sys.argv[4]) if len(sys.argv) > 4 else None)
