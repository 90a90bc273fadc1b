"""Strict validation of the algorithms' hyperparameters and of the zoo's command-line flags.

One place for the algorithm layer: :data:`RULES` holds the rule of every hyperparameter the zoo's
algorithms take; the EM algorithms' constructors check their own arguments with it, and the zoo's
:func:`check_hyperparams` checks a whole YAML entry (updated by ``-params``) before anything is built
or written. The environment's arguments are checked by the environment itself
(:class:`~wildlife_reserve.reserve.config.ReserveConfig`), the flags by the argparse types below.

Every rule names the value and what is allowed: types first (a boolean must be ``true``/``false``, a
size an integer, a string ``"abc"`` is never a number), then ranges (upper bounds keep a typo such as
``buffer_size: 1e12`` from allocating before anything runs). SB3 checks few of its arguments and
rl_zoo3 none, hence this module.
"""

from __future__ import annotations

import argparse
import math
import re
from collections.abc import Callable
from typing import Any

import numpy as np
import torch as th
from stable_baselines3.common.base_class import BaseAlgorithm

from sb3_emmarl.common.trust.safe_config import ACTIVATIONS, OPTIMIZERS, check_imports, is_plain, parse_kwargs, parse_value

#: Keys of a zoo YAML entry that are not constructor arguments (rl_zoo3 handles them).
ZOO_KEYS = ("n_timesteps", "n_envs", "normalize", "env_kwargs", "env_wrapper", "vec_env_wrapper", "callback",
            "frame_stack", "monitor_kwargs", "noise_type", "noise_std")
#: Constructor arguments the zoo sets from its flags (a YAML entry may not set them).
FLAG_KEYS = ("env", "seed", "verbose", "device", "tensorboard_log", "_init_setup_model", "monitor_wrapper")
#: Largest values accepted (documented in docs/zoo.md): beyond them a value is a typo, not an experiment.
MAX_TIMESTEPS = 10**10
MAX_N_ENVS = 256
MAX_LAYER = 4096
MAX_BUFFER = 10**7
MAX_STEPS = 10**6
MAX_EPISODES = 10_000  # evaluation episodes a command plays
MAX_SEED = 2**32 - 1
#: Keys of ``normalize`` (SB3's ``VecNormalize`` arguments) and of ``monitor_kwargs`` (SB3's ``Monitor``'s).
NORMALIZE_KEYS = ("norm_obs", "norm_reward", "clip_obs", "clip_reward", "gamma", "epsilon", "norm_obs_keys")
MONITOR_KEYS = ("allow_early_resets", "reset_keywords", "info_keywords", "override_existing")
SCHEDULE = re.compile(r"^lin_(?P<value>[-+0-9.eE]+)$")


class Rule:
    """A check of one hyperparameter: ``check(name, value)`` returns the value or raises a ValueError."""

    def __init__(self, check: Callable[[str, Any], Any], allowed: str) -> None:
        self.check, self.allowed = check, allowed

    def __call__(self, name: str, value: Any) -> Any:
        return self.check(name, value)


def fail(name: str, value: Any, allowed: str) -> None:
    """Raise the ValueError of every rule: ``<name> must be <allowed>, got <value>`` (the value abbreviated)."""
    text = repr(value)
    raise ValueError(f"{name} must be {allowed}, got {text if len(text) <= 80 else text[:77] + '...'}")


def _is_int(value: Any) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))


def _is_number(value: Any) -> bool:
    return (isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_))
            and math.isfinite(float(value)))


def _non_empty(name: str, value: Any, parsed: dict[str, Any]) -> dict[str, Any]:
    if not parsed:
        fail(name, value, "a non-empty mapping (true normalizes with the defaults)")
    return parsed


