"""Fuzz cases of the zoo's hyperparameters (YAML files and ``-params``) and flags, and their runner.

Used by ``tests/test_fuzz_zoo.py`` and ``benchmarks/fuzz_zoo.py``. Each case is a ``zoo/train.py``
command line (with a YAML file written for it when the case mutates one) and a label, valid or
invalid, that comes from the catalogue below, not from the code under test, so that a silent
acceptance shows. Running a case calls ``train_main`` in this process on a tiny reserve and a
one-rollout budget; its outcome is one of:

- ``ran``: exit code 0 for a valid case;
- ``clean``: exit code 2, an ``error:`` line naming the argument, and no run folder left, for an invalid case;
- ``silent``: an invalid case that ran (a failure);
- ``rejected``: a valid case refused (a failure);
- ``unclear``: an error that does not name the argument, an exit code other than 0 or 2, any other
  exception, or a folder left behind (a failure);
- ``hang``: longer than the time limit (a failure).
"""

from __future__ import annotations

import contextlib
import io
import signal
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from sb3_emmarl.zoo.exp_manager import zoo_hyperparams

TINY = ["--env-kwargs", "n_uavs:2", "grid_size:20", "max_cycles:40"]
QUICK = ["--eval-freq", "-1", "--team-eval-episodes", "0", "--verbose", "0", "--seed", "0"]
FAILURES = ("silent", "rejected", "unclear", "hang")

