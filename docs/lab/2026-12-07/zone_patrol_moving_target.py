"""Does EM-PPO on ZonePatrol lose its gain to the E-step's moving target, or to a belief that comes too late?

Two runs of ``em_ppo.yml``'s ZonePatrol-v1 settings, 1M agent-steps, scored as ``benchmarks/zone_patrol_value.py``
scores its runs (200 held-out team episodes from seed 50,000, actions sampled):

- ``frozen SEED MODEL``: a fresh policy learns on the belief of a latent model fitted earlier (the latent model of the
  EM-PPO zip ``MODEL``, loaded and frozen: ``freeze_e_step``), so the belief's components never move under it;
- ``warmup SEED STEPS``: the policy is not updated (``freeze_m_step``) for the first ``STEPS`` agent-steps while the
  E-steps fit the latent model on the random team's episodes, then both learn as in training.

``python docs/lab/2026-12-07/zone_patrol_moving_target.py frozen 0 RUN/ZonePatrol-v1.zip``
``python docs/lab/2026-12-07/zone_patrol_moving_target.py warmup 0 65536``
"""

from __future__ import annotations

import argparse
import importlib.util
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch as th

from sb3_emmarl import EMPPO
from sb3_emmarl.zoo.exp_manager import zoo_model

spec = importlib.util.spec_from_file_location("zone_patrol_value",
                                              Path(__file__).resolve().parents[3] / "benchmarks" / "zone_patrol_value.py")
assert spec is not None and spec.loader is not None
value = importlib.util.module_from_spec(spec)
spec.loader.exec_module(value)

BUDGET = 1_000_000


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("how", choices=["frozen", "warmup"])
    parser.add_argument("seed", type=int)
    parser.add_argument("source", help="frozen: the EM-PPO zip whose latent model is used; warmup: agent-steps")
    args = parser.parse_args()
    th.set_num_threads(1)
    if args.how == "frozen":
        model = zoo_model("em_ppo", value.make_env(args.seed), args.seed, "ZonePatrol-v1",
                          latent_kwargs={"freeze_e_step": True})
        trained = EMPPO.load(args.source, device="cpu")
        model.policy.latent_model.load_state_dict(trained.policy.latent_model.state_dict())
        model.learn(BUDGET)
    else:
        warm = int(args.source)
        model = zoo_model("em_ppo", value.make_env(args.seed), args.seed, "ZonePatrol-v1",
                          latent_kwargs={"freeze_m_step": True})
        model.learn(warm)
        model.latent_config = replace(model.latent_config, freeze_m_step=False)
        model.learn(BUDGET - model.num_timesteps, reset_num_timesteps=False)
    env = model.wrap_env(value.make_env(value.EVAL_SEED))
    rewards = value.play(model, env, 200, value.EVAL_SEED)[0]
    print(f"{args.how} {args.source}, seed {args.seed}: team reward {np.mean(rewards):.3f} "
          f"({model.num_timesteps} agent-steps)")


if __name__ == "__main__":
    main()
