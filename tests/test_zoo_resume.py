"""The zoo's runs survive: resume after a crash, continue with -i, refuse unsafe or broken files, stop at NaN."""

import shutil

import numpy as np
import pytest
import torch as th
import yaml
from stable_baselines3.common.save_util import load_from_zip_file

from sb3_emmarl.common.checkpoints import REPLAY_BUFFER, TRAINING_STATE, companion, list_checkpoints
from sb3_emmarl.common.trust.safe_pickle import load_vec_normalize
from sb3_emmarl.zoo.cli import enjoy_main, train_main
from wildlife_reserve.reserve.reserve import ReserveParallelEnv

ENV = "WildlifeReserve-v1"
TINY = ["--env-kwargs", "n_uavs:2", "grid_size:20", "max_cycles:40"]
QUIET = ["--eval-freq", "-1", "--team-eval-episodes", "0", "--verbose", "0"]


def train(folder, *args):
    return train_main(["-f", str(folder), "--seed", "1", *QUIET, *TINY, *args])


def parameters(path):
    _, params, _ = load_from_zip_file(path, device="cpu")
    return params["policy"]


def killed_after_first_checkpoint(tmp_path, algo, *args):
    """Train ``algo`` to two checkpoints (1024 and 2048 steps) in ``tmp_path/a``, and leave in ``tmp_path/b`` a copy
    of the run as a kill after its first checkpoint leaves it; returns both run folders."""
    th.set_num_threads(1)
    assert train(tmp_path / "a", "--algo", algo, "--save-freq", "500", *args) == 0
    run = tmp_path / "a" / algo / f"{ENV}_1"
    assert [steps for steps, _ in list_checkpoints(run)] == [1024, 2048]
    assert all(companion(path, TRAINING_STATE).is_file() for _, path in list_checkpoints(run))
    killed = tmp_path / "b" / algo / f"{ENV}_1"
    shutil.copytree(run, killed)
    for name in (f"{ENV}.zip", "rl_model_2048_steps.zip", "rl_model_training_state_2048_steps.pkl", "run_stats.json"):
        (killed / name).unlink()
    return run, killed


def test_resume_continues_a_killed_run_to_the_same_model(tmp_path, capsys):
    run, killed = killed_after_first_checkpoint(tmp_path, "em_ppo", "-n", "3000")
    (killed / ".rl_model_2048_steps.zip.123.tmp").write_bytes(b"half a zip")  # a file being written at the kill
    # its config.yml as runs of 0.22.0 wrote it, each latent setting a hyperparameter of its own: resumed alike
    config_file = killed / ENV / "config.yml"
    config = yaml.safe_load(config_file.read_text())
    config_file.write_text(yaml.safe_dump({**{k: v for k, v in config.items() if k != "latent_kwargs"},
                                           **config["latent_kwargs"]}))
    capsys.readouterr()
    assert train_main(["--algo", "em_ppo", "--resume", "-f", str(tmp_path / "b"), "--verbose", "0"]) == 0
    assert "Resuming" in capsys.readouterr().out
    assert not list(killed.glob(".*.tmp"))
    reference, resumed = parameters(run / f"{ENV}.zip"), parameters(killed / f"{ENV}.zip")
    assert all(th.equal(reference[k], resumed[k]) for k in reference)
    assert (killed / "monitor.csv").is_file() and (killed / "resumed_rl_model_1024_steps.monitor.csv").is_file()
    # A finished run has nothing to resume; a folder without checkpoints cannot be resumed.
    assert train_main(["--algo", "em_ppo", "--resume", str(killed)]) == 0
    assert "nothing to resume" in capsys.readouterr().out
    assert train(tmp_path / "c", "--algo", "ppo", "-n", "500") == 0
    (tmp_path / "c" / "ppo" / f"{ENV}_1" / f"{ENV}.zip").unlink()
    with pytest.raises(SystemExit) as exit_info:
        train_main(["--algo", "ppo", "--resume", "-f", str(tmp_path / "c")])
    assert exit_info.value.code == 2 and "has no checkpoint" in capsys.readouterr().err


