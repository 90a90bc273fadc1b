"""How a policy's networks read a context appended to their features (the told mode, the belief): ``belief_conditioning``.

- ``"concat"``: SB3's ``MlpExtractor`` over the features, the context among them (what every algorithm did before).
- ``"mixture"``: one network per component of the context over the rest of the features, their outputs mixed by the
  context's weights (a told one-hot picks one network, a belief weights them): a head per mode, routed by the mode.
- ``"film"``: SB3's layers over the rest of the features, every hidden layer's units scaled and shifted by linear
  functions of the context (FiLM, Perez et al. 2018): the context changes what each unit computes, and cannot be left
  unread as a concatenated input can while the rest of the observation explains the return.

Both start as a network that does not read the context: the mixture's networks as copies of one, FiLM's scales and
shifts at zero (:meth:`ConditionedMlpExtractor.start_blind`, after SB3's initialisation), as the zero start of a
concatenated context does (:mod:`sb3_emmarl.common.appended.initialization`). Written here because SB3 builds its
networks' hidden layers in one class, ``MlpExtractor``, that reads all its features alike.
"""

from __future__ import annotations

from itertools import pairwise
from typing import TYPE_CHECKING, Any

import torch as th
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.torch_layers import create_mlp
from stable_baselines3.common.type_aliases import Schedule
from stable_baselines3.common.utils import get_device
from torch import nn

from sb3_emmarl.common.trust.validation import CONDITIONINGS, RULES


class ConditionedMlp(nn.Module):
    """One network (the policy's or the value's hidden layers) over features whose last ``n_context`` values are the
    context, reading the context as ``conditioning`` says (``"mixture"`` or ``"film"``).

    :param in_dim: the features' size, context included
    :param layers: hidden layer sizes (at least one: without a hidden layer nothing would read the context)
    :param activation_fn: the hidden layers' activation
    :param n_context: the context's size, at the end of the features
    :param conditioning: ``"mixture"`` or ``"film"``
    """

    def __init__(self, in_dim: int, layers: list[int], activation_fn: type[nn.Module], n_context: int,
                 conditioning: str) -> None:
        super().__init__()
        if conditioning not in CONDITIONINGS[1:]:
            raise ValueError(f"conditioning must be one of {list(CONDITIONINGS[1:])}, got {conditioning!r}")
        if not layers:
            raise ValueError(f"belief_conditioning={conditioning!r} needs at least one hidden layer per network "
                             "(net_arch), got none")
        if not 0 < n_context < in_dim:
            raise ValueError(f"n_context must be in [1, {in_dim - 1}], got {n_context}")
        self.n_context, self.conditioning, self.out_dim = n_context, conditioning, layers[-1]
        rest = in_dim - n_context
        if conditioning == "mixture":
            self.heads = nn.ModuleList(nn.Sequential(*create_mlp(rest, -1, layers, activation_fn))
                                       for _ in range(n_context))
        else:
            sizes = [rest, *layers]
            self.layers = nn.ModuleList(nn.Linear(i, o) for i, o in pairwise(sizes))
            self.films = nn.ModuleList(nn.Linear(n_context, 2 * o) for o in layers)
            self.activation = activation_fn()

    def forward(self, features: th.Tensor) -> th.Tensor:
        x, context = features[..., :-self.n_context], features[..., -self.n_context:]
        if self.conditioning == "mixture":
            outputs = th.stack([head(x) for head in self.heads], dim=-2)
            return (context.unsqueeze(-1) * outputs).sum(dim=-2)
        for layer, film in zip(self.layers, self.films):
            scale, shift = film(context).chunk(2, dim=-1)
            x = self.activation(layer(x)) * (1.0 + scale) + shift
        return x

    @th.no_grad()
    def start_blind(self) -> None:
        """Make the network start as one that does not read the context (see the module's docstring)."""
        if self.conditioning == "mixture":
            first = self.heads[0].state_dict()
            for head in self.heads[1:]:
                head.load_state_dict(first)
        else:
            for film in self.films:
                assert isinstance(film, nn.Linear)  # (the ModuleList's items are typed as modules)
                film.weight.zero_()
                film.bias.zero_()


