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
    "em_ppo": {"latent_kwargs.e_step_interval": "int>=1", "latent_kwargs.likelihood_temperature": "float>0",
               "latent_kwargs.fusion": "bool", "latent_kwargs.team_pooling": "bool", "latent_kwargs.use_latent": "bool",
               "latent_kwargs.freeze_e_step": "bool", "latent_kwargs.freeze_m_step": "bool", "n_steps": "int>=1",
               "gamma": "prob"},
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
    ("entry not a mapping", "WildlifeReserve-v1: [1, 2]\n", "no mapping of hyperparameters"),
    ("no entry", "CartPole-v1:\n  n_timesteps: 10\n", "no mapping of hyperparameters"),
    ("syntax error", "WildlifeReserve-v1:\n  n_timesteps: [1,\n", "not valid YAML"),
    ("python tag", "WildlifeReserve-v1: !!python/object/apply:os.getcwd []\n", "Python object tag"),
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
    ("em_ppo", "latent_kwargs.decoder_hidden", "'64'", False, "decoder_hidden"),
    ("em_ppo", "latent_kwargs.decoder_hidden", "[0]", False, "decoder_hidden"),
    ("em_ppo", "latent_kwargs.decoder_hidden", "[32, 32]", True, ""),
    ("em_ppo", "latent_kwargs.estimator", "'bayes'", False, "estimator"),
    ("em_ppo", "latent_kwargs.e_step_kwargs", "{n_epochs: 0}", False, "e_step_kwargs"),
    ("em_ppo", "latent_kwargs.e_step_kwargs", "{bogus: 1}", False, "e_step_kwargs"),
    ("em_ppo", "latent_kwargs.e_step_kwargs", "'abc'", False, "e_step_kwargs"),
    ("em_ppo", "latent_kwargs.e_step_kwargs", "{learning_rate: .nan}", False, "e_step_kwargs"),
    ("em_ppo", "latent_kwargs.e_step_kwargs", "{window: 2, n_epochs: 1}", True, ""),
    # n_components must fit em_ppo.yml's count_factors [4, 2] (their product)
    ("em_ppo", "n_components", "8", False, "latent_kwargs"),  # a latent setting at the top level (as up to 0.22.0)
    ("em_ppo", "latent_kwargs", "{n_componentz: 8}", False, "n_componentz"),
    ("em_ppo", "latent_kwargs.n_components", "8", True, ""),
    ("em_ppo", "latent_kwargs.n_components", "3", False, "count_factors"),
    ("em_ppo", "latent_kwargs.n_components", "0", False, "n_components"),
    ("em_ppo", "latent_kwargs.n_components", "'abc'", False, "n_components"),
    ("em_ppo", "latent_kwargs.count_factors", "null", True, ""),
    ("em_ppo", "latent_kwargs.count_factors", "[8, 1]", True, ""),
    ("em_ppo", "latent_kwargs.count_factors", "[4, 3]", False, "count_factors"),
    ("em_ppo", "latent_kwargs.count_factors", "[4]", False, "count_factors"),
    ("em_ppo", "latent_kwargs.count_factors", "'4x2'", False, "count_factors"),
    ("em_ppo", "latent_kwargs.count_factors", "[4, 2.5]", False, "count_factors"),
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
    """The algorithm's zoo entry with ``key`` set to the YAML text ``value`` (``outer.inner``: a field of a mapping, as
    ``latent_kwargs.n_components``)."""
    entry = _entry(algo)
    if "." in key:
        outer, inner = key.split(".")
        entry = {**entry, outer: {**(entry.get(outer) or {}), inner: "__VALUE__"}}
    elif key not in entry:
        return yaml.safe_dump({"WildlifeReserve-v1": entry}).rstrip("\n") + f"\n  {key}: {value}\n"
    else:
        entry = {**entry, key: "__VALUE__"}
    return yaml.safe_dump({"WildlifeReserve-v1": entry}).replace("__VALUE__", value)