def integer(low: int, high: int, allow_float: bool = False) -> Rule:
    """An int in ``[low, high]`` (a float with an integral value too if ``allow_float``: YAML's ``2e6``)."""
    allowed = f"an int in [{low}, {high}]"

    def check(name: str, value: Any) -> int:
        if allow_float and _is_number(value) and float(value).is_integer():
            value = int(value)
        if not _is_int(value) or not low <= value <= high:
            fail(name, value, allowed)
        return int(value)

    return Rule(check, allowed)


def number(low: float, high: float, low_open: bool = False, schedule: bool = False, high_open: bool = False) -> Rule:
    """A finite number in ``[low, high]`` (``(`` / ``)`` with ``low_open`` / ``high_open``); with ``schedule``, also a
    callable or rl_zoo3's ``lin_<value>`` string, whose value must be in the same range."""
    allowed = (f"a number in {'(' if low_open else '['}{low}, {high}{')' if high_open else ']'}"
               + (" or 'lin_<value>'" if schedule else ""))

    def check(name: str, value: Any) -> Any:
        if schedule and callable(value):
            return value
        raw = value
        if schedule and isinstance(value, str) and (match := SCHEDULE.match(value)):
            try:
                value = float(match["value"])
            except ValueError:
                fail(name, raw, allowed)
        if not _is_number(value) or value > high or value < low or (low_open and value == low) \
                or (high_open and value == high):
            fail(name, raw, allowed)
        return raw

    return Rule(check, allowed)


def boolean() -> Rule:
    def check(name: str, value: Any) -> bool:
        if not isinstance(value, (bool, np.bool_)):
            fail(name, value, "true or false")
        return bool(value)

    return Rule(check, "true or false")


def choice(*options: Any) -> Rule:
    allowed = f"one of {list(options)}"

    def check(name: str, value: Any) -> Any:
        if not isinstance(value, (str, type(None))) or value not in options:
            fail(name, value, allowed)
        return value

    return Rule(check, allowed)


def one_of(*rules: Rule) -> Rule:
    allowed = " or ".join(rule.allowed for rule in rules)

    def check(name: str, value: Any) -> Any:
        for rule in rules:
            try:
                return rule(name, value)
            except ValueError:
                pass
        fail(name, value, allowed)

    return Rule(check, allowed)


def optional(rule: Rule) -> Rule:
    """None, or a value ``rule`` accepts (the message says both)."""
    allowed = f"null or {rule.allowed}"

    def check(name: str, value: Any) -> Any:
        if value is None:
            return None
        try:
            return rule(name, value)
        except ValueError:
            fail(name, value, allowed)

    return Rule(check, allowed)


def no_schedule_string(rule: Rule) -> Rule:
    """``rule`` without rl_zoo3's ``"lin_<value>"`` strings, for constructors: the zoo turns those strings into
    schedules before it calls the constructor, so a string there is a mistake."""
    allowed = rule.allowed.replace(" or 'lin_<value>'", " or a schedule")

    def check(name: str, value: Any) -> Any:
        if isinstance(value, str):
            fail(name, value, allowed)
        try:
            return rule(name, value)
        except ValueError:
            fail(name, value, allowed)

    return Rule(check, allowed)


def layers() -> Rule:
    """A list of layer sizes (ints in ``[1, MAX_LAYER]``)."""
    size = integer(1, MAX_LAYER)
    allowed = f"a list of layer sizes (ints in [1, {MAX_LAYER}])"

    def check(name: str, value: Any) -> list[int]:
        if not isinstance(value, (list, tuple)) or len(value) > 16:
            fail(name, value, allowed)
        return [size(f"{name}[{i}]", v) for i, v in enumerate(value)]

    return Rule(check, allowed)


def train_freq() -> Rule:
    steps = integer(1, MAX_STEPS)
    allowed = f"an int in [1, {MAX_STEPS}] or [n, 'step'|'episode']"

    def check(name: str, value: Any) -> Any:
        if isinstance(value, (list, tuple)):
            if len(value) != 2 or value[1] not in ("step", "episode"):
                fail(name, value, allowed)
            return (steps(f"{name}[0]", value[0]), value[1])
        return steps(name, value)

    return Rule(check, allowed)


