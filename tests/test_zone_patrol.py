"""ZonePatrol: PettingZoo's API, seeding and rendering tests, its mechanics on hand-built cases, bad arguments, and
the scripted teams' gate."""

import json
from pathlib import Path

import numpy as np
import pytest
from pettingzoo.test import api_test, max_cycles_test, parallel_api_test, parallel_seed_test, render_test, seed_test
from scripts import load_benchmark

from wildlife_reserve import zone_patrol_v0
from wildlife_reserve.zone_patrol.scripted import BlindTeam, ToldTeam, play, posts
from wildlife_reserve.zone_patrol.world import NARROW, WIDE, ZonePatrolConfig, ZonePatrolWorld

CONFIGS = [{}, {"n_uavs": 1}, {"n_uavs": 6, "grid_size": 12, "zone_size": 3, "max_cycles": 20},
           {"told": True, "window_radius": 1}, {"initial_tracks": 0, "spawn_prob": 1.0, "intruder_life": 1},
           {"agent_ids": True, "told": True, "n_uavs": 3}, {"zone_cue": 0.2, "agent_ids": True}]


@pytest.mark.parametrize("kwargs", CONFIGS)
def test_pettingzoo_s_api_and_seed_tests_pass(kwargs):
    parallel_api_test(zone_patrol_v0.parallel_env(**kwargs), num_cycles=70)
    api_test(zone_patrol_v0.env(**kwargs), num_cycles=70)
    seed_test(lambda: zone_patrol_v0.env(**kwargs), num_cycles=70)
    parallel_seed_test(lambda: zone_patrol_v0.parallel_env(**kwargs), num_cycles=70)


def test_render_and_max_cycles_tests_pass(monkeypatch):
    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")
    render_test(zone_patrol_v0.env)
    max_cycles_test(zone_patrol_v0)


def test_the_same_seed_plays_the_same_episode_and_the_infos_carry_the_mode_and_links():
    def episode(seed):
        env = zone_patrol_v0.parallel_env()
        obs, infos = env.reset(seed=seed)
        trace, rng = [obs["uav_0"]], np.random.default_rng(0)
        while env.agents:
            obs, rewards, _, _, infos = env.step({a: int(rng.integers(10)) for a in env.agents})
            trace += [obs["uav_0"], np.array([rewards["uav_0"]])]
        return np.concatenate(trace), infos

    (a, infos), (b, _), (c, _) = episode(7), episode(7), episode(8)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    info = infos["uav_0"]
    assert 0 <= info["mode"] < 8 and all(0 <= j < 4 and j != 0 for j in info["heard_from"])
    assert info["metrics"]["mode"] == info["mode"]
    assert info["metrics"]["detections"] - 0.25 * info["metrics"]["escapes"] == pytest.approx(info["metrics"]["team_reward"])


def test_a_mode_can_be_fixed_and_told_observations_end_with_its_one_hot():
    env = zone_patrol_v0.parallel_env(told=True)
    obs, infos = env.reset(seed=0, options={"mode": 5})
    assert infos["uav_2"]["mode"] == 5 and env.mode == 5
    assert obs["uav_2"].shape == (87,) and obs["uav_2"][-8:].argmax() == 5
    assert env.state().shape == env.state_space.shape == (2 * 4 + 2 * 28 * 28 + 1,)


def test_agent_ids_append_each_uav_s_index_as_a_one_hot_before_the_told_mode():
    env = zone_patrol_v0.parallel_env(agent_ids=True, told=True, n_uavs=3)
    obs, _ = env.reset(seed=0, options={"mode": 6})
    plain = zone_patrol_v0.parallel_env(n_uavs=3).reset(seed=0, options={"mode": 6})[0]
    for i, agent in enumerate(env.agents):
        assert obs[agent].shape == env.observation_space(agent).shape == (79 + 3 + 8,)
        np.testing.assert_array_equal(obs[agent][:79], plain[agent])
        np.testing.assert_array_equal(obs[agent][79:82], np.eye(3)[i])
        assert obs[agent][-8:].argmax() == 6 and obs[agent][-8:].sum() == 1


