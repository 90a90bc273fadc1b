"""Decentralised features extractors over what teammates send (the table 6 baselines): graph attention, transformer.

Both read the observations of :class:`~sb3_emmarl.common.messages.NeighbourMessageWrapper`, ``[observation,
n_slots x (d_row, d_col, distance, present, message)]``, and depend on the team size only through the slots, so a
policy trained with 10 UAVs runs on 20 or 50. Both are invariant to the order of the slots, and absent slots
(``present = 0``) never change their output: their content is zeroed and they are masked out of every attention.

- :class:`GraphAttentionExtractor`: the UAV's own node ``h_i = enc(summary(o_i))`` (the 16-float message it would
  send, see :func:`~sb3_emmarl.common.messages.message_summary`) attends, in one or two rounds of GATv2-style
  attention, over its neighbours' nodes ``h_j = enc(m_j)`` (the same encoder) with edge features
  ``(d_row, d_col, distance)``; a UAV that heard nobody gets a zero aggregate. Output:
  ``ReLU(Linear([MLP(o_i), aggregate]))``.
- :class:`TransformerExtractor`: a small ``nn.TransformerEncoder`` over entity tokens: the UAV itself (its own
  message), one token per neighbour slot (message + edge features; absent ones are padding), one token per row of
  the sensing window (all channels of that row, ``7 * w`` floats, plus a learned row embedding) and one per row of
  the three coarse maps (``3 * b`` floats, plus a row embedding); the UAV's own output token is the feature.

:func:`message_policy_kwargs` builds the ``policy_kwargs`` for SB3 (``PPO("MlpPolicy", ...)``), and the same
``policy_kwargs`` work with EM-PPO, EM-DDPG, VDN+EM and MAPPO: their policies append to the environment's observation what
the algorithm adds (the belief; the global state and agent id) and run the user's extractor on the environment's
part alone through :class:`~sb3_emmarl.common.appended.extractor.SplitFeaturesExtractor`.
"""

from __future__ import annotations

from typing import Any

import torch as th
from gymnasium import spaces
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from stable_baselines3.common.vec_env import VecEnv
from torch import nn

from sb3_emmarl.common.appended.wrapping import find_wrapper
from sb3_emmarl.common.messages import EDGE_DIM, MessageLayout, NeighbourMessageWrapper, message_summary
from sb3_emmarl.common.trust.validation import MAX_LAYER, integer


def _check_space(observation_space: spaces.Space, layout: MessageLayout) -> None:
    if not isinstance(observation_space, spaces.Box) or observation_space.shape != (layout.total_dim,):
        raise ValueError(f"observation_space must be a flat Box of {layout.total_dim} floats (the reserve's "
                         f"observation with {layout.n_slots} message slots), got {observation_space}")


def _check_int(name: str, value: Any, low: int) -> int:
    return integer(low, MAX_LAYER)(name, value)


def split_observation(observations: th.Tensor, layout: MessageLayout) -> tuple[th.Tensor, th.Tensor, th.Tensor, th.Tensor]:
    """``(own observation (B, obs_dim), edges (B, S, 3), present (B, S) bool, messages (B, S, message_dim))``;
    the edges and messages of absent slots are zeroed."""
    own = observations[:, :layout.obs_dim]
    slots = observations[:, layout.obs_dim:layout.total_dim].reshape(-1, layout.n_slots, layout.slot_dim)
    present = slots[..., 3] > 0.5
    keep = present.unsqueeze(-1).to(slots.dtype)
    return own, slots[..., :3] * keep, present, slots[..., EDGE_DIM:] * keep


