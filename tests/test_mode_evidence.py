"""The mode-evidence benchmark: features of observation histories, accuracies, and the script end to end."""

import numpy as np
import pytest
from scripts import load_benchmark

from wildlife_reserve import reserve_v1
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
    single, team, modes, now = evidence.collect_features(TINY, "random", range(3, 5), points=(0.0, 0.5, 1.0),
                                                         patrol_seed=7)
    env = reserve_v1.parallel_env(**TINY)
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
            np.testing.assert_array_equal(now[point][2 * episode:2 * episode + 2], history[t])  # that step's alone


def test_a_subset_of_uavs_gives_their_rows_and_leaves_the_team_whole(evidence):
    points = (0.0, 1.0)
    single, team, modes, now = evidence.collect_features(TINY, "random", range(3, 6), points=points, patrol_seed=7)
    some, some_team, some_modes, some_now = evidence.collect_features(TINY, "random", range(3, 6), points=points,
                                                                      patrol_seed=7, uavs_per_episode=1)
    np.testing.assert_array_equal(some_modes, modes)
    for point in points:
        assert some[point].shape == (3, single[point].shape[1])
        np.testing.assert_array_equal(some_team[point], team[point])
        assert some_now[point].shape == (3, now[point].shape[1])
        for episode in range(3):  # each kept row is one of its episode's UAVs, the same one in both parts
            kept = (some[point][episode] == single[point][2 * episode:2 * episode + 2]).all(axis=1)
            assert kept.any()
            assert (some_now[point][episode] == now[point][2 * episode:2 * episode + 2][kept]).all()


def test_env_kwargs_are_read_as_literals_only(evidence):
    assert evidence.parse_env_kwargs("dict(n_uavs=2, region='forest')") == {"n_uavs": 2, "region": "forest"}
    assert evidence.parse_env_kwargs(" {'n_uavs': 2, 'grid_size': 20} ") == {"n_uavs": 2, "grid_size": 20}
    assert evidence.parse_env_kwargs("dict()") == {}
    for text in ("[1, 2]", "n_uavs:2", "dict(**{'n_uavs': 2})", "dict([('n_uavs', 2)])", "dict(n_uavs=len('ab'))",
                 "__import__('os').getcwd()"):
        with pytest.raises(ValueError):
            evidence.parse_env_kwargs(text)


def test_accuracies_and_commonest_class_rates(evidence):
    result = evidence.accuracies(np.array([0, 1, 2, 7]), np.array([0, 0, 3, 7]))
    assert result["mode"] == 0.5 and result["strategy"] == 1.0 and result["weather"] == 0.5
    assert result["mode_majority"] == 0.5 and result["strategy_majority"] == 0.5 and result["weather_majority"] == 0.5


def test_the_script_prints_every_row(evidence, capsys):
    tiny = "dict(n_uavs=2, grid_size=20, max_cycles=8)"
    assert evidence.main(["--episodes", "6", "--test-episodes", "4", "--epochs", "1", "--env-kwargs", tiny]) == 0
    out = capsys.readouterr().out
    rows = [line for line in out.splitlines() if line.startswith(("random", "scripted"))]
    assert len(rows) == 2 * 3 * len(evidence.POINTS)
    for patrol in ("random", "scripted"):
        for source in ("one UAV", "team", "UAV now"):
            points = [row.split()[-8] for row in rows if row.startswith(patrol) and source in row]
            assert points == ["first", "25%", "50%", "100%"]
    assert "random subset" not in out and "wall time" in out.splitlines()[-1]
    one_uav = [row for row in rows if "one UAV" in row or "UAV now" in row]
    assert len(one_uav) == 4 * len(evidence.POINTS) and all(row.split()[-1] == "12" for row in one_uav)  # 6 x 2 UAVs


def test_the_script_says_when_it_keeps_a_subset_of_uavs(evidence, capsys):
    flags = ["--episodes", "6", "--test-episodes", "4", "--epochs", "1", "--patrols", "random", "--max-uav-samples", "6"]
    assert evidence.main([*flags, "--env-kwargs", repr(TINY)]) == 0
    out = capsys.readouterr().out
    assert "a random 1 of the 2 UAVs of each episode (--max-uav-samples 6)" in out
    rows = [line for line in out.splitlines() if line.startswith("random")]
    assert [row.split()[-1] for row in rows] == ["6"] * 12  # 6 episodes x 1 UAV (so far and now); 6 team samples


@pytest.mark.parametrize("flags, message", [(["--episodes", "0"], "--episodes must be >= 1, got 0"),
                                            (["--test-episodes", "-3"], "--test-episodes must be >= 1, got -3"),
                                            (["--max-uav-samples", "0"], "--max-uav-samples must be >= 1, got 0"),
                                            (["--seed", "-1"], "--seed must be >= 0, got -1"),
                                            (["--patrols", "lawnmower"], "'lawnmower'"),
                                            (["--env-kwargs", "[1, 2]"], "must be a dict literal of the reserve's arguments, "
                                                                         "got '[1, 2]'"),
                                            (["--env-kwargs", "dict(n_uavs=0)"], "n_uavs must be in [1, 1000], got 0"),
                                            (["--env-kwargs", "{'n_uavs': 0}"], "n_uavs must be in [1, 1000], got 0"),
                                            (["--env-kwargs", "{'n_drones': 2}"], "n_drones"),
                                            (["--env-kwargs", "{'continuous_actions': True}"], "continuous_actions=False")])
def test_bad_arguments_are_rejected_by_name(evidence, flags, message, capsys):
    with pytest.raises(SystemExit) as exit_info:
        evidence.main(flags)
    assert exit_info.value.code == 2 and message in capsys.readouterr().err