def test_zone_readings_carry_the_mode_s_zone_under_noise_and_a_blind_team_reads_them():
    config = ZonePatrolConfig(zone_cue=1.0, agent_ids=True)
    world, rng = ZonePatrolWorld(config, 200), np.random.default_rng(0)
    world.reset(rng)
    obs = world.observations()
    assert obs.shape == (200, 4, 79 + 4 + 4) and config.obs_dim == 87
    readings = []
    for _ in range(20):
        world.step(rng.integers(10, size=(200, 4)), rng)
        readings.append(world.observations()[..., 79:83])
    readings = np.stack(readings)  # (steps, copies, uavs, 4), clipped to [-4, 4] over 4
    mine = np.arange(4)[None, :] == world.zones[:, None]  # (copies, 4)
    assert readings.mean((0, 2))[mine].mean() == pytest.approx(0.25, abs=0.02)
    assert readings.mean((0, 2))[~mine].mean() == pytest.approx(0.0, abs=0.02)
    np.testing.assert_array_equal(obs[..., 83:], np.broadcast_to(np.eye(4), (200, 4, 4)))  # the ids follow
    team = BlindTeam("together", "estimate", confidence=0.9)
    world.reset(rng)
    team.reset(world)
    for _ in range(10):
        world.step(team.act(world), rng)
    assert (team.zone_posterior(world).argmax(1) == world.zones).mean() > 0.95
    uniform = BlindTeam()
    uniform.reset(ZonePatrolWorld(ZonePatrolConfig(), 2))
    np.testing.assert_array_equal(uniform.zone_posterior(ZonePatrolWorld(ZonePatrolConfig(), 2)), np.full((2, 4), 0.25))
    with pytest.raises(ValueError, match="confidence must be in"):
        BlindTeam(confidence=1.0)


@pytest.mark.parametrize("kwargs, message", [
    ({"grid_size": 3}, r"grid_size must be in \[6, 256\], got 3$"), ({"n_uavs": 2.0}, "n_uavs must be an int in"),
    ({"spawn_prob": 1.5}, r"spawn_prob must be in \[0.0, 1.0\]"), ({"wide_detect": (0.5,)}, "wide_detect must be a pair"),
    ({"narrow_detect": (0.2, float("nan"))}, r"narrow_detect\[1\] must be a finite number"),
    ({"zone_size": 20}, r"zone_size must be in \[1, 14\], got 20"), ({"told": 1}, r"told must be a bool \(True or False\)"),
    ({"agent_ids": "yes"}, "agent_ids must be a bool"), ({"zone_cue": "0.2"}, "zone_cue must be a finite number in"),
    ({"n_uavs": True}, r"n_uavs must be an int in \[1, 64\], got True \(bool\)"),
    ({"speed": 3}, r"unknown ZonePatrol argument\(s\) \['speed'\]"), ({"render_mode": "ansi"}, "render_mode must be"),
])
def test_bad_arguments_raise_a_value_error_naming_them(kwargs, message):
    with pytest.raises(ValueError, match=message):
        zone_patrol_v0.parallel_env(**kwargs)


def test_bad_actions_options_and_calls_out_of_order_are_refused():
    env = zone_patrol_v0.parallel_env()
    with pytest.raises(RuntimeError, match="reset"):
        env.step({})
    with pytest.raises(RuntimeError, match="reset"):
        env.state()
    with pytest.raises(ValueError, match=r"options\['mode'\] must be in \[0, 7\], got 8"):
        env.reset(options={"mode": 8})
    with pytest.raises(ValueError, match=r"options\['mode'\] must be an int in \[0, 7\], got 2.0 \(float\)"):
        env.reset(options={"mode": 2.0})
    env.reset(seed=0)
    for bad in (10, -1, 2.5, "3", True):
        with pytest.raises(ValueError, match=r"action of uav_0 must be an int in \[0, 9\]"):
            env.step({"uav_0": bad})
    env.step({"uav_0": np.int64(3)})  # numpy integers are actions


def world_with_one_intruder(weather, sensor_reach_gap, **kwargs):
    config = ZonePatrolConfig(initial_tracks=0, spawn_prob=0.0, intruder_move_prob=0.0, n_uavs=1, **kwargs)
    world = ZonePatrolWorld(config, 1)
    world.reset(np.random.default_rng(0), np.array([weather]))  # zone 0
    world.alive[0, 0], world.intruders[0, 0], world.ages[0, 0] = True, (2, 2), 0
    world.positions[0, 0] = (2, 2 + sensor_reach_gap)
    return world