class GraphAttentionExtractor(BaseFeaturesExtractor):
    """GATv2-style attention of a UAV over the messages of the teammates it heard, plus an MLP of its observation.

    Round ``r``: ``s_ij = a^T LeakyReLU(W_q h_i + W_k h_j + W_e e_ij)`` per head, ``alpha = softmax_j`` over the
    present slots, ``agg = sum_j alpha_ij (W_v h_j + W_ev e_ij)``, then ``h_i <- LayerNorm(h_i + W_o agg)``.

    :param observation_space: the wrapped observation space
    :param layout: the :class:`MessageLayout` (or its ``to_dict()``) of the :class:`NeighbourMessageWrapper`
    :param features_dim: output size
    :param hidden_dim: size of the node embeddings and of the observation MLP
    :param n_heads: attention heads (must divide ``hidden_dim``)
    :param n_rounds: rounds of attention, 1 or 2
    """

    def __init__(self, observation_space: spaces.Box, layout: MessageLayout | dict[str, Any], features_dim: int = 128,
                 hidden_dim: int = 64, n_heads: int = 4, n_rounds: int = 1) -> None:
        layout = MessageLayout.from_dict(layout)
        _check_space(observation_space, layout)
        _check_int("features_dim", features_dim, 1)
        _check_int("hidden_dim", hidden_dim, 1)
        _check_int("n_heads", n_heads, 1)
        if hidden_dim % n_heads:
            raise ValueError(f"n_heads must divide hidden_dim, got n_heads={n_heads}, hidden_dim={hidden_dim}")
        if n_rounds not in (1, 2) or isinstance(n_rounds, bool):
            raise ValueError(f"n_rounds must be 1 or 2, got {n_rounds!r}")
        super().__init__(observation_space, features_dim)
        self.layout, self.n_heads, self.n_rounds = layout, n_heads, n_rounds
        d, m = hidden_dim, layout.message_dim
        self.encoder = nn.Sequential(nn.Linear(m, d), nn.ReLU(), nn.Linear(d, d))  # own and neighbour messages alike
        self.obs_mlp = nn.Sequential(nn.Linear(layout.obs_dim, d), nn.ReLU(), nn.Linear(d, d), nn.ReLU())
        self.rounds = nn.ModuleList(_GATv2Round(d, n_heads) for _ in range(n_rounds))
        self.head = nn.Sequential(nn.Linear(2 * d, features_dim), nn.ReLU())

    def forward(self, observations: th.Tensor) -> th.Tensor:
        own, edges, present, messages = split_observation(observations, self.layout)
        h_i = self.encoder(message_summary(own, self.layout))
        h_j = self.encoder(messages)
        aggregate = th.zeros_like(h_i)
        for layer in self.rounds:
            aggregate, h_i = layer(h_i, h_j, edges, present)
        return self.head(th.cat([self.obs_mlp(own), aggregate], dim=-1))


