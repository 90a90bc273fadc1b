"""Issue 52, items 6 and 8: settings that would fail in the first rollout or update fail before the run folder exists,
with one line and nothing left behind; --resume falls back to the newest checkpoint that loads; devices, algorithms and
runs that do not match are refused with one line."""

import shutil

import optuna
import pytest
import torch as th
import yaml
from fuzz_zoo import QUICK, TINY, train_template_run

from sb3_emmarl.common.checkpoints import TRAINING_STATE, companion, list_checkpoints
from sb3_emmarl.common.trust.signatures import check_arguments, check_optimizer, conforms
from sb3_emmarl.zoo.algos import ZOO_ALGOS, convert_latent_params, merge_hyperparams
from sb3_emmarl.zoo.cli import make_manager, train_main, train_parser
from sb3_emmarl.zoo.exp_manager import zoo_hyperparams

ENV = "WildlifeReserve-v1"
CALLBACK = "stable_baselines3.common.callbacks.StopTrainingOnMaxEpisodes"


@pytest.fixture(autouse=True)
def one_thread():
    th.set_num_threads(1)


def run(tmp_path, capsys, *argv, conf=None):
    """``train_main`` on a tiny reserve into ``tmp_path/logs`` (tensorboard into ``tmp_path/tb``); returns the exit
    code and the lines it printed on stderr."""
    extra = []
    if conf is not None:
        extra = ["-conf", str(tmp_path / "conf.yml")]
        (tmp_path / "conf.yml").write_text(conf if isinstance(conf, str) else yaml.safe_dump({ENV: conf}))
    capsys.readouterr()
    try:
        code = train_main([*argv, "-n", "64", *QUICK, *TINY, "-f", str(tmp_path / "logs"), *extra])
    except SystemExit as exit_info:
        code = exit_info.code
    return code, capsys.readouterr().err.strip().splitlines()


def ppo_with(**settings):
    return {**zoo_hyperparams("ppo"), **settings}


FILE_CASES = {  # name: (algo, the YAML entry (or text), what the one line names)
    "ent_coef 'auto' for PPO (only SAC takes it)": ("ppo", ppo_with(ent_coef="auto"), "ent_coef must be a number for PPO"),
    "ent_coef 'auto' for A2C": ("a2c", {**zoo_hyperparams("a2c"), "ent_coef": "auto_0.1"}, "ent_coef must be a number"),
    "an optimizer class given as a string": ("ppo", ppo_with(policy_kwargs={"optimizer_class": "th.optim.LBFGS"}),
                                             "optimizer_class must be a class derived from Optimizer"),
    "an activation given as a string": ("ppo", ppo_with(policy_kwargs={"activation_fn": "relu"}),
                                        "activation_fn must be a class derived from Module"),
    "optimizer arguments the optimizer does not take": (
        "ppo", ppo_with(policy_kwargs="dict(optimizer_class=th.optim.SGD, optimizer_kwargs=dict(betas=(0.9, 0.99)))"),
        "cannot be stepped as SB3 steps it"),
    "optimizer arguments out of range": ("ppo", ppo_with(policy_kwargs="dict(optimizer_kwargs=dict(eps=-1.0))"),
                                         "cannot be stepped"),
    "a policy argument the policy does not take": ("ppo", ppo_with(policy_kwargs={"bogus": 1}),
                                                   "'bogus' is not an argument of ActorCriticPolicy"),
    "a callback whose argument is not of its type": ("ppo", ppo_with(callback={CALLBACK: {"max_episodes": "abc"}}),
                                                     "max_episodes must be an int"),
    "a callback without its required argument": ("ppo", ppo_with(callback=CALLBACK), "missing keyword argument"),
    "a wrapper whose parts are one string": (
        "ppo", ppo_with(vec_env_wrapper={"sb3_emmarl.common.masking.HideObservationParts": {"parts": "mode"}}),
        "parts must be a list"),
    "gSDE with discrete actions": ("ppo", ppo_with(use_sde=True), "gSDE"),
    "a self-referencing anchor": ("ppo", f"{ENV}: &e\n  <<: *e\n  n_timesteps: 64\n  policy: MlpPolicy\n", "recursive"),
    "an anchor used inside itself": ("ppo", f"{ENV}: &e\n  n_timesteps: 64\n  policy_kwargs: *e\n", "recursive"),
}


