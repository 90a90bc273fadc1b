"""What a trained EM-PPO team's belief on ZonePatrol is made of, and how it compares with the exact team posterior.

Loads a saved EM-PPO model of ``ZonePatrol-v1`` (a zoo run's zip), plays 200 held-out team episodes (8 copies from
seed 50,000, actions sampled, the same episodes as ``benchmarks/zone_patrol_value.py``) and prints:

1. how often the model's evidence, summed over the whole team up to mid-episode (step 30), tells the zone when it is
   made of all the features (as the model was trained, untempered), the readings alone, the transition features alone,
   and the readings plus the transition features tempered by 0.3 and 0.1 (components aligned to modes by Hungarian
   matching at step 30);
2. by step, the accuracy and the mean confidence (largest probability) of the belief the policy read, beside those of
   the exact posterior of the whole team's readings (``wildlife_reserve.zone_patrol.posterior``).

``python docs/lab/2026-12-07/zone_patrol_belief_anatomy.py PATH/ZonePatrol-v1.zip``
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import torch as th

from sb3_emmarl import EMPPO
from sb3_emmarl.common.latent.metrics import align_components
from wildlife_reserve.zone_patrol.posterior import reading_log_likelihoods

spec = importlib.util.spec_from_file_location("zone_patrol_value",
                                              Path(__file__).resolve().parents[3] / "benchmarks" / "zone_patrol_value.py")
bench = importlib.util.module_from_spec(spec)
spec.loader.exec_module(bench)

EPISODES, MID = 200, 30


def main(path: str) -> int:
    th.set_num_threads(1)
    model = EMPPO.load(path, env=bench.make_env(0), device="cpu")
    venv = model.wrap_env(bench.make_env(bench.EVAL_SEED))
    latent, layout = model.policy.latent_model, model.latent_layout
    config = venv.get_attr("config", [0])[0]
    n, per_copy = venv.num_envs, venv.agents_per_copy
    rounds = -(-EPISODES // (n // per_copy))
    rows: dict[str, list] = {key: [] for key in ("x", "a", "y", "step", "mode", "copy", "belief", "exact")}
    th.manual_seed(bench.EVAL_SEED)
    obs = venv.reset()
    state, starts, step = None, np.ones(n, dtype=bool), np.zeros(n, dtype=np.int64)
    features = model._feature_fn(obs[:, :layout.obs_dim])
    team = reading_log_likelihoods(config, obs)
    for t in range(config.max_cycles * rounds):
        actions, state = model.predict(obs, state=state, episode_start=starts)
        obs, _, starts, infos = venv.step(actions)
        following = model._feature_fn(obs[:, :layout.obs_dim])
        after = following.copy()
        for i in np.flatnonzero(starts):
            after[i] = model._feature_fn(infos[i]["terminal_observation"][None, :layout.obs_dim])[0]
        modes = np.array([info["metrics"]["mode"] if done else info["mode"] for info, done in zip(infos, starts)])
        rows["x"].append(features)
        rows["a"].append(model._encode_action(actions))
        rows["y"].append(after)
        rows["step"].append(step.copy())  # the transition from step `step` to the next
        rows["mode"].append(modes)
        rows["copy"].append(t // config.max_cycles * (n // per_copy) + np.arange(n) // per_copy)
        step = np.where(starts, 0, step + 1)
        evidence = reading_log_likelihoods(config, obs)
        team = np.where(starts[:, None], evidence, team + evidence)
        rows["belief"].append(np.where(starts[:, None], np.nan, obs[:, -latent.n_components:]))
        rows["exact"].append(np.repeat(team.reshape(-1, per_copy, team.shape[1]).sum(1), per_copy, axis=0))
        features = following
    x, a, y, steps, modes, copies = (np.concatenate(rows[k]) for k in ("x", "a", "y", "step", "mode", "copy"))
    beliefs, exact = np.concatenate(rows["belief"]), np.concatenate(rows["exact"])
    with th.no_grad():
        means = latent.component_means(th.as_tensor(x), th.as_tensor(a)).numpy()
        log_std = latent.log_std().numpy()
    terms = -0.5 * ((y[:, None, :] - means) / np.exp(log_std)) ** 2 - log_std  # (N, K, d_x), per feature
    readings = list(layout.reading_features)
    others = [i for i in range(layout.feature_dim) if i not in readings]
    upto = steps < MID
    ids, index = np.unique(copies[upto], return_inverse=True)
    truth = np.zeros(len(ids), dtype=np.int64)
    truth[index] = modes[upto]
    print(f"{path}: {len(ids)} team episodes; reading features {readings}")
    print(f"1. the team's evidence up to step {MID}: how often it tells the zone")
    for name, weights in (("all features, untempered", (1.0, 1.0)), ("readings alone", (1.0, 0.0)),
                          ("transition features alone", (0.0, 1.0)), ("readings + 0.3 x transitions", (1.0, 0.3)),
                          ("readings + 0.1 x transitions", (1.0, 0.1))):
        per_step = weights[0] * terms[:, :, readings].sum(2) + weights[1] * terms[:, :, others].sum(2)
        evidence = np.zeros((len(ids), latent.n_components))
        np.add.at(evidence, index, per_step[upto])
        posterior = np.exp(evidence - evidence.max(1, keepdims=True))
        posterior /= posterior.sum(1, keepdims=True)
        aligned = align_components(posterior, truth, latent.n_components)[posterior.argmax(1)]
        print(f"   {name:<32} zone {np.mean(aligned // 2 == truth // 2):.3f}  mode {np.mean(aligned == truth):.3f}")
    observed = ~np.isnan(beliefs[:, 0])
    at_mid = observed & (steps + 1 == MID)
    mapping = align_components(beliefs[at_mid], modes[at_mid], latent.n_components)
    posterior = np.exp(exact - exact.max(1, keepdims=True))
    posterior /= posterior.sum(1, keepdims=True)
    print("2. by step: the belief the policy read, and the exact posterior of the whole team's readings")
    print(f"   {'step':>4}{'belief right':>14}{'confidence':>12}{'exact right':>13}{'confidence':>12}")
    for s in (1, 3, 5, 10, 15, 20, 30, 45):
        sel = observed & (steps + 1 == s)
        right = mapping[beliefs[sel].argmax(1)] == modes[sel]
        print(f"   {s:>4}{right.mean():>14.3f}{beliefs[sel].max(1).mean():>12.3f}"
              f"{np.mean(posterior[sel].argmax(1) == modes[sel]):>13.3f}{posterior[sel].max(1).mean():>12.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))
