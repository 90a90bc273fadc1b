"""The true mode in the observation (ModeObservationWrapper, OraclePPO) and the value-of-information benchmark."""

import numpy as np
import pytest
import torch as th
from scripts import load_benchmark
from stable_baselines3 import PPO
from stable_baselines3.common.evaluation import evaluate_policy

from sb3_emmarl import OraclePPO
from sb3_emmarl.common.initialization import zero_tail_weights
from sb3_emmarl.common.mode_aware import ModeObservationWrapper, wrap_with_mode
from sb3_emmarl.common.vec_env import make_vec_env
from wildlife_reserve.reserve.modes import N_MODES

SMALL = {"n_uavs": 2, "grid_size": 20, "max_cycles": 5}


def true_modes(venv):
    return np.array(venv.get_attr("mode"))


def test_the_one_hot_is_the_true_mode_at_reset_after_steps_and_across_episode_ends():
    venv = ModeObservationWrapper(make_vec_env(3, seed=0, env_kwargs=SMALL))
    assert venv.observation_space.shape == (venv.venv.observation_space.shape[0] + N_MODES,)
    obs = venv.reset()
    seen_modes = set()
    for step in range(23):  # crosses four episode ends
        one_hot = obs[:, -N_MODES:]
        assert (one_hot.sum(axis=1) == 1).all()
        np.testing.assert_array_equal(one_hot.argmax(axis=1), true_modes(venv))
        seen_modes |= set(one_hot.argmax(axis=1).tolist())
        obs, _, dones, infos = venv.step(np.random.default_rng(step).integers(0, 15, venv.num_envs))
        for i in np.flatnonzero(dones):
            terminal = infos[i]["terminal_observation"]
            assert terminal.shape == obs[i].shape
            assert terminal[-N_MODES:].argmax() == infos[i]["metrics"]["mode"]  # the finished episode's mode
    assert len(seen_modes) > 1  # the modes change from episode to episode, and the one-hot follows


def test_wrap_with_mode_wraps_once_and_rejects_what_it_cannot_read():
    venv = wrap_with_mode(make_vec_env(1, seed=0, env_kwargs=SMALL))
    assert wrap_with_mode(venv) is venv
    with pytest.raises(ValueError, match="n_modes must be an int >= 1"):
        ModeObservationWrapper(make_vec_env(1, seed=0, env_kwargs=SMALL), n_modes=0)


def test_oracle_ppo_learns_saves_loads_and_evaluates_on_the_plain_environment(tmp_path):
    model = OraclePPO("MlpPolicy", make_vec_env(2, seed=0, env_kwargs=SMALL), n_steps=16, batch_size=32, seed=0)
    model.learn(128)
    plain = PPO("MlpPolicy", make_vec_env(2, seed=0, env_kwargs=SMALL), n_steps=16, batch_size=32, seed=0)
    assert model.observation_space.shape[0] == plain.observation_space.shape[0] + N_MODES
    model.save(tmp_path / "oracle")
    loaded = OraclePPO.load(tmp_path / "oracle", env=make_vec_env(1, seed=1, env_kwargs=SMALL), device="cpu")
    env = loaded.get_env()
    obs = env.reset()
    np.testing.assert_array_equal(model.predict(obs, deterministic=True)[0], loaded.predict(obs, deterministic=True)[0])
    mean, _ = evaluate_policy(loaded, env, n_eval_episodes=2)
    assert np.isfinite(mean)


def test_oracle_ppo_starts_as_the_same_function_of_every_mode_and_learns_the_mode_s_weights():
    venv = make_vec_env(2, seed=0, env_kwargs=SMALL)
    model = OraclePPO("MlpPolicy", venv, n_steps=16, batch_size=32, seed=0)
    obs = th.as_tensor(model.get_env().reset())
    outputs = []
    for mode in range(N_MODES):
        told = obs.clone()
        told[:, -N_MODES:] = th.nn.functional.one_hot(th.tensor(mode), N_MODES)
        with th.no_grad():
            outputs.append((model.policy.get_distribution(told).distribution.probs, model.policy.predict_values(told)))
    for probs, values in outputs[1:]:  # the same actions' probabilities and values, whatever the mode
        th.testing.assert_close(probs, outputs[0][0])
        th.testing.assert_close(values, outputs[0][1])
    first = model.policy.mlp_extractor.policy_net[0].weight
    assert (first[:, -N_MODES:] == 0).all() and (first[:, :-N_MODES] != 0).any()
    model.learn(64)
    assert (model.policy.mlp_extractor.policy_net[0].weight[:, -N_MODES:] != 0).any()  # the gradient reaches them
    random = OraclePPO("MlpPolicy", venv, n_steps=16, batch_size=32, seed=0, zero_mode_weights=False)
    assert (random.policy.mlp_extractor.value_net[0].weight[:, -N_MODES:] != 0).all(dim=1).any()
    with pytest.raises(ValueError, match="zero_mode_weights must be true or false"):
        OraclePPO("MlpPolicy", venv, zero_mode_weights="yes")


def test_zero_tail_weights_through_the_split_extractor_and_not_where_the_tail_is_not_passed_through():
    from sb3_emmarl.common.extractors import SplitFeaturesExtractor

    venv = wrap_with_mode(make_vec_env(1, seed=0, env_kwargs=SMALL))
    head = venv.observation_space.shape[0] - N_MODES
    for keep, zeroed in ((None, True), (head, False), (head + N_MODES - 1, False)):
        extractor_kwargs = {"head_dim": head - 2, "keep": keep}  # keep=head drops the one-hot; head + 7 a part of it
        policy_kwargs = {"features_extractor_class": SplitFeaturesExtractor, "features_extractor_kwargs": extractor_kwargs}
        model = PPO("MlpPolicy", venv, policy_kwargs=policy_kwargs, seed=0)
        weights = [model.policy.mlp_extractor.policy_net[0].weight, model.policy.mlp_extractor.value_net[0].weight]
        before = [w.clone() for w in weights]
        assert zero_tail_weights(model.policy, N_MODES) is zeroed
        for w, b in zip(weights, before):
            th.testing.assert_close(w[:, :-N_MODES], b[:, :-N_MODES])  # the other inputs' weights never change
            assert (w[:, -N_MODES:] == 0).all() if zeroed else th.equal(w, b)
    assert not zero_tail_weights(model.policy, 0)


