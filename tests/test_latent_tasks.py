"""The hidden-mode tasks, and EM-PPO with default arguments on them (identifies the mode and acts on it).

The training case trains three models (minutes on two cores): marked ``expensive`` and left out of ``make test``;
``python -m pytest -m expensive tests/test_latent_tasks.py`` or ``make benchmark-latent-tasks`` (10 seeds) run it.
"""

import json

import numpy as np
import pytest
from scripts import load_benchmark

from sb3_emmarl.common.mode_tasks import ModeCorridorEnv, ModeCueEnv, ModeDynamicsEnv, ModeGoalEnv, ModeReachEnv


@pytest.mark.expensive
@pytest.mark.parametrize("task", ["cue", "dynamics", "reach", "goal", "corridor"])
def test_em_ppo_defaults_reach_the_mode_and_most_of_the_told_return(task):
    bench = load_benchmark("latent_tasks")
    em = bench.run(task, "em_ppo", 0, bench.BUDGETS[task], eval_episodes=50)["curve"][-1]
    told = bench.run(task, "told_ppo", 0, bench.BUDGETS[task], eval_episodes=50)["curve"][-1]
    assert em["latent_accuracy"] >= 0.8
    assert em["return"] >= 0.85 * told["return"]
    assert em["permuted_return"] < em["return"]


@pytest.mark.parametrize("env_class", [ModeCueEnv, ModeDynamicsEnv, ModeReachEnv, ModeGoalEnv, ModeCorridorEnv])
@pytest.mark.parametrize("told", [False, True])
def test_the_tasks_follow_gymnasium_s_api_and_hide_the_mode_unless_told(env_class, told):
    from gymnasium.utils.env_checker import check_env

    env = env_class(told=told)
    check_env(env, skip_render_check=True)
    obs, info = env.reset(seed=3)
    assert obs.shape == env.observation_space.shape and info["mode"] == env.mode
    if told:
        assert obs[-env.n_modes:].argmax() == env.mode


def test_the_cue_task_pays_the_mode_and_its_cue_is_right_as_often_as_stated():
    env = ModeCueEnv(cue_accuracy=0.4)
    right, steps = 0, 0
    for seed in range(50):
        obs, info = env.reset(seed=seed)
        for _ in range(env.length):
            right += int(obs.argmax() == info["mode"])
            obs, reward, _, _, info = env.step(info["mode"])
            assert reward == 1.0
            steps += 1
    assert abs(right / steps - (0.4 + 0.6 / 4)) < 0.03


def test_the_dynamics_task_moves_by_the_mode_s_rotation():
    env = ModeDynamicsEnv(noise=0.0)
    for seed in range(8):
        env.reset(seed=seed)
        env.position = [0.0, 0.0]
        obs, *_ = env.step(0)
        assert obs.tolist() == pytest.approx((ModeDynamicsEnv.DIRECTIONS[env.mode] * 0.15).tolist())
    with pytest.raises(ValueError, match="need step > 0"):
        ModeDynamicsEnv(step=0)
    with pytest.raises(ValueError, match="cue_accuracy must be in"):
        ModeCueEnv(cue_accuracy=1.5)


def test_the_reach_task_pays_progress_and_ends_on_arrival():
    env = ModeReachEnv(noise=0.0)
    env.reset(seed=1)
    env.position = np.array([0.0, 0.45])
    for _ in range(4):  # one step of 0.15 towards the origin is action (3 - mode) % 4 (down)
        _, reward, terminated, truncated, _ = env.step((3 - info_mode(env)) % 4)
        if terminated:
            break
    assert terminated and not truncated
    assert reward == pytest.approx(0.15 + 1.0)  # the last step's progress, and the arrival
    env.reset(seed=2)
    start = np.linalg.norm(env.position)
    assert start >= 2 * env.radius
    _, reward, terminated, _, _ = env.step((1 - info_mode(env)) % 4)  # up: away from or along
    assert reward == pytest.approx(start - np.linalg.norm(env.position)) and not terminated
    with pytest.raises(ValueError, match="radius must be in"):
        ModeReachEnv(radius=0.7)


