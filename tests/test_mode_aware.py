"""The true mode in the observation (ModeObservationWrapper, OraclePPO) and the value-of-information benchmark."""

import argparse
import json

import numpy as np
import pytest
import torch as th
from scripts import load_benchmark, load_study
from stable_baselines3 import PPO
from stable_baselines3.common.evaluation import evaluate_policy

from sb3_emmarl import OraclePPO
from sb3_emmarl.common.appended.initialization import zero_tail_weights
from sb3_emmarl.common.mode_aware import ModeObservationWrapper, wrap_with_mode
from sb3_emmarl.common.vec_env import make_vec_env
from wildlife_reserve.reserve.modes import N_MODES, STRATEGIES, WEATHERS, decode_mode, encode_mode, next_strategy

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


def test_relabel_tells_another_mode_and_bad_relabels_are_rejected():
    wrong = [next_strategy(mode) for mode in range(N_MODES)]
    venv = ModeObservationWrapper(make_vec_env(3, seed=0, env_kwargs=SMALL), relabel=wrong)
    obs = venv.reset()
    for step in range(12):  # crosses episode ends
        np.testing.assert_array_equal(obs[:, -N_MODES:].argmax(axis=1), np.array(wrong)[true_modes(venv)])
        obs, _, dones, infos = venv.step(np.random.default_rng(step).integers(0, 15, venv.num_envs))
        for i in np.flatnonzero(dones):
            assert infos[i]["terminal_observation"][-N_MODES:].argmax() == wrong[infos[i]["metrics"]["mode"]]
    for bad in ([0] * (N_MODES - 1), [N_MODES] * N_MODES, [0.5] * N_MODES, [True] * N_MODES, "01234567"):
        with pytest.raises(ValueError, match=f"relabel must be {N_MODES} ints"):
            ModeObservationWrapper(make_vec_env(1, seed=0, env_kwargs=SMALL), relabel=bad)


def test_a_subclass_appends_another_form_of_the_told_mode_at_resets_steps_and_episode_ends():
    class ToldAsRow(ModeObservationWrapper):  # the told mode as one float, beside the observation's first value
        def _bounds(self, dtype):
            return np.array([-np.inf, 0.0], dtype), np.array([np.inf, N_MODES], dtype)

        def _append(self, observations, told):
            return np.stack([observations[:, 0], told], axis=1).astype(np.float32)

    wrong = [next_strategy(mode) for mode in range(N_MODES)]
    venv = ToldAsRow(make_vec_env(3, seed=0, env_kwargs=SMALL), relabel=wrong)
    assert venv.observation_space.shape == (venv.venv.observation_space.shape[0] + 2,)
    obs = venv.reset()
    ends = 0
    for step in range(12):  # crosses episode ends
        np.testing.assert_array_equal(obs[:, -1], np.array(wrong)[true_modes(venv)])
        np.testing.assert_array_equal(obs[:, -2], obs[:, 0])  # read from the observation it is appended to
        obs, _, dones, infos = venv.step(np.random.default_rng(step).integers(0, 15, venv.num_envs))
        for i in np.flatnonzero(dones):
            terminal = infos[i]["terminal_observation"]
            assert terminal[-1] == wrong[infos[i]["metrics"]["mode"]] and terminal[-2] == terminal[0]
            ends += 1
    assert ends


