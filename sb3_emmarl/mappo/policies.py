"""MAPPO's policy: SB3's ``ActorCriticPolicy`` whose actor reads the agent's own observation and whose critic reads
MAPPO's agent-specific global state, and the value normaliser.

The policy acts on augmented observations ``[observation, global state, agent one-hot]`` (see
:class:`~sb3_emmarl.mappo.wrappers.StateLayout`): its actor network reads the first ``obs_dim`` values (through
the features extractor of ``policy_kwargs``, if any), so that the actions never depend on the state, and its critic
network reads them all. ``predict`` also takes plain
observations (``obs_dim`` values), which is all the actor needs: SB3's ``evaluate_policy`` then runs on the plain
environment. Both networks are MLPs as in marlbenchmark/on-policy's ``MLPBase``: a LayerNorm on the input, then
``Linear -> activation -> LayerNorm`` per hidden layer (``layer_norm=False``: SB3's plain MLPs), ReLU, orthogonal
initialisation (gain sqrt(2), 0.01 on the action logits, 1 on the value; biases 0).

:class:`ValueNorm` is on-policy's ``ValueNorm``: debiased exponential running averages of the returns and of
their squares. With value normalisation on, the value head predicts normalised returns; ``forward``,
``predict_values`` and ``evaluate_actions`` give values in the returns' own units (denormalised) as SB3's rollout
collection, bootstrapping and GAE expect, and :meth:`MAPPOPolicy.evaluate_actions_normalized` the head's own
output, for MAPPO's value loss. The normaliser's statistics are buffers of the policy: saved and loaded with it.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import AbstractContextManager, contextmanager
from typing import Any, cast

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.torch_layers import FlattenExtractor
from stable_baselines3.common.type_aliases import PyTorchObs, Schedule
from torch import nn

from sb3_emmarl.common.appended.extractor import SplitFeaturesExtractor
from sb3_emmarl.mappo.wrappers import StateLayout

#: Defaults of on-policy's ValueNorm: the averaging factor, the floor of the debiasing term and of the variance.
VALUE_NORM_BETA, VALUE_NORM_EPSILON, VALUE_NORM_MIN_VAR = 0.99999, 1e-5, 1e-2


def check_value_norm_beta(value: Any) -> float:
    """``value_norm_beta`` as a float in the open interval (0, 1), or a ValueError naming it."""
    if (isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating))
            or not 0.0 < float(value) < 1.0):
        raise ValueError(f"value_norm_beta must be a number in the open interval (0, 1), got {value!r}")
    return float(value)


class ValueNorm(nn.Module):
    """Running mean and standard deviation of the returns, debiased (on-policy's ``ValueNorm``, one value).

    Each :meth:`update` with a batch ``x`` sets ``m <- beta m + (1 - beta) mean(x)``, ``s <- beta s + (1 - beta)
    mean(x^2)`` and ``d <- beta d + (1 - beta)``, with ``m = s = d = 0`` at first; the statistics are the debiased
    ``mean = m / max(d, epsilon)`` and ``var = max(s / max(d, epsilon) - mean^2, min_var)`` (so ``d = 1 - beta^n``
    after ``n`` updates, and after one update they are the batch's own mean and variance). Before any update:
    mean 0 and the variance floor. Kept in float64 (``beta`` is within 1e-5 of 1).

    :param beta: weight of the past at each update, in (0, 1): every batch weighs about the same when it is close to 1
    :param epsilon: floor of the debiasing term
    :param min_var: floor of the variance
    """

    # Buffers (register_buffer), declared for the type checker.
    running_mean: th.Tensor
    running_mean_sq: th.Tensor
    debiasing_term: th.Tensor

    def __init__(self, beta: float = VALUE_NORM_BETA, epsilon: float = VALUE_NORM_EPSILON,
                 min_var: float = VALUE_NORM_MIN_VAR) -> None:
        super().__init__()
        self.beta = check_value_norm_beta(beta)
        self.epsilon, self.min_var = float(epsilon), float(min_var)
        self.register_buffer("running_mean", th.zeros((), dtype=th.float64))
        self.register_buffer("running_mean_sq", th.zeros((), dtype=th.float64))
        self.register_buffer("debiasing_term", th.zeros((), dtype=th.float64))

    @th.no_grad()
    def update(self, values: th.Tensor | np.ndarray) -> None:
        """Add a batch of returns (any shape; every element counts once, the batch as one update)."""
        x = th.as_tensor(np.asarray(values) if not isinstance(values, th.Tensor) else values)
        x = x.to(device=self.running_mean.device, dtype=th.float64).reshape(-1)
        if x.numel() == 0:
            return
        beta = self.beta
        self.running_mean.mul_(beta).add_((1.0 - beta) * x.mean())
        self.running_mean_sq.mul_(beta).add_((1.0 - beta) * (x**2).mean())
        self.debiasing_term.mul_(beta).add_(1.0 - beta)

    def mean_var(self) -> tuple[th.Tensor, th.Tensor]:
        """The debiased mean and variance (float64 scalars)."""
        debias = self.debiasing_term.clamp(min=self.epsilon)
        mean = self.running_mean / debias
        var = (self.running_mean_sq / debias - mean**2).clamp(min=self.min_var)
        return mean, var

    def mean_std(self) -> tuple[float, float]:
        """The debiased mean and standard deviation, as floats."""
        mean, var = self.mean_var()
        return float(mean), float(var.sqrt())

    def normalize(self, values: th.Tensor) -> th.Tensor:
        """``(values - mean) / std``, in ``values``' dtype."""
        mean, var = self.mean_var()
        return ((values.double() - mean) / var.sqrt()).to(values.dtype)

    def denormalize(self, values: th.Tensor) -> th.Tensor:
        """``values * std + mean``, in ``values``' dtype."""
        mean, var = self.mean_var()
        return (values.double() * var.sqrt() + mean).to(values.dtype)

    def extra_repr(self) -> str:
        return f"beta={self.beta}, epsilon={self.epsilon}, min_var={self.min_var}"


#: Rows from which the critic computes the first layer's product with the global state once per distinct state
#: (:func:`first_layer_once_per_state`): a training batch; a rollout step's few rows take the plain path.
SHARED_STATE_MIN_ROWS = 256


def state_groups(state: th.Tensor, probe: th.Tensor) -> tuple[th.Tensor, th.Tensor] | None:
    """Rows of ``state`` ``(N, S)`` grouped by equal value: ``(first, inverse)``, a row of each group and each row's
    group; None when two different states project alike (never merged) or the rows hold fewer than two copies of each
    state on average (nothing to share). The groups come from two random projections (``probe``, float32 ``(S, 2)``,
    their bits one 64-bit key per row) and are checked row by row."""
    keys = (state @ probe).contiguous().view(th.int64).reshape(-1)
    _, inverse = th.unique(keys, return_inverse=True)
    groups = int(inverse.max()) + 1 if len(inverse) else 0
    if 2 * groups > len(state):
        return None
    first = th.empty(groups, dtype=th.long, device=state.device).scatter_(
        0, inverse, th.arange(len(state), device=state.device))
    if not th.equal(state.index_select(0, first).index_select(0, inverse), state):
        return None
    return first, inverse


def first_layer_once_per_state(features: th.Tensor, lo: int, hi: int, norm: nn.LayerNorm | None, linear: nn.Linear,
                               first: th.Tensor, inverse: th.Tensor) -> th.Tensor:
    """``linear(norm(features))`` (``norm`` optional) computed with the product of ``linear``'s weights and the columns
    ``[lo, hi)`` (the global state, the same for every agent of a copy at a step) once per group of rows with the same
    state (:func:`state_groups`).

    The same function, written out: with ``x = [r, s]`` (the rest and the state), ``W' = W diag(gamma)``, a LayerNorm
    then a linear layer give ``(W' x - mean(x) W' 1) / sqrt(var(x) + eps) + W beta + b``, whose ``W'_s s`` and the
    state's sums enter each row through its group; without the norm, ``W x + b``. Equal to the plain path up to
    floating-point rounding (a different order of sums), with gradients for every parameter. Written here because torch
    has no layer that shares an input block across rows.

    :param features: ``(N, D)`` the critic's input
    :param lo: the state's first column
    :param hi: one past its last
    :param norm: the input's LayerNorm, or None
    :param linear: the first linear layer (``D`` inputs)
    :param first: a row of each group
    :param inverse: each row's group
    """
    states = features[:, lo:hi].index_select(0, first)
    rest = th.cat([features[:, :lo], features[:, hi:]], dim=1)
    weight = linear.weight if norm is None else linear.weight * norm.weight
    bias = linear.bias if norm is None else linear.bias + linear.weight @ norm.bias
    shared = states @ weight[:, lo:hi].T  # (groups, hidden): the state's part, once per group
    out = rest @ th.cat([weight[:, :lo], weight[:, hi:]], dim=1).T + shared.index_select(0, inverse)
    if norm is None:
        return out + bias
    width = features.shape[1]
    mean = (rest.sum(1) + states.sum(1).index_select(0, inverse)) / width
    var = ((rest * rest).sum(1) + (states * states).sum(1).index_select(0, inverse)) / width - mean * mean
    scale = th.rsqrt(var.clamp(min=0.0) + norm.eps)
    return scale[:, None] * (out - mean[:, None] * weight.sum(1)[None, :]) + bias


def _mlp(input_dim: int, sizes: list[int], activation_fn: type[nn.Module], layer_norm: bool) -> nn.Sequential:
    """on-policy's ``MLPBase``: [LayerNorm(input)], then ``Linear -> activation -> [LayerNorm]`` per hidden layer."""
    layers: list[nn.Module] = [nn.LayerNorm(input_dim)] if layer_norm else []
    size = input_dim
    for hidden in sizes:
        layers += [nn.Linear(size, hidden), activation_fn()]
        if layer_norm:
            layers.append(nn.LayerNorm(hidden))
        size = hidden
    return nn.Sequential(*layers)


class MAPPOExtractor(nn.Module):
    """The actor's and the critic's hidden layers (SB3's ``MlpExtractor`` interface) over an augmented observation.

    :param actor_dim: the features of the agent's own observation, first in the features (the actor reads them alone)
    :param critic_dim: all the features (the critic reads them all)
    :param net_arch: hidden sizes, shared by both networks (a list) or ``dict(pi=[...], vf=[...])``
    :param activation_fn: activation
    :param layer_norm: LayerNorm on the input and after each hidden layer
    :param state_dim: the global state's size, right after the actor's features in the critic's: the critic's first
        layer then computes its product with the state once per distinct state in a training batch (the agents of a
        copy share it; :func:`first_layer_once_per_state`); None: always the plain path
    """

    def __init__(self, actor_dim: int, critic_dim: int, net_arch: list[int] | dict[str, list[int]],
                 activation_fn: type[nn.Module], layer_norm: bool, state_dim: int | None = None) -> None:
        super().__init__()
        if isinstance(net_arch, dict):
            pi_sizes, vf_sizes = list(net_arch.get("pi", [])), list(net_arch.get("vf", []))
        else:
            pi_sizes = vf_sizes = list(net_arch)
        self.obs_dim = actor_dim
        self.policy_net = _mlp(actor_dim, pi_sizes, activation_fn, layer_norm)
        self.value_net = _mlp(critic_dim, vf_sizes, activation_fn, layer_norm)
        self.latent_dim_pi = pi_sizes[-1] if pi_sizes else actor_dim
        self.latent_dim_vf = vf_sizes[-1] if vf_sizes else critic_dim
        self.state_columns = None if state_dim is None or not vf_sizes else (actor_dim, actor_dim + state_dim)
        # (fixed projections, not parameters: a buffer would change the saved policy's keys)
        self._probe = th.randn(state_dim or 0, 2, generator=th.Generator().manual_seed(0))
        self._groups: tuple[th.Tensor, th.Tensor] | None = None

    def forward(self, features: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
        return self.forward_actor(features), self.forward_critic(features)

    def forward_actor(self, features: th.Tensor) -> th.Tensor:
        """The actor's latent from the features of the agent's own observation (the first ``obs_dim`` values) only."""
        return self.policy_net(features[..., : self.obs_dim])

    def forward_critic(self, features: th.Tensor) -> th.Tensor:
        """The critic's latent from the whole augmented observation (a training batch's first layer once per state)."""
        if (self.state_columns is None or features.ndim != 2 or len(features) < SHARED_STATE_MIN_ROWS
                or features.dtype != th.float32):
            return self.value_net(features)
        lo, hi = self.state_columns
        groups = self._groups if self._groups is not None and len(self._groups[1]) == len(features) else None
        groups = groups or state_groups(features[:, lo:hi], self._probe.to(features.device))
        if groups is None:
            return self.value_net(features)
        norm = self.value_net[0] if isinstance(self.value_net[0], nn.LayerNorm) else None
        linear = self.value_net[1 if norm is not None else 0]
        assert isinstance(linear, nn.Linear)  # (_mlp's layout)
        return self.value_net[2 if norm is not None else 1:](first_layer_once_per_state(features, lo, hi, norm, linear,
                                                                                        *groups))

    @contextmanager
    def grouped(self, state: th.Tensor) -> Iterator[None]:
        """Within the block, the critic's forward passes on ``len(state)`` rows take their groups of equal states from
        ``state`` (the same rows, in the same order: MAPPO's epochs over one whole rollout) instead of finding them at
        each pass."""
        self._groups = state_groups(state, self._probe.to(state.device)) if state.dtype == th.float32 else None
        try:
            yield
        finally:
            self._groups = None


class MAPPOPolicy(ActorCriticPolicy):
    """SB3's ``ActorCriticPolicy`` with a decentralised actor and a critic over MAPPO's agent-specific global state.

    Takes ``ActorCriticPolicy``'s arguments (``net_arch`` as a list shared by both networks or ``dict(pi, vf)``),
    with on-policy's defaults, plus the ones below. A ``features_extractor_class`` (e.g. the message extractors of
    :mod:`sb3_emmarl.common.extractors`) reads the agent's own observation; the critic's copy of it (actor and
    critic do not share a learned extractor unless ``share_features_extractor=True``) is followed by the global state
    and agent id.

    :param state_layout: the :class:`~sb3_emmarl.mappo.wrappers.StateLayout` fields (set by MAPPO)
    :param layer_norm: LayerNorm on each network's input and after each hidden layer (on-policy's
        ``use_feature_normalization`` and ``MLPLayer``)
    :param value_norm: the value head predicts normalised returns (:class:`ValueNorm`)
    :param value_norm_beta: the normaliser's ``beta``
    """

    state_layout: StateLayout
    layer_norm: bool

    def __init__(
        self,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        lr_schedule: Schedule,
        net_arch: list[int] | dict[str, list[int]] | None = None,
        activation_fn: type[nn.Module] = nn.ReLU,
        *args: Any,
        state_layout: dict[str, Any],
        layer_norm: bool = True,
        value_norm: bool = True,
        value_norm_beta: float = VALUE_NORM_BETA,
        **kwargs: Any,
    ) -> None:
        layout = StateLayout.from_dict(state_layout)
        if not isinstance(observation_space, spaces.Box) or observation_space.shape != (layout.critic_dim,):
            raise ValueError(f"the observation space must be a Box of shape ({layout.critic_dim},) (observation, state "
                             f"and agent id), got {observation_space}")
        # on-policy's actor and critic are separate networks: a learned extractor is not shared (sharing SB3's
        # parameterless FlattenExtractor changes nothing and saves a pass)
        kwargs.setdefault("share_features_extractor",
                          kwargs.get("features_extractor_class", FlattenExtractor) is FlattenExtractor)
        for name, value in (("layer_norm", layer_norm), ("value_norm", value_norm)):
            if not isinstance(value, (bool, np.bool_)):
                raise ValueError(f"{name} must be True or False, got {value!r}")
        # Plain attributes: nn.Module.__init__ has not run yet, and _build_mlp_extractor (inside it) reads them.
        object.__setattr__(self, "state_layout", layout)
        object.__setattr__(self, "layer_norm", bool(layer_norm))
        if net_arch is None:
            net_arch = dict(pi=[64, 64], vf=[64, 64])  # on-policy: hidden_size 64, two hidden layers
        super().__init__(observation_space, action_space, lr_schedule, net_arch, activation_fn, *args, **kwargs)
        self.value_norm = ValueNorm(check_value_norm_beta(value_norm_beta)) if value_norm else None
        self._value_norm_beta = check_value_norm_beta(value_norm_beta)
        self.to(self.device)

    def make_features_extractor(self) -> SplitFeaturesExtractor:
        """``policy_kwargs``' features extractor (default: none) over the agent's observation, then the global state
        and agent id as they are."""
        return SplitFeaturesExtractor(cast(spaces.Box, self.observation_space), self.state_layout.obs_dim,  # (checked)
                                      self.features_extractor_class, self.features_extractor_kwargs)

    def _build_mlp_extractor(self) -> None:
        layout = self.state_layout
        actor_dim = self.features_dim - (layout.critic_dim - layout.obs_dim)
        self.mlp_extractor = MAPPOExtractor(  # type: ignore[assignment]  # SB3 types it MlpExtractor; any module with its interface works
            actor_dim, self.features_dim, self.net_arch, self.activation_fn, self.layer_norm, layout.state_dim)

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data.update(state_layout=self.state_layout.to_dict(), layer_norm=self.layer_norm,
                    value_norm=self.value_norm is not None, value_norm_beta=self._value_norm_beta)
        return data

    def grouped(self, observations: th.Tensor) -> AbstractContextManager[None]:
        """:meth:`MAPPOExtractor.grouped` with the global state of these augmented observations."""
        layout = self.state_layout
        extractor = cast(MAPPOExtractor, self.mlp_extractor)  # (_build_mlp_extractor's)
        return extractor.grouped(observations[:, layout.obs_dim:layout.obs_dim + layout.state_dim])

    # ------------------------------------------------------------------ values in the returns' units
    def denormalize(self, values: th.Tensor) -> th.Tensor:
        """The value head's output in the returns' units (unchanged without value normalisation)."""
        return values if self.value_norm is None else self.value_norm.denormalize(values)

    def forward(self, obs: th.Tensor, deterministic: bool = False) -> tuple[th.Tensor, th.Tensor, th.Tensor]:
        actions, values, log_prob = super().forward(obs, deterministic)
        return actions, self.denormalize(values), log_prob

    def predict_values(self, obs: PyTorchObs) -> th.Tensor:
        return self.denormalize(super().predict_values(obs))

    def evaluate_actions(self, obs: PyTorchObs, actions: th.Tensor) -> tuple[th.Tensor, th.Tensor, th.Tensor | None]:
        values, log_prob, entropy = super().evaluate_actions(obs, actions)
        return self.denormalize(values), log_prob, entropy

    def evaluate_actions_normalized(self, obs: PyTorchObs,
                                    actions: th.Tensor) -> tuple[th.Tensor, th.Tensor, th.Tensor | None]:
        """As ``evaluate_actions``, with the value head's own (normalised) output: MAPPO's value loss."""
        return super().evaluate_actions(obs, actions)

    # ------------------------------------------------------------------ parameter groups
    def critic_parameters(self) -> list[nn.Parameter]:
        """The critic's parameters (its hidden layers and the value head, and its features extractor unless shared)."""
        own = [] if self.share_features_extractor else list(self.vf_features_extractor.parameters())
        return [*own, *self.mlp_extractor.value_net.parameters(), *self.value_net.parameters()]

    def actor_parameters(self) -> list[nn.Parameter]:
        """Every other parameter: the actor's hidden layers, the action head (and ``log_std``)."""
        critic = {id(p) for p in self.critic_parameters()}
        return [p for p in self.parameters() if id(p) not in critic]

    # ------------------------------------------------------------------ plain observations
    def predict(self, observation: np.ndarray | dict[str, np.ndarray], state: tuple[np.ndarray, ...] | None = None,
                episode_start: np.ndarray | None = None,
                deterministic: bool = False) -> tuple[np.ndarray, tuple[np.ndarray, ...] | None]:
        """SB3's ``predict``, for augmented observations or plain ones (``obs_dim`` values: the actor's whole input;
        the critic's part is filled with zeros, which the actions do not depend on).

        :raise ValueError: for observations of another size
        """
        obs = np.asarray(observation)
        layout = self.state_layout
        if obs.ndim >= 1 and obs.shape[-1] == layout.obs_dim:
            obs = np.concatenate([obs, np.zeros((*obs.shape[:-1], layout.critic_dim - layout.obs_dim), obs.dtype)], -1)
        elif obs.ndim == 0 or obs.shape[-1] != layout.critic_dim:
            raise ValueError(f"observations must have {layout.obs_dim} values (plain) or {layout.critic_dim} (with the "
                             f"global state), got shape {obs.shape}")
        return super().predict(obs, state, episode_start, deterministic)


#: MAPPO's ``"MlpPolicy"``.
MlpPolicy = MAPPOPolicy