def test_the_corridor_moves_by_the_mode_s_action_and_ends_on_success():
    env = ModeCorridorEnv(cells=3, length=5, step_cost=0.2)
    obs, info = env.reset(seed=4)
    mode = info["mode"]
    assert obs.tolist() == pytest.approx([1 / 3])
    obs, reward, terminated, truncated, info = env.step((mode + 1) % 4)  # stays
    assert obs.tolist() == pytest.approx([1 / 3]) and reward == pytest.approx(-0.2) and "success" not in info
    obs, *_ = env.step((mode + 2) % 4)  # back
    obs, *_ = env.step((mode + 2) % 4)  # back, not below cell 0
    assert obs.tolist() == [0.0]
    for _ in range(2):
        obs, reward, terminated, truncated, info = env.step(mode)
    assert not terminated and truncated and info["success"] is False  # 5 steps used, at cell 2 of 3
    env.reset(seed=4)
    env.step(mode)
    obs, reward, terminated, truncated, info = env.step(mode)
    assert terminated and not truncated and info["success"] and reward == pytest.approx(1 - 0.2)
    with pytest.raises(ValueError, match="cells must be an int >= 2"):
        ModeCorridorEnv(cells=1)
    with pytest.raises(ValueError, match=r"length must be at least cells \(7\)"):
        ModeCorridorEnv(length=5)
    with pytest.raises(ValueError, match=r"step_cost must be in \[0, 1 / length = 0.03333\], got 0.5"):
        ModeCorridorEnv(step_cost=0.5)


def test_the_corridor_s_best_blind_player_earns_its_stated_ceiling():
    """The player not told the mode that the docstring (and ``latent_tasks.BLIND_CEILINGS``) describes: press action 0;
    if it moved forward keep it, if it moved back the mode is 2 (press 2); if it stayed, press 1, which moves forward
    in mode 1 and back in mode 3."""
    env = ModeCorridorEnv()
    returns = []
    for seed in range(400):
        obs, _ = env.reset(seed=seed)
        total, action, last, done = 0.0, 0, obs[0], False
        while not done:
            obs, reward, terminated, truncated, _ = env.step(action)
            total, done = total + reward, terminated or truncated
            moved = np.sign(obs[0] - last)
            if action == 0 and moved < 0:
                action = 2
            elif action == 0 and moved == 0:
                action = 1
            elif action == 1 and moved < 0:
                action = 3
            last = obs[0]
        returns.append(total)
    assert np.mean(returns) == pytest.approx(0.925, abs=0.004)
    assert load_benchmark("latent_tasks").BLIND_CEILINGS["corridor"] == 0.925


def test_solved_modes_counts_successes_per_mode():
    solved = ModeCorridorEnv.solved_modes([0, 0, 1, 1, 1, 2], [True, True, True, False, True, False], share=0.6)
    assert solved.tolist() == [True, True, False, False]  # mode 3 has no episode
    with pytest.raises(ValueError, match="one entry per episode"):
        ModeCorridorEnv.solved_modes([0, 1], [True])


def info_mode(env) -> int:
    return env._info()["mode"]


def test_the_goal_task_pays_at_the_mode_s_corner_only_and_its_cue_is_right_as_often_as_stated():
    env = ModeGoalEnv(noise=0.0)
    right, steps = 0, 0
    for seed in range(40):
        obs, info = env.reset(seed=seed)
        assert np.abs(obs[:2]).max() <= 0.3
        for corner in range(4):
            env.position = ModeGoalEnv.SIGNS[corner] * env.corner
            obs, reward, *_ , info = env.step(0)  # stay
            assert reward == float(corner == info["mode"])
            right += int(obs[2:].argmax() == info["mode"])
            steps += 1
    assert abs(right / steps - (0.5 + 0.5 / 4)) < 0.05
    with pytest.raises(ValueError, match="need 0 < corner <= 1"):
        ModeGoalEnv(corner=2.0)


def fake_run(task, variant, seed, returns, permuted=None):
    curve = [{"steps": 100 * (i + 1), "seconds": 1.0, "return": r} for i, r in enumerate(returns)]
    if variant == "em_ppo":
        for point, p in zip(curve, permuted):
            point.update(permuted_return=p, latent_accuracy=0.9, belief_use=1.0)
    return {"task": task, "variant": variant, "seed": seed, "budget": 500, "curve": curve}