def test_next_strategy_keeps_the_weather_and_changes_the_strategy_and_encode_inverts_decode():
    for mode in range(N_MODES):
        strategy, weather = decode_mode(mode)
        assert encode_mode(STRATEGIES.index(strategy), WEATHERS.index(weather)) == mode
        other, same_weather = decode_mode(next_strategy(mode))
        assert other != strategy and same_weather == weather
    assert sorted(next_strategy(mode) for mode in range(N_MODES)) == list(range(N_MODES))  # a permutation
    with pytest.raises(ValueError, match="strategy must be in"):
        encode_mode(len(STRATEGIES), 0)


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
    from sb3_emmarl.common.appended.extractor import SplitFeaturesExtractor

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
                            "--patrol-episodes", "3", "--env-kwargs", "n_uavs:2", "grid_size:20", "max_cycles:10",
                            "-params", "n_epochs:2"])
    out = capsys.readouterr().out
    assert code == 0
    assert "ppo.yml settings with n_epochs:2 for both" in out
    for variant in ("told_mode", "told_random", "ppo"):  # the overrides reached the training of every variant
        run = mode_value.latest_run(mode_value.run_folder(argparse.Namespace(log_folder=str(tmp_path)), variant, 0),
                                    "ppo" if variant == "ppo" else "oracle_ppo")
        config = (run / "WildlifeReserve-v1" / "config.yml").read_text()
        assert "n_epochs: 2" in config and ("random_label" in config) == (variant == "told_random")
    with pytest.raises(ValueError, match=r"needs a run told the mode \(oracle_ppo\), not ppo"):
        mode_value.evaluate_run("ppo", run, 1, 0, mode_value.WRONG_STRATEGY)  # run: the last one, plain PPO's
    out, mode_use = out.split("Does told PPO act on the mode?")
    assert "true_mode" in mode_use and "wrong_strategy" in mode_use and "p (paired t)" in mode_use
    assert len([line for line in mode_use.splitlines() if line.startswith(("0 ", "1 "))]) == 2
    scripted, trained = out.split("PPO told the mode or not")
    assert "not_told" in scripted and "poaching_events" in scripted and "p (paired t)" in scripted
    assert "Not told: the best single plan" in scripted and "roads<0.75" in scripted
    assert "Power: " in trained
    assert "told_mode" in trained and "p (paired t)" in trained and "team_reward" in trained
    trained, control = trained.split("The control: PPO told a random label")
    control, weights = control.split("How strongly the told runs read the mode")
    told_against, against_ppo = control.split("The control against PPO")
    assert told_against.split("\n")[1].split() == ["metric", "told_mode", "told_random", "difference", "p", "(paired",
                                                   "t)", "higher", "on"]
    assert "told_random" in against_ppo.split("\n")[1] and "ppo" in against_ppo.split("\n")[1]
    assert len([line for line in against_ppo.splitlines() if line.startswith(("0 ", "1 "))]) == 2
    assert len([line for line in trained.splitlines() if line.startswith(("0 ", "1 "))]) == 2
    rows = [line.split() for line in weights.splitlines() if line.startswith(("0 ", "1 "))]
    assert [row[0] for row in rows] == ["0", "1"] and all(float(x) > 0 for row in rows for x in row[2:])


@pytest.mark.parametrize("flags, message", [(["--seeds", "0"], "at least 2 seeds"),
                                            (["-n", "0"], "n-timesteps: must be an int in [1, "),
                                            (["--n-jobs", "0"], "n-jobs: must be an int in [1, 64]"),
                                            (["--seeds", "1", "1"], "must be distinct"),
                                            (["--patrol-episodes", "1"], "--patrol-episodes must be 0 or >= 2"),
                                            (["--eval-seed", "299"], "must not overlap the fitting episodes"),
                                            (["--scripted-only", "--patrol-episodes", "0"], "needs --patrol-episodes"),
                                            (["-params", "nope"], "-params expects key:value pairs, got 'nope'")])
def test_the_benchmark_rejects_bad_arguments(flags, message, capsys):
    with pytest.raises(SystemExit) as exit_info:
        load_mode_value().main(flags)
    assert exit_info.value.code == 2 and message in capsys.readouterr().err


def test_the_told_mode_patrol_holds_stations_where_the_strategy_s_poachers_come_from():
    from wildlife_reserve import reserve_v1
    from wildlife_reserve.reserve.modes import STRATEGIES, WEATHERS
    from wildlife_reserve.reserve.scripted import StalestBlockPatrol, ToldModePatrol

    env = reserve_v1.parallel_env(n_poachers=0)
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


