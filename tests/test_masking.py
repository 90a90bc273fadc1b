"""Observation parts hidden from the policy (HideObservationParts), in training and in every evaluation path."""

import numpy as np
import pytest
from gymnasium import spaces
from scripts import load_benchmark

from sb3_emmarl.common.evaluation import RandomPolicy, evaluate_team
from sb3_emmarl.common.masking import HideObservationParts, hidden_indices
from sb3_emmarl.common.vec_env import make_vec_env
from sb3_emmarl.zoo.cli import enjoy_main, latest_run, train_main
from sb3_emmarl.zoo.compare import evaluate_run
from wildlife_reserve import reserve_v1
from wildlife_reserve.reserve.kernels.constants import CH_SIGN

SMALL = {"n_uavs": 3, "grid_size": 20, "max_cycles": 6}


def layout():
    return reserve_v1.parallel_env(**SMALL).observation_layout


def test_hidden_indices_name_layout_parts_and_window_channels():
    parts = layout()
    signs, _ = parts["signs"]
    window, (_, w, _) = parts["window"]
    np.testing.assert_array_equal(hidden_indices(parts, ["signs"]), np.arange(signs.start, signs.stop))
    channel = hidden_indices(parts, ["window.sign"])
    np.testing.assert_array_equal(channel, window.start + CH_SIGN * w * w + np.arange(w * w))
    both = hidden_indices(parts, ["window.sign", "signs", "signs"])  # sorted, each index once
    np.testing.assert_array_equal(both, np.concatenate([channel, np.arange(signs.start, signs.stop)]))


@pytest.mark.parametrize("parts, message", [(["sign"], "unknown observation part 'sign'"),
                                            (["window.signs"], "unknown observation part 'window.signs'"),
                                            ([], "non-empty list"), ("signs", "non-empty list")])
def test_bad_part_names_are_rejected_with_the_allowed_ones(parts, message):
    with pytest.raises(ValueError, match=message) as error:
        HideObservationParts(make_vec_env(1, seed=0, env_kwargs=SMALL), parts)
    assert "window.sign" in str(error.value)


def test_the_parts_are_zero_everywhere_and_the_rest_as_without_the_wrapper():
    plain = make_vec_env(2, seed=3, env_kwargs=SMALL)
    hidden = HideObservationParts(make_vec_env(2, seed=3, env_kwargs=SMALL), ["signs", "window.sign", "belief"])
    assert hidden.observation_space == plain.observation_space
    keep = np.setdiff1d(np.arange(plain.observation_space.shape[0]), hidden.hidden)
    a, b = plain.reset(), hidden.reset()
    rng = np.random.default_rng(0)
    ended = 0
    for _ in range(14):  # crosses two episode ends
        assert (b[:, hidden.hidden] == 0).all()
        np.testing.assert_array_equal(a[:, keep], b[:, keep])
        actions = rng.integers(0, 15, plain.num_envs)
        (a, ra, da, ia), (b, rb, db, ib) = plain.step(actions), hidden.step(actions)
        np.testing.assert_array_equal(ra, rb)
        np.testing.assert_array_equal(da, db)
        for i in np.flatnonzero(db):
            ended += 1
            assert (ib[i]["terminal_observation"][hidden.hidden] == 0).all()
            np.testing.assert_array_equal(ia[i]["terminal_observation"][keep], ib[i]["terminal_observation"][keep])
    assert ended > 0
    # Something was hidden that the plain environment shows (the sign map fills as the UAVs find signs).
    assert np.abs(a[:, hidden.hidden]).sum() > 0


class Recorder(RandomPolicy):
    """A random team that keeps every observation it was asked to act on."""

    def __init__(self) -> None:
        super().__init__(spaces.Discrete(15), seed=0)
        self.seen = []

    def predict(self, observation, state=None, episode_start=None, deterministic=False):
        self.seen.append(np.array(observation))
        return super().predict(observation, state, episode_start, deterministic)