def test_a_normalized_run_resumes_to_the_same_model_and_statistics(tmp_path):
    """normalize: the reward normaliser's running returns are in the training state (before 0.22.1 a wrapper's own
    state was skipped for its inner environment's, and the resumed run's weights drifted by about 1e-3)."""
    run, killed = killed_after_first_checkpoint(tmp_path, "ppo", "-n", "3000", "-params", "normalize:True")
    assert train_main(["--algo", "ppo", "--resume", "-f", str(tmp_path / "b"), "--verbose", "0"]) == 0
    reference, resumed = parameters(run / f"{ENV}.zip"), parameters(killed / f"{ENV}.zip")
    assert all(th.equal(reference[k], resumed[k]) for k in reference)
    statistics = [load_vec_normalize(folder / ENV / "vecnormalize.pkl", None) for folder in (run, killed)]
    for name in ("obs_rms", "ret_rms"):
        first, second = (getattr(s, name) for s in statistics)
        assert np.array_equal(first.mean, second.mean) and np.array_equal(first.var, second.var)
        assert first.count == second.count


def test_resume_passes_over_another_runs_checkpoint_and_a_damaged_final_model(tmp_path, capsys):
    """A valid zip of another model as the newest checkpoint is passed over (it used to leave --resume failing on every
    try); a final model that does not load does not make the run "finished"."""
    from stable_baselines3 import PPO

    run, killed = killed_after_first_checkpoint(tmp_path, "ppo", "-n", "3000")
    PPO("MlpPolicy", "CartPole-v1", n_steps=32, batch_size=32).save(killed / "rl_model_2048_steps.zip")
    capsys.readouterr()
    assert train_main(["--algo", "ppo", "--resume", "-f", str(tmp_path / "b"), "--verbose", "0"]) == 0
    out = capsys.readouterr().out
    assert "from rl_model_1024_steps.zip" in out and "rl_model_2048_steps.zip: its networks' shapes differ" in out
    reference = parameters(run / f"{ENV}.zip")
    assert all(th.equal(reference[k], v) for k, v in parameters(killed / f"{ENV}.zip").items())
    (killed / f"{ENV}.zip").write_bytes(b"PK\x03\x04 cut short")
    assert train_main(["--algo", "ppo", "--resume", "-f", str(tmp_path / "b"), "--verbose", "0"]) == 0
    captured = capsys.readouterr()
    assert "does not load" in captured.err and "from rl_model_2048_steps.zip" in captured.out
    assert all(th.equal(reference[k], v) for k, v in parameters(killed / f"{ENV}.zip").items())


def test_a_run_with_its_reserves_in_worker_processes_resumes_to_the_same_model(tmp_path):
    """--vec-env subproc: the checkpoints hold the reserves of the worker processes too."""
    run, killed = killed_after_first_checkpoint(tmp_path, "ppo", "-n", "2500", "--vec-env", "subproc")
    assert train_main(["--algo", "ppo", "--resume", "-f", str(tmp_path / "b"), "--verbose", "0"]) == 0
    reference, resumed = parameters(run / f"{ENV}.zip"), parameters(killed / f"{ENV}.zip")
    assert all(th.equal(reference[k], resumed[k]) for k in reference)