def test_a_station_plan_rejects_bad_values_and_a_plan_per_strategy_must_name_every_strategy():
    from wildlife_reserve import reserve_v1
    from wildlife_reserve.reserve.scripted import StationPatrol, StationPlan

    with pytest.raises(ValueError, match="spots must be None or one of"):
        StationPlan("waterholes", 0.5)
    with pytest.raises(ValueError, match=r"until must be a fraction of the episode in \[0, 1\], got 1.5"):
        StationPlan("dens", 1.5)
    with pytest.raises(ValueError, match="one per strategy"):
        StationPatrol(reserve_v1.parallel_env(), {"hotspot_raid": StationPlan("dens", 0.5)})
    assert StationPlan(None).name == "sweep" and StationPlan("roads", 0.75).name == "roads<0.75"


def test_a_station_plan_guards_its_spots_in_every_mode_until_its_time_then_sweeps():
    from wildlife_reserve import reserve_v1
    from wildlife_reserve.reserve.scripted import StalestBlockPatrol, StationPatrol, StationPlan

    env = reserve_v1.parallel_env(n_poachers=0)
    plan = StationPlan("dens", 0.5)
    for mode in (0, 2 * 2 + 1, 3 * 2):  # a hotspot raid, a coordinated group in fog, a dispersed evasion
        obs, _ = env.reset(seed=1, options={"mode": mode})
        patrol = StationPatrol(env, plan)
        for _ in range(int(plan.until * env.max_cycles) - 2):
            obs, *_ = env.step(patrol(obs))
        distance = np.abs(env.uav_pos[:, None, :] - env.hotspots.dens[None] - 0.5).max(-1).min(axis=1)
        assert np.mean(distance <= 2 * patrol.spread + 2) >= 0.8, (mode, distance)
        for _ in range(3):  # past its time it is the stalest-block patrol
            obs, *_ = env.step(patrol(obs))
        assert patrol(obs) == StalestBlockPatrol(env)(obs)


def test_the_scripted_plans_are_chosen_on_hand_built_records():
    mode_value = load_mode_value()

    def records(rewards_by_mode):
        return [{"seed": i, "mode": mode, "team_reward": reward} for i, (mode, reward) in enumerate(rewards_by_mode)]

    # Modes 0/1 are hotspot raids, 2/3 edge infiltrations, 4/5 coordinated groups; no dispersed evasion drawn.
    fitted = {"a": records([(0, 10), (1, 10), (2, 0), (4, 0)]),   # mean 5: best single plan
              "b": records([(0, 0), (1, 0), (2, 12), (4, 1)]),    # mean 3.25: best on edge infiltrations
              "c": records([(0, 0), (1, 0), (2, 0), (5, 15)])}    # mean 3.75: best on coordinated groups
    single, per_strategy = mode_value.choose_plans(fitted)
    assert single == "a"
    assert per_strategy == {"hotspot_raid": "a", "edge_infiltration": "b", "coordinated_group": "c",
                            "dispersed_evasion": "a"}
    table = mode_value.plan_table(fitted).splitlines()
    assert table[0].split()[1:4] == ["hotspot_raid", "(2)", "edge_infiltration"]
    assert table[1].split() == ["a", "10.00", "0.00", "0.00", "nan", "5.00"]


def test_scripted_only_stops_before_training(tmp_path, capsys):
    code = load_mode_value().main(["--scripted-only", "--patrol-episodes", "2", "-f", str(tmp_path), "--n-jobs", "1",
                                   "--env-kwargs", "n_uavs:2", "grid_size:20", "max_cycles:10"])
    out = capsys.readouterr().out
    assert code == 0 and "Not told: the best single plan" in out and "held-out episodes" in out
    assert "PPO told the mode or not" not in out and not list(tmp_path.iterdir())


