"""Which algorithms the zoo trains on the reserve, and in which view.

rl_zoo3 takes new algorithms by insertion into ``rl_zoo3.ALGOS`` (and, for ``-optimize``, into its
``HYPERPARAMS_SAMPLER`` / ``HYPERPARAMS_CONVERTER``); :func:`register_algorithms` does that once. Each algorithm tunes
with its base algorithm's sampler (rl_zoo3's); the EM algorithms' samplers add EM's own settings
(:func:`sample_latent_params`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from sb3_contrib import RecurrentPPO
from stable_baselines3 import A2C, DDPG, DQN, PPO, TD3
from stable_baselines3.common.base_class import BaseAlgorithm

from sb3_emmarl.em_ddpg import EMDDPG
from sb3_emmarl.em_ppo import EMPPO
from sb3_emmarl.mappo import MAPPO
from sb3_emmarl.message_ppo import MessagePPO
from sb3_emmarl.oracle_ppo import OraclePPO
from sb3_emmarl.qmix import QMIX
from sb3_emmarl.vdn import VDN
from sb3_emmarl.vdn_em import EMVDN

#: Algorithms trained with one policy shared by all UAVs (the parameter-sharing vector environment).
SHARED_ALGOS: dict[str, type[BaseAlgorithm]] = {
    "ppo": PPO,  # decentralized PPO
    "a2c": A2C,
    "dqn": DQN,  # the paper's Q-learning
    "ddpg": DDPG,  # continuous action mode
    "td3": TD3,  # continuous action mode
    "ppo_lstm": RecurrentPPO,
    "em_ppo": EMPPO,  # the paper's method, with PPO as the M-step
    "em_ddpg": EMDDPG,  # the paper's method, with DDPG as the M-step (continuous action mode)
    "oracle_ppo": OraclePPO,  # PPO told the true hidden mode: the upper bound of every latent method
    "mappo": MAPPO,  # PPO whose critic reads the global state (MAPPO)
    "qmix": QMIX,  # shared agent Q-network, monotonic mixing conditioned on the global state
    "vdn": VDN,  # shared agent Q-network, team value the sum of the agents'
    "vdn_em": EMVDN,  # the paper's VDN+EM: VDN whose agents see the EM belief
    "ppo_gat": MessagePPO,  # PPO with graph attention over the messages the UAV received (table 6)
    "ppo_transformer": MessagePPO,  # PPO with a transformer over the UAV, its messages and its window (table 6)
}
#: Algorithms trained on the centralised view (global state in, joint action out).
CENTRALIZED_ALGOS: dict[str, type[BaseAlgorithm]] = {
    "cppo": PPO,  # Centralized PPO
}
ZOO_ALGOS: dict[str, type[BaseAlgorithm]] = {**SHARED_ALGOS, **CENTRALIZED_ALGOS}
#: The EM algorithms (they add their belief wrapper themselves; the zoo logs their latent metrics).
LATENT_ALGOS = ("em_ppo", "em_ddpg", "vdn_em")
#: Algorithms that read the environment's global state (the zoo builds their environment with it).
STATE_ALGOS = ("mappo", "qmix")
#: Algorithms trained with another algorithm's hyperparameter file (the same settings by construction).
SHARED_HYPERPARAMS: dict[str, str] = {"oracle_ppo": "ppo"}


#: The rl_zoo3 algorithm whose optuna sampler (and converter) each zoo algorithm takes for its base settings.
SAMPLER_BASES: dict[str, str] = {
    "cppo": "ppo", "em_ppo": "ppo", "em_ddpg": "ddpg", "oracle_ppo": "ppo", "mappo": "ppo", "qmix": "dqn", "vdn": "dqn",
    "vdn_em": "dqn", "ppo_gat": "ppo", "ppo_transformer": "ppo"}
#: What ``-optimize`` searches of EM's own settings, beside the base algorithm's (:func:`sample_latent_params`):
#: the mixture's size, the decoder's likelihood temperature, how often the E-step runs and the window of data it
#: fits (``e_step_kwargs`` ``window``). EM-PPO counts both in rollouts; EM-DDPG and VDN+EM in ``train()`` calls
#: (their YAMLs: an E-step every 200 / 500 calls on the last 800 / 2,000), hence their own choices.
LATENT_SEARCH: dict[str, dict[str, Any]] = {
    "em_ppo": {"e_step_interval": [1, 2, 4, 8, 16], "e_step_window": [2, 4, 8, 16, 32]},
    "em_ddpg": {"e_step_interval": [50, 100, 200, 500, 1000], "e_step_window": [200, 400, 800, 2000, 4000]},
    "vdn_em": {"e_step_interval": [50, 100, 200, 500, 1000], "e_step_window": [200, 400, 800, 2000, 4000]},
}
#: The mixture sizes and likelihood temperatures ``-optimize`` tries for every EM algorithm.
N_COMPONENTS_CHOICES = [2, 4, 8, 16]
LIKELIHOOD_TEMPERATURE_RANGE = (0.03, 3.0)


def sample_latent_params(trial: Any, algo: str) -> dict[str, Any]:
    """EM's own settings for an optuna trial of ``algo`` (:data:`LATENT_SEARCH`) as the ``latent_kwargs``
    hyperparameter: ``n_components``, ``likelihood_temperature`` (log-uniform), ``e_step_interval`` and the E-step's
    window (in ``e_step_kwargs``; :func:`merge_hyperparams` keeps the YAML's other latent and E-step settings).

    :param trial: the optuna trial
    :param algo: ``em_ppo``, ``em_ddpg`` or ``vdn_em``
    """
    search = LATENT_SEARCH[algo]
    window = trial.suggest_categorical("e_step_window", search["e_step_window"])
    return {"latent_kwargs": {
        "n_components": trial.suggest_categorical("n_components", N_COMPONENTS_CHOICES),
        "likelihood_temperature": trial.suggest_float("likelihood_temperature", *LIKELIHOOD_TEMPERATURE_RANGE, log=True),
        "e_step_interval": trial.suggest_categorical("e_step_interval", search["e_step_interval"]),
        "e_step_kwargs": {"window": window}}}


#: The optuna names of what :func:`sample_latent_params` suggests that are ``latent_kwargs`` fields as they are.
SAMPLED_LATENT_FIELDS = ("n_components", "likelihood_temperature", "e_step_interval")


def convert_latent_params(params: dict[str, Any]) -> dict[str, Any]:
    """A trial's EM parameters (optuna's names) as hyperparameters: ``latent_kwargs``, with ``e_step_window`` as its
    ``e_step_kwargs`` ``window``.

    :param params: the trial's parameters that :func:`sample_latent_params` suggested
    """
    latent: dict[str, Any] = {key: params[key] for key in SAMPLED_LATENT_FIELDS if key in params}
    if "e_step_window" in params:
        latent["e_step_kwargs"] = {"window": params["e_step_window"]}
    return {"latent_kwargs": latent} if latent else {}


def merge_hyperparams(base: dict[str, Any], update: dict[str, Any]) -> dict[str, Any]:
    """``update`` (``-params``, a variant's overrides, an optuna trial's sample) laid over the YAML's ``base``, as the
    zoo reads them: every key replaced, but ``latent_kwargs`` merged field by field (its ``e_step_kwargs`` key by key),
    so that ``-params latent_kwargs:"dict(fusion=False)"`` keeps the YAML's other latent settings; and when the update
    changes ``n_components`` but not ``count_factors``, the YAML's factors refitted: its pair if it still multiplies to
    ``n_components``, else the same second factor (how far) with the first scaled, else None.

    :param base: the YAML's hyperparameters
    :param update: what overrides them
    """
    merged = {**base, **update}
    changes = update.get("latent_kwargs")
    if not isinstance(changes, dict) or not isinstance(base.get("latent_kwargs"), dict):
        return merged
    latent = {**base["latent_kwargs"], **changes}
    if "e_step_kwargs" in changes:
        latent["e_step_kwargs"] = {**(base["latent_kwargs"].get("e_step_kwargs") or {}), **(changes["e_step_kwargs"] or {})}
    factors, n_components = latent.get("count_factors"), changes.get("n_components")
    if "count_factors" not in changes and factors is not None and isinstance(n_components, int) \
            and factors[0] * factors[1] != n_components:
        latent["count_factors"] = [n_components // factors[1], factors[1]] if n_components % factors[1] == 0 \
            and n_components >= factors[1] else None
    merged["latent_kwargs"] = latent
    return merged


def _latent_sampler(algo: str, base_sampler: Callable[..., dict[str, Any]]) -> Callable[..., dict[str, Any]]:
    def sample(trial: Any, n_actions: int, n_envs: int, additional_args: dict[str, Any]) -> dict[str, Any]:
        return {**base_sampler(trial, n_actions, n_envs, additional_args), **sample_latent_params(trial, algo)}

    sample.__doc__ = f"rl_zoo3's sampler of {SAMPLER_BASES[algo]} and EM's own settings (sample_latent_params)."
    return sample


def _latent_converter(base_converter: Callable[[dict[str, Any]], dict[str, Any]]) -> Callable[..., dict[str, Any]]:
    def convert(params: dict[str, Any]) -> dict[str, Any]:
        names = {"e_step_window", *SAMPLED_LATENT_FIELDS}
        return {**base_converter({key: value for key, value in params.items() if key not in names}),
                **convert_latent_params(params)}

    return convert


def register_algorithms() -> None:
    """Make rl_zoo3 know every algorithm of :data:`ZOO_ALGOS`, with an optuna sampler and converter each: the base
    algorithm's (:data:`SAMPLER_BASES`), plus EM's own settings for the EM algorithms (idempotent)."""
    import rl_zoo3
    from rl_zoo3 import hyperparams_opt

    for name, algo in ZOO_ALGOS.items():
        rl_zoo3.ALGOS.setdefault(name, algo)
    for name, like in SAMPLER_BASES.items():
        sampler, converter = hyperparams_opt.HYPERPARAMS_SAMPLER[like], hyperparams_opt.HYPERPARAMS_CONVERTER[like]
        if name in LATENT_SEARCH:
            sampler, converter = _latent_sampler(name, sampler), _latent_converter(converter)
        hyperparams_opt.HYPERPARAMS_SAMPLER.setdefault(name, sampler)
        hyperparams_opt.HYPERPARAMS_CONVERTER.setdefault(name, converter)
