"""The zoo's train and enjoy commands: rl-zoo's folder layout, tensorboard metrics, early and clean failures."""

import json
import shutil
from pathlib import Path

import pytest
from PIL import Image
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from sb3_emmarl.common.metrics import TEAM_METRICS
from sb3_emmarl.common.phases import PHASES
from sb3_emmarl.zoo import exp_manager
from sb3_emmarl.zoo.algos import ZOO_ALGOS
from sb3_emmarl.zoo.cli import enjoy_main, parse_key_values, train_main
from sb3_emmarl.zoo.exp_manager import read_yaml, yaml_section, zoo_hyperparams

TINY = ["--env-kwargs", "n_uavs:2", "grid_size:20", "max_cycles:40"]


def load_config(run):
    return dict(read_yaml(run / "WildlifeReserve-v1" / "config.yml", "the run's config"))


def train(tmp_path, *extra):
    return train_main(["--algo", "ppo", "--env", "WildlifeReserve-v1", "-n", "1024", "--seed", "1", "-f",
                       str(tmp_path / "logs"), "-tb", str(tmp_path / "runs"), "--eval-freq", "512", "--eval-episodes", "2",
                       "--team-eval-episodes", "2", "--verbose", "0", "-params", "n_steps:32", "batch_size:64", *TINY,
                       *extra])


@pytest.fixture(scope="module")
def trained_run(tmp_path_factory):
    tmp_path = tmp_path_factory.mktemp("zoo")
    assert train(tmp_path) == 0
    return tmp_path


def test_train_saves_the_run_in_rl_zoo_layout(trained_run):
    run = trained_run / "logs" / "ppo" / "WildlifeReserve-v1_1"
    for name in ["WildlifeReserve-v1.zip", "best_model.zip", "evaluations.npz", "monitor.csv", "team_eval.json",
                 "WildlifeReserve-v1/config.yml", "WildlifeReserve-v1/args.yml", "WildlifeReserve-v1/command.txt"]:
        assert (run / name).is_file(), name
    config = load_config(run)
    assert config["n_steps"] == 32 and config["env_kwargs"]["n_uavs"] == 2
    records = json.loads((run / "team_eval.json").read_text())
    assert len(records) == 2 and set(TEAM_METRICS) <= set(records[0]) and "mode" in records[0]


def test_tensorboard_holds_every_reserve_metric(trained_run):
    events = list((trained_run / "runs").rglob("events.out.tfevents.*"))
    assert len(events) == 1
    accumulator = EventAccumulator(str(events[0]))
    accumulator.Reload()
    tags = set(accumulator.Tags()["scalars"])
    expected = {f"reserve/{metric}" for metric in TEAM_METRICS} | {"reserve/policy_entropy"}
    assert expected <= tags, expected - tags
    entropy = [event.value for event in accumulator.Scalars("reserve/policy_entropy")]
    assert all(0.0 < value <= 2.71 for value in entropy)  # at most ln(15)
    coverage = [event.value for event in accumulator.Scalars("reserve/coverage_efficiency")]
    assert all(0.0 <= value <= 1.0 for value in coverage)


def test_enjoy_prints_metrics_and_records_a_gif(trained_run, capsys):
    gif = trained_run / "patrol.gif"
    assert enjoy_main(["--algo", "ppo", "-f", str(trained_run / "logs"), "--episodes", "2", "-o", str(gif)]) == 0
    out = capsys.readouterr().out
    assert all(metric in out for metric in TEAM_METRICS)
    with Image.open(gif) as image:
        assert image.n_frames > 20 and image.size == (600, 600)  # identical frames may be merged