def test_the_told_station_team_plays_its_strategy_s_plan_on_the_held_out_episodes():
    from wildlife_reserve.reserve.scripted import StationPlan, play_station_plan

    mode_value = load_mode_value()
    tiny, plans = {"n_uavs": 2, "grid_size": 20, "max_cycles": 10}, (StationPlan(None), StationPlan("dens", 1.0))
    fitted, single, per_strategy, held_out = mode_value.station_value(4, 100, tiny, n_jobs=1, plans=plans)
    assert set(fitted) == {"sweep", "dens<1"} and [r["seed"] for r in fitted["sweep"]] == [0, 1, 2, 3]
    assert (single, per_strategy) == mode_value.choose_plans(fitted)
    by_plan = {plan.name: play_station_plan(plan, 4, 100, tiny) for plan in plans}
    assert held_out["not_told"] == by_plan[single]
    assert held_out["told"] == [by_plan[per_strategy[mode_value.strategy_of(r)]][i] for i, r in enumerate(by_plan[single])]


def test_seeds_needed_matches_the_paired_t_test_s_power_tables():
    from sb3_emmarl.common.statistics import seeds_needed

    # Cohen's tables, two-sided paired t-test at 0.05 and power 0.8: d = 1 needs 10 pairs, d = 0.5 needs 34.
    assert seeds_needed(1.0, 1.0) == 10 and seeds_needed(-2.5, 5.0) == 34
    assert seeds_needed(0.0, 1.0) is None and seeds_needed(0.001, 1.0, max_n=1000) is None
    assert seeds_needed(100.0, 1.0) == 2 and seeds_needed(10.0, 1.0) == 3  # 2 pairs: critical t 12.7
    with pytest.raises(ValueError, match="sd must be > 0"):
        seeds_needed(1.0, 0.0)


def test_tail_weight_norms_on_hand_set_weights():
    from sb3_emmarl.common.appended.initialization import first_layers, tail_weight_norms

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


@pytest.mark.parametrize("mode_input, blind", [("policy", "value"), ("value", "policy")])
def test_mode_input_holds_the_other_network_s_weights_on_the_mode_at_zero_through_training_and_loading(
        tmp_path, mode_input, blind):
    from sb3_emmarl.common.appended.initialization import first_layers

    model = OraclePPO("MlpPolicy", make_vec_env(2, seed=0, env_kwargs=SMALL), n_steps=16, batch_size=32, seed=0,
                      mode_input=mode_input)
    model.learn(128)
    layers = first_layers(model.policy)
    assert th.count_nonzero(layers[blind].weight[:, -N_MODES:]) == 0
    assert th.count_nonzero(layers[mode_input].weight[:, -N_MODES:]) > 0  # the reading network learned weights on it
    assert th.count_nonzero(layers[blind].weight[:, :-N_MODES]) > 0
    model.save(tmp_path / "oracle")
    loaded = OraclePPO.load(tmp_path / "oracle", env=make_vec_env(2, seed=1, env_kwargs=SMALL), device="cpu")
    assert loaded.mode_input == mode_input
    loaded.learn(64)  # the mask is set up again on loading
    assert th.count_nonzero(first_layers(loaded.policy)[blind].weight[:, -N_MODES:]) == 0


def test_mode_input_rejects_an_unknown_network():
    with pytest.raises(ValueError, match="mode_input"):
        OraclePPO("MlpPolicy", make_vec_env(1, seed=0, env_kwargs=SMALL), mode_input="critic")