def test_trained_agent_continues_from_a_checkpoint_with_its_replay_buffer(tmp_path, capsys):
    params = ["-params", "learning_starts:100", "buffer_size:5000", "train_freq:4"]
    assert train(tmp_path, "--algo", "dqn", "-n", "1000", "--save-freq", "400", "--save-replay-buffer", *params) == 0
    run = tmp_path / "dqn" / f"{ENV}_1"
    _steps, checkpoint = list_checkpoints(run)[-1]
    assert companion(checkpoint, REPLAY_BUFFER).is_file() and (run / "replay_buffer.pkl").is_file()
    assert train(tmp_path, "--algo", "dqn", "-n", "500", "-i", str(checkpoint), *params) == 0
    assert (tmp_path / "dqn" / f"{ENV}_2" / f"{ENV}.zip").is_file()
    for bad, message in ((tmp_path / "missing.zip", "no model file"),
                         (run / f"{ENV}.zip", "was not saved by PPO")):
        with pytest.raises(SystemExit) as exit_info:
            train(tmp_path, "--algo", "ppo", "-i", str(bad))
        assert exit_info.value.code == 2 and message in capsys.readouterr().err
    truncated = tmp_path / "truncated.zip"
    truncated.write_bytes(checkpoint.read_bytes()[:1000])
    with pytest.raises(SystemExit):
        train(tmp_path, "--algo", "dqn", "-i", str(truncated))
    assert "truncated.zip is incomplete or corrupt" in capsys.readouterr().err
    assert sorted(p.name for p in (tmp_path / "dqn").iterdir()) == [f"{ENV}_1", f"{ENV}_2"]


def test_run_files_are_plain_data_and_python_tags_are_refused(tmp_path, capsys):
    assert train(tmp_path, "--algo", "ppo", "-n", "500") == 0
    params = tmp_path / "ppo" / f"{ENV}_1" / ENV
    assert "!!python" not in (params / "config.yml").read_text() + (params / "args.yml").read_text()
    assert enjoy_main(["--algo", "ppo", "-f", str(tmp_path), "--episodes", "1", "--no-record"]) == 0
    shutil.copytree(tmp_path / "ppo", tmp_path / "a2c")
    config = params / "config.yml"
    config.write_text(config.read_text() + "evil: !!python/object/apply:os.system ['touch " + str(tmp_path / "pwned") + "']\n")
    capsys.readouterr()
    assert enjoy_main(["--algo", "ppo", "-f", str(tmp_path), "--episodes", "1", "--no-record"]) == 2
    err = capsys.readouterr().err
    assert "refusing to load the run's config holding a Python object tag" in err and "config.yml" in err
    assert not (tmp_path / "pwned").exists()
    # A model of another algorithm in the folder is refused by name, not with an attribute error.
    assert enjoy_main(["--algo", "a2c", "-f", str(tmp_path), "--episodes", "1", "--no-record"]) == 2
    assert "was not saved by A2C" in capsys.readouterr().err


@pytest.mark.parametrize("save_freq", [None, "200"])
def test_a_nan_stops_training_with_a_message_and_no_model_less_folder(tmp_path, capsys, monkeypatch, save_freq):
    original = ReserveParallelEnv.step_arrays  # what the zoo's (batched) vector environment calls
    calls = []

    def step_arrays(self, actions, out=None):
        observations, rewards, *rest = original(self, actions, out)
        calls.append(1)
        if len(calls) >= 4 * 45:  # 4 copies: step 45, in the third rollout, after the first checkpoint (step 256)
            rewards = np.full_like(rewards, np.nan)
        return observations, rewards, *rest

    monkeypatch.setattr(ReserveParallelEnv, "step_arrays", step_arrays)
    flags = ["--save-freq", save_freq] if save_freq else []
    assert train(tmp_path, "--algo", "ppo", "-n", "5000", "-params", "n_steps:16", "batch_size:32", *flags) == 1
    err = capsys.readouterr().err
    assert "non-finite rewards (nan)" in err and "of the vector environment" in err
    run = tmp_path / "ppo" / f"{ENV}_1"
    if save_freq is None:
        assert "no checkpoint had been written, so the run folder" in err and not (tmp_path / "ppo").exists()
    else:
        assert "keeps its checkpoints up to step" in err and "--resume" in err
        assert list_checkpoints(run) and not (run / f"{ENV}.zip").exists()


def test_overflowing_reward_weights_are_refused_before_anything_runs(tmp_path, capsys):
    assert train(tmp_path, "--algo", "ppo", "--env-kwargs", "reward_weights:{'coverage':1e308}") == 2
    assert "reward_weights" in capsys.readouterr().err and not tmp_path.joinpath("ppo").exists()