@pytest.mark.parametrize("name", list(FILE_CASES))
def test_a_setting_that_would_fail_mid_run_fails_first_with_one_line_and_no_folder(tmp_path, capsys, name):
    algo, conf, message = FILE_CASES[name]
    code, lines = run(tmp_path, capsys, "--algo", algo, "-tb", str(tmp_path / "tb"), conf=conf)
    assert code == 2 and len(lines) == 1 and lines[0].startswith("error:") and message in lines[0], lines
    assert not (tmp_path / "logs").exists() and not (tmp_path / "tb").exists()


@pytest.mark.parametrize(("conf", "params", "key"), [({"bogus": 1}, [], "'bogus'"), ({"gamma": 2.0}, [], "gamma"),
                                                    ({}, ["gamma:2.0"], "gamma"), ({"ent_coef": "auto"}, [], "ent_coef")])
def test_an_error_names_the_file_and_the_key(tmp_path, capsys, conf, params, key):
    code, lines = run(tmp_path, capsys, "--algo", "ppo", *(["-params", *params] if params else []), conf=ppo_with(**conf))
    source = f"{tmp_path / 'conf.yml'}{' with -params' if params else ''}: "
    assert code == 2 and len(lines) == 1 and lines[0].startswith(f"error: {source}") and key in lines[0], lines


@pytest.mark.parametrize("params", [["ent_coef:'auto'"], ["policy_kwargs:dict(optimizer_class=th.optim.LBFGS)"],
                                    ["policy_kwargs:dict(optimizer_kwargs=dict(momentum=0.9))"]])
def test_the_same_from_params(tmp_path, capsys, params):
    code, lines = run(tmp_path, capsys, "--algo", "ppo", "-params", *params)
    assert code == 2 and len(lines) == 1 and "error:" in lines[0], lines
    assert not (tmp_path / "logs").exists()


@pytest.mark.parametrize("where", ["file", "file/tb"])
def test_a_tensorboard_folder_that_is_or_lies_under_a_file_is_refused_first(tmp_path, capsys, where):
    (tmp_path / "file").write_text("")
    code, lines = run(tmp_path, capsys, "--algo", "ppo", "-tb", str(tmp_path / where))
    assert code == 2 and len(lines) == 1 and "--tensorboard-log" in lines[0] and "which is a file" in lines[0], lines
    assert not (tmp_path / "logs").exists()


def test_a_model_that_fails_to_build_leaves_no_log_folder(tmp_path, capsys, monkeypatch):
    """What no check foresees (here a reserve that fails once the run folder exists) still leaves nothing behind."""
    from sb3_emmarl.zoo.exp_manager import ReserveExperimentManager

    def broken(self, *args, **kwargs):
        raise RuntimeError("no environment today")

    monkeypatch.setattr(ReserveExperimentManager, "create_envs", broken)
    code, lines = run(tmp_path, capsys, "--algo", "ppo", "-tb", str(tmp_path / "tb"))
    assert code == 2 and lines == ["error: no environment today"]
    assert not (tmp_path / "logs").exists() and not (tmp_path / "tb").exists()


def test_every_zoo_yaml_passes_the_checks_without_making_a_folder(tmp_path):
    for env in ("WildlifeReserve-v1", "ZonePatrol-v0"):
        for algo in sorted(ZOO_ALGOS):
            try:
                zoo_hyperparams(algo, env)
            except ValueError:  # no section for this environment
                continue
            args = train_parser().parse_args(["--algo", algo, "--env", env, "-f", str(tmp_path / "logs"), "--verbose",
                                              "0", "--seed", "0", "-tb", str(tmp_path / "tb")])
            manager = make_manager(args)
            hyperparams, _ = manager.read_hyperparameters()
            manager._preprocess_hyperparams(hyperparams)  # the checks before the folder
    assert not (tmp_path / "logs").exists()