def test_enjoy_finds_a_run_saved_under_the_former_id(trained_run, tmp_path, capsys):
    """A run made before the reserve became v1 (``WildlifeReserve-v0_1/WildlifeReserve-v0.zip``) plays on v1."""
    run = tmp_path / "ppo" / "WildlifeReserve-v0_1"
    shutil.copytree(trained_run / "logs" / "ppo" / "WildlifeReserve-v1_1" / "WildlifeReserve-v1", run / "WildlifeReserve-v0")
    shutil.copy(trained_run / "logs" / "ppo" / "WildlifeReserve-v1_1" / "WildlifeReserve-v1.zip",
                run / "WildlifeReserve-v0.zip")
    assert enjoy_main(["--algo", "ppo", "-f", str(tmp_path), "--episodes", "1", "--no-record"]) == 0
    out = capsys.readouterr().out
    assert f"{run / 'WildlifeReserve-v0.zip'}: 1 episodes from seed 0" in out


def test_enjoy_without_a_run_fails_cleanly(tmp_path, capsys):
    assert enjoy_main(["--algo", "ppo", "-f", str(tmp_path), "--no-record"]) == 2
    assert "folder was not found" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--env-kwargs", "n_drones:3"], "n_drones"),
        (["--env-kwargs", "n_uavs:-1"], "n_uavs must be in [1, 1000], got -1"),
        (["--env-kwargs", "comm_loss:1.5"], "comm_loss must be in [0.0, 1.0], got 1.5"),
        (["-params", "n_stepz:32"], "n_stepz"),
    ],
)
def test_bad_inputs_stop_before_training_and_leave_nothing(tmp_path, capsys, args, message):
    assert train(tmp_path, *args) == 2
    assert message in capsys.readouterr().err
    assert not list((tmp_path / "logs").rglob("*.zip"))
    assert not (tmp_path / "logs" / "ppo" / "WildlifeReserve-v1_1").exists()


def test_malformed_yaml_stops_with_its_name(tmp_path, capsys):
    bad = tmp_path / "bad.yml"
    bad.write_text("WildlifeReserve-v1:\n  n_timesteps: [1,\n  policy: 'MlpPolicy'\n")
    assert train(tmp_path, "-conf", str(bad)) == 2
    assert "bad.yml" in capsys.readouterr().err
    missing = tmp_path / "other.yml"
    missing.write_text("CartPole-v1:\n  n_timesteps: 10\n")
    assert train(tmp_path, "-conf", str(missing)) == 2
    assert "has no mapping of hyperparameters under 'WildlifeReserve-v1'" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--algo", "sac"], "argument --algo: invalid choice: 'sac'"),
        (["--env", "CartPole-v1"], "argument --env: invalid choice: 'CartPole-v1'"),
        (["--env-kwargs", "n_uavs=3"], "--env-kwargs expects key:value pairs, got 'n_uavs=3'"),
        (["--env-kwargs", "region:forest"], "--env-kwargs region: 'forest' is not a valid Python value"),
        (["-n", "0"], "argument -n/--n-timesteps: must be an int in [1, 10000000000] or -1, got 0"),
    ],
)
def test_bad_flags_are_rejected_by_the_parser(capsys, args, message):
    with pytest.raises(SystemExit) as exit_info:
        train_main(args)
    assert exit_info.value.code == 2
    assert message in capsys.readouterr().err


def test_key_values_take_python_values():
    assert parse_key_values(["n_uavs:20", "region:'forest'", "grid_size:(40, 60)", "policy:dict(a=1)"], "--x") == {
        "n_uavs": 20, "region": "forest", "grid_size": (40, 60), "policy": {"a": 1}}
    with pytest.raises(ValueError, match="not a valid Python value"):
        parse_key_values(["x:__import__('os')"], "--x")


def test_the_off_policy_em_yamls_give_the_e_step_as_many_episodes():
    """em_ddpg.yml and vdn_em.yml keep and refit the same stretch of play (40 episodes of 200 steps of their one
    reserve copy, every 10), though their window and interval count train() calls, one every train_freq steps."""
    def stretch(algo):
        settings = zoo_hyperparams(algo)
        latent = ZOO_ALGOS[algo].latent_defaults.updated(settings["latent_kwargs"])
        return latent.e_step_kwargs["window"] * settings["train_freq"], latent.e_step_interval * settings["train_freq"]

    assert stretch("em_ddpg") == stretch("vdn_em") == (40 * 200, 10 * 200)