def test_evaluate_team_plays_under_the_wrapper_it_is_given():
    wrapper = lambda venv: HideObservationParts(venv, ["signs"])  # noqa: E731
    recorder = Recorder()
    evaluate_team(recorder, n_episodes=1, seed=0, env_kwargs=SMALL, vec_env_wrapper=wrapper)
    signs = hidden_indices(layout(), ["signs"])
    assert (np.concatenate(recorder.seen)[:, signs] == 0).all()
    shown = Recorder()
    evaluate_team(shown, n_episodes=1, seed=0, env_kwargs=SMALL)
    assert np.abs(np.concatenate(shown.seen)[:, signs]).sum() > 0


def test_a_zoo_run_trained_without_a_part_is_played_without_it_everywhere(tmp_path, monkeypatch):
    """Training, the zoo's own team evaluation, enjoy and the comparisons' evaluate_run (which rebuild the wrapper
    from the run's config.yml) all see the observation without the hidden part."""
    seen = []
    original = HideObservationParts.reset

    def reset(self):
        seen.append(self.parts)
        return original(self)

    monkeypatch.setattr(HideObservationParts, "reset", reset)
    wrapper = {"sb3_emmarl.common.masking.HideObservationParts": {"parts": ["signs"]}}
    assert train_main(["--algo", "ppo", "-n", "64", "--seed", "0", "-f", str(tmp_path), "--eval-freq", "-1",
                       "--team-eval-episodes", "1", "--verbose", "0", "--env-kwargs", "n_uavs:2", "grid_size:20",
                       "max_cycles:10", "-params", "n_steps:16", "batch_size:32", f"vec_env_wrapper:{wrapper!r}"]) == 0
    assert seen == [("signs",)] * 2  # the training environment, then the final team evaluation's
    assert enjoy_main(["--algo", "ppo", "-f", str(tmp_path), "--episodes", "1", "--no-record"]) == 0
    evaluate_run("ppo", latest_run(tmp_path, "ppo"), 1, seed=0)
    assert seen == [("signs",)] * 4


def test_mode_value_hides_the_parts_in_both_variants(tmp_path, capsys):
    mode_value = load_benchmark("mode_value")
    assert mode_value.main(["-n", "64", "--seeds", "0", "1", "--eval-episodes", "1", "-f", str(tmp_path),
                            "--patrol-episodes", "0", "--hide", "signs", "window.sign", "--env-kwargs", "n_uavs:2",
                            "grid_size:20", "max_cycles:10"]) == 0
    for variant, algo in (("told_mode", "oracle_ppo"), ("ppo", "ppo")):
        config = (latest_run(tmp_path / variant / "seed_1", algo) / "WildlifeReserve-v1" / "config.yml").read_text()
        assert "HideObservationParts" in config and "window.sign" in config
    runs = sorted(tmp_path.glob("*/seed_*/*/*"))
    # The finished runs are evaluated again with the same --hide, and refused without it (another observation).
    flags = ["-n", "64", "--seeds", "0", "1", "--eval-episodes", "1", "-f", str(tmp_path), "--patrol-episodes", "0",
             "--reuse-runs", "--env-kwargs", "n_uavs:2", "grid_size:20", "max_cycles:10"]
    assert mode_value.main([*flags, "--hide", "signs", "window.sign"]) == 0
    assert sorted(tmp_path.glob("*/seed_*/*/*")) == runs
    assert mode_value.main(flags) == 2
    assert "vec_env_wrapper" in capsys.readouterr().err


def test_mode_value_rejects_an_unknown_part(capsys):
    with pytest.raises(SystemExit) as exit_info:
        load_benchmark("mode_value").main(["--hide", "sign", "-n", "10"])
    assert exit_info.value.code == 2 and "unknown observation part 'sign'" in capsys.readouterr().err


def test_the_centralised_view_refuses_a_vec_env_wrapper():
    from sb3_emmarl.common.evaluation import make_eval_env

    with pytest.raises(ValueError, match="vec_env_wrapper applies to the parameter-sharing view"):
        make_eval_env(0, SMALL, centralized=True, vec_env_wrapper=lambda venv: venv)


def test_evaluate_team_refuses_a_wrapper_beside_a_vec_env_of_its_own():
    with pytest.raises(ValueError, match="give vec_env_wrapper or vec_env, not both"):
        evaluate_team(RandomPolicy(spaces.Discrete(15), seed=0), 1, vec_env=make_vec_env(1, seed=0, env_kwargs=SMALL),
                      vec_env_wrapper=lambda venv: venv)
