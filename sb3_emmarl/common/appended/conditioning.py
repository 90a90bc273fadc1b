"""How a policy's networks read a context appended to their features (the told mode, the belief): ``belief_conditioning``.

- ``"concat"``: SB3's ``MlpExtractor`` over the features, the context among them (what every algorithm did before).
- ``"mixture"``: one output head per component of the context (the policy's action head and its value head), on
  hidden layers shared by all and reading the rest of the features, the heads' outputs mixed by the context's weights
  (a told one-hot picks one head, a belief weights them): ``sum_k c_k (W_k h + b_k)``. The hidden layers pass the
  context on beside their last layer, and :class:`MixedHeads` takes the place of SB3's linear action and value heads:
  one linear layer computes every component's outputs, then the context weighs them. It costs the hidden layers of
  one network and ``K`` heads (its first form, SB3's heads over the context's outer product with the last layer, cost
  a ``K``-times wider head: 1.36x concatenation's training time on the reserve).
- ``"film"``: SB3's layers over the rest of the features, every hidden layer's units scaled and shifted by linear
  functions of the context (FiLM, Perez et al. 2018): the context changes what each unit computes, and cannot be left
  unread as a concatenated input can while the rest of the observation explains the return.

Both start as a network that does not read the context: the mixture's heads as copies of one
(:meth:`ConditionedPolicyMixin._build`), FiLM's scales and shifts at zero
(:meth:`ConditionedMlpExtractor.start_blind`), after SB3's initialisation, as the zero start of a concatenated context
does (:mod:`sb3_emmarl.common.appended.initialization`). Written here because SB3 builds its networks' hidden layers
in one class, ``MlpExtractor``, that reads all its features alike.
"""

from __future__ import annotations

from itertools import pairwise
from typing import TYPE_CHECKING, Any