def test_a_yaml_section_starts_from_the_zoo_file_its_base_names():
    ppo = zoo_hyperparams("ppo")
    em_ppo = zoo_hyperparams("em_ppo")
    # em_ppo.yml writes only what differs: every PPO setting is ppo.yml's, and its own keys are added.
    assert {key: em_ppo[key] for key in ppo} == ppo and em_ppo["latent_kwargs"]["n_components"] == 8 and "base" not in em_ppo
    assert zoo_hyperparams("oracle_ppo") == ppo  # oracle_ppo reads ppo.yml itself
    ddpg, em_ddpg = zoo_hyperparams("ddpg"), zoo_hyperparams("em_ddpg")  # likewise em_ddpg.yml over ddpg.yml
    assert {key: em_ddpg[key] for key in ddpg} == ddpg and em_ddpg["latent_kwargs"]["n_components"] == 8
    vdn, vdn_em = zoo_hyperparams("vdn"), zoo_hyperparams("vdn_em")  # and vdn_em.yml over vdn.yml
    assert {key: vdn_em[key] for key in vdn} == vdn and vdn_em["latent_kwargs"]["n_components"] == 8
    lstm = zoo_hyperparams("ppo_lstm")
    assert lstm["policy"] == "MlpLstmPolicy" and lstm["n_epochs"] == ppo["n_epochs"]
    # Own keys win, a whole value at a time; "default" is read when the env has no section.
    own = yaml_section({"default": {"base": "ppo", "n_epochs": 3, "env_kwargs": {"n_uavs": 2}}}, "WildlifeReserve-v1",
                       "own.yml")
    assert own == {**ppo, "n_epochs": 3, "env_kwargs": {"n_uavs": 2}}


@pytest.mark.parametrize(("base", "message"), [("sac", "base must name a zoo hyperparameter file"),
                                               (["ppo"], "base must name a zoo hyperparameter file")])
def test_a_bad_base_is_rejected_naming_it(base, message):
    with pytest.raises(ValueError, match=message) as error:
        yaml_section({"WildlifeReserve-v1": {"base": base}}, "WildlifeReserve-v1", "own.yml")
    assert "own.yml" in str(error.value) and repr(base) in str(error.value)


def test_a_cycle_of_base_files_is_rejected(tmp_path, monkeypatch):
    (tmp_path / "a.yml").write_text("WildlifeReserve-v1:\n  base: b\n")
    (tmp_path / "b.yml").write_text("WildlifeReserve-v1:\n  base: a\n")
    monkeypatch.setattr(exp_manager, "HYPERPARAMS_DIR", tmp_path)
    with pytest.raises(ValueError, match="cycle: a -> b -> a"):
        yaml_section({"WildlifeReserve-v1": {"base": "a"}}, "WildlifeReserve-v1", "own.yml")


def test_training_reads_a_users_file_through_its_base(tmp_path):
    own = tmp_path / "own.yml"
    own.write_text("WildlifeReserve-v1:\n  base: ppo\n  n_epochs: 1\n")
    assert train(tmp_path, "-conf", str(own)) == 0
    config = load_config(tmp_path / "logs" / "ppo" / "WildlifeReserve-v1_1")
    assert config["n_epochs"] == 1 and config["ent_coef"] == zoo_hyperparams("ppo")["ent_coef"] and "base" not in config


def test_cli_env_kwargs_update_the_yaml_ones(tmp_path):
    assert train_main(["--algo", "ddpg", "-n", "200", "--seed", "0", "-f", str(tmp_path), "--eval-freq", "-1",
                       "--team-eval-episodes", "0", "--verbose", "0", "-params", "learning_starts:50", *TINY]) == 0
    config = load_config(Path(tmp_path) / "ddpg" / "WildlifeReserve-v1_1")
    assert config["env_kwargs"] == {"continuous_actions": True, "n_uavs": 2, "grid_size": 20, "max_cycles": 40}