class ConditionedMlpExtractor(nn.Module):
    """SB3's ``MlpExtractor`` (``net_arch`` as it takes it: a list, or ``dict(pi=..., vf=...)``) whose policy and value
    networks read the last ``n_context`` features as ``conditioning`` says (:class:`ConditionedMlp`).

    :param feature_dim: the features' size, context included
    :param net_arch: SB3's ``net_arch``
    :param activation_fn: the hidden layers' activation
    :param n_context: the context's size
    :param conditioning: ``"mixture"`` or ``"film"``
    :param device: torch device
    """

    def __init__(self, feature_dim: int, net_arch: list[int] | dict[str, list[int]], activation_fn: type[nn.Module],
                 n_context: int, conditioning: str, device: th.device | str = "auto") -> None:
        super().__init__()
        pi, vf = (net_arch.get("pi", []), net_arch.get("vf", [])) if isinstance(net_arch, dict) else (net_arch, net_arch)
        self.policy_net = ConditionedMlp(feature_dim, list(pi), activation_fn, n_context, conditioning)
        self.value_net = ConditionedMlp(feature_dim, list(vf), activation_fn, n_context, conditioning)
        self.latent_dim_pi, self.latent_dim_vf = self.policy_net.out_dim, self.value_net.out_dim
        self.to(get_device(device))

    def forward(self, features: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
        return self.forward_actor(features), self.forward_critic(features)

    def forward_actor(self, features: th.Tensor) -> th.Tensor:
        return self.policy_net(features)

    def forward_critic(self, features: th.Tensor) -> th.Tensor:
        return self.value_net(features)

    def start_blind(self) -> None:
        """Both networks start as ones that do not read the context."""
        self.policy_net.start_blind()
        self.value_net.start_blind()


if TYPE_CHECKING:  # the type checker sees the SB3 policy the mixin is placed before; at run time it is a plain class
    from stable_baselines3.common.policies import ActorCriticPolicy as _PolicyBase
else:
    _PolicyBase = object


class ConditionedPolicyMixin(_PolicyBase):
    """An SB3 actor-critic policy whose networks read the context at the end of its features (:meth:`context_width`
    values) as ``belief_conditioning`` says (:data:`CONDITIONINGS`; ``"concat"`` builds SB3's networks unchanged).

    :param belief_conditioning: ``"concat"``, ``"mixture"`` or ``"film"``
    """

    belief_conditioning: str

    def __init__(self, *args: Any, belief_conditioning: str = "concat", **kwargs: Any) -> None:
        belief_conditioning = RULES["belief_conditioning"]("belief_conditioning", belief_conditioning)
        object.__setattr__(self, "belief_conditioning", belief_conditioning)  # (read while super().__init__ builds)
        super().__init__(*args, **kwargs)

    def context_width(self) -> int:
        """The context's size, at the end of the features (0: no context, SB3's networks)."""
        raise NotImplementedError

    def _build_mlp_extractor(self) -> None:
        n_context = self.context_width()
        if self.belief_conditioning == "concat" or n_context == 0:
            super()._build_mlp_extractor()
            return
        self.mlp_extractor = ConditionedMlpExtractor(  # type: ignore[assignment]  # SB3 types it as its own class
            self.features_dim, self.net_arch, self.activation_fn, n_context, self.belief_conditioning, self.device)

    def _build(self, lr_schedule: Schedule) -> None:
        super()._build(lr_schedule)
        if isinstance(self.mlp_extractor, ConditionedMlpExtractor):
            self.mlp_extractor.start_blind()  # (after SB3's orthogonal initialisation)

    def _get_constructor_parameters(self) -> dict[str, Any]:
        return {**super()._get_constructor_parameters(), "belief_conditioning": self.belief_conditioning}


class ContextActorCriticPolicy(ConditionedPolicyMixin, ActorCriticPolicy):
    """SB3's ``ActorCriticPolicy`` over observations that end with ``context_dim`` values (OraclePPO's told mode),
    read as ``belief_conditioning`` says.

    Takes ``ActorCriticPolicy``'s arguments plus ``context_dim`` (set by the algorithm) and ``belief_conditioning``.
    """

    context_dim: int

    def __init__(self, *args: Any, context_dim: int = 0, **kwargs: Any) -> None:
        object.__setattr__(self, "context_dim", int(context_dim))
        super().__init__(*args, **kwargs)

    def context_width(self) -> int:
        return self.context_dim

    def _get_constructor_parameters(self) -> dict[str, Any]:
        return {**super()._get_constructor_parameters(), "context_dim": self.context_dim}
