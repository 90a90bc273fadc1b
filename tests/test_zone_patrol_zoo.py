"""ZonePatrol through the zoo (``--env ZonePatrol-v1``), the team evaluation, SB3's evaluation and the centralised view."""

import json

import numpy as np
import pytest
from PIL import Image
from stable_baselines3.common.evaluation import evaluate_policy
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from sb3_emmarl.common.centralized import CentralizedZonePatrolEnv, centralized_env
from sb3_emmarl.common.env_ids import ENV_MODULES, ZONE_PATROL_ID, check_env_id, parallel_env_fn
from sb3_emmarl.common.evaluation import evaluate_team
from sb3_emmarl.common.metrics import format_summary, summarize, team_metric_keys
from sb3_emmarl.zoo.cli import enjoy_main, latest_run, run_env_id, train_main
from sb3_emmarl.zoo.exp_manager import zoo_hyperparams, zoo_model
from wildlife_reserve import zone_patrol_v0, zone_patrol_v1

#: ZonePatrol's episode metrics (its world's ``metrics``).
METRICS = ("team_reward", "detections", "escapes", "intruders", "detection_rate")


def train(tmp_path, algo, *extra):
    return train_main(["--algo", algo, "--env", ZONE_PATROL_ID, "-n", "1024", "--seed", "2", "-f",
                       str(tmp_path / "logs"), "-tb", str(tmp_path / "runs"), "--eval-freq", "-1",
                       "--team-eval-episodes", "2", "--verbose", "0", "-params", "n_envs:2", "n_steps:32", *extra])


@pytest.fixture(scope="module")
def zoo_runs(tmp_path_factory):
    tmp_path = tmp_path_factory.mktemp("zone_patrol_zoo")
    for algo in ("ppo", "em_ppo", "oracle_ppo", "ppo_lstm", "mappo"):
        assert train(tmp_path, algo) == 0, algo
    return tmp_path


@pytest.mark.parametrize("algo", ["ppo", "em_ppo", "oracle_ppo", "ppo_lstm", "mappo"])
def test_the_zoo_trains_every_yaml_on_zone_patrol(zoo_runs, algo):
    run = latest_run(zoo_runs / "logs", algo, ZONE_PATROL_ID)
    assert run.name == f"{ZONE_PATROL_ID}_1" and run_env_id(run) == ZONE_PATROL_ID
    assert (run / f"{ZONE_PATROL_ID}.zip").is_file() and (run / ZONE_PATROL_ID / "config.yml").is_file()
    records = json.loads((run / "team_eval.json").read_text())
    assert len(records) == 2 and set(METRICS) <= set(records[0]) and 0 <= records[0]["mode"] < 8
    if algo == "em_ppo":
        assert "latent_accuracy" in records[0] and "belief_use" in records[0]


def test_tensorboard_holds_zone_patrols_metrics(zoo_runs):
    events = sorted((zoo_runs / "runs").rglob("events.out.tfevents.*"))
    assert len(events) == 5
    accumulator = EventAccumulator(str(events[0]))
    accumulator.Reload()
    tags = set(accumulator.Tags()["scalars"])
    assert {f"reserve/{metric}" for metric in METRICS} <= tags


def test_enjoy_plays_and_records_a_zone_patrol_run(zoo_runs, capsys):
    gif = zoo_runs / "patrol.gif"
    assert enjoy_main(["--algo", "em_ppo", "--env", ZONE_PATROL_ID, "-f", str(zoo_runs / "logs"), "--episodes", "2",
                       "-o", str(gif)]) == 0
    out = capsys.readouterr().out
    assert all(metric in out for metric in METRICS) and "latent_accuracy" in out
    with Image.open(gif) as image:
        assert image.n_frames > 10


#: em_ppo.yml's likelihood_temperature on ZonePatrol: the transition features' evidence nearly off (docs/zone_patrol.md)
LATENT_TEMPERATURE = 0.001


def test_the_yamls_sections_are_the_protocols_settings():
    ppo, em = zoo_hyperparams("ppo", ZONE_PATROL_ID), zoo_hyperparams("em_ppo", ZONE_PATROL_ID)
    assert (ppo["n_envs"], ppo["n_steps"], ppo["batch_size"], ppo["n_epochs"], ppo["ent_coef"]) == (8, 128, 1024, 10, 0.01)
    latent = {"n_components": 8, "fusion": True, "team_pooling": True, "likelihood_temperature": LATENT_TEMPERATURE,
              "e_step_interval": 8,
              "e_step_kwargs": zoo_hyperparams("em_ppo")["latent_kwargs"]["e_step_kwargs"]}  # the reserve's E-step schedule
    own = ("latent_kwargs", "zero_belief_weights")
    assert {k: v for k, v in em.items() if k not in own} == ppo  # EM-PPO at PPO's settings (PROTOCOL item 10)
    assert em["latent_kwargs"] == latent and em["zero_belief_weights"] is True


def test_the_zoo_refuses_an_algorithm_without_a_zone_patrol_section(tmp_path, capsys):
    assert train(tmp_path, "ddpg") == 2
    assert f"has no mapping of hyperparameters under '{ZONE_PATROL_ID}'" in capsys.readouterr().err
    assert not (tmp_path / "logs" / "ddpg").exists()


def test_environment_ids_are_checked():
    assert set(ENV_MODULES) == {"WildlifeReserve-v1", ZONE_PATROL_ID, "ZonePatrol-v0"}
    assert parallel_env_fn(ZONE_PATROL_ID) is zone_patrol_v1.parallel_env
    assert parallel_env_fn("ZonePatrol-v0") is zone_patrol_v0.parallel_env
    assert zoo_hyperparams("em_ppo", "ZonePatrol-v0") == zoo_hyperparams("em_ppo", ZONE_PATROL_ID)  # one section
    with pytest.raises(ValueError, match="unknown environment id 'CartPole-v1'; known"):
        check_env_id("CartPole-v1")


def test_evaluate_team_and_sb3s_evaluate_policy_on_zone_patrol():
    from sb3_emmarl.common.vec_env import make_vec_env

    env = make_vec_env(2, seed=0, env_fn=zone_patrol_v1.parallel_env, vec_env_type="batched")
    model = zoo_model("em_ppo", env, seed=0, env_id=ZONE_PATROL_ID, n_steps=32)
    first = evaluate_team(model, n_episodes=3, seed=7, env_id=ZONE_PATROL_ID)
    assert first == evaluate_team(model, n_episodes=3, seed=7, env_id=ZONE_PATROL_ID)  # same seed, same episodes
    assert len(first) == 3 and team_metric_keys(first[0]) == METRICS
    table = format_summary(summarize(first))
    assert table.splitlines()[0].startswith("team_reward") and "latent_accuracy" in table
    plain = make_vec_env(1, seed=3, env_fn=zone_patrol_v1.parallel_env, vec_env_type="batched")
    mean, _ = evaluate_policy(model, plain, n_eval_episodes=4)
    assert np.isfinite(mean)


def test_the_centralised_view_of_zone_patrol():
    env = centralized_env(ZONE_PATROL_ID)
    assert isinstance(env, CentralizedZonePatrolEnv)
    state, info = env.reset(seed=1)
    assert env.observation_space.contains(state) and "mode" in info
    assert env.action_space.nvec.tolist() == [env.n_actions] * 4
    state, reward, terminated, truncated, info = env.step(env.action_space.sample())
    assert env.observation_space.contains(state) and isinstance(reward, float) and not (terminated or truncated)
    with pytest.raises(ValueError, match=r"integers in \[0, "):
        env.step(np.full(4, 0.5))