def test_the_report_compares_at_the_checkpoint_where_told_ppo_reaches_nine_tenths_of_its_last_return(tmp_path):
    bench = load_benchmark("latent_tasks")
    runs = []
    for seed in range(3):
        runs.append(fake_run("goal", "told_ppo", seed, [1.0, 9.0 + seed, 10.0, 10.0, 10.0]))
        runs.append(fake_run("goal", "ppo", seed, [1.0, 2.0, 2.0, 2.0, 2.0]))
        runs.append(fake_run("goal", "em_ppo", seed, [1.0, 8.0 + 2 * seed, 9.0, 9.0, 9.0],
                             [1.0, 3.0, 3.0, 3.0, 3.0]))
    for run in runs:
        (tmp_path / f"{run['task']}_{run['variant']}_{run['seed']}.json").write_text(json.dumps(run))
    text = bench.report(bench.load_runs(tmp_path))
    assert "first at 0.9 of its last at 200 agent-steps" in text  # told's mean 10.0 at 200 (0.9 of 10 is 9)
    assert "em_ppo / told_ppo per seed: 0.89 1.00 1.09; at >= 0.85: 3 of 3" in text
    assert "permuting costs +7.000" in text and "em_ppo - ppo +8.000" in text
    # told's areas 8.625, 8.875, 9.125 (trapezoids over 100..500 agent-steps), em_ppo's 7.75, 8.25, 8.75; finals 9 / 10
    assert ("area under the return curve 0.90 0.93 0.96 (>= 0.85: 3 of 3); final return 0.90 0.90 0.90 (>= 0.95: 0 of 3)"
            in text)
    assert text.startswith("PPO settings of every variant") and "'n_steps': 128" in text
    for seed in range(3):  # told PPO at SB3's defaults, better here: it becomes the whole-budget reference
        run = fake_run("goal", "told_ppo_sb3", seed, [2.0, 10.0, 12.0, 12.0, 12.0])
        (tmp_path / f"goal_told_ppo_sb3_{seed}.json").write_text(json.dumps(run))
    text = bench.report(bench.load_runs(tmp_path))
    assert "told PPO's final return: at EM-PPO's settings 10.000, at SB3's defaults 12.000" in text
    assert "em_ppo / told_ppo_sb3 per seed" in text and "final return 0.75 0.75 0.75" in text
    assert "collapsed (final return below PPO's mean - 2.0 std, 2.000): none" in text
    collapsed = fake_run("goal", "em_ppo", 0, [1.0, 1.0, 1.0, 1.0, 1.0], [1.0] * 5)
    (tmp_path / "goal_em_ppo_0.json").write_text(json.dumps(collapsed))
    assert "2.000): em_ppo seed 0" in bench.report(bench.load_runs(tmp_path))


def test_the_report_counts_modes_solved_and_measures_a_candidate_in_em_ppo_s_place(tmp_path):
    bench = load_benchmark("latent_tasks")
    solved = {"told_ppo": [[True] * 4, [True, True, True, False]], "ppo": [[True, False, False, False]] * 2,
              "em_ppo": [[True, True, False, True], [True, True, True, False]],
              "em_ppo_sb3": [[True] * 4, [True] * 4]}
    for variant, per_seed in solved.items():
        for seed, modes in enumerate(per_seed):
            last = {"ppo": 0.3 + 0.07 * seed, "told_ppo": 0.9}.get(variant, 0.8 - 0.03 * seed)
            run = fake_run("corridor", variant, seed, [0.5] + [last] * 4, [0.0] + [0.1 * seed] * 4)
            if variant == "em_ppo_sb3":
                for point in run["curve"]:
                    point.update(permuted_return=0.1 * seed, latent_accuracy=0.9, belief_use=1.0)
            for point in run["curve"]:
                point["solved"] = modes
            (tmp_path / f"corridor_{variant}_{seed}.json").write_text(json.dumps(run))
    text = bench.report(bench.load_runs(tmp_path))
    assert "modes solved at the full budget per seed: em_ppo 3 3; told_ppo 4 3; ppo 1 1" in text
    # em_ppo's final returns 0.8 and 0.77 over the corridor's blind ceiling 0.925
    assert "final return over the blind ceiling 0.925 per seed: 0.86 0.83 (>= 0.95: 0 of 2)" in text
    assert "seeds where em_ppo misses a mode told PPO solves: [0]" in text  # seed 1: told misses mode 3 too
    assert "policy and value parameters" not in text  # (runs saved without their sizes)
    for path in tmp_path.glob("corridor_*.json"):
        run = json.loads(path.read_text())
        path.write_text(json.dumps({**run, "parameters": {"em_ppo": 9413, "ppo": 9285}.get(run["variant"], 9541)}))
    assert ("policy and value parameters: em_ppo 9,413, told_ppo 9,541, ppo 9,285"
            in bench.report(bench.load_runs(tmp_path)))
    text = bench.report(bench.load_runs(tmp_path), "em_ppo_sb3")
    assert "measured in em_ppo's place: em_ppo_sb3" in text
    assert "em_ppo 4 4; told_ppo 4 3" in text and "misses a mode told PPO solves: none" in text