import torch as th
from stable_baselines3.common.policies import ActorCriticPolicy, ContinuousCritic
from stable_baselines3.common.preprocessing import get_action_dim
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor, create_mlp
from stable_baselines3.common.type_aliases import Schedule
from stable_baselines3.common.utils import get_device
from stable_baselines3.td3.policies import Actor
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
        self.n_context, self.conditioning = n_context, conditioning
        #: the last hidden layer's width, what an output head reads
        self.head_inputs = layers[-1]
        #: the output's size (``"mixture"``: the last hidden layer, then the context, for :class:`MixedHeads`)
        self.out_dim = layers[-1] + (n_context if conditioning == "mixture" else 0)
        rest = in_dim - n_context
        if conditioning == "mixture":
            self.trunk = nn.Sequential(*create_mlp(rest, -1, layers, activation_fn))
        else:
            sizes = [rest, *layers]
            self.layers = nn.ModuleList(nn.Linear(i, o) for i, o in pairwise(sizes))
            self.films = nn.ModuleList(nn.Linear(n_context, 2 * o) for o in layers)
            self.activation = activation_fn()

    def forward(self, features: th.Tensor) -> th.Tensor:
        x, context = features[..., :-self.n_context], features[..., -self.n_context:]
        if self.conditioning == "mixture":
            return th.cat([self.trunk(x), context], dim=-1)
        for layer, film in zip(self.layers, self.films):
            scale, shift = film(context).chunk(2, dim=-1)
            x = self.activation(layer(x)) * (1.0 + scale) + shift
        return x

    @th.no_grad()
    def start_blind(self) -> None:
        """Make FiLM start as a network that does not read the context (the mixture's hidden layers do not read it; its
        heads are the policy's, see :meth:`ConditionedPolicyMixin._build`)."""
        if self.conditioning == "film":
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
        # (the widths SB3 builds its heads over; the mixture's heads are then :class:`MixedHeads` over them)
        self.latent_dim_pi, self.latent_dim_vf = self.policy_net.head_inputs, self.value_net.head_inputs
        self.to(get_device(device))

    def forward(self, features: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
        return self.forward_actor(features), self.forward_critic(features)

    def forward_actor(self, features: th.Tensor) -> th.Tensor:
        return self.policy_net(features)

    def forward_critic(self, features: th.Tensor) -> th.Tensor:
        return self.value_net(features)

    def start_blind(self) -> None:
        """Both networks' FiLM starts at zero (:meth:`ConditionedMlp.start_blind`)."""
        self.policy_net.start_blind()
        self.value_net.start_blind()


class MixedHeads(nn.Module):
    """``n_context`` linear heads over the same hidden units, mixed by the context: reads ``[h, c]`` (the mixture's
    hidden layers' output, :class:`ConditionedMlp`) and gives ``sum_k c_k (W_k h + b_k)``. One linear layer computes
    every head's outputs (component-major), so a head costs its own outputs only. Written here because SB3's heads
    are single linear layers over the latent features.

    :param in_features: the hidden units' width
    :param out_features: one head's outputs
    :param n_context: the context's size (the number of heads)
    """

    def __init__(self, in_features: int, out_features: int, n_context: int) -> None:
        super().__init__()
        self.in_features, self.out_features, self.n_context = in_features, out_features, n_context
        self.heads = nn.Linear(in_features, n_context * out_features)

    @classmethod
    def alike(cls, head: nn.Linear, n_context: int) -> MixedHeads:
        """``n_context`` copies of ``head`` (its weights, as initialised): a mixture that starts as one head that does
        not read the context."""
        mixed = cls(head.in_features, head.out_features, n_context).to(head.weight.device)
        with th.no_grad():
            mixed.heads.weight.copy_(head.weight.repeat(n_context, 1))
            mixed.heads.bias.copy_(head.bias.repeat(n_context))
        return mixed

    def forward(self, inputs: th.Tensor) -> th.Tensor:
        hidden, context = inputs[..., :-self.n_context], inputs[..., -self.n_context:]
        outputs = self.heads(hidden).unflatten(-1, (self.n_context, self.out_features))
        return (context.unsqueeze(-1) * outputs).sum(dim=-2)


class ConditionedHead(nn.Module):
    """A network with its output layer (TD3's actor and critics): :class:`ConditionedMlp`, then a linear layer (and
    ``tanh`` with ``squash_output``), starting as a network that does not read the context.

    :param in_dim: the input's size, the context (its last ``n_context`` values) included
    :param out_dim: the output's size
    :param layers: hidden layer sizes (at least one)
    :param activation_fn: the hidden layers' activation
    :param n_context: the context's size
    :param conditioning: ``"mixture"`` or ``"film"``
    :param squash_output: end with ``tanh`` (the actor's actions)
    """

    def __init__(self, in_dim: int, out_dim: int, layers: list[int], activation_fn: type[nn.Module], n_context: int,
                 conditioning: str, squash_output: bool = False) -> None:
        super().__init__()
        self.hidden = ConditionedMlp(in_dim, layers, activation_fn, n_context, conditioning)
        out = nn.Linear(self.hidden.head_inputs, out_dim)
        self.out: nn.Module = MixedHeads.alike(out, n_context) if conditioning == "mixture" else out
        self.squash_output = squash_output
        self.hidden.start_blind()

    def forward(self, inputs: th.Tensor) -> th.Tensor:
        outputs = self.out(self.hidden(inputs))
        return th.tanh(outputs) if self.squash_output else outputs


class ConditionedCritic(ContinuousCritic):
    """SB3's ``ContinuousCritic`` whose Q-networks read the context at the end of the features as ``conditioning`` says
    (the actions go in before the context: ``[rest of the features, actions, context]``).

    Takes ``ContinuousCritic``'s arguments (by keyword, as ``TD3Policy.make_critic`` gives them) plus ``n_context`` and
    ``conditioning``.
    """

    def __init__(self, *, n_context: int, conditioning: str, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.n_context = n_context
        in_dim = int(kwargs["features_dim"]) + get_action_dim(self.action_space)
        for index in range(self.n_critics):
            q_net = ConditionedHead(in_dim, 1, list(kwargs["net_arch"]), kwargs.get("activation_fn", nn.ReLU), n_context,
                                    conditioning)
            self.add_module(f"qf{index}", q_net)  # (in place of SB3's network of that name)
            self.q_networks[index] = q_net

    def _q_input(self, features: th.Tensor, actions: th.Tensor) -> th.Tensor:
        n = self.n_context
        return th.cat([features[:, :-n], actions, features[:, -n:]], dim=1)

    def forward(self, obs: th.Tensor, actions: th.Tensor) -> tuple[th.Tensor, ...]:
        with th.set_grad_enabled(not self.share_features_extractor):  # (as SB3's)
            features = self.extract_features(obs, self.features_extractor)
        q_input = self._q_input(features, actions)
        return tuple(q_net(q_input) for q_net in self.q_networks)

    def q1_forward(self, obs: th.Tensor, actions: th.Tensor) -> th.Tensor:
        with th.no_grad():
            features = self.extract_features(obs, self.features_extractor)
        return self.q_networks[0](self._q_input(features, actions))


if TYPE_CHECKING:  # the type checker sees the SB3 policies the mixins are placed before; at run time plain classes
    from stable_baselines3.common.policies import ActorCriticPolicy as _ActorCriticBase
    from stable_baselines3.common.policies import BasePolicy as _PolicyBase
    from stable_baselines3.td3.policies import TD3Policy as _TD3Base
else:
    _ActorCriticBase = _PolicyBase = _TD3Base = object


class Conditioning(_PolicyBase):
    """What the conditioned policies share: ``belief_conditioning`` (checked, saved with the policy) and the context's
    width (:meth:`context_width`, the policy's own).

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

    def _conditioned_width(self) -> int:
        """The context's size where the networks read it apart (0 where they are SB3's: ``"concat"`` or no context)."""
        return 0 if self.belief_conditioning == "concat" else self.context_width()

    def _get_constructor_parameters(self) -> dict[str, Any]:
        return {**super()._get_constructor_parameters(), "belief_conditioning": self.belief_conditioning}


class ConditionedPolicyMixin(Conditioning, _ActorCriticBase):
    """An SB3 actor-critic policy whose networks read the context at the end of its features (:meth:`context_width`
    values) as ``belief_conditioning`` says (:data:`CONDITIONINGS`; ``"concat"`` builds SB3's networks unchanged).

    :param belief_conditioning: ``"concat"``, ``"mixture"`` or ``"film"``
    """

    def _build_mlp_extractor(self) -> None:
        n_context = self._conditioned_width()
        if not n_context:
            super()._build_mlp_extractor()
            return
        self.mlp_extractor = ConditionedMlpExtractor(  # type: ignore[assignment]  # SB3 types it as its own class
            self.features_dim, self.net_arch, self.activation_fn, n_context, self.belief_conditioning, self.device)

    def _build(self, lr_schedule: Schedule) -> None:
        super()._build(lr_schedule)
        if not isinstance(self.mlp_extractor, ConditionedMlpExtractor):
            return
        # (after SB3's orthogonal initialisation)
        self.mlp_extractor.start_blind()
        if self.belief_conditioning == "mixture":  # SB3's heads become K copies of themselves, mixed by the context
            assert isinstance(self.action_net, nn.Linear)  # (SB3's heads of every action distribution)
            self.action_net = MixedHeads.alike(self.action_net, self.context_width())
            self.value_net = MixedHeads.alike(self.value_net, self.context_width())
            # (the optimizer as SB3's _build makes it, over the heads that replaced SB3's)
            self.optimizer = self.optimizer_class(self.parameters(), lr=lr_schedule(1), **self.optimizer_kwargs)


class ConditionedTD3Mixin(Conditioning, _TD3Base):
    """SB3's ``TD3Policy`` whose actor and critics (and their targets) read the context at the end of the features as
    ``belief_conditioning`` says (:class:`ConditionedHead`, :class:`ConditionedCritic`; ``"concat"``: SB3's).

    :param belief_conditioning: ``"concat"``, ``"mixture"`` or ``"film"``
    """

    def make_actor(self, features_extractor: BaseFeaturesExtractor | None = None) -> Actor:
        actor = super().make_actor(features_extractor)
        n_context = self._conditioned_width()
        if n_context:
            actor.mu = nn.Sequential(ConditionedHead(  # (a Sequential, as SB3 types the actor's network)
                actor.features_dim, get_action_dim(self.action_space), list(actor.net_arch), actor.activation_fn,
                n_context, self.belief_conditioning, squash_output=True)).to(self.device)
        return actor

    def make_critic(self, features_extractor: BaseFeaturesExtractor | None = None) -> ContinuousCritic:
        n_context = self._conditioned_width()
        if not n_context:
            return super().make_critic(features_extractor)
        critic_kwargs = self._update_features_extractor(self.critic_kwargs, features_extractor)
        return ConditionedCritic(**critic_kwargs, n_context=n_context, conditioning=self.belief_conditioning).to(self.device)


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
