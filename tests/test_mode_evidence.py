"""The mode-evidence benchmark: features of observation histories, accuracies, and the script end to end."""

import numpy as np
import pytest
from scripts import load_benchmark

from wildlife_reserve import reserve_v0
from wildlife_reserve.reserve.scripted import RandomPatrol

TINY = {"n_uavs": 2, "grid_size": 20, "max_cycles": 8}


@pytest.fixture(scope="module")
def evidence():
    return load_benchmark("mode_evidence")


def test_features_are_running_means_and_maxima(evidence):
    history = np.array([[[0.0, 1.0], [2.0, 0.0]], [[1.0, 3.0], [0.0, 0.0]], [[2.0, 2.0], [1.0, 6.0]]])  # (t, n, d)
    per_uav = evidence.summarise(history)
    np.testing.assert_allclose(per_uav, [[1.0, 2.0, 2.0, 3.0], [1.0, 2.0, 2.0, 6.0]])
    np.testing.assert_allclose(evidence.team_features(per_uav), [1.0, 2.0, 2.0, 4.5, 1.0, 2.0, 2.0, 6.0])


def test_collected_features_summarise_the_episode_as_played(evidence):
    single, team, modes = evidence.collect_features(TINY, "random", range(3, 5), points=(0.0, 0.5, 1.0), patrol_seed=7)
    env = reserve_v0.parallel_env(**TINY)
    policy = RandomPatrol(env, seed=7)
    for episode, seed in enumerate(range(3, 5)):
        observations, infos = env.reset(seed=seed)
        history = [np.stack([observations[a] for a in env.possible_agents])]
        while env.agents:
            observations, _, _, _, infos = env.step(policy(observations))
            history.append(np.stack([observations[a] for a in env.possible_agents]))
            assert infos["uav_0"]["mode"] == modes[episode]  # the mode recorded is the episode's
        history = np.array(history, dtype=np.float64)
        for point, t in ((0.0, 0), (0.5, 4), (1.0, 8)):
            expected = evidence.summarise(history[:t + 1])
            np.testing.assert_allclose(single[point][2 * episode:2 * episode + 2], expected, rtol=1e-5, atol=1e-6)
            np.testing.assert_allclose(team[point][episode], evidence.team_features(expected), rtol=1e-5, atol=1e-6)


def test_accuracies_and_commonest_class_rates(evidence):
    result = evidence.accuracies(np.array([0, 1, 2, 7]), np.array([0, 0, 3, 7]))
    assert result["mode"] == 0.5 and result["strategy"] == 1.0 and result["weather"] == 0.5
    assert result["mode_majority"] == 0.5 and result["strategy_majority"] == 0.5 and result["weather_majority"] == 0.5


def test_the_script_prints_every_row(evidence, capsys):
    assert evidence.main(["--episodes", "6", "--test-episodes", "4", "--epochs", "1", "--env-kwargs", repr(TINY)]) == 0
    out = capsys.readouterr().out
    rows = [line for line in out.splitlines() if line.startswith(("random", "scripted"))]
    assert len(rows) == 2 * 2 * len(evidence.POINTS)
    assert any(" first " in row for row in rows) and any("50%" in row for row in rows)


@pytest.mark.parametrize("flags, message", [(["--episodes", "0"], "--episodes must be >= 1"),
                                            (["--patrols", "lawnmower"], "'lawnmower'"),
                                            (["--env-kwargs", "dict(n_uavs=0)"], "--env-kwargs must be a dict literal"),
                                            (["--env-kwargs", "{'n_uavs': 0}"], "n_uavs must be >= 1")])
def test_bad_arguments_are_rejected_by_name(evidence, flags, message, capsys):
    with pytest.raises(SystemExit) as exit_info:
        evidence.main(flags)
    assert exit_info.value.code == 2 and message in capsys.readouterr().err