@pytest.mark.parametrize("weather, sensor, gap, caught", [(0, WIDE, 2, True), (0, WIDE, 3, False), (1, WIDE, 2, False),
                                                         (1, NARROW, 1, True), (0, NARROW, 2, False)])
def test_each_sensor_detects_within_its_reach_with_its_weather_s_chance(weather, sensor, gap, caught):
    world = world_with_one_intruder(weather, gap, wide_detect=(1.0, 0.0), narrow_detect=(1.0, 1.0))
    reward = world.step(np.array([[5 * sensor]]), np.random.default_rng(1))  # stay, with the sensor
    assert (reward[0] == 1.0) == caught and world.caught[0] == int(caught)
    if caught:
        assert world.observations()[0, 0, 25:50].sum() == 1.0  # the detection in this UAV's window


def test_an_undetected_intruder_escapes_at_the_end_of_its_life_and_its_track_fades():
    world = world_with_one_intruder(0, 10, intruder_life=2, track_life=3)
    rng = np.random.default_rng(0)
    assert world.step(np.array([[0]]), rng)[0] == 0.0
    assert world.tracks[0, 2, 2] == 3
    assert world.step(np.array([[0]]), rng)[0] == -0.25 and world.escaped[0] == 1
    assert world.tracks[0, 2, 2] == 2  # no new track once it has gone
    for remaining in (1, 0, 0):
        world.step(np.array([[0]]), rng)
        assert world.tracks[0, 2, 2] == remaining


def test_posts_tile_each_zone_with_the_narrow_reach():
    world = ZonePatrolWorld(ZonePatrolConfig(), 1)
    cells = posts(world)  # (4 zones, 4 UAVs, 2)
    origins = world.config.zone_origins()
    for zone in range(4):
        covered = np.zeros((6, 6), dtype=bool)
        for row, col in cells[zone] - origins[zone]:
            covered[max(row - 1, 0):row + 2, max(col - 1, 0):col + 2] = True
        assert covered.all()


def test_the_told_team_beats_the_best_blind_team_and_a_blind_team_finds_the_zone():
    config = ZonePatrolConfig()
    told = play(ToldTeam(), ZonePatrolWorld(config, 64), np.random.default_rng(0))
    blind = play(BlindTeam("split", "estimate"), ZonePatrolWorld(config, 64), np.random.default_rng(0))
    assert told.mean() > 1.3 * blind.mean() > 0
    with pytest.raises(ValueError, match="search must be one of"):
        BlindTeam("circle")


def test_the_gate_benchmark_prints_the_comparison_at_a_small_size(capsys):
    assert load_benchmark("zone_patrol_gate").main(["--fit", "8", "--episodes", "16", "--no-speed"]) == 0
    text = capsys.readouterr().out
    assert "the best blind plan on the fitting episodes" in text and "paired t p =" in text and "7 (3, fog)" in text


@pytest.mark.parametrize("version, expected", [
    (0, "806e273477ab14ea68724e66a49a47d46c6d929b0671ba87e29c7346296f1a60"),  # as pinned before v1 existed
    (1, "aa42bbb2271fd170b6a637657158ab1ca2b65424d43c40e673c5c473dd60b3fe")])
def test_episodes_are_pinned_by_a_digest(version, expected):
    """Rewards, observations, states and links of three configurations over whole episodes, with each version's
    defaults: a change that moves any of them changes an episode, and the environment's version must rise."""
    import hashlib

    from wildlife_reserve.zone_patrol.zone_patrol import FORMER_DEFAULTS

    digest = hashlib.sha256()
    for kwargs in ({}, {"told": True, "n_uavs": 6, "grid_size": 12, "zone_size": 3},
                   {"window_radius": 1, "spawn_prob": 1.0, "intruder_life": 1}):
        config = ZonePatrolConfig(**{**FORMER_DEFAULTS.get(version, {}), **kwargs})
        world, rng, actions = ZonePatrolWorld(config, 5), np.random.default_rng(3), np.random.default_rng(4)
        world.reset(rng)
        for _ in range(config.max_cycles):
            rewards = world.step(actions.integers(10, size=(5, config.n_uavs)), rng)
            links = np.array([sum(map(len, row)) for row in world.links()])
            for array in (rewards, world.observations(), world.states(), links):
                digest.update(np.ascontiguousarray(array).tobytes())
    assert digest.hexdigest() == expected