def mapping(rules: dict[str, Rule], label: str) -> Rule:
    """A dict whose keys are among ``rules``, each value checked by its rule (errors named ``label[key]``)."""
    allowed = f"a mapping with keys among {sorted(rules)}"

    def check(name: str, value: Any) -> dict[str, Any]:
        if value is None:
            return {}
        if not isinstance(value, dict):
            fail(name, value, allowed)
        unknown = sorted(set(value) - set(rules), key=str)
        if unknown:
            raise ValueError(f"{label} keys must be among {sorted(rules)}, got {unknown}")
        return {key: rules[key](f"{label}[{key!r}]", v) for key, v in value.items()}

    return Rule(check, allowed)


#: Rules of ``e_step_kwargs`` (the keys of :data:`~sb3_emmarl.common.latent.config.E_STEP_DEFAULTS`).
E_STEP_RULES: dict[str, Rule] = {
    "learning_rate": number(0.0, 10.0, low_open=True),
    "n_epochs": integer(1, 1000),
    "batch_size": integer(1, MAX_BUFFER),
    # Rollouts (EM-PPO) or train() calls (the off-policy ones): 40 episodes of one reserve copy are 800 calls at
    # train_freq 10 (EM-DDPG) and 2,000 at train_freq 4 (VDN+EM).
    "window": integer(1, 10_000),
    "max_transitions": integer(1, MAX_BUFFER),
    "temperature": number(0.0, 100.0, low_open=True),
    "min_temperature": number(0.0, 100.0, low_open=True),
    "anneal_rate": number(0.0, 10.0),
    "starved_share": number(0.0, 0.999),
    "starved_patience": integer(1, 1_000_000),
}


#: How the networks read the told mode or the belief (``policy_kwargs["belief_conditioning"]``,
#: :mod:`sb3_emmarl.common.appended.conditioning`).
CONDITIONINGS = ("concat", "mixture", "film")

#: The rules of the EM algorithms' latent settings (the fields of ``latent_kwargs``).
LATENT_RULES: dict[str, Rule] = {
    "n_components": integer(1, 64),
    "decoder_hidden": layers(),
    "likelihood_temperature": number(0.0, 100.0, low_open=True),
    "fusion": one_of(boolean(), choice("team")),
    "estimator": choice("enumerate", "gumbel"),
    "belief_input": choice("probabilities", "map", "both"),
    "team_pooling": boolean(),
    "reading_counts": boolean(),
    "count_factors": optional(Rule(lambda n, v: [integer(1, 64)(f"{n}[{i}]", x) for i, x in enumerate(v)]
                                   if isinstance(v, (list, tuple)) and len(v) == 2 else fail(n, v, "two ints"),
                                   "two ints in [1, 64] (where x how far)")),
    "e_step_interval": integer(1, 10**4),
    "e_step_every": optional(integer(1, 10**9)),
    "e_step_kwargs": mapping(E_STEP_RULES, "e_step_kwargs"),
    "use_latent": boolean(),
    "freeze_e_step": boolean(),
    "freeze_m_step": boolean(),
}