def test_the_curve_area_is_the_mean_return_over_the_budget():
    bench = load_benchmark("latent_tasks")
    assert bench.curve_area([{"steps": 100, "return": 2.0}, {"steps": 300, "return": 2.0}]) == 2.0
    assert bench.curve_area([{"steps": 0, "return": 0.0}, {"steps": 100, "return": 1.0},
                             {"steps": 300, "return": 1.0}]) == pytest.approx((50 + 200) / 300)


def test_the_report_refuses_runs_of_different_budgets_and_an_empty_folder(tmp_path):
    bench = load_benchmark("latent_tasks")
    with pytest.raises(SystemExit, match="no runs in"):
        bench.load_runs(tmp_path)
    runs = [fake_run("cue", v, 0, [1.0] * 5, [1.0] * 5) for v in bench.VARIANTS]
    runs[0]["budget"] = 1000
    with pytest.raises(SystemExit, match="runs of different budgets"):
        bench.report(runs)


def test_the_benchmark_rejects_bad_flags_with_a_message(capsys):
    with pytest.raises(SystemExit) as exit_info:
        load_benchmark("latent_tasks").main(["run", "--folder", "x", "--seeds", "1", "1"])
    assert exit_info.value.code == 2
    assert "--seeds distinct and >= 0" in capsys.readouterr().err


def test_the_trace_reads_the_latent_metrics_every_em_ppo_run_logs():
    bench = load_benchmark("latent_tasks")
    kept = bench.trace("cue", 0, 3 * 1024, rows=3, n_steps=128)
    assert [row["steps"] for row in kept] == [1024, 2048, 3072]
    last = kept[-1]
    for key in bench.TRACE_KEYS:
        assert last[key] is not None, key
    assert 0.0 <= last["latent/assignment_kept"] <= last["latent/assignment_matched"] <= 1.0
    text = bench.trace_table("cue", kept)
    assert text.splitlines()[0].split()[:3] == ["cue:", "agent-steps", "accuracy"] and "3,072" in text


def test_a_run_keeps_where_its_training_s_time_went_and_the_machine_s_load(tmp_path):
    bench = load_benchmark("latent_tasks")
    message = bench.run_and_save(str(tmp_path), "cue", "ppo", 0, 1280, 2)
    record = json.loads(next(tmp_path.glob("cue_ppo_0.json")).read_text())
    phases = record["phase_seconds"]
    assert phases["gradient epochs"] > 0 and phases["environment"] > 0
    assert 0 < sum(phases.values()) <= record["curve"][-1]["seconds"]  # (the rest: SB3's set-up of each learn call)
    assert set(record["load"]) == {"start", "end"} and record["load"]["end"]["cores"] >= 1
    assert "where its training's time went (load average" in message and "wall / floor" in message


def test_the_goal_task_s_exact_cue_posterior_is_the_bayes_filter_of_its_cues():
    bench = load_benchmark("latent_tasks")
    venv = bench.make_task("goal", n_envs=1, seed=3, exact=True)
    obs = venv.reset()
    assert venv.observation_space.shape == (10,) and venv.observation_space.dtype == np.float32
    weight = np.log((0.5 + 0.5 / 4) / (0.5 / 4))  # the default cue accuracy, 0.5: each cue multiplies its odds by 5
    counts = np.zeros(4)
    for step in range(6):
        counts += obs[0, 2:6]
        expected = np.exp(weight * counts) / np.exp(weight * counts).sum()
        np.testing.assert_allclose(obs[0, 6:], expected, rtol=1e-5)
        obs, _, _, _ = venv.step(np.array([step % 5]))
    with pytest.raises(ValueError, match="defined on the goal task only, got 'cue'"):
        bench.make_task("cue", exact=True)