def cases() -> list[Case]:
    """Every case, in a fixed order."""
    out: list[Case] = []
    for algo, kinds in KINDS.items():
        for key, kind in kinds.items():
            for value, accepting in VALUES.items():
                valid = kind in accepting
                budget = ["-n", "64"]
                out.append(Case(f"{algo} {key}: {value}", ["--algo", algo, *budget], valid, key.split(".")[-1],
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


# ---------------------------------------------------------------------------------------------- hostile cases
# Issue 52: command lines, config files and run folders that try to run code. Every case tries to create the file
# ``<case folder>/marker``; the zoo must refuse each with exit code 2 and one ``error:`` line, before anything runs.
# ``{m}`` stands for the marker's path.
PY_PAYLOADS = [
    "[c for c in ().__class__.__base__.__subclasses__() if c.__name__ == '_wrap_close'][0].__init__.__globals__"
    "['system']('touch {m}')",
    "[x for x in ().__class__.__mro__[1].__subclasses__() if x.__name__ == 'Popen'][0]('touch {m}', shell=True)",
    "__import__('os').system('touch {m}')",
    "th.os.system('touch {m}')",
    "th.save(1, '{m}')",
    "torch.save(1, '{m}')",
    "nn.Module.__init__.__globals__['os'].system('touch {m}')",
    "open('{m}', 'w')",
    "lambda: open('{m}', 'w')",
    "(lambda: __import__('os').system('touch {m}'))()",
    "dict(a=__import__('os').system('touch {m}'))",
    "[__import__('os').system('touch {m}') for _ in [1]]",
    "exec(\"open('{m}', 'w')\")",
    "eval(\"open('{m}', 'w')\")",
    "getattr(__import__('os'), 'system')('touch {m}')",
    "f\"{{open('{m}', 'w')}}\"",
    "__builtins__['open']('{m}', 'w')",
    "globals()['__builtins__'].open('{m}', 'w')",
    "dict(**{{'a': open('{m}', 'w')}})",
    "9**9**9 or open('{m}', 'w')",
    "'x' * 10**10 or open('{m}', 'w')",
    "dict(activation_fn=th.nn.modules.module.os.system('touch {m}'))",
]
# Callables that create the marker when rl_zoo3 imports them by name and calls them with keyword arguments.
CALLABLES = [
    ("pydoc.pipepager", {"text": "x", "cmd": "touch {m}"}),
    ("os.system", {"command": "touch {m}"}),
    ("subprocess.getoutput", {"cmd": "touch {m}"}),
    ("subprocess.run", {"args": "touch {m}", "shell": True}),
    ("io.open", {"file": "{m}", "mode": "w"}),
    ("codecs.open", {"filename": "{m}", "mode": "w"}),
]
# Keys rl_zoo3 evaluates as Python when they hold a string, and an algorithm that takes each.
EVAL_KEYS = [("policy_kwargs", "ppo"), ("normalize", "ppo"), ("monitor_kwargs", "ppo"), ("replay_buffer_kwargs", "dqn"),
             ("replay_buffer_class", "dqn")]
# Keys rl_zoo3 imports by name and calls, and an algorithm whose set-up calls each.
IMPORT_KEYS = [("callback", "ppo"), ("vec_env_wrapper", "ppo"), ("env_wrapper", "cppo")]
BOMB = "".join(["    a: &a [lol, lol, lol, lol, lol, lol, lol, lol, lol]\n"] + [
    f"    {chr(97 + i)}: &{chr(97 + i)} [" + ", ".join([f"*{chr(96 + i)}"] * 9) + "]\n" for i in range(1, 9)])
YAML_CASES = [  # (name, the file's text ({m}: the marker), mention)
    ("billion laughs under monitor_kwargs", "{env}:\n  n_timesteps: 64\n  policy: MlpPolicy\n  monitor_kwargs:\n" + BOMB,
     "expand"),
    ("billion laughs under policy_kwargs", "{env}:\n  n_timesteps: 64\n  policy: MlpPolicy\n  policy_kwargs:\n" + BOMB,
     "expand"),
    ("billion laughs under env_kwargs", "{env}:\n  n_timesteps: 64\n  policy: MlpPolicy\n  env_kwargs:\n" + BOMB,
     "expand"),
    ("recursive alias", "{env}: &e\n  n_timesteps: 64\n  policy: MlpPolicy\n  env_kwargs: *e\n", "recursive"),
    ("python tag os.system", "{env}: !!python/object/apply:os.system ['touch {m}']\n", "Python object tag"),
    ("python tag Popen", "{env}:\n  n_timesteps: !!python/object/new:subprocess.Popen [['touch', '{m}']]\n",
     "Python object tag"),
    ("python tag open", "{env}:\n  policy_kwargs: !!python/object/apply:io.open ['{m}', 'w']\n", "Python object tag"),
    ("python name", "{env}:\n  callback: !!python/name:pydoc.pipepager\n", "Python object tag"),
    ("oversized file", "{env}:\n  n_timesteps: 64\n  monitor_kwargs: {{info_keywords: [" + "'x', " * 300_000 + "]}}\n",
     "bytes"),
    ("deep nesting", "{env}:\n  env_kwargs: " + "[" * 3000 + "]" * 3000 + "\n", "YAML"),
]
# Run-folder keys tampered with in config.yml before --resume or enjoy (value, with {m}).
RUN_CASES = [
    *[("policy_kwargs", payload) for payload in PY_PAYLOADS[:6]],
    ("normalize", "dict(norm_obs=__import__('os').system('touch {m}') == 0)"),
    ("monitor_kwargs", "__import__('os').system('touch {m}') or {{}}"),
    *[(key, {name: kwargs}) for key in ("vec_env_wrapper", "callback") for name, kwargs in CALLABLES[:3]],
    ("policy", "pydoc.pipepager"),
]


# Issue 52, items 6 and 8: settings that SB3 takes and that fail in the first rollout or update, and flags that do not
# fit the run, the zip or the machine. Each must be refused before a folder exists. ``{f}`` stands for a file, ``{t}``
# for the template run's folder (a finished PPO run).
CALLBACK = "stable_baselines3.common.callbacks.StopTrainingOnMaxEpisodes"
HIDE = "sb3_emmarl.common.masking.HideObservationParts"
MID_RUN_PARAMS = [  # (algo, -params values)
    *[(algo, ["ent_coef:'auto'"]) for algo in ("ppo", "a2c", "mappo", "em_ppo", "ppo_lstm", "oracle_ppo", "cppo")],
    ("ppo", ["ent_coef:'auto_0.1'"]),
    *[("ppo", [f"policy_kwargs:dict(optimizer_kwargs=dict({kwargs}))"]) for kwargs in (
        "momentum=0.9", "eps=-1.0", "betas=(2.0, 0.5)", "lr=0.1", "weight_decay=-1.0", "betas=(0.9,)")],
    ("ppo", ["policy_kwargs:dict(optimizer_class=th.optim.SGD, optimizer_kwargs=dict(betas=(0.9, 0.99)))"]),
    ("ppo", ["policy_kwargs:dict(optimizer_class=th.optim.LBFGS)"]),
    ("ppo", ["policy_kwargs:dict(bogus=1)"]),
    ("ppo", ["policy_kwargs:dict(ortho_init='{m}')"]),
    ("ppo", ["policy_kwargs:dict(log_std_init='x')"]),
    ("ppo", ["policy_kwargs:dict(features_extractor_kwargs=5)"]),
    ("ppo", ["policy_kwargs:dict(share_features_extractor='no')"]),
    ("ppo", ["use_sde:True"]),
    ("dqn", ["policy_kwargs:dict(optimizer_kwargs=dict(momentum=0.9))"]),
    ("em_ppo", ["ent_coef:'auto'", "latent_kwargs:dict(n_components=4, count_factors=[2, 2])"]),
]
MID_RUN_YAML = [  # (algo, settings updating the zoo's entry)
    ("ppo", {"policy_kwargs": {"optimizer_class": "th.optim.LBFGS"}}),
    ("ppo", {"policy_kwargs": {"optimizer_class": "{m}"}}),
    ("ppo", {"policy_kwargs": {"activation_fn": "relu"}}),
    ("ppo", {"policy_kwargs": {"activation_fn": "os.system"}}),
    ("ppo", {"policy_kwargs": {"features_extractor_class": "pydoc.pipepager"}}),
    ("ppo", {"callback": {CALLBACK: {"max_episodes": "abc"}}}),
    ("ppo", {"callback": {CALLBACK: {"max_episodes": 1.5}}}),
    ("ppo", {"callback": {CALLBACK: {"max_episodes": ["{m}"]}}}),
    ("ppo", {"callback": CALLBACK}),
    ("ppo", {"callback": [{CALLBACK: {"verbose": 1}}]}),
    ("ppo", {"vec_env_wrapper": {HIDE: {"parts": "mode"}}}),
    ("ppo", {"vec_env_wrapper": {HIDE: {"parts": 5}}}),
    ("ppo", {"vec_env_wrapper": HIDE}),
    ("a2c", {"ent_coef": "auto"}),
    ("ppo", {"ent_coef": "auto"}),
]
FLAG_CASES = [  # (name, command line) refused before anything is written
    *[(f"--device {device}", ["--algo", "ppo", "--device", device])
      for device in ("cuda:99", "cuda", "xla", "meta", "hpu", "mps", "tpu", "vulkan", "cuda:-1")],
    ("-tb a file", ["--algo", "ppo", "-tb", "{f}"]),
    ("-tb under a file", ["--algo", "ppo", "-tb", "{f}/tb"]),
    ("-tb under a file, em_ppo", ["--algo", "em_ppo", "-tb", "{f}/a/b"]),
    *[(f"-i a PPO zip with --algo {algo}", ["--algo", algo, "-i", "{t}/WildlifeReserve-v1.zip"])
      for algo in ("em_ppo", "dqn", "a2c", "ddpg", "ppo_lstm", "mappo", "qmix", "vdn_em")],
    ("-i a PPO checkpoint with --algo em_ppo", ["--algo", "em_ppo", "-i", "{t}/rl_model_128_steps.zip"]),
    ("-i a config file", ["--algo", "ppo", "-i", "{t}/WildlifeReserve-v1/config.yml"]),
    ("self-merging anchor", ["--algo", "ppo", "-conf", "{f}.yml"]),
]
RESUME_FLAGS = [  # flags given with --resume of a stopped PPO run (their values differ from the run's own)
    ["--algo", "a2c"], ["--algo", "em_ppo"], ["--env", "ZonePatrol-v0"], ["--seed", "5"], ["-n", "100000"],
    ["-params", "n_steps:8"], ["--device", "cpu"], ["--vec-env", "supersuit"], ["--save-freq", "7"],
    ["--env-kwargs", "n_uavs:3"], ["-conf", "{f}"], ["--eval-freq", "100"], ["-tb", "{m}"],
]


@dataclass
class HostileCase:
    """One hostile attempt: a ``zoo/train.py`` (or, with ``enjoy``, ``zoo/enjoy.py``) command line; ``{m}`` in any
    text is the marker's path, ``{f}`` a file, ``{t}`` the template run's folder; ``yaml_text`` is written to a
    ``-conf`` file; ``config`` updates a copy of a finished run's ``config.yml`` (the copy is resumed with ``argv``
    added, or played by ``enjoy``); ``corrupt`` cuts every checkpoint of the copy short."""

    name: str
    argv: list[str]
    yaml_text: str | None = None
    config: dict | None = None
    enjoy: bool = False
    corrupt: bool = False
    gadget: tuple[str, str] | None = None  # (data entry, :data:`GADGETS` name): planted in the copy's model zips
    state_gadget: tuple[str, str] | None = None  # (:data:`STATE_PLACES` name, gadget): planted in its training states


class Call:
    """Pickles as ``func(*args)``, as a hostile file would."""

    def __init__(self, func, *args):
        self.func, self.args = func, args

    def __reduce__(self):
        return self.func, self.args


class Touch:
    """Pickles as ``os.system("touch <path>")``: code that leaves a marker where it runs."""

    def __init__(self, path: str):
        self.path = path

    def __reduce__(self):
        import os

        return os.system, (f"touch {self.path}",)


def _gadget(name: str, marker: str) -> bytes:
    """The pickle of the gadget ``name`` (issue 65's families: torch, numpy, copyreg, builtins, the opcodes), built to
    create ``marker`` where it runs code, else to allocate without bound."""
    import copyreg
    import pickle

    import numpy as np
    import torch as th
    from numpy.random._pickle import __bit_generator_ctor, __generator_ctor, __randomstate_ctor
    from stable_baselines3.common.buffers import RolloutBuffer
    from stable_baselines3.common.utils import ConstantSchedule
    from torch.storage import _load_from_bytes

    if name.startswith("torch"):
        buffer = io.BytesIO()
        th.save(Touch(marker), buffer, _use_new_zipfile_serialization=name == "torch new format")
        return pickle.dumps(Call(_load_from_bytes, buffer.getvalue()))
    space = [Call(np.zeros, 1)]
    calls = {
        "numpy generator ctor": Call(__generator_ctor, 10 ** 12, bytearray),
        "numpy randomstate ctor": Call(__randomstate_ctor, range(10 ** 10), list),
        "numpy bit generator class": Call(__bit_generator_ctor, RolloutBuffer),
        "copyreg base": Call(copyreg._reconstructor, ConstantSchedule, bytearray, 10 ** 12),
        "builtins bytearray": Call(bytearray, 10 ** 12),
        "builtins list of range": Call(list, range(10 ** 11)),
        "a buffer built": Call(RolloutBuffer, 10 ** 9, space, space),
    }
    if name == "an environment module's function":  # a function of a module whose classes a training state may hold
        from sb3_emmarl.common.vec_env import make_vec_env

        return pickle.dumps(Call(make_vec_env, Touch(marker)))
    if name == "a class outside the environments":  # an instance of a class with methods that write files
        from stable_baselines3.common.logger import Logger

        logger = Logger.__new__(Logger)
        logger.__dict__.update(dir=marker, output_formats=[])
        return pickle.dumps({"venv": logger, "copy_seeds": [], "never_reset": [], "reset_infos": []})
    if name == "other copies":  # data only, but not this environment's copies
        return pickle.dumps({"venv": {"envs": [np.zeros(3)]}, "copy_seeds": [], "never_reset": [], "reset_infos": []})
    if name in calls:
        return pickle.dumps(calls[name])
    raw = {  # opcodes by hand: BYTEARRAY8 declaring 64 GiB; BUILD on a class; OBJ calling bytearray
        "opcode bytearray8": b"\x80\x05\x96" + (1 << 36).to_bytes(8, "little") + b".",
        "opcode build on a class": b"\x80\x02cstable_baselines3.common.utils\nConstantSchedule\nN}X\x03\x00\x00\x00valN"
                                   b"s\x86b.",
        "opcode obj": b"(cbuiltins\nbytearray\nL99999999999\no.",
    }
    return raw[name]


#: The gadget families planted in model zips by :func:`hostile_cases` (none may run or allocate).
GADGETS = ("torch new format", "torch legacy format", "numpy generator ctor", "numpy randomstate ctor",
           "numpy bit generator class", "copyreg base", "builtins bytearray", "builtins list of range", "a buffer built",
           "opcode bytearray8", "opcode build on a class", "opcode obj")
#: The data entries they are planted in.
GADGET_ENTRIES = ("observation_space", "lr_schedule", "clip_range", "policy_class", "_last_obs", "action_space")
#: Gadgets that only a training state's environments could carry (planted there besides :data:`GADGETS`).
STATE_GADGETS = ("an environment module's function", "a class outside the environments", "other copies")
#: Where a training state gets its gadget: the whole file, or its environment copies' state (a pickle in the pickle).
STATE_PLACES = ("file", "environment")


def _fill(value, marker: str):
    if isinstance(value, str):
        return value.replace("{m}", marker)
    if isinstance(value, dict):
        return {k: _fill(v, marker) for k, v in value.items()}
    if isinstance(value, list):
        return [_fill(v, marker) for v in value]
    return value


def hostile_cases() -> list[HostileCase]:
    """Every hostile case, in a fixed order."""
    env = "WildlifeReserve-v1"
    out: list[HostileCase] = []
    for i, payload in enumerate(PY_PAYLOADS):
        out.append(HostileCase(f"-params learning_rate #{i}", ["--algo", "ppo", "-params", f"learning_rate:{payload}"]))
        out.append(HostileCase(f"-params policy_kwargs #{i}", ["--algo", "ppo", "-params", f"policy_kwargs:{payload}"]))
        out.append(HostileCase(f"--env-kwargs #{i}", ["--algo", "ppo", "--env-kwargs", f"region:{payload}"]))
        out.append(HostileCase(f"-params normalize string #{i}", ["--algo", "ppo", "-params", f"normalize:{payload!r}"]))
        for key, algo in EVAL_KEYS:
            entry = {**zoo_hyperparams(algo), key: "__VALUE__"}
            text = yaml.safe_dump({env: entry}).replace("__VALUE__", yaml.safe_dump(payload).strip().removesuffix("..."))
            out.append(HostileCase(f"-conf {key} #{i}", ["--algo", algo], yaml_text=text.replace("\n...", "")))
    for key, algo in IMPORT_KEYS:
        for name, kwargs in CALLABLES:
            value = {name: kwargs}
            out.append(HostileCase(f"-params {key} {name}", ["--algo", algo, "-params", f"{key}:{value!r}"]))
            out.append(HostileCase(f"-params {key} [{name}]", ["--algo", algo, "-params", f"{key}:{[value]!r}"]))
            text = yaml.safe_dump({env: {**zoo_hyperparams(algo), key: value}})
            out.append(HostileCase(f"-conf {key} {name}", ["--algo", algo], yaml_text=text))
    for name, _ in CALLABLES:
        out.append(HostileCase(f"-params policy {name}", ["--algo", "ppo", "-params", f"policy:{name!r}"]))
    for name, text, _ in YAML_CASES:
        out.append(HostileCase(f"yaml {name}", ["--algo", "ppo"], yaml_text=text.replace("{env}", env)))
    for key, value in RUN_CASES:
        out.append(HostileCase(f"--resume config.yml {key} {str(value)[:40]}", ["--algo", "ppo"], config={key: value}))
    for name, kwargs in CALLABLES:  # enjoy plays under the run's vec_env_wrapper
        for value in ({name: kwargs}, name, [{name: kwargs}]):
            out.append(HostileCase(f"enjoy config.yml vec_env_wrapper {str(value)[:40]}", ["--algo", "ppo"],
                                   config={"vec_env_wrapper": value}, enjoy=True))
    for algo, params in MID_RUN_PARAMS:
        out.append(HostileCase(f"mid-run -params {algo} {' '.join(params)[:60]}", ["--algo", algo, "-params", *params]))
    for algo, settings in MID_RUN_YAML:
        text = yaml.safe_dump({env: {**zoo_hyperparams(algo), **settings}})
        out.append(HostileCase(f"mid-run -conf {algo} {str(settings)[:60]}", ["--algo", algo], yaml_text=text))
    for name, argv in FLAG_CASES:
        out.append(HostileCase(f"flags {name}", argv))
    for flags in RESUME_FLAGS:
        out.append(HostileCase(f"--resume {' '.join(flags)}", flags, config={}))
    out.append(HostileCase("--resume with every checkpoint cut short", [], config={}, corrupt=True))
    return out + _gadget_cases()


def _gadget_cases() -> list[HostileCase]:
    """Each gadget family planted in two of a finished run's data entries, played by enjoy (the final zip) and
    resumed (the checkpoints)."""
    out = []
    for i, gadget in enumerate(GADGETS):
        for j, enjoy in enumerate((True, False)):
            entry = GADGET_ENTRIES[(2 * i + j) % len(GADGET_ENTRIES)]
            out.append(HostileCase(f"{'enjoy' if enjoy else '--resume'} zip {entry} {gadget}", [], config={},
                                   enjoy=enjoy, gadget=(entry, gadget)))
    for i, gadget in enumerate((*GADGETS, *STATE_GADGETS)):
        place = "environment" if gadget in STATE_GADGETS else STATE_PLACES[i % len(STATE_PLACES)]
        out.append(HostileCase(f"--resume training state {place} {gadget}", [], config={},
                               state_gadget=(place, gadget)))
    return out


def plant_state(path: Path, place: str, blob: bytes) -> None:
    """Put the pickle ``blob`` in the training state ``path``: as the whole file, or as the state of its innermost
    environment layer (the reserve copies)."""
    import pickle

    if place == "file":
        path.write_bytes(blob)
        return
    with open(path, "rb") as file:
        state = pickle.load(file)  # (the template run's own file)
    state["env"][-1] = blob
    path.write_bytes(pickle.dumps(state))


def write_data(path: Path, text: str) -> None:
    """Replace the ``data`` entry of the model zip ``path`` by ``text``."""
    import zipfile

    with zipfile.ZipFile(path) as archive:
        members = {name: archive.read(name) for name in archive.namelist()}
    members["data"] = text.encode()
    with zipfile.ZipFile(path, "w") as archive:
        for name, content in members.items():
            archive.writestr(name, content)


def plant(path: Path, entry: str, blob: bytes) -> None:
    """Replace the ``data`` entry ``entry`` of the model zip ``path`` by the pickle ``blob``."""
    import base64
    import json
    import zipfile

    with zipfile.ZipFile(path) as archive:
        data = json.loads(archive.read("data"))
    data[entry] = {":type:": "<class 'object'>", ":serialized:": base64.b64encode(blob).decode()}
    write_data(path, json.dumps(data))


def train_template_run(folder: Path) -> Path:
    """A tiny finished PPO run with checkpoints, which the run-folder cases copy; returns its run folder."""
    from sb3_emmarl.zoo.cli import train_main

    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        code = train_main(["--algo", "ppo", "-n", "384", *TINY, *QUICK, "--save-freq", "128", "-f", str(folder),
                           "-params", "n_steps:16", "batch_size:32"])
    assert code == 0, "the template run failed"
    return folder / "ppo" / "WildlifeReserve-v1_1"


def _files(folder: Path) -> set[Path]:
    return set(folder.rglob("*")) if folder.exists() else set()


def run_hostile_case(case: HostileCase, folder: Path, template: Path | None = None, time_limit: int = 30) -> dict:
    """Run one hostile case in ``folder`` (fresh); ``template`` is :func:`train_template_run`'s run (for the cases
    with a ``config`` or ``{t}``). Returns ``{"marker", "traceback", "leftover", "accepted", "text"}``: the marker was created;
    an exception escaped, a traceback was printed, the error was not one ``error:`` line, or the case hung; files were
    left behind (anything new in ``folder``: a run or tensorboard folder, new files in the tampered run); the case ran
    (exit code 0)."""
    import shutil

    from sb3_emmarl.zoo.cli import enjoy_main, train_main

    folder.mkdir(parents=True, exist_ok=True)
    marker = str(folder / "marker")
    logs = folder / "logs"
    a_file = folder / "file"
    a_file.write_text("")
    (folder / "file.yml").write_text("WildlifeReserve-v1: &e\n  <<: *e\n  n_timesteps: 64\n  policy: MlpPolicy\n")
    places = {"{f}": str(a_file), "{t}": str(template)}
    argv = [_fill(a, marker) for a in case.argv]
    for key, value in places.items():
        argv = [a.replace(key, value) for a in argv]
    if case.yaml_text is not None:
        conf = folder / "conf.yml"
        conf.write_text(case.yaml_text.replace("{m}", marker))
        argv += ["-conf", str(conf)]
    if case.config is not None:
        assert template is not None, "run-folder cases need the template run"
        run = logs / "ppo" / template.name
        shutil.copytree(template, run)
        if not case.enjoy:
            (run / "WildlifeReserve-v1.zip").unlink()
        config_file = run / "WildlifeReserve-v1" / "config.yml"
        config = yaml.safe_load(config_file.read_text())
        config.update(_fill(case.config, marker))
        config_file.write_text(yaml.safe_dump(config))
        if case.corrupt:
            for path in run.glob("rl_model_*_steps.zip"):
                path.write_bytes(path.read_bytes()[:100])
        if case.gadget is not None:
            entry, gadget = case.gadget
            for path in [run / "WildlifeReserve-v1.zip", *run.glob("rl_model_*_steps.zip")]:
                if path.exists():
                    plant(path, entry, _gadget(gadget, marker))
        if case.state_gadget is not None:
            place, gadget = case.state_gadget
            for path in run.glob("rl_model_training_state_*_steps.pkl"):
                plant_state(path, place, _gadget(gadget, marker))
        argv = (["--algo", "ppo", "-f", str(logs), "--episodes", "1", "--no-record"] if case.enjoy else
                ["--algo", "ppo", "--resume", str(run), "--verbose", "0", *argv])
    else:
        argv = [*argv, "-n", "64", *QUICK, *(TINY if "--env-kwargs" not in argv else []), "-f", str(logs)]
    before = _files(folder)
    out, err = io.StringIO(), io.StringIO()
    escaped = hung = False
    previous = signal.signal(signal.SIGALRM, _alarm)
    signal.alarm(time_limit)
    code: object = None
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                code = (enjoy_main if case.enjoy else train_main)(argv)
            except SystemExit as exit_info:
                code = exit_info.code
    except _Timeout:
        hung = True
    except Exception as error:
        escaped = True
        err.write(f"{type(error).__name__}: {error}")
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)
    text = err.getvalue().strip()
    lines = text.splitlines()
    one_line = len(lines) == 1 and "error:" in lines[0] and "Traceback" not in text
    return {"marker": Path(marker).exists(), "traceback": escaped or hung or (code != 0 and not one_line),
            "leftover": _files(folder) - {Path(marker)} != before, "accepted": code == 0, "text": text[-300:]}
