"""Mixers: the team's value ``Q_tot`` from the agents' chosen-action values ``Q_a`` (and the global state).

- :class:`VDNMixer` (Sunehag et al. 2018): ``Q_tot = sum_a Q_a``.
- :class:`QMixer` (Rashid et al. 2018): a two-layer network over ``(Q_1, ..., Q_n)`` whose weights and biases
  are produced by hypernetworks of the global state ``s``; the weights pass through ``abs``, so that
  ``dQ_tot / dQ_a >= 0`` for every agent (monotonicity), and the greedy joint action is every agent's greedy action.
  As in the paper and EPyMARL's ``modules/mixers/qmix.py``: ELU on the hidden layer, a state-dependent bias
  ``b_1(s)`` on it and a two-layer ``V(s)`` in place of the output bias; ``hypernet_layers=2`` (EPyMARL's default)
  makes the weight hypernetworks two-layer MLPs of width ``hypernet_embed``, ``hypernet_layers=1`` single linear
  layers (the paper).
"""

from __future__ import annotations

import torch as th
from torch import nn
from torch.nn import functional as F

#: The mixers by name (the ``mixer`` argument of :class:`~sb3_emmarl.qmix.policies.ValueDecompositionPolicy`).
MIXERS = ("qmix", "vdn")


class VDNMixer(nn.Module):
    """``Q_tot = sum_a Q_a`` (no parameters, no state)."""

    def forward(self, agent_qs: th.Tensor, states: th.Tensor | None = None) -> th.Tensor:
        """:param agent_qs: ``(batch, n_agents)`` chosen-action values
        :param states: ignored
        :return: ``(batch,)`` team values"""
        return agent_qs.sum(dim=-1)


class QMixer(nn.Module):
    """QMIX's monotonic mixing network conditioned on the global state.

    :param n_agents: agents per team
    :param state_dim: size of the (flat) global state
    :param embed_dim: width of the mixing network's hidden layer (EPyMARL's ``mixing_embed_dim``)
    :param hypernet_layers: 1 (linear hypernetworks, the paper) or 2 (EPyMARL's default)
    :param hypernet_embed: hidden width of two-layer hypernetworks
    """

    def __init__(self, n_agents: int, state_dim: int, embed_dim: int = 32, hypernet_layers: int = 2,
                 hypernet_embed: int = 64) -> None:
        super().__init__()
        for name, value, low in (("n_agents", n_agents, 1), ("state_dim", state_dim, 1), ("embed_dim", embed_dim, 1),
                                 ("hypernet_embed", hypernet_embed, 1)):
            if isinstance(value, bool) or not isinstance(value, int) or value < low:
                raise ValueError(f"{name} must be an int >= {low}, got {value!r}")
        if hypernet_layers not in (1, 2) or isinstance(hypernet_layers, bool):
            raise ValueError(f"hypernet_layers must be 1 or 2, got {hypernet_layers!r}")
        self.n_agents, self.state_dim, self.embed_dim = n_agents, state_dim, embed_dim

        def hypernet(out_dim: int) -> nn.Module:
            if hypernet_layers == 1:
                return nn.Linear(state_dim, out_dim)
            return nn.Sequential(nn.Linear(state_dim, hypernet_embed), nn.ReLU(), nn.Linear(hypernet_embed, out_dim))

        self.hyper_w_1 = hypernet(embed_dim * n_agents)
        self.hyper_w_final = hypernet(embed_dim)
        self.hyper_b_1 = nn.Linear(state_dim, embed_dim)
        self.V = nn.Sequential(nn.Linear(state_dim, embed_dim), nn.ReLU(), nn.Linear(embed_dim, 1))

    def forward(self, agent_qs: th.Tensor, states: th.Tensor) -> th.Tensor:
        """:param agent_qs: ``(batch, n_agents)`` chosen-action values
        :param states: ``(batch, state_dim)`` global states
        :return: ``(batch,)`` team values, non-decreasing in every ``agent_qs[:, a]``"""
        states = states.reshape(-1, self.state_dim)
        qs = agent_qs.reshape(-1, 1, self.n_agents)
        w_1 = th.abs(self.hyper_w_1(states)).view(-1, self.n_agents, self.embed_dim)
        b_1 = self.hyper_b_1(states).view(-1, 1, self.embed_dim)
        hidden = F.elu(th.bmm(qs, w_1) + b_1)
        w_final = th.abs(self.hyper_w_final(states)).view(-1, self.embed_dim, 1)
        return (th.bmm(hidden, w_final) + self.V(states).view(-1, 1, 1)).view(-1)


def make_mixer(mixer: str, n_agents: int, state_dim: int, embed_dim: int = 32, hypernet_layers: int = 2,
               hypernet_embed: int = 64) -> nn.Module:
    """The mixer named ``mixer`` (one of :data:`MIXERS`); the sizes are QMixer's."""
    if mixer == "vdn":
        return VDNMixer()
    if mixer == "qmix":
        return QMixer(n_agents, state_dim, embed_dim, hypernet_layers, hypernet_embed)
    raise ValueError(f"mixer must be one of {list(MIXERS)}, got {mixer!r}")