class _GATv2Round(nn.Module):
    """One round of GATv2 attention of a node over its (masked) neighbours, with edge features."""

    def __init__(self, d: int, n_heads: int) -> None:
        super().__init__()
        self.n_heads, self.d_head = n_heads, d // n_heads
        self.query, self.key, self.edge = nn.Linear(d, d), nn.Linear(d, d, bias=False), nn.Linear(3, d, bias=False)
        self.value, self.edge_value = nn.Linear(d, d), nn.Linear(3, d, bias=False)
        self.score = nn.Parameter(th.randn(n_heads, self.d_head) / self.d_head**0.5)
        self.out, self.norm = nn.Linear(d, d), nn.LayerNorm(d)

    def forward(self, h_i: th.Tensor, h_j: th.Tensor, edges: th.Tensor, present: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
        batch, slots, _ = h_j.shape
        heads = (batch, slots, self.n_heads, self.d_head)
        mixed = nn.functional.leaky_relu(self.query(h_i).unsqueeze(1) + self.key(h_j) + self.edge(edges), 0.2)
        scores = (mixed.view(heads) * self.score).sum(-1)  # (B, S, H)
        mask = present.unsqueeze(-1)
        heard = present.any(dim=1, keepdim=True).unsqueeze(-1)  # (B, 1, 1)
        scores = scores.masked_fill(~mask, float("-inf")).masked_fill(~heard, 0.0)
        alpha = th.softmax(scores, dim=1) * mask * heard  # nobody heard: all weights 0
        values = (self.value(h_j) + self.edge_value(edges)).view(heads)
        aggregate = (alpha.unsqueeze(-1) * values).sum(dim=1).reshape(batch, -1)
        return aggregate, self.norm(h_i + self.out(aggregate))


class TransformerExtractor(BaseFeaturesExtractor):
    """A small transformer encoder over the UAV, its neighbours' messages and rows of its window and maps.

    :param observation_space: the wrapped observation space
    :param layout: the :class:`MessageLayout` (or its ``to_dict()``) of the :class:`NeighbourMessageWrapper`
    :param features_dim: output size
    :param d_model: token size
    :param n_heads: attention heads (must divide ``d_model``)
    :param n_layers: encoder layers
    :param dim_feedforward: size of each layer's feed-forward network
    """

    def __init__(self, observation_space: spaces.Box, layout: MessageLayout | dict[str, Any], features_dim: int = 128,
                 d_model: int = 64, n_heads: int = 4, n_layers: int = 2, dim_feedforward: int = 128) -> None:
        layout = MessageLayout.from_dict(layout)
        _check_space(observation_space, layout)
        for name, value in (("features_dim", features_dim), ("d_model", d_model), ("n_heads", n_heads),
                            ("n_layers", n_layers), ("dim_feedforward", dim_feedforward)):
            _check_int(name, value, 1)
        if d_model % n_heads:
            raise ValueError(f"n_heads must divide d_model, got n_heads={n_heads}, d_model={d_model}")
        super().__init__(observation_space, features_dim)
        self.layout = layout
        c, w, _ = layout.window_shape
        b, m = layout.map_size, layout.message_dim
        self.self_token = nn.Linear(m, d_model)
        self.neighbour_token = nn.Linear(m + 3, d_model)
        self.window_token = nn.Linear(c * w, d_model)
        self.map_token = nn.Linear(len(layout.map_starts) * b, d_model)
        self.type_embedding = nn.Parameter(th.zeros(4, d_model))  # self, neighbour, window row, map row
        self.window_rows = nn.Parameter(th.zeros(w, d_model))
        self.map_rows = nn.Parameter(th.zeros(b, d_model))
        nn.init.normal_(self.type_embedding, std=0.02)
        nn.init.normal_(self.window_rows, std=0.02)
        nn.init.normal_(self.map_rows, std=0.02)
        layer = nn.TransformerEncoderLayer(d_model, n_heads, dim_feedforward, dropout=0.0, batch_first=True)
        self.encoder = nn.TransformerEncoder(layer, n_layers, enable_nested_tensor=False)
        self.head = nn.Sequential(nn.Linear(d_model, features_dim), nn.ReLU())

    def forward(self, observations: th.Tensor) -> th.Tensor:
        lay = self.layout
        own, edges, present, messages = split_observation(observations, lay)
        batch = own.shape[0]
        c, w, _ = lay.window_shape
        b = lay.map_size
        window = own[:, lay.window_start:lay.window_start + c * w * w].reshape(batch, c, w, w)
        window_rows = window.permute(0, 2, 1, 3).reshape(batch, w, c * w)  # one token per window row, all channels
        maps = th.stack([own[:, s:s + b * b].reshape(batch, b, b) for s in lay.map_starts], dim=2)  # (B, b, 3, b)
        types = self.type_embedding
        tokens = th.cat([
            (self.self_token(message_summary(own, lay)) + types[0]).unsqueeze(1),
            self.neighbour_token(th.cat([messages, edges], dim=-1)) + types[1],
            self.window_token(window_rows) + self.window_rows + types[2],
            self.map_token(maps.reshape(batch, b, -1)) + self.map_rows + types[3],
        ], dim=1)
        padding = th.zeros(batch, tokens.shape[1], dtype=th.bool, device=tokens.device)
        padding[:, 1:1 + lay.n_slots] = ~present
        encoded = self.encoder(tokens, src_key_padding_mask=padding)
        return self.head(encoded[:, 0])


EXTRACTORS: dict[str, type[BaseFeaturesExtractor]] = {"gat": GraphAttentionExtractor, "transformer": TransformerExtractor}


def message_policy_kwargs(venv: VecEnv, kind: str = "gat", net_arch: Any = None, **kwargs: Any) -> dict[str, Any]:
    """``policy_kwargs`` for an ``MlpPolicy`` with a message extractor, on a :class:`NeighbourMessageWrapper` env:
    PPO's, EM-PPO's, EM-DDPG's, VDN+EM's or MAPPO's (the wrapper inside the belief or state wrapper those algorithms add).

    :param venv: the wrapped vector environment (the wrapper anywhere in its stack)
    :param kind: ``"gat"`` (:class:`GraphAttentionExtractor`) or ``"transformer"`` (:class:`TransformerExtractor`)
    :param net_arch: the policy's ``net_arch`` after the extractor (None: SB3's default)
    :param kwargs: more arguments of the extractor (``features_dim``, ``n_rounds``, ...)
    """
    if kind not in EXTRACTORS:
        raise ValueError(f"kind must be one of {sorted(EXTRACTORS)}, got {kind!r}")
    wrapper = find_wrapper(venv, NeighbourMessageWrapper)
    if wrapper is None:
        raise ValueError(f"venv must be wrapped in NeighbourMessageWrapper, got {type(venv).__name__}")
    policy_kwargs: dict[str, Any] = {"features_extractor_class": EXTRACTORS[kind],
                                     "features_extractor_kwargs": {"layout": wrapper.layout, **kwargs}}
    if net_arch is not None:
        policy_kwargs["net_arch"] = net_arch
    return policy_kwargs