#: The rule of every hyperparameter the zoo's algorithms take (SB3's, sb3-contrib's and the EM ones).
RULES: dict[str, Rule] = {
    "n_timesteps": integer(1, MAX_TIMESTEPS, allow_float=True),
    "n_envs": integer(1, MAX_N_ENVS),
    # rl_zoo3 evaluates these strings and imports these names: here they are parsed as data (safe_config.parse_value)
    # and the names checked against an allow-list (safe_config.IMPORT_KEYS), so that rl_zoo3 never sees a string
    "normalize": one_of(boolean(), Rule(lambda n, v: _non_empty(n, v, parse_kwargs(n, v, NORMALIZE_KEYS)),
                                        f"a non-empty mapping (or \"dict(...)\" string) with keys among "
                                        f"{list(NORMALIZE_KEYS)}")),
    "monitor_kwargs": Rule(lambda n, v: parse_kwargs(n, v, MONITOR_KEYS), "a mapping of Monitor's arguments"),
    "replay_buffer_kwargs": Rule(lambda n, v: parse_kwargs(n, v), "a mapping of the replay buffer's arguments"),
    "replay_buffer_class": Rule(lambda n, v: v if v is None else fail(n, v, "null (the algorithms choose their own)"),
                                "null"),
    "frame_stack": optional(integer(1, 64)),
    "belief_conditioning": choice(*CONDITIONINGS),
    "callback": Rule(lambda n, v: check_imports(n, v), "an allowed callback"),
    "env_wrapper": Rule(lambda n, v: check_imports(n, v), "an allowed wrapper"),
    "vec_env_wrapper": Rule(lambda n, v: check_imports(n, v), "an allowed wrapper"),
    "policy": Rule(lambda n, v: v if isinstance(v, str) and v.isidentifier() else
                   fail(n, v, "a policy name such as 'MlpPolicy' (not a module path)"), "a policy name"),
    "learning_rate": number(0.0, 10.0, low_open=True, schedule=True),
    "n_steps": integer(1, MAX_STEPS),
    "batch_size": integer(1, MAX_BUFFER),
    "n_epochs": integer(1, 1000),
    "gamma": number(0.0, 1.0),
    "gae_lambda": number(0.0, 1.0),
    "clip_range": number(0.0, 10.0, low_open=True, schedule=True),
    "clip_range_vf": optional(number(0.0, 10.0, low_open=True, schedule=True)),
    "normalize_advantage": boolean(),
    "ent_coef": one_of(number(0.0, 100.0), Rule(lambda n, v: v if isinstance(v, str) and v.startswith("auto") else
                                                 fail(n, v, "'auto'"), "'auto'")),
    "vf_coef": number(0.0, 100.0),
    "max_grad_norm": number(0.0, 1e6, low_open=True),
    "use_sde": boolean(),
    "sde_sample_freq": integer(-1, MAX_STEPS),
    "target_kl": optional(number(0.0, 100.0, low_open=True)),
    "stats_window_size": integer(1, 10**5),
    "use_rms_prop": boolean(),
    "rms_prop_eps": number(0.0, 1.0, low_open=True),
    "buffer_size": integer(1, MAX_BUFFER, allow_float=True),
    "learning_starts": integer(0, MAX_TIMESTEPS, allow_float=True),
    "tau": number(0.0, 1.0),
    "train_freq": train_freq(),
    "gradient_steps": one_of(integer(1, 10**4), Rule(lambda n, v: v if _is_int(v) and v == -1 else fail(n, v, "-1"),
                                                     "-1")),
    "optimize_memory_usage": boolean(),
    "target_update_interval": integer(1, MAX_TIMESTEPS),
    "exploration_fraction": number(0.0, 1.0),
    "exploration_initial_eps": number(0.0, 1.0),
    "exploration_final_eps": number(0.0, 1.0),
    "policy_delay": integer(1, 1000),
    "target_policy_noise": number(0.0, 100.0),
    "target_noise_clip": number(0.0, 100.0),
    "use_sde_at_warmup": boolean(),
    "noise_type": choice("normal", "ornstein-uhlenbeck"),
    "noise_std": number(0.0, 100.0),
    # the EM algorithms' latent settings (LATENT_RULES: their record, sb3_emmarl.common.latent.config.LatentConfig,
    # also checks how they fit together)
    "latent_kwargs": mapping(LATENT_RULES, "latent_kwargs"),
    # the weights that read what an algorithm appends to the observation (sb3_emmarl.common.appended.initialization)
    "zero_mode_weights": boolean(),
    "mode_input": choice("both", "policy", "value"),
    "random_label": boolean(),
    "zero_belief_weights": boolean(),
    # MAPPO (and QMIX / VDN: the agent's one-hot index as an input)
    "agent_id": boolean(),
    "use_value_norm": boolean(),
    "value_norm_beta": number(0.0, 1.0, low_open=True, high_open=True),
    "huber_delta": optional(number(0.0, 1e6, low_open=True)),
    # QMIX and VDN (agent_id as MAPPO's)
    "double_q": boolean(),
    "mixing_embed_dim": integer(1, MAX_LAYER),
    "hypernet_embed": integer(1, MAX_LAYER),
    "hypernet_layers": integer(1, 2),
    # PPO over the neighbour messages (graph attention, transformer)
    "extractor": choice("gat", "transformer"),
    "max_messages": integer(1, 64),
    "extractor_kwargs": mapping({"features_dim": integer(1, MAX_LAYER), "hidden_dim": integer(1, MAX_LAYER),
                                 "n_heads": integer(1, 64), "n_rounds": integer(1, 2), "d_model": integer(1, MAX_LAYER),
                                 "n_layers": integer(1, 16), "dim_feedforward": integer(1, MAX_LAYER)},
                                "extractor_kwargs"),
    "recurrent": boolean(),
    "rnn_hidden_dim": integer(1, MAX_LAYER),
    "sequence_length": integer(1, 10**4),
    "burn_in": integer(0, 10**4 - 1),
}
#: The ``policy_kwargs`` keys that may name a class, and the classes each may name.
POLICY_CLASS_KEYS: dict[str, dict[str, type]] = {"activation_fn": ACTIVATIONS, "optimizer_class": OPTIMIZERS}


