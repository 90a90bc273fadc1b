"""Train EM-PPO on the corridor (60k agent-steps) and read its belief and its first action per mode.

Usage (from the repository's root): ``python docs/lab/2026-12-07/corridor_belief_per_mode.py SEED ['{"latent": "kwargs"}']``
(section 4 of issue_67_stage_1.md in this folder).
"""

import json
import sys
from pathlib import Path

import numpy as np
import torch as th

from sb3_emmarl import EMPPO

sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "benchmarks"))
import latent_tasks as lt


def main() -> None:
    th.set_num_threads(1)
    seed = int(sys.argv[1]) if len(sys.argv) > 1 else 1
    latent = json.loads(sys.argv[2]) if len(sys.argv) > 2 else {}
    model = EMPPO("MlpPolicy", lt.make_task("corridor", seed=seed), seed=seed, latent_kwargs=latent)
    model.learn(60_000)
    venv = model.wrap_env(lt.make_task("corridor", n_envs=4, seed=300 + seed))
    obs = venv.reset()
    steps = np.zeros(4, int)
    confusion = np.zeros((4, model.latent_layout.n_components))  # mode x most likely component, from the third step
    actions = np.zeros((4, 4))  # mode x action at the first step
    success: dict[int, list[bool]] = {m: [] for m in range(4)}
    episodes = 0
    while episodes < 200:
        modes = np.array(venv.get_attr("mode"))
        belief = model.posterior(obs)
        act, _ = model.predict(obs, deterministic=True)
        for i in range(4):
            if steps[i] >= 2:
                confusion[modes[i], belief[i].argmax()] += 1
            if steps[i] == 0:
                actions[modes[i], act[i]] += 1
        obs, _, dones, infos = venv.step(act)
        steps = np.where(dones, 0, steps + 1)
        for i in np.flatnonzero(dones):
            success[infos[i]["mode"]].append(infos[i]["success"])
            episodes += 1
    np.set_printoptions(precision=2, suppress=True)
    print("seed", seed, "success per mode", {m: round(float(np.mean(v)), 2) for m, v in success.items()})
    print("belief's most likely component per mode (rows), from the third step:\n",
          confusion / confusion.sum(1, keepdims=True))
    print("first action per mode (rows):\n", actions / actions.sum(1, keepdims=True))
    print("prior", model.policy.latent_model.log_prior.exp().detach().numpy())


if __name__ == "__main__":
    main()