# What each fuzzed hyperparameter accepts (the oracle): a kind per name.
KINDS = {
    "ppo": {"n_steps": "int>=1", "batch_size": "int>=1", "n_epochs": "int>=1", "n_envs": "int>=1", "gamma": "prob",
            "gae_lambda": "prob", "learning_rate": "float>0", "clip_range": "float>0", "ent_coef": "float>=0",
            "vf_coef": "float>=0", "max_grad_norm": "float>0", "normalize_advantage": "bool", "normalize": "bool"},
    "dqn": {"buffer_size": "int>=1", "learning_starts": "int>=0", "batch_size": "int>=1", "gamma": "prob",
            "train_freq": "int>=1", "target_update_interval": "int>=1", "exploration_fraction": "prob",
            "exploration_final_eps": "prob", "tau": "prob", "learning_rate": "float>0", "n_envs": "int>=1"},
    "em_ppo": {"e_step_interval": "int>=1", "likelihood_temperature": "float>0",
               "fusion": "bool", "team_pooling": "bool", "use_latent": "bool", "freeze_e_step": "bool",
               "freeze_m_step": "bool", "n_steps": "int>=1", "gamma": "prob"},
}
# Values (YAML text) and the kinds that accept them.
VALUES = {
    "'abc'": (), "'4'": (), "[1]": (), "{}": (), "null": (), "true": ("bool",), "'true'": (),
    "0": ("int>=0", "prob", "float>=0"), "-1": (), "1.5": ("float>0", "float>=0"), ".nan": (), ".inf": (), "-.inf": (),
    "1.0e+30": (), "3": ("int>=1", "int>=0", "float>0", "float>=0"),
}
# Whole-file and structural cases: (name, YAML text or a mutation of the algorithm's entry, mentions).
STRUCTURE = [
    ("empty file", "", "must map"),
    ("a list", "- 1\n- 2\n", "must map"),
    ("entry not a mapping", "WildlifeReserve-v0: [1, 2]\n", "no mapping of hyperparameters"),
    ("no entry", "CartPole-v1:\n  n_timesteps: 10\n", "no mapping of hyperparameters"),
    ("syntax error", "WildlifeReserve-v0:\n  n_timesteps: [1,\n", "not valid YAML"),
    ("python tag", "WildlifeReserve-v0: !!python/object/apply:os.getcwd []\n", "Python object tag"),
]
MUTATIONS = [  # (algo, key, YAML value, valid?, mention)
    ("ppo", "n_stepz", "32", False, "n_stepz"),
    ("ppo", "seed", "3", False, "seed"),
    ("ppo", "env", "'CartPole-v1'", False, "env"),
    ("ppo", "policy_kwargs", "'dict(net_arch=[-5])'", False, "net_arch"),
    ("ppo", "policy_kwargs", "'dict(net_arch=[64,'", False, "policy_kwargs"),
    ("ppo", "policy_kwargs", "\"__import__('os').getcwd()\"", False, "policy_kwargs"),
    ("ppo", "policy_kwargs", "5", False, "policy_kwargs"),
    ("ppo", "policy_kwargs", "'dict(net_arch=dict(pi=[32], vf=[32]))'", True, ""),
    ("ppo", "policy_kwargs", "'dict(net_arch=dict(pi=[32], xx=[32]))'", False, "net_arch"),
    ("ppo", "policy", "5", False, "policy"),
    ("ppo", "learning_rate", "'lin_3e-4'", True, ""),
    ("ppo", "learning_rate", "'lin_abc'", False, "learning_rate"),
    ("ppo", "learning_rate", "'exp_3e-4'", False, "learning_rate"),
    ("ppo", "env_kwargs", "'x'", False, "env_kwargs"),
    ("ppo", "env_kwargs", "{adversarial: 'false'}", False, "adversarial"),
    ("ppo", "env_kwargs", "{n_uavs: 1000000000}", False, "n_uavs"),
    ("ppo", "env_kwargs", "{continuous_actions: 0}", False, "continuous_actions"),
    ("ppo", "n_timesteps", "-5", False, "n_timesteps"),
    ("ppo", "n_timesteps", "0", False, "n_timesteps"),
    ("ppo", "n_timesteps", "'abc'", False, "n_timesteps"),
    ("ppo", "n_timesteps", "64", True, ""),
    ("ppo", "n_timesteps", "64.5", False, "n_timesteps"),
    ("ppo", "n_steps", "1000000", False, "n_steps"),  # within the bound, beyond this machine's memory (10 UAVs)
    ("dqn", "buffer_size", "9000000", False, "buffer_size"),
    ("dqn", "train_freq", "[4, 'step']", True, ""),
    ("dqn", "train_freq", "[4, 'week']", False, "train_freq"),
    ("dqn", "gradient_steps", "-1", True, ""),
    ("dqn", "gradient_steps", "0", False, "gradient_steps"),
    ("em_ppo", "decoder_hidden", "'64'", False, "decoder_hidden"),
    ("em_ppo", "decoder_hidden", "[0]", False, "decoder_hidden"),
    ("em_ppo", "decoder_hidden", "[32, 32]", True, ""),
    ("em_ppo", "estimator", "'bayes'", False, "estimator"),
    ("em_ppo", "e_step_kwargs", "{n_epochs: 0}", False, "e_step_kwargs"),
    ("em_ppo", "e_step_kwargs", "{bogus: 1}", False, "e_step_kwargs"),
    ("em_ppo", "e_step_kwargs", "'abc'", False, "e_step_kwargs"),
    ("em_ppo", "e_step_kwargs", "{learning_rate: .nan}", False, "e_step_kwargs"),
    ("em_ppo", "e_step_kwargs", "{window: 2, n_epochs: 1}", True, ""),
    # n_components must fit em_ppo.yml's count_factors [4, 2] (their product)
    ("em_ppo", "n_components", "8", True, ""),
    ("em_ppo", "n_components", "3", False, "count_factors"),
    ("em_ppo", "n_components", "0", False, "n_components"),
    ("em_ppo", "n_components", "'abc'", False, "n_components"),
    ("em_ppo", "count_factors", "null", True, ""),
    ("em_ppo", "count_factors", "[8, 1]", True, ""),
    ("em_ppo", "count_factors", "[4, 3]", False, "count_factors"),
    ("em_ppo", "count_factors", "[4]", False, "count_factors"),
    ("em_ppo", "count_factors", "'4x2'", False, "count_factors"),
    ("em_ppo", "count_factors", "[4, 2.5]", False, "count_factors"),
]
# Flags: (flags, valid?, mention)
FLAGS = [
    *[([flag, value], False, flag) for flag in ("--eval-episodes", "--n-eval-envs", "--n-trials", "--n-jobs")
      for value in ("0", "-5", "abc", "1.5", "99999999999")],
    *[([flag, value], False, flag) for flag in ("--seed", "-n", "--save-freq", "--eval-freq", "--team-eval-episodes",
                                                "--num-threads", "--verbose", "--log-interval")
      for value in ("-7", "abc", "2.5", "99999999999999")],
    (["--device", "gpu0"], False, "--device"),
    (["--algo", "sac"], False, "--algo"),
    (["--env", "CartPole-v1"], False, "--env"),
    (["-i", "missing.zip"], False, "-i"),
    (["--conf-file", "missing.yml"], False, "--conf-file"),
    (["--env-kwargs", "n_uavs=3"], False, "--env-kwargs"),
    (["--env-kwargs", "region:forest"], False, "--env-kwargs"),
    (["-params", "n_steps:'abc'"], False, "n_steps"),
    (["-params", "n_envs:'4'"], False, "n_envs"),
    (["-params", "n_epochs:True"], False, "n_epochs"),
    (["-params", "gamma:[0.9]"], False, "gamma"),
    (["-params", "ent_coef:-1"], False, "ent_coef"),
    (["-params", "n_steps:16"], True, ""),
    (["--vec-env", "threads"], False, "--vec-env"),
    (["--resume", "no/such/run"], False, "--resume"),
    (["--save-freq", "0"], True, ""),
    (["--seed", "-1"], True, ""),
]