def test_random_labels_are_one_per_copy_and_episode_independent_of_the_mode_and_seeded():
    def labels_per_episode(seed):
        venv = ModeObservationWrapper(make_vec_env(3, seed=0, env_kwargs=SMALL), random_labels=True)
        venv.seed(seed)
        obs = venv.reset()
        per_copy = venv.per_copy
        rows, current = [], None
        for _ in range(500):  # 100 episodes of 5 steps in each of the 3 copies
            label = obs[:, -N_MODES:].argmax(axis=1)
            assert (obs[:, -N_MODES:].sum(axis=1) == 1).all()
            assert (label.reshape(3, per_copy) == label[::per_copy, None]).all()  # shared by a copy's UAVs
            if current is not None:
                assert (label == current).all()  # constant over an episode
            current = label
            modes = true_modes(venv)
            obs, _, dones, infos = venv.step(np.zeros(venv.num_envs, dtype=int))
            for i in np.flatnonzero(dones):  # the finished episode's label on its terminal observation
                assert infos[i]["terminal_observation"][-N_MODES:].argmax() == current[i]
            if dones.any():
                rows += list(zip(current[::per_copy], modes[::per_copy]))
                current = None
        return np.array(rows)

    rows = labels_per_episode(7)
    np.testing.assert_array_equal(rows[:, 0], labels_per_episode(7)[:, 0])  # the same seed, the same labels
    assert not np.array_equal(rows[:, 0], labels_per_episode(8)[:, 0])
    assert len(rows) == 300
    # uniform over the modes' labels and independent of the mode: the chi-square tests on 300 episodes
    from scipy.stats import chi2_contingency, chisquare

    assert chisquare(np.bincount(rows[:, 0], minlength=N_MODES)).pvalue > 1e-3
    table = np.zeros((N_MODES, N_MODES))
    np.add.at(table, (rows[:, 0], rows[:, 1]), 1)
    assert chi2_contingency(table + 0.5).pvalue > 1e-3
    assert np.mean(rows[:, 0] == rows[:, 1]) < 0.3  # a true one-hot would agree every time


def test_random_labels_reject_bad_values_and_relabel_beside_them():
    with pytest.raises(ValueError, match="random_labels must be true or false, got 'yes'"):
        ModeObservationWrapper(make_vec_env(1, seed=0, env_kwargs=SMALL), random_labels="yes")
    with pytest.raises(ValueError, match="not both"):
        ModeObservationWrapper(make_vec_env(1, seed=0, env_kwargs=SMALL), relabel=list(range(N_MODES)),
                               random_labels=True)
    with pytest.raises(ValueError, match="random_label"):
        OraclePPO("MlpPolicy", make_vec_env(1, seed=0, env_kwargs=SMALL), random_label=1)


def test_oracle_ppo_with_a_random_label_keeps_it_through_saving_loading_and_evaluation(tmp_path):
    from sb3_emmarl.common.appended.wrapping import find_wrapper
    from sb3_emmarl.common.evaluation import evaluate_team
    from sb3_emmarl.common.mode_aware import ModeObservationWrapper

    model = OraclePPO("MlpPolicy", make_vec_env(2, seed=0, env_kwargs=SMALL), n_steps=16, batch_size=32, seed=0,
                      random_label=True)
    assert find_wrapper(model.get_env(), ModeObservationWrapper).random_labels
    model.learn(64)
    model.save(tmp_path / "control")
    loaded = OraclePPO.load(tmp_path / "control", env=make_vec_env(1, seed=1, env_kwargs=SMALL), device="cpu")
    assert loaded.random_label and find_wrapper(loaded.get_env(), ModeObservationWrapper).random_labels
    assert find_wrapper(loaded.wrap_env(make_vec_env(1, seed=1, env_kwargs=SMALL)), ModeObservationWrapper).random_labels
    told = OraclePPO.load(tmp_path / "control", device="cpu")
    told.random_label = False  # the same networks, told the true mode: the wrapper follows the model's setting
    assert not find_wrapper(told.wrap_env(make_vec_env(1, seed=1, env_kwargs=SMALL)), ModeObservationWrapper).random_labels
    records = evaluate_team(loaded, 3, seed=5, env_kwargs=SMALL)
    assert len(records) == 3 and all(np.isfinite(r["team_reward"]) for r in records)


def test_wrap_with_mode_refuses_an_environment_wrapped_to_tell_the_other_thing():
    told = wrap_with_mode(make_vec_env(1, seed=0, env_kwargs=SMALL))
    with pytest.raises(ValueError, match="already wrapped to tell the mode, but random_labels=True"):
        wrap_with_mode(told, random_labels=True)
    with pytest.raises(ValueError, match="already wrapped to tell the mode"):
        OraclePPO("MlpPolicy", told, random_label=True)
    control = wrap_with_mode(make_vec_env(1, seed=0, env_kwargs=SMALL), random_labels=True)
    assert wrap_with_mode(control, random_labels=True) is control
    with pytest.raises(ValueError, match="already wrapped to tell a random label per episode, but random_labels=False"):
        OraclePPO("MlpPolicy", control)