def test_conforms_reads_the_outer_type():
    assert conforms(3, float) and not conforms(True, float) and not conforms("auto", float)
    assert conforms("auto", str | float) and conforms(None, int | None) and not conforms(1.5, int)
    assert conforms([64, 64], tuple[int, ...]) and not conforms("64", list[int])
    assert conforms(th.optim.Adam, type[th.optim.Optimizer]) and not conforms(th.nn.ReLU, type[th.optim.Optimizer])
    with pytest.raises(ValueError, match="ent_coef must be a number for PPO"):
        check_arguments(ZOO_ALGOS["ppo"], {"ent_coef": "auto"}, "the hyperparameters")
    with pytest.raises(ValueError, match="without a closure"):
        check_optimizer(th.optim.LBFGS, None, "policy_kwargs")
    check_optimizer(th.optim.SGD, {"momentum": 0.9}, "policy_kwargs")


# ---------------------------------------------------------------------------------------------- item 8
@pytest.fixture(scope="module")
def template(tmp_path_factory):
    """A tiny finished PPO run with checkpoints (tests/fuzz_zoo.py's)."""
    th.set_num_threads(1)
    return train_template_run(tmp_path_factory.mktemp("template"))


def stopped_copy(template, tmp_path):
    run = tmp_path / "logs" / "ppo" / template.name
    shutil.copytree(template, run)
    (run / f"{ENV}.zip").unlink()
    return run


def resume(capsys, *argv):
    capsys.readouterr()
    try:
        code = train_main(["--verbose", "0", *argv])
    except SystemExit as exit_info:
        code = exit_info.code
    out = capsys.readouterr()
    return code, out.out, out.err.strip().splitlines()


def test_a_run_folder_states_one_budget_and_checkpoints_count_agent_steps(template):
    """-n 384 --save-freq 128 (tests/fuzz_zoo.py's template): config.yml says the budget args.yml says, and the
    checkpoints fall every 128 agent-steps."""
    config = yaml.safe_load((template / ENV / "config.yml").read_text())
    arguments = yaml.safe_load((template / ENV / "args.yml").read_text())
    assert config["n_timesteps"] == arguments["n_timesteps"] == 384
    assert [steps for steps, _ in list_checkpoints(template)] == [128, 256]