def test_the_batched_and_supersuit_vector_environments_give_the_same_data():
    from sb3_emmarl.common.vec_env import make_vec_env

    traces = {}
    for kind in ("batched", "supersuit"):
        venv = make_vec_env(2, seed=4, env_fn=zone_patrol_v0.parallel_env, vec_env_type=kind, with_state=True,
                            env_kwargs={"max_cycles": 20})
        rng, trace = np.random.default_rng(0), [venv.reset()]
        for _ in range(45):
            obs, rewards, dones, infos = venv.step(rng.integers(10, size=venv.num_envs))
            trace += [obs, rewards, dones.astype(float), infos[1]["state"], np.array((*infos[1]["heard_from"], -1))]
            if dones.any():
                trace += [infos[0]["terminal_observation"], np.array([infos[0]["metrics"]["team_reward"]])]
        traces[kind] = trace
        venv.close()
    assert len(traces["batched"]) == len(traces["supersuit"])
    for a, b in zip(traces["batched"], traces["supersuit"]):
        np.testing.assert_array_equal(a, b)


def test_step_arrays_refuses_what_step_refuses():
    env = zone_patrol_v0.parallel_env()
    env.reset(seed=0)
    for bad in (np.array([0, 1, 2]), np.array([0, 1, 2, 10]), np.array([0.0, 1.0, 2.0, 3.0])):
        with pytest.raises(ValueError, match=r"actions must be 4 ints in \[0, 9\]"):
            env.step_arrays(bad)
    obs, rewards, _, _, info, heard = env.step_arrays(np.array([0, 1, 2, 3]))
    assert obs.shape == (4, env.obs_dim) and rewards.shape == (4,) and info["mode"] == env.mode and len(heard) == 4


def test_the_value_benchmark_trains_evaluates_and_reports_every_variant(tmp_path, capsys):
    bench = load_benchmark("zone_patrol_value")
    assert bench.main(["run", "--seeds", "0", "1", "-n", "4096", "--eval-episodes", "8", "--n-jobs", "1",
                       "--folder", str(tmp_path)]) == 0
    runs = [json.loads(p.read_text()) for p in sorted(tmp_path.glob("*.json"))]
    assert sorted((r["variant"], r["seed"]) for r in runs) == sorted(
        (v, s) for v in bench.DEFAULT_VARIANTS for s in (0, 1))
    told = next(r for r in runs if r["variant"] == "told")
    assert all(len(told[key]) == 8 for key in ("team_reward", "wrong_zone_1", "wrong_zone_2", "wrong_zone_3",
                                                 "wrong_weather"))
    em = next(r for r in runs if r["variant"] == "em_ppo")
    assert 0.0 <= em["belief_accuracy"] <= 1.0 and len(em["permuted"]) == 8 and em["swap_kl"] >= 0.0
    assert 0.0 <= em["belief_zone_accuracy"] <= 1.0 and 0.0 <= em["exact_team_zone_accuracy"] <= 1.0
    assert len(told["belief_executed"]) == 8
    assert 0 < sum(told["phase_seconds"].values()) <= told["seconds"] and told["load"]["start"]["cores"] >= 1
    assert not list(tmp_path.glob("*.partial")) and told["resumed_at"] == [] and told["evaluation_seconds"] > 0
    # mode 5 = zone 2, fog: the wrong zones 3, 0, 1 in fog, the wrong weather zone 2 clear
    assert [bench.WRONG[f"wrong_zone_{k}"][5] for k in (1, 2, 3)] == [7, 1, 3] and bench.WRONG["wrong_weather"][5] == 4
    assert bench.main(["report", "--folder", str(tmp_path)]) == 0
    text = capsys.readouterr().out
    assert "told -" in text and "random team" in text and "collapsed runs" in text and "null calibration" in text
    assert "(em_ppo - ppo) / (told - ppo)" in text and "em_ppo, belief permuted" in text
    assert "em_ppo - em_ppo permuted = " in text and "the exact posterior of the whole team's readings" in text
    assert "(told, acting on the exact belief along the links - ppo) / (told - ppo)" in text
    assert "settings: em_ppo (em_ppo): n_envs 8, n_steps 128, batch_size 1024" in text  # PROTOCOL item 10
    with pytest.raises(SystemExit, match="no runs in"):
        bench.main(["report", "--folder", str(tmp_path / "empty")])
    with pytest.raises(SystemExit, match=r"the same runs twice \(variant, seed\): \[\('control', 0\)"):
        bench.main(["report", "--folder", str(tmp_path), str(tmp_path)])  # (a protocol and its confirmation: together)
    assert all(r["env_kwargs"] == {} for r in runs)
    cue = {**runs[0], "env_kwargs": {"zone_cue": 0.2}}
    assert bench.heading([cue]).startswith('ZonePatrol {"zone_cue": 0.2}, 4,096 agent-steps per run')
    with pytest.raises(SystemExit, match="runs of different ZonePatrol arguments"):
        bench.heading([runs[0], cue])
    with pytest.raises(SystemExit):  # argparse: the argument named, before anything runs
        bench.main(["run", "--folder", str(tmp_path / "bad"), "--env-kwargs", '{"zone_cue": -1}'])
    assert "zone_cue must be" in capsys.readouterr().err and not (tmp_path / "bad").exists()