def load_mode_value():
    return load_benchmark("mode_value")


def test_the_paired_table_on_hand_built_records():
    mode_value = load_mode_value()
    told = [{"seed": s, "team_reward": r, "detection_rate": 0.5, "coverage_efficiency": 0.5} for s, r in enumerate([3, 5, 4])]
    plain = [{"seed": s, "team_reward": r, "detection_rate": 0.5, "coverage_efficiency": 0.5} for s, r in enumerate([1, 2, 2])]
    table = mode_value.paired_table({"told_mode": told, "ppo": plain})
    row = next(line for line in table.splitlines() if line.startswith("team_reward"))
    # Differences 2, 3, 2: mean 2.333; ttest_rel p = 0.0198; higher on 3 of 3 seeds.
    assert "2.333 +- 0.471" in row and "0.0198" in row and "3/3" in row
    assert "1" in next(line for line in table.splitlines() if line.startswith("detection_rate")).split()[-2]
    with pytest.raises(ValueError, match="same seeds"):
        mode_value.paired_table({"told_mode": told, "ppo": plain[::-1]})


def test_the_benchmark_runs_end_to_end_on_a_tiny_budget(tmp_path, capsys):
    mode_value = load_mode_value()
    code = mode_value.main(["-n", "200", "--seeds", "0", "1", "--eval-episodes", "1", "-f", str(tmp_path),
                            "--patrol-episodes", "3", "--env-kwargs", "n_uavs:2", "grid_size:20", "max_cycles:10"])
    out = capsys.readouterr().out
    assert code == 0
    scripted, trained = out.split("PPO told the mode or not")
    assert "not_told" in scripted and "poaching_events" in scripted and "p (paired t)" in scripted
    assert "told_mode" in trained and "p (paired t)" in trained and "team_reward" in trained
    trained, weights = trained.split("How strongly the told runs read the mode")
    assert len([line for line in trained.splitlines() if line.startswith(("0 ", "1 "))]) == 2
    rows = [line.split() for line in weights.splitlines() if line.startswith(("0 ", "1 "))]
    assert [row[0] for row in rows] == ["0", "1"] and all(float(x) > 0 for row in rows for x in row[2:])


@pytest.mark.parametrize("flags, message", [(["--seeds", "0"], "at least 2 seeds"), (["-n", "0"], "n-timesteps must be >= 1"),
                                            (["--n-jobs", "0"], "n-jobs must be >= 1"),
                                            (["--seeds", "1", "1"], "must be distinct"),
                                            (["--patrol-episodes", "1"], "--patrol-episodes must be 0 or >= 2")])
def test_the_benchmark_rejects_bad_arguments(flags, message, capsys):
    with pytest.raises(SystemExit) as exit_info:
        load_mode_value().main(flags)
    assert exit_info.value.code == 2 and message in capsys.readouterr().err


def test_the_told_mode_patrol_holds_stations_where_the_strategy_s_poachers_come_from():
    from wildlife_reserve import reserve_v0
    from wildlife_reserve.reserve.modes import STRATEGIES, WEATHERS
    from wildlife_reserve.reserve.scripted import StalestBlockPatrol, ToldModePatrol

    env = reserve_v0.parallel_env(n_poachers=0)
    guarded = {"hotspot_raid": lambda: env.hotspots.dens, "edge_infiltration": lambda: env.hotspots.road_entries}
    for strategy, spots in guarded.items():
        index = [s.name for s in STRATEGIES].index(strategy)
        obs, _ = env.reset(seed=0, options={"mode": index * len(WEATHERS)})
        patrol = ToldModePatrol(env)
        for _ in range(int(env.strategy.entry_window[1] * env.max_cycles) - 2):  # still inside the entry window
            obs, *_ = env.step(patrol(obs))
        distance = np.abs(env.uav_pos[:, None, :] - spots()[None] - 0.5).max(-1).min(axis=1)
        # Stations ring the spot (or a point up to `spread` inside the map from it); the far-flung may still fly.
        assert np.mean(distance <= 2 * patrol.spread + 2) >= 0.8, (strategy, distance)
    # A dispersed evasion gives no place to guard: the told patrol acts as the stalest-block patrol.
    obs, _ = env.reset(seed=0, options={"mode": 3 * len(WEATHERS)})
    assert ToldModePatrol(env)(obs) == StalestBlockPatrol(env)(obs)


def test_tail_weight_norms_on_hand_set_weights():
    from sb3_emmarl.common.initialization import first_layers, tail_weight_norms

    model = PPO("MlpPolicy", wrap_with_mode(make_vec_env(1, seed=0, env_kwargs=SMALL)), seed=0)
    for layer in first_layers(model.policy).values():
        with th.no_grad():
            layer.weight.fill_(0.5)  # every column's norm: 0.5 * sqrt(64 rows)
            layer.weight[:, -N_MODES:] = 0.0
            layer.weight[0, -N_MODES:] = 3.0
    norms = tail_weight_norms(model.policy, N_MODES)
    assert norms == {"policy": (3.0, 4.0), "value": (3.0, 4.0)}
    with pytest.raises(ValueError, match="n_tail must be in"):
        tail_weight_norms(model.policy, 0)