def parse_policy_kwargs(value: Any) -> dict[str, Any]:
    """``policy_kwargs`` as a dict: rl_zoo3's ``"dict(net_arch=[64, 64])"`` string (read by
    :func:`~sb3_emmarl.common.trust.safe_config.parse_value`, never evaluated) or a mapping; ``net_arch`` checked (layer
    sizes, or ``dict(pi=[...], vf=[...])`` / ``qf``), classes only as ``activation_fn`` (an activation) and
    ``optimizer_class`` (an optimizer).

    :param value: the string or mapping
    :raise ValueError: naming ``policy_kwargs`` and what is wrong
    """
    if value is None:
        return {}
    if isinstance(value, str):
        value = parse_value(value, "policy_kwargs")
    if not isinstance(value, dict):
        fail("policy_kwargs", value, "a dict or a \"dict(...)\" string")
    value = dict(value)
    for key, item in value.items():
        classes = POLICY_CLASS_KEYS.get(key)
        if classes is not None and isinstance(item, type):
            if item not in classes.values():
                fail(f"policy_kwargs {key}", item, f"one of {sorted(classes)}")
        elif not is_plain(item):
            fail(f"policy_kwargs {key}", item, "plain data (classes only as " + " or ".join(POLICY_CLASS_KEYS) + ")")
    if "belief_conditioning" in value:
        value["belief_conditioning"] = RULES["belief_conditioning"]("policy_kwargs belief_conditioning",
                                                                    value["belief_conditioning"])
    if "net_arch" in value:
        arch = value["net_arch"]
        if isinstance(arch, dict):
            unknown = sorted(set(arch) - {"pi", "vf", "qf"}, key=str)
            if unknown:
                raise ValueError(f"policy_kwargs net_arch keys must be among ['pi', 'qf', 'vf'], got {unknown}")
            value["net_arch"] = {key: layers()(f"policy_kwargs net_arch[{key!r}]", v) for key, v in arch.items()}
        else:
            value["net_arch"] = layers()("policy_kwargs net_arch", arch)
    return value