def test_optimize_runs_optuna_trials_into_a_sqlite_study(tmp_path):
    import optuna

    assert train_main(["--algo", "ppo", "-optimize", "--n-trials", "2", "-n", "1000", "--n-evaluations", "1",
                       "--sampler", "random", "--pruner", "none", "-f", str(tmp_path), "--verbose", "0",
                       "--eval-episodes", "1", "--no-optim-plots", *TINY]) == 0
    study = optuna.load_study(study_name="ppo-WildlifeReserve-v1", storage=f"sqlite:///{tmp_path / 'optuna.db'}")
    assert len(study.trials) == 2 and all(t.state == optuna.trial.TrialState.COMPLETE for t in study.trials)


def test_train_compiles_the_reserves_kernels_before_its_timed_training(tmp_path, monkeypatch, capsys):
    """The training and the evaluation reserves' kernels are compiled before the clock of
    ``run_stats.json`` starts, not inside the training (on a fresh machine that took tens of seconds of it); the
    training's time by phase is printed and saved, the phases within the training's wall time."""
    from sb3_emmarl.zoo import cli

    events = []
    monkeypatch.setattr(cli, "compile_reserve", lambda env_kwargs: events.append(("compile", dict(env_kwargs))))
    learn = exp_manager.ReserveExperimentManager.learn
    monkeypatch.setattr(exp_manager.ReserveExperimentManager, "learn",
                        lambda self, model: (events.append(("learn",)), learn(self, model))[1])
    assert train_main(["--algo", "ppo", "-n", "64", "--seed", "1", "-f", str(tmp_path), "--eval-freq", "-1",
                       "--team-eval-episodes", "0", "--verbose", "0", "-params", "n_steps:32", "batch_size:64", *TINY,
                       "--eval-env-kwargs", "n_uavs:2", "grid_size:20", "max_cycles:40", "adversarial:True"]) == 0
    train_kwargs = {"n_uavs": 2, "grid_size": 20, "max_cycles": 40}
    assert [event[0] for event in events] == ["compile", "compile", "learn"]
    assert train_kwargs.items() <= events[0][1].items() and events[1][1] == {**events[0][1], "adversarial": True}
    stats = json.loads(next(tmp_path.rglob("run_stats.json")).read_text())
    assert set(stats["phase_seconds"]) == set(PHASES) and stats["phase_seconds"]["gradient epochs"] > 0
    assert 0 < sum(stats["phase_seconds"].values()) <= stats["train_seconds"]
    assert "where the training's" in capsys.readouterr().out


@pytest.mark.parametrize("random_label", [True, False])
def test_the_zoos_oracle_ppo_trains_and_evaluates_on_what_its_random_label_asks(tmp_path, monkeypatch, random_label):
    """``-params random_label:True`` reaches the zoo's own environments (training and evaluation), not only the model:
    until 0.18.8 the zoo wrapped them told the true mode, which the model then kept, so its control trained told."""
    from sb3_emmarl.common.appended.wrapping import find_wrapper
    from sb3_emmarl.common.mode_aware import ModeObservationWrapper

    seen = []
    learn = exp_manager.ReserveExperimentManager.learn
    monkeypatch.setattr(exp_manager.ReserveExperimentManager, "learn",
                        lambda self, model: (seen.append(model), learn(self, model))[1])
    create_envs = exp_manager.ReserveExperimentManager.create_envs

    def recording_create_envs(self, *args, **kwargs):
        seen.append(create_envs(self, *args, **kwargs))
        return seen[-1]

    monkeypatch.setattr(exp_manager.ReserveExperimentManager, "create_envs", recording_create_envs)
    params = ["n_steps:32", "batch_size:64"] + (["random_label:True"] if random_label else [])
    assert train_main(["--algo", "oracle_ppo", "-n", "64", "--seed", "1", "-f", str(tmp_path), "--eval-freq", "32",
                       "--eval-episodes", "1", "--team-eval-episodes", "0", "--verbose", "0", "-params", *params,
                       *TINY]) == 0
    model, envs = seen[-1], seen[:-1]
    assert len(envs) == 2  # the training and the evaluation environment
    assert find_wrapper(model.get_env(), ModeObservationWrapper).random_labels is random_label
    assert all(find_wrapper(env, ModeObservationWrapper).random_labels is random_label for env in envs)
