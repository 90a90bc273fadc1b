"""Initialisation of the inputs an algorithm appends to the environment's observation (the told mode, the belief).

Inputs that stay constant over an episode, or over long stretches of it, enter every hidden unit with SB3's random
(orthogonal) weights at initialisation: each value of them then starts with its own features and its own behaviour,
which the policy must correct for each value separately, from a fraction of the data. Started at zero, the networks
start as the same functions with or without those inputs, learn first what serves every value of them, and let
their weights grow only as far as the gradient finds that they pay. What the zero start changes on the reserve is
measured in docs/lab/results-history.md ("How much knowing the mode pays").
"""

from __future__ import annotations

from typing import cast

import torch as th
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.torch_layers import FlattenExtractor, MlpExtractor

from sb3_emmarl.common.appended.extractor import SplitFeaturesExtractor


def reads_tail_as_input(policy: ActorCriticPolicy) -> bool:
    """Whether the policy's first layers read the features' tail as inputs among the others: SB3's ``MlpExtractor``
    (``belief_conditioning="concat"``); the other conditionings read it apart
    (:mod:`sb3_emmarl.common.appended.conditioning`), and start as networks that do not read it."""
    return isinstance(policy.mlp_extractor, MlpExtractor)


def features_end_with_observation_tail(extractor: th.nn.Module, obs_dim: int, n_tail: int) -> bool:
    """Whether the extractor's features end with the observation's last ``n_tail`` values, unchanged.

    True for SB3's ``FlattenExtractor`` (the features are the flat observation) and for a
    :class:`~sb3_emmarl.common.extractors.SplitFeaturesExtractor` that appends at least the last ``n_tail`` values (or
    as many values computed from them: the belief's forms of
    :class:`~sb3_emmarl.common.latent.policies.BeliefFeaturesExtractor`).
    """
    if isinstance(extractor, FlattenExtractor):
        return True
    return (isinstance(extractor, SplitFeaturesExtractor) and extractor.keep == obs_dim
            and extractor.features_dim - extractor.inner.features_dim >= n_tail)


def zero_tail_weights(policy: ActorCriticPolicy, n_tail: int) -> bool:
    """Set to zero the weights with which the policy's and the value's first layers read the last ``n_tail`` values
    of a flat observation (see the module's docstring for why).

    Returns False, changing nothing, where the features extractor does not pass those values through unchanged (see
    :func:`features_end_with_observation_tail`), where the networks read them apart (:func:`reads_tail_as_input`), or
    where ``n_tail`` is 0.

    :param policy: an SB3 actor-critic policy (its ``mlp_extractor`` and heads as built by SB3)
    :param n_tail: values at the end of the observation
    """
    assert policy.observation_space.shape is not None  # (a flat Box)
    obs_dim = int(policy.observation_space.shape[0])
    extractors = {id(e): e for e in (policy.features_extractor, policy.pi_features_extractor, policy.vf_features_extractor)}
    if (n_tail <= 0 or not reads_tail_as_input(policy)
            or not all(features_end_with_observation_tail(e, obs_dim, n_tail) for e in extractors.values())):
        return False
    for first in first_layers(policy).values():
        with th.no_grad():
            first.weight[:, -n_tail:] = 0.0
    return True


def hold_tail_weights_at_zero(policy: ActorCriticPolicy, n_tail: int, network: str) -> bool:
    """Set to zero, and keep there, the weights with which one network's first layer (``"policy"`` or ``"value"``, see
    :func:`first_layers`) reads the last ``n_tail`` values of a flat observation: that network does not read them.

    Their gradient is masked by a hook on the weight (hooks are not saved: call this again after loading, as
    ``_setup_model`` does), so no optimiser step moves them. Returns False, changing nothing, where the features
    extractor does not pass those values through unchanged (see :func:`features_end_with_observation_tail`) or the
    networks read them apart (:func:`reads_tail_as_input`).

    :param policy: an SB3 actor-critic policy
    :param n_tail: values at the end of the observation, at least 1
    :param network: ``"policy"`` or ``"value"``
    """
    assert policy.observation_space.shape is not None  # (a flat Box)
    obs_dim = int(policy.observation_space.shape[0])
    extractor = policy.pi_features_extractor if network == "policy" else policy.vf_features_extractor
    if n_tail <= 0 or not reads_tail_as_input(policy) or not features_end_with_observation_tail(extractor, obs_dim, n_tail):
        return False
    layer = first_layers(policy)[network]
    mask = th.ones_like(layer.weight)
    mask[:, -n_tail:] = 0.0
    with th.no_grad():
        layer.weight.mul_(mask)
    layer.weight.register_hook(lambda grad: grad * mask)
    return True


def first_layers(policy: ActorCriticPolicy) -> dict[str, th.nn.Linear]:
    """The layers that read the features first: ``{"policy": ..., "value": ...}`` (the first ``Linear`` of each
    network of SB3's ``mlp_extractor``, or the action and value heads where that network has no layer)."""
    mlp = policy.mlp_extractor
    # (SB3 types the action head as a module: it is a Linear layer)
    heads = {"policy": cast(th.nn.Linear, policy.action_net), "value": policy.value_net}
    return {name: next((m for m in net.modules() if isinstance(m, th.nn.Linear)), heads[name])
            for name, net in (("policy", mlp.policy_net), ("value", mlp.value_net))}


def tail_weight_norms(policy: ActorCriticPolicy, n_tail: int) -> dict[str, tuple[float, float]]:
    """How strongly the first layers read the last ``n_tail`` features: per network (``"policy"``, ``"value"``), the
    mean norm of a weight column on those features and the mean over the other features' columns.

    A diagnostic for what an algorithm appends (the told mode, the belief): a policy whose column norms on it stay
    far below the others' has barely learned to act on it.

    :param policy: an SB3 actor-critic policy whose features end with the ``n_tail`` values (see
        :func:`features_end_with_observation_tail`)
    :param n_tail: features at the end, at least 1 and fewer than all
    """
    if not reads_tail_as_input(policy):
        raise ValueError("tail_weight_norms reads the first layers' weights on the tail: the policy's networks read it "
                         "apart (belief_conditioning other than 'concat')")
    norms = {}
    for name, layer in first_layers(policy).items():
        columns = layer.weight.detach().norm(dim=0)
        if not 0 < n_tail < len(columns):
            raise ValueError(f"n_tail must be in [1, {len(columns) - 1}], got {n_tail}")
        norms[name] = (float(columns[-n_tail:].mean()), float(columns[:-n_tail].mean()))
    return norms