def test_the_0_1_0_repeat_counts_the_issue_s_protocol_on_hand_built_runs():
    repeat = load_study("mode_value_0_1_0")
    ppo = {s: np.zeros(40) for s in range(4)}
    told = {s: np.r_[np.full(20, 10.0), np.zeros(20)] for s in range(3)}  # 10 higher on the first 20 episodes
    told[3] = np.full(40, -1.0)
    # 4 sets of 3 seeds x 2 blocks of 20: only seeds 0, 1, 2 on the first block are higher on every seed.
    assert repeat.protocol_draws(told, ppo) == (1, 8)
    assert repeat.protocol_draws(told, ppo, gain=10.5) == (0, 8)
    assert repeat.protocol_draws(told, ppo, n_seeds=2, block=40) == (0, 6)  # 5 higher on average: below 7


def test_the_0_1_0_repeat_reports_every_table_and_refuses_runs_that_do_not_pair(tmp_path, capsys):
    repeat = load_study("mode_value_0_1_0")

    def episodes(reward):
        return [{m: reward + e % 2 for m in repeat.METRICS} for e in range(repeat.ISSUE_EPISODES)]

    def write(variant, seed, reward, n_timesteps=500_000):
        data = {"variant": variant, "seed": seed, "n_timesteps": n_timesteps, "records": episodes(reward)}
        if variant == "told":
            data["next_strategy_records"] = episodes(reward - 1.0 - seed**2)
        (tmp_path / f"{variant}_{seed}.json").write_text(json.dumps(data))

    for seed in range(3):
        write("told", seed, 10.0 + seed)
        write("ppo", seed, 1.0)
        write("control", seed, 2.0 + seed**2)
    repeat.main(["report", "--folder", str(tmp_path)])
    out = capsys.readouterr().out
    for title in ("PPO told the mode or not", "Told the mode or a random label", "A random label or nothing",
                  "the true mode or the next strategy", "The issue's protocol"):
        assert title in out
    assert "in 1 of 1 draws (100.0%)" in out and "median 10.000" in out and "3 seeds x 500,000 agent-steps" in out
    write("control", 2, 6.0, n_timesteps=2048)
    with pytest.raises(SystemExit, match=r"runs of different budgets \[2048, 500000\]"):
        repeat.main(["report", "--folder", str(tmp_path)])
    write("ppo", 3, 1.0)
    with pytest.raises(SystemExit, match=r"same seeds; has told: \[0, 1, 2\], ppo: \[0, 1, 2, 3\]"):
        repeat.main(["report", "--folder", str(tmp_path)])


def test_the_0_1_0_repeat_trains_only_on_0_1_0(tmp_path):
    import re

    from sb3_emmarl.version import __version__

    with pytest.raises(SystemExit, match=rf"run needs sb3-emmarl 0.1.0 on the path .* got {re.escape(__version__)} "):
        load_study("mode_value_0_1_0").main(["run", "--variant", "told", "--seed", "0", "--folder", str(tmp_path)])
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("algo", ["oracle", "message"])
def test_predict_on_plain_observations_names_wrap_env(algo):
    from sb3_emmarl import MessagePPO, OraclePPO
    from sb3_emmarl.common.vec_env import make_vec_env

    kwargs = {"n_uavs": 2, "grid_size": 20, "max_cycles": 10}
    env = make_vec_env(1, seed=0, env_kwargs=kwargs)
    model = (OraclePPO if algo == "oracle" else MessagePPO)("MlpPolicy", env, n_steps=16, batch_size=16)
    plain = make_vec_env(1, seed=1, env_kwargs=kwargs)
    with pytest.raises(ValueError, match=r"evaluate it on model.wrap_env\(env\)"):
        model.predict(plain.reset())
    wrapped = model.wrap_env(make_vec_env(1, seed=1, env_kwargs=kwargs))
    actions, _ = model.predict(wrapped.reset())
    assert actions.shape == (2,)