def test_a_protocol_killed_mid_run_continues_where_it_was_with_the_same_digits(tmp_path, capsys):
    """SIGKILL at a random moment after a checkpoint: the run goes on from its newest checkpoint (the reserves
    mid-episode, EM-PPO's belief and E-step, the random generators) and its record is the uninterrupted run's."""
    import random
    import signal
    import subprocess
    import sys
    import time

    bench = load_benchmark("zone_patrol_value")
    flags = ["--variants", "em_ppo", "--seeds", "0", "-n", "12288", "--checkpoint-every", "4096", "--eval-episodes",
             "2", "--n-jobs", "1"]
    assert bench.main(["run", *flags, "--folder", str(tmp_path / "whole")]) == 0
    killed = tmp_path / "killed"
    process = subprocess.Popen([sys.executable, str(Path(bench.__file__)), "run", *flags, "--folder", str(killed)],
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 240
    while not list(killed.glob("*.partial/run_*_steps.zip")) and process.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(random.Random(0).uniform(0.0, 1.0))
    process.send_signal(signal.SIGKILL)
    process.wait()
    assert not (killed / "em_ppo_0.json").exists(), "the run ended before it was killed: kill it sooner"
    steps = sorted(int(p.name.split("_")[1]) for p in killed.glob("em_ppo_0.partial/run_*_steps.zip"))
    assert steps and steps[-1] < 12288
    capsys.readouterr()
    assert bench.main(["run", *flags, "--folder", str(killed)]) == 0
    assert "1 of 1 runs to do" in capsys.readouterr().out
    whole, resumed = (json.loads((tmp_path / name / "em_ppo_0.json").read_text()) for name in ("whole", "killed"))
    assert resumed["resumed_at"] == steps[-1:] and whole["resumed_at"] == []
    timing = ("seconds", "phase_seconds", "load", "evaluation_seconds", "resumed_at")
    assert {k: v for k, v in resumed.items() if k not in timing} == {k: v for k, v in whole.items() if k not in timing}
    assert not list(killed.glob("*.partial"))
    with pytest.raises(SystemExit):
        bench.main(["run", "--folder", str(tmp_path / "bad"), "--checkpoint-every", "0"])
    assert "--checkpoint-every must be >= 1 (got 1000000, 2, 0)" in capsys.readouterr().err


def test_the_told_conditionings_keep_the_yaml_s_policy_arguments_and_are_scored_as_told():
    bench = load_benchmark("zone_patrol_value")
    algo, overrides = bench.variant_overrides("told_film")
    assert algo == "oracle_ppo" and overrides["policy_kwargs"] == {"net_arch": [128, 128], "belief_conditioning": "film"}
    assert "'belief_conditioning': 'film'" in bench.settings("told_film") and "told_mixture" in bench.TOLD_VARIANTS
    model = bench.build("told_mixture", 0, {"max_cycles": 4})
    assert model.policy.belief_conditioning == "mixture" and model.policy.mlp_extractor.policy_net.head_inputs == 128
    model.env.close()


def test_runs_say_how_they_read_the_mode_and_runs_that_differ_are_not_pooled():
    bench = load_benchmark("zone_patrol_value")
    old = {"variant": "em_ppo", "seed": 0, "budget": 4096, "task": "zone_patrol", "env_kwargs": {}}  # (0.22.0's record)
    assert bench.conditioning_of(old) == "concat"
    assert bench.conditioning_of({**old, "variant": "em_ppo_mixture"}) == "mixture"
    assert bench.conditioning_of({**old, "belief_conditioning": "mixture"}) == "mixture"
    assert "'belief_conditioning': 'concat'" in bench.settings("em_ppo", conditioning="concat")
    with pytest.raises(SystemExit, match=r"the em_ppo runs read the mode or the belief in different ways \['concat', "
                                         r"'mixture'\]"):
        bench.report([old, {**old, "seed": 1, "belief_conditioning": "mixture"}])


def test_the_protocols_bar_and_its_null_calibration():
    bench = load_benchmark("zone_patrol_value")
    rng = np.random.default_rng(0)
    base = rng.normal(0.0, 1.0, 10)
    assert bench.passes_bar(base + 1.0 + rng.normal(0, 0.1, 10), base)  # higher on every seed, far beyond the noise
    assert not bench.passes_bar(base, base) and not bench.passes_bar(base - 1.0, base)
    lucky = base + np.r_[np.full(7, 0.5), np.full(3, -0.01)]  # significant but higher on 7 of 10 seeds only
    assert not bench.passes_bar(lucky, base)
    noise = {s: list(rng.normal(0.0, 1.0, 50)) for s in range(10)}
    other = {s: list(rng.normal(0.0, 1.0, 50)) for s in range(10)}
    observed, rate = bench.null_calibration(noise, other, draws=300)
    assert not observed and rate < 0.05  # a label that carries nothing rarely passes
    shifted = {s: [x + 2.0 for x in values] for s, values in noise.items()}
    assert bench.null_calibration(shifted, other, draws=50)[0]  # a real gain passes on the runs themselves


def test_the_exact_belief_is_the_posterior_of_the_readings_that_reached_each_uav():
    from scipy.special import softmax

    from wildlife_reserve.zone_patrol.posterior import reading_log_likelihoods

    bench = load_benchmark("zone_patrol_value")
    venv = bench.ExactBelief(bench.make_env(3, n_copies=2, env_kwargs={"max_cycles": 4}))
    config = venv.get_attr("config", [0])[0]
    obs = venv.reset()
    evidence = reading_log_likelihoods(config, obs)
    np.testing.assert_allclose(obs[:, -8:], softmax(evidence, axis=1), atol=1e-5)  # before any message: its own
    for _ in range(4):
        obs, _, dones, infos = venv.step(np.zeros(venv.num_envs, dtype=np.int64))
        seen = np.stack([info["terminal_observation"] for info in infos]) if dones.all() else obs
        heard = np.repeat(evidence.reshape(2, 4, 8).sum(1), 4, axis=0) - evidence  # the teammates' versions so far
        evidence += reading_log_likelihoods(config, seen)
        if not dones.all():  # the team starts together, within half the grid: every teammate's newest evidence arrives
            heard = np.repeat(evidence.reshape(2, 4, 8).sum(1), 4, axis=0) - evidence
        # (at an episode's end the vector environment moves the last step's links to "terminal_heard_from": the
        # terminal belief holds the teammates' versions of the step before, as EM-PPO's does)
        np.testing.assert_allclose(seen[:, -8:], softmax(evidence + heard, axis=1), atol=1e-5)
    assert dones.all() and seen.shape == (8, config.obs_dim + 8)  # the terminal observations carry the last belief
    np.testing.assert_allclose(obs[:, -8:], softmax(reading_log_likelihoods(config, obs), axis=1), atol=1e-5)  # anew
    venv.close()


def test_the_reach_benchmark_prints_reach_and_posteriors(capsys):
    bench = load_benchmark("zone_patrol_reach")
    assert bench.main(["--teams", "random", "split", "--ranges", "0", "28", "--episodes", "20", "--steps", "10"]) == 0
    rows = [line.split() for line in capsys.readouterr().out.splitlines()[2:]]
    reach = {(team, int(r)): float(value) for team, r, _, value, *_ in rows}
    assert 0.25 <= reach[("random", 0)] < 0.5 and reach[("random", 28)] == pytest.approx(1.0)  # (0: same cell only)
    for *_, one, links, whole in rows:  # the links pool between one UAV's and the whole team's
        assert float(one) <= float(links) + 1e-9 and float(links) <= float(whole) + 0.05
    with pytest.raises(SystemExit):
        bench.main(["--episodes", "0"])