@pytest.mark.parametrize("broken", ["zip", "training state"])
def test_resume_falls_back_to_the_newest_checkpoint_that_loads(template, tmp_path, capsys, broken):
    run = stopped_copy(template, tmp_path)
    (_, newest), (steps, previous) = list_checkpoints(run)[-1], list_checkpoints(run)[-2]
    target = newest if broken == "zip" else companion(newest, TRAINING_STATE)
    target.write_bytes(target.read_bytes()[: target.stat().st_size // 2])  # cut short by a crash
    code, out, err = resume(capsys, "--resume", str(run))
    assert code == 0, err
    line = next(line for line in out.splitlines() if line.startswith("Resuming"))
    assert f"from {previous.name} (step {steps}" in line and f"newer checkpoints that do not load: {newest.name}" in line
    assert (run / f"{ENV}.zip").is_file()


def test_resume_without_any_checkpoint_that_loads_is_refused_with_one_line(template, tmp_path, capsys):
    run = stopped_copy(template, tmp_path)
    for _, path in list_checkpoints(run):
        path.write_bytes(b"not a zip")
    before = set(run.rglob("*"))
    code, _, err = resume(capsys, "--resume", str(run))
    assert code == 2 and len(err) == 1 and "none of the run's" in err[0] and "checkpoints loads" in err[0], err
    assert set(run.rglob("*")) == before


def test_a_resumed_start_that_fails_adds_nothing_to_the_run(template, tmp_path, capsys, monkeypatch):
    """A failure after the resumed run's environment is built (its new resumed_*.monitor.csv) leaves the folder as it
    was."""
    from sb3_emmarl.zoo.exp_manager import ReserveExperimentManager

    def broken(self, hyperparams, env):
        raise ValueError("the checkpoint does not fit")

    monkeypatch.setattr(ReserveExperimentManager, "_load_pretrained_agent", broken)
    run = stopped_copy(template, tmp_path)
    before = set(run.rglob("*"))
    code, _, err = resume(capsys, "--resume", str(run))
    assert code == 2 and err == ["error: the checkpoint does not fit"]
    assert set(run.rglob("*")) == before and not list(run.glob("resumed_*"))


@pytest.mark.parametrize(("flags", "message"), [
    (["--algo", "a2c"], "--algo 'a2c' (the run's: 'ppo')"),
    (["--algo", "em_ppo", "-n", "5000"], "-n-timesteps"),
    (["--env", "ZonePatrol-v0"], "--env 'ZonePatrol-v0'"),
    (["--device", "cpu", "--seed", "7"], "--seed 7"),
])
def test_resume_refuses_flags_that_differ_from_the_runs_own(template, tmp_path, capsys, flags, message):
    run = stopped_copy(template, tmp_path)
    before = set(run.rglob("*"))
    code, _, err = resume(capsys, "--resume", str(run), *flags)
    assert code == 2 and len(err) == 1 and "differ" in err[0] and message in err[0], err
    assert set(run.rglob("*")) == before
    # the run's own values (and output flags) are taken
    code, _, err = resume(capsys, "--resume", str(run), "--algo", "ppo")
    assert code == 0, err


@pytest.mark.parametrize("device", ["cuda:99", "xla", "tpu", "meta"])
def test_a_device_this_machine_has_not_is_refused_with_one_line(tmp_path, capsys, device):
    if device.startswith("cuda") and th.cuda.device_count() > 99:
        pytest.skip("a machine with 100 GPUs")
    code, lines = run(tmp_path, capsys, "--algo", "ppo", "--device", device)
    assert code == 2 and len(lines) == 1 and "--device" in lines[0], lines
    assert not (tmp_path / "logs").exists()


def test_a_zip_of_another_algorithm_is_refused_with_one_line(template, tmp_path, capsys):
    code, lines = run(tmp_path, capsys, "--algo", "em_ppo", "-i", str(template / f"{ENV}.zip"))
    assert code == 2 and len(lines) == 1 and "was not saved by EMPPO" in lines[0], lines
    assert not (tmp_path / "logs").exists()


def test_an_a2c_zip_is_refused_by_ppo(tmp_path, capsys):
    assert train_main(["--algo", "a2c", "-n", "64", *QUICK, *TINY, "-f", str(tmp_path / "a2c_logs")]) == 0
    code, lines = run(tmp_path, capsys, "--algo", "ppo", "-i", str(tmp_path / "a2c_logs" / "a2c" / f"{ENV}_1" / f"{ENV}.zip"))
    assert code == 2 and len(lines) == 1 and "was not saved by PPO: its settings fit a2c" in lines[0], lines
    assert not (tmp_path / "logs").exists()


def test_a_refused_optimization_leaves_no_log_folder(tmp_path, capsys):
    code, lines = run(tmp_path, capsys, "--algo", "ppo", "-optimize", "-params", "ent_coef:'auto'")
    assert code == 2 and len(lines) == 1, lines
    assert not (tmp_path / "logs").exists()


def test_cppo_checkpoints_and_resumes_with_its_monitor_files(tmp_path, capsys):
    """The centralised path's DummyVecEnv holds SB3 Monitors with open files: the training state keeps them out."""
    logs = tmp_path / "logs"
    assert train_main(["--algo", "cppo", "-n", "512", "--save-freq", "8", *QUICK, *TINY, "-f", str(logs),
                       "-params", "n_steps:16", "batch_size:32"]) == 0
    run = logs / "cppo" / f"{ENV}_1"
    assert [steps for steps, _ in list_checkpoints(run)] == [128, 256, 384]
    for path in [run / f"{ENV}.zip", *run.glob("rl_model_*256_steps*"), *run.glob("rl_model_*384_steps*")]:
        path.unlink()  # stopped after its first checkpoint: 384 steps (48 per copy) to go, an episode (40) among them
    monitor = (run / "0.monitor.csv").read_text()
    assert train_main(["--algo", "cppo", "--resume", str(run), "--verbose", "0"]) == 0
    assert (run / f"{ENV}.zip").is_file()
    after = (run / "0.monitor.csv").read_text()
    assert after.startswith(monitor) and after.count("\n") > monitor.count("\n")  # appended to, not started again


# ---------------------------------------------------------------------------------------------- issue 53, item 6
def test_em_settings_merge_into_the_yamls():
    base = zoo_hyperparams("em_ppo")
    yaml_latent = base["latent_kwargs"]

    def latent(changes):
        return merge_hyperparams(base, {"latent_kwargs": changes})["latent_kwargs"]

    merged = latent({"n_components": 4, "e_step_kwargs": {"window": 4}})
    assert merged["e_step_kwargs"] == {**yaml_latent["e_step_kwargs"], "window": 4} and merged["count_factors"] == [2, 2]
    assert merged["likelihood_temperature"] == yaml_latent["likelihood_temperature"]  # the YAML's other fields stay
    assert latent({"n_components": 8})["count_factors"] == [4, 2]  # the YAML's [4, 2] still fits
    assert latent({"n_components": 1})["count_factors"] is None
    assert latent({"n_components": 4, "count_factors": [4, 1]})["count_factors"] == [4, 1]  # given: kept
    assert merge_hyperparams(base, {"gamma": 0.9})["latent_kwargs"] == yaml_latent
    assert convert_latent_params({"n_components": 2, "e_step_window": 8, "gamma": 0.9}) == {
        "latent_kwargs": {"n_components": 2, "e_step_kwargs": {"window": 8}}}


@pytest.mark.parametrize("algo", ["em_ppo", "em_ddpg", "vdn_em"])
def test_em_samplers_add_ems_settings_to_the_base_ones(algo):
    from rl_zoo3.hyperparams_opt import HYPERPARAMS_CONVERTER, HYPERPARAMS_SAMPLER

    from sb3_emmarl.zoo.algos import register_algorithms

    register_algorithms()
    trial = optuna.create_study().ask()
    sampled = HYPERPARAMS_SAMPLER[algo](trial, 3, 8, {"using_her_replay_buffer": False, "her_kwargs": {}})
    assert {"n_components", "likelihood_temperature", "e_step_interval", "e_step_kwargs"} <= set(sampled["latent_kwargs"])
    assert {"n_components", "likelihood_temperature", "e_step_interval", "e_step_window"} <= set(trial.params)
    assert "learning_rate" in trial.params  # the base algorithm's sampler ran too
    converted = HYPERPARAMS_CONVERTER[algo](trial.params)
    assert converted["latent_kwargs"]["e_step_kwargs"] == {"window": trial.params["e_step_window"]}


def test_optimize_em_ppo_searches_ems_settings_into_a_sqlite_study(tmp_path, capsys):
    storage = f"sqlite:///{tmp_path / 'study.db'}"
    code, lines = run(tmp_path, capsys, "--algo", "em_ppo", "-optimize", "--n-trials", "2", "--n-evaluations", "1",
                      "--sampler", "random", "--pruner", "none", "--eval-episodes", "1", "--no-optim-plots",
                      "--storage", storage, "--study-name", "em", "-params", "n_envs:1")  # one reserve copy: short rollouts
    assert code == 0, lines
    study = optuna.load_study(study_name="em", storage=storage)
    assert len(study.trials) == 2
    assert all(t.state == optuna.trial.TrialState.COMPLETE for t in study.trials), [t.state for t in study.trials]
    for trial in study.trials:
        assert {"n_components", "likelihood_temperature", "e_step_interval", "e_step_window"} <= set(trial.params)
