"""Can EM-PPO's latent model tell ZonePatrol's mode from what a team sees? Fitted by EM and fitted told the mode.

The question behind issue 49's acceptance 3 (EM-PPO's belief right 0.37 of the time at mid-episode): is it the model
(the transition mixture over the generic features, a fixed random projection of the 79-float observation), or the
data (a learned team that does not visit the zones gives any belief nothing to read)? As
``docs/lab/studies/mixture_ceiling.py`` does on the reserve, this plays episodes with a fixed team (uniformly random
actions, or the best scripted blind team, which splits over the zones), fits EM-PPO's latent model by its E-step over
all the training episodes (``em``) or told each episode's mode (``told``: the ceiling of the model family and its
features), and scores the aligned accuracy of the posterior's argmax on held-out episodes, from one UAV's evidence
and the team's, at 25 %, 50 % and 100 % of the episode.

Feature sets: ``generic`` (what EM-PPO reads on ZonePatrol today) and ``zone`` (where the tracks lie: per zone, the
track cells and the zone cells in the UAV's window, found from its own position; the visibility reading; the
detections).

``python docs/lab/2026-12-05/zone_patrol_latent_ceiling.py [--teams random blind] [--features generic zone]``
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch as th

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "studies"))
from mixture_ceiling import POINTS, Episodes, ToldEStep, accuracies

from sb3_emmarl.common.latent.algorithm import E_STEP_DEFAULTS
from sb3_emmarl.common.latent.em import EStep
from sb3_emmarl.common.latent.features import generic_features
from sb3_emmarl.common.latent.layout import LatentLayout
from sb3_emmarl.common.latent.model import LatentModel
from sb3_emmarl.common.latent.zone_evidence import zone_features, zone_readings
from wildlife_reserve import zone_patrol_v0
from wildlife_reserve.zone_patrol.scripted import BlindTeam
from wildlife_reserve.zone_patrol.world import ZonePatrolConfig, ZonePatrolWorld


def zone_map_features(cfg: ZonePatrolConfig):
    """EM's zone features (:func:`~sb3_emmarl.common.latent.zone_evidence.zone_features`) of ``cfg``'s map. (The first two
    tables of the notebook were made with this script's own copy of them, before they joined the package: the same
    features, the track counts not yet capped at 5.)"""
    return zone_features(zone_patrol_v0.parallel_env(**cfg.__dict__).zone_map)


#: What :func:`collect` counts of each team episode: whether the team's windows held a track of the mode's zone by
#: mid-episode, and the share of UAV-steps whose window held a cell of the mode's zone.
SEEN: dict[str, list[float]] = {}


def collect(cfg: ZonePatrolConfig, team: str, n_episodes: int, n_copies: int, seed: int, feature_fn) -> Episodes:
    """Episodes of ``team`` ("random", "blind": ``BlindTeam("split", "estimate")``, or "ppo:PATH" / "told:PATH", a
    saved PPO or OraclePPO zip acting on the plain or the told observation, actions sampled) as latent data."""
    from stable_baselines3 import PPO

    if team.startswith("told:"):
        cfg = ZonePatrolConfig.from_kwargs(**{**cfg.__dict__, "told": True})
    policy = PPO.load(team.split(":", 1)[1], device="cpu") if ":" in team else None
    world, rng = ZonePatrolWorld(cfg, n_copies), np.random.default_rng(seed)
    n, rows = cfg.n_uavs, []
    zone_fn = zone_map_features(cfg)[0]
    for round_ in range(-(-n_episodes // n_copies)):
        world.reset(rng)
        scripted = BlindTeam("split", "estimate") if team == "blind" else None
        if scripted is not None:
            scripted.reset(world)
        obs = world.observations()
        team_ids = np.repeat(round_ * n_copies + np.arange(n_copies), n)
        tracked, exposed = np.zeros(n_copies, dtype=bool), []
        for t in range(cfg.max_cycles):
            if scripted is not None:
                actions = scripted.act(world)
            elif policy is not None:
                actions = policy.predict(obs.reshape(-1, obs.shape[-1]), deterministic=False)[0].reshape(n_copies, n)
            else:
                actions = rng.integers(10, size=(n_copies, n))
            zones = zone_fn(obs.reshape(-1, obs.shape[-1])).reshape(n_copies, n, -1)
            own = zones[np.arange(n_copies), :, world.zones]  # (copies, n): tracks of the mode's zone in view
            exposed.append(zones[np.arange(n_copies), :, 4 + world.zones] > 0)
            if t < cfg.max_cycles // 2:
                tracked |= (own > 0).any(1)
            world.step(actions, rng)
            following = world.observations()
            rows.append((feature_fn(obs.reshape(-1, obs.shape[-1])), np.eye(10, dtype=np.float32)[actions.ravel()],
                         feature_fn(following.reshape(-1, obs.shape[-1])), team_ids * n + np.tile(np.arange(n), n_copies),
                         team_ids, np.full(n_copies * n, t), np.repeat(world.modes, n)))
            obs = following
        SEEN.setdefault(team, []).extend([*tracked.tolist()])
        SEEN.setdefault(team + " exposed", []).append(float(np.mean(exposed)))
    empty = np.zeros((0, len(POINTS), 1, 1))
    return Episodes(*(np.concatenate(column) for column in zip(*rows)), counts=empty, exposure=empty[..., 0],
                    count_uav=np.zeros(0, int), count_team=np.zeros(0, int), count_mode=np.zeros(0, int))


class Fitted:
    """What :func:`accuracies` reads of a model: the latent model and the likelihood temperature."""

    def __init__(self, latent: LatentModel, beta: float) -> None:
        self.policy = type("P", (), {"latent_model": latent})()
        self.likelihood_temperature = beta


def fit(seed: int, train: Episodes, dim: int, e_steps: int, told: bool, team_pooling: bool, beta: float,
        readings: tuple[int, ...] = ()) -> Fitted:
    th.manual_seed(seed)
    latent = LatentModel(LatentLayout(obs_dim=dim, feature_dim=dim, action_dim=10, n_components=8,
                                      reading_features=readings))
    kwargs = {**E_STEP_DEFAULTS, "window": 1, "likelihood_temperature": beta, "seed": seed}
    if told:
        e_step = ToldEStep(dict(zip(train.team_episode.tolist(), train.mode.tolist())), latent_model=latent, **kwargs)
    else:
        e_step = EStep(latent, **kwargs)
    e_step.add(train.transitions(team=team_pooling or told))
    for _ in range(e_steps):
        e_step.step()
    return Fitted(latent, beta)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--teams", nargs="+", default=["random", "blind"],
                        help="random, blind, ppo:PATH or told:PATH (a saved PPO / OraclePPO zip)")
    parser.add_argument("--features", nargs="+", default=["generic", "zone"], choices=["generic", "zone"])
    parser.add_argument("--train-episodes", type=int, default=200)
    parser.add_argument("--test-episodes", type=int, default=200)
    parser.add_argument("--e-steps", type=int, default=20)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    parser.add_argument("--beta", type=float, default=1.0, help="likelihood_temperature")
    parser.add_argument("--team-pooling", action="store_true")
    parser.add_argument("--readings", action="store_true",
                        help="model the zone features' readings as readings (zone_readings; since 2026-12-07)")
    parser.add_argument("--env-kwargs", default="{}", help="ZonePatrol's arguments, as JSON (e.g. '{\"agent_ids\": true}')")
    args = parser.parse_args()
    th.set_num_threads(1)
    cfg = ZonePatrolConfig.from_kwargs(**json.loads(args.env_kwargs))
    start = time.perf_counter()
    print(f"ZonePatrol defaults; {args.train_episodes} training and {args.test_episodes} held-out episodes; "
          f"{args.e_steps} E-steps; beta {args.beta}; team pooling {args.team_pooling}; seeds {args.seeds}; "
          f"aligned mode accuracy (mean over seeds) at {[f'{p:.0%}' for p in POINTS]} of the episode")
    for features in args.features:
        fn, dim = zone_map_features(cfg) if features == "zone" else generic_features(cfg.obs_dim)
        readings = zone_readings(zone_patrol_v0.parallel_env(**cfg.__dict__).zone_map) \
            if args.readings and features == "zone" else ()
        for team in args.teams:
            train = collect(cfg, team, args.train_episodes, 20, 0, fn)
            test = collect(cfg, team, args.test_episodes, 20, 1_000_000, fn)
            print(f"{team}: a track of the mode's zone in some UAV's window by mid-episode in "
                  f"{np.mean(SEEN[team][-args.test_episodes:]):.3f} of the held-out episodes; a cell of the zone in "
                  f"view in {np.mean(SEEN[team + ' exposed'][-(-args.test_episodes // 20):]):.3f} of the UAV-steps")
            for told in (False, True):
                runs = [accuracies(fit(s, train, dim, args.e_steps, told, args.team_pooling, args.beta, readings), test)
                        for s in args.seeds]
                for source in ("one UAV", "team"):
                    cells = [np.mean([run[f"{source} mode {p:.0%}"] for run in runs]) for p in POINTS]
                    zone = [np.mean([run[f"{source} strategy {p:.0%}"] for run in runs]) for p in POINTS]
                    print(f"{features:<8}{team.split('/')[-1]:<10}{'told' if told else 'em':<5}{source:<8} mode "
                          + " ".join(f"{c:.3f}" for c in cells) + "   zone " + " ".join(f"{c:.3f}" for c in zone),
                          flush=True)
    print(f"wall time {time.perf_counter() - start:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
