"""EM-PPO with default arguments identifies the hidden mode of both small tasks and acts on it.

Each case trains three models (minutes on two cores): marked ``expensive`` and left out of ``make test``;
``python -m pytest -m expensive tests/test_latent_tasks.py`` or ``make benchmark-latent-tasks`` (3 seeds) run it.
"""

import pytest
from scripts import load_benchmark

from sb3_emmarl.common.envs import ModeCueEnv, ModeDynamicsEnv


@pytest.mark.expensive
@pytest.mark.parametrize("task", ["cue", "dynamics"])
def test_em_ppo_defaults_reach_the_mode_and_most_of_the_told_return(task):
    bench = load_benchmark("latent_tasks")
    em = bench.run(task, "em_ppo", 0, bench.BUDGETS[task], eval_episodes=50)
    told = bench.run(task, "told_ppo", 0, bench.BUDGETS[task], eval_episodes=50)
    assert em["latent_accuracy"] >= 0.9
    assert em["return"] >= 0.85 * told["return"]


@pytest.mark.parametrize("env_class", [ModeCueEnv, ModeDynamicsEnv])
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


@pytest.mark.parametrize("item, shown", [("foo:1000", "foo:1000"), ("dynamics:0", "dynamics:0"),
                                         ("dynamics:'x'", "dynamics:'x'"), ("dynamics:2.5", "dynamics:2.5")])
def test_the_benchmark_rejects_a_bad_budget_with_a_message(item, shown, capsys):
    with pytest.raises(SystemExit) as exit_info:
        load_benchmark("latent_tasks").main(["--budgets", item])
    assert exit_info.value.code == 2
    assert f"--budgets takes TASK:N with TASK one of ['cue', 'dynamics'] and N an integer >= 1, got {shown}" in \
        capsys.readouterr().err


def test_a_budget_without_a_colon_is_refused_by_the_zoos_key_value_parser(capsys):
    with pytest.raises(SystemExit):
        load_benchmark("latent_tasks").main(["--budgets", "dynamics"])
    assert "--budgets expects key:value pairs, got 'dynamics'" in capsys.readouterr().err