@dataclass
class Case:
    """One command line; ``yaml_text`` (if set) is written to a file passed with ``-conf``."""

    name: str
    argv: list[str]
    valid: bool
    mention: str
    yaml_text: str | None = None
    extra: list[str] = field(default_factory=list)


def _entry(algo: str) -> dict:
    return zoo_hyperparams(algo)


def _mutated(algo: str, key: str, value: str) -> str:
    entry = yaml.safe_dump({"WildlifeReserve-v0": _entry(algo)})
    return entry.rstrip("\n") + f"\n  {key}: {value}\n" if key not in _entry(algo) else \
        yaml.safe_dump({"WildlifeReserve-v0": {**_entry(algo), key: "__VALUE__"}}).replace("__VALUE__", value)


def cases() -> list[Case]:
    """Every case, in a fixed order."""
    out: list[Case] = []
    for algo, kinds in KINDS.items():
        for key, kind in kinds.items():
            for value, accepting in VALUES.items():
                valid = kind in accepting
                budget = ["-n", "64"]
                out.append(Case(f"{algo} {key}: {value}", ["--algo", algo, *budget], valid, key,
                                _mutated(algo, key, value)))
    for name, text, mention in STRUCTURE:
        out.append(Case(f"yaml {name}", ["--algo", "ppo", "-n", "64"], False, mention, text))
    for algo, key, value, valid, mention in MUTATIONS:
        budget = [] if key == "n_timesteps" else ["-n", "64"]
        if key == "n_steps":
            budget += ["--env-kwargs", "n_uavs:10"]  # the default reserve: the buffer's size is the point
        out.append(Case(f"{algo} {key}: {value}", ["--algo", algo, *budget], valid, mention, _mutated(algo, key, value)))
    for flags, valid, mention in FLAGS:
        budget = [] if "-n" in flags else ["-n", "64"]
        out.append(Case(f"flags {' '.join(flags)}", ["--algo", "ppo", *budget, *flags], valid, mention))
    return out


class _Timeout(Exception):
    pass


def _alarm(signum, frame):
    raise _Timeout


def run_case(case: Case, folder: Path, time_limit: int = 60) -> tuple[str, str]:
    """Run one case in ``folder`` (a fresh, empty folder); return its outcome and the text it printed."""
    from sb3_emmarl.zoo.cli import train_main

    folder.mkdir(parents=True, exist_ok=True)
    logs = folder / "logs"
    argv = list(case.argv)
    if case.yaml_text is not None:
        conf = folder / "conf.yml"
        conf.write_text(case.yaml_text)
        argv += ["-conf", str(conf)]
    argv = [*argv, *QUICK, *(TINY if "--env-kwargs" not in argv and "env_kwargs" not in case.name else []),
            "-f", str(logs)]
    out, err = io.StringIO(), io.StringIO()
    previous = signal.signal(signal.SIGALRM, _alarm)
    signal.alarm(time_limit)
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                code = train_main(argv)
            except SystemExit as exit_info:
                code = exit_info.code
    except _Timeout:
        return "hang", err.getvalue()
    except Exception as error:
        return "unclear", f"{type(error).__name__}: {error}"
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)
    text = err.getvalue()
    if code == 0:
        return ("ran" if case.valid else "silent"), text
    left = [p for p in logs.rglob("*")] if logs.exists() else []
    if code == 2 and "error:" in text and case.mention in text and not left:
        return ("clean" if not case.valid else "rejected"), text
    return ("rejected" if case.valid and code == 2 and not left else "unclear"), text + (f"\nleft: {left}" if left else "")