def allowed_hyperparams(algo: type[BaseAlgorithm]) -> set[str]:
    """Keys a zoo YAML entry may hold for ``algo``: the zoo's, and the constructor arguments of ``algo`` and of the base
    classes its constructor passes ``**kwargs`` on to (down to the first constructor without ``**kwargs``)."""
    import inspect

    names: set[str] = set()
    for cls in algo.__mro__:
        init = cls.__dict__.get("__init__")
        if init is None or cls is object:
            continue
        parameters = inspect.signature(init).parameters
        names |= set(parameters)
        if not any(p.kind is inspect.Parameter.VAR_KEYWORD for p in parameters.values()):
            break
    return (names - set(FLAG_KEYS) - {"self", "args", "kwargs", "support_multi_env", "sde_support",
                                      "supported_action_spaces"}) | set(ZOO_KEYS)


def check_hyperparams(algo_name: str, algo: type[BaseAlgorithm], hyperparams: Any) -> dict[str, Any]:
    """Check a zoo YAML entry (after ``-params``) for ``algo``; returns it with ``policy_kwargs`` parsed.

    :raise ValueError: naming the hyperparameter, its value and what is allowed
    """
    if not isinstance(hyperparams, dict):
        raise ValueError(f"the hyperparameters of {algo_name} must be a mapping of names to values, got {hyperparams!r}")
    allowed = allowed_hyperparams(algo)
    for key in hyperparams:
        if key in FLAG_KEYS:
            raise ValueError(f"hyperparameter {key!r} is set by the zoo's flags, not by the YAML file or -params")
        if key in LATENT_RULES and "latent_kwargs" in allowed:  # (as YAMLs wrote them up to 0.22.0)
            raise ValueError(f"hyperparameter {key!r} of {algo_name} is a field of latent_kwargs: write it under "
                             f"latent_kwargs ({{latent_kwargs: {{{key}: ...}}}} in the YAML, "
                             f"latent_kwargs:\"dict({key}=...)\" in -params)")
        if key not in allowed:
            raise ValueError(f"unknown hyperparameter {key!r} for {algo_name}; allowed: {sorted(allowed)}")
    if "n_timesteps" not in hyperparams:
        raise ValueError(f"the hyperparameters of {algo_name} must set n_timesteps")
    checked = dict(hyperparams)
    for key, value in hyperparams.items():
        if key in RULES:
            checked[key] = RULES[key](key, value)
        elif key == "policy_kwargs":
            checked[key] = parse_policy_kwargs(value)
        elif key == "env_kwargs" and not isinstance(value, (dict, type(None))):
            fail(key, value, "a mapping of the reserve's arguments")
    aliases = sorted(getattr(algo, "policy_aliases", None) or {})
    if "policy" in checked and aliases and checked["policy"] not in aliases:
        fail("policy", checked["policy"], f"one of {aliases}")
    return checked


# ---------------------------------------------------------------------------------------------- flags
def int_flag(low: int, high: int, extra: tuple[int, ...] = ()) -> Callable[[str], int]:
    """An argparse ``type``: an int in ``[low, high]`` (or one of ``extra``); argparse turns the failure into exit
    code 2 with ``error: argument --flag: ...``."""
    allowed = f"an int in [{low}, {high}]" + (f" or {' or '.join(map(str, extra))}" if extra else "")

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be {allowed}, got {text!r}") from None
        if value not in extra and not low <= value <= high:
            raise argparse.ArgumentTypeError(f"must be {allowed}, got {value}")
        return value

    parse.__name__ = "int"
    return parse


def float_flag(low: float, high: float) -> Callable[[str], float]:
    """An argparse ``type``: a finite float in ``[low, high]`` (see :func:`int_flag`)."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be a number in [{low}, {high}], got {text!r}") from None
        if not low <= value <= high:  # (NaN fails too)
            raise argparse.ArgumentTypeError(f"must be a number in [{low}, {high}], got {text}")
        return value

    parse.__name__ = "float"
    return parse


def device_flag(text: str) -> str:
    """An argparse ``type`` for ``--device``: ``auto`` or a torch device name."""
    if text == "auto":
        return text
    try:
        th.device(text)
    except (RuntimeError, ValueError):
        raise argparse.ArgumentTypeError(f"must be 'auto' or a torch device such as 'cpu', got {text!r}") from None
    return text
