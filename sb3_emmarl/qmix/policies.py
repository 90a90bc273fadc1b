"""The policies of QMIX and VDN: one agent Q-network shared by every agent, its target, the mixer and its target.

The agent network is SB3's ``QNetwork`` pattern: a features extractor (``make_features_extractor``, so that
another extractor, e.g. the EM belief's, can slot in), optionally the agent's index as a one-hot vector appended
to the features (``agent_id``, EPyMARL's ``obs_agent_id``), then an MLP to one value per action. Acting is
decentralised: each entry's greedy action on its own Q-values (``predict`` on per-entry observations); the mixer
is used in training only.

With ``recurrent=True`` the agent network is :class:`RecurrentAgentQNetwork` (EPyMARL's ``RNNAgent``): the same
features extractor, agent index and MLP, then a ``GRUCell`` of ``rnn_hidden_dim`` units and a linear Q-head; its
hidden state travels in ``predict``'s ``state`` (``(n, rnn_hidden_dim)``, zeroed where ``episode_start``), as
sb3-contrib's RecurrentPPO carries its LSTM state.
"""

from __future__ import annotations

from itertools import chain
from typing import Any, ClassVar

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor, FlattenExtractor, create_mlp
from stable_baselines3.common.type_aliases import PyTorchObs, Schedule
from stable_baselines3.common.utils import polyak_update
from torch import nn
from torch.nn import functional as F

from sb3_emmarl.qmix.mixers import MIXERS, make_mixer


class AgentNetwork(BasePolicy):
    """What the shared agent networks have in common: the features of an observation, with the one-hot agent index
    appended (``agent_id``), as their input (:meth:`agent_inputs`).

    :param observation_space: one agent's observation space
    :param action_space: one agent's action space (``Discrete``)
    :param features_extractor: the features extractor
    :param features_dim: its output size
    :param n_agents: agents per team (the size of the one-hot index)
    :param agent_id: append the one-hot agent index to the features
    :param net_arch: hidden layer sizes (None: ``default_net_arch``)
    :param activation_fn: activation function
    :param normalize_images: divide image observations by 255
    """

    action_space: spaces.Discrete
    #: the hidden layers without ``net_arch``
    default_net_arch: ClassVar[list[int]] = [64, 64]

    def __init__(self, observation_space: spaces.Space, action_space: spaces.Discrete,
                 features_extractor: BaseFeaturesExtractor, features_dim: int, n_agents: int = 1,
                 agent_id: bool = False, net_arch: list[int] | None = None,
                 activation_fn: type[nn.Module] = nn.ReLU, normalize_images: bool = True) -> None:
        super().__init__(observation_space, action_space, features_extractor=features_extractor,
                         normalize_images=normalize_images)
        self.net_arch = list(self.default_net_arch if net_arch is None else net_arch)
        self.activation_fn, self.features_dim = activation_fn, features_dim
        self.n_agents, self.agent_id = int(n_agents), bool(agent_id)
        #: the size of :meth:`agent_inputs`' rows
        self.input_dim = features_dim + (self.n_agents if self.agent_id else 0)

    def agent_inputs(self, obs: PyTorchObs, agent_ids: th.Tensor | None = None) -> th.Tensor:
        """The features ``(n, input_dim)`` of ``n`` observations made by the agents ``agent_ids`` (``(n,)`` ints;
        needed with ``agent_id``: their one-hot index is appended)."""
        features = self.extract_features(obs, self.features_extractor)
        if self.agent_id:
            if agent_ids is None:
                raise ValueError("this Q-network takes the agent's index (agent_id=True): pass agent_ids")
            features = th.cat([features, F.one_hot(agent_ids.long(), self.n_agents).to(features.dtype)], dim=-1)
        return features

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data.update(net_arch=self.net_arch, features_dim=self.features_dim, activation_fn=self.activation_fn,
                    features_extractor=self.features_extractor, n_agents=self.n_agents, agent_id=self.agent_id)
        return data


class AgentQNetwork(AgentNetwork):
    """The shared agent network: observation (and one-hot agent index) -> one Q-value per action.

    Takes :class:`AgentNetwork`'s arguments (``net_arch`` default ``[64, 64]``).
    """

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.q_net = nn.Sequential(*create_mlp(self.input_dim, int(self.action_space.n), self.net_arch,
                                               self.activation_fn))

    def forward(self, obs: PyTorchObs, agent_ids: th.Tensor | None = None) -> th.Tensor:
        """Q-values ``(n, n_actions)`` of ``n`` observations made by the agents ``agent_ids`` (``(n,)`` ints; needed
        with ``agent_id``)."""
        return self.q_net(self.agent_inputs(obs, agent_ids))

    def _predict(self, observation: PyTorchObs, deterministic: bool = True) -> th.Tensor:
        return self(observation, entry_agent_ids(observation, self.n_agents, self.agent_id)).argmax(dim=1)


class RecurrentAgentQNetwork(AgentNetwork):
    """The shared recurrent agent network: observation (and one-hot agent index) -> MLP -> ``GRUCell`` -> Q-values.

    EPyMARL's ``RNNAgent`` (``fc1 -> ReLU -> GRUCell -> fc2``) with SB3's features extractor and ``net_arch`` in
    place of ``fc1`` (``net_arch=[]``: the GRU reads the features directly). One call is one time step of ``n``
    entries: ``forward(obs, hidden)`` returns the Q-values and the next hidden state.

    Takes :class:`AgentNetwork`'s arguments (``net_arch`` default ``[64]``, EPyMARL's ``fc1``) and:

    :param rnn_hidden_dim: the GRU's hidden size
    """

    default_net_arch: ClassVar[list[int]] = [64]

    def __init__(self, *args: Any, rnn_hidden_dim: int = 64, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.rnn_hidden_dim = int(rnn_hidden_dim)
        self.mlp = nn.Sequential(*create_mlp(self.input_dim, -1, self.net_arch, self.activation_fn))
        self.rnn = nn.GRUCell(self.net_arch[-1] if self.net_arch else self.input_dim, self.rnn_hidden_dim)
        self.q_head = nn.Linear(self.rnn_hidden_dim, int(self.action_space.n))

    def embed(self, obs: PyTorchObs, agent_ids: th.Tensor | None = None) -> th.Tensor:
        """The GRU's inputs ``(n, gru_input)`` of ``n`` observations made by the agents ``agent_ids``."""
        return self.mlp(self.agent_inputs(obs, agent_ids))

    def forward(self, obs: PyTorchObs, hidden: th.Tensor, agent_ids: th.Tensor | None = None) -> tuple[th.Tensor, th.Tensor]:
        """One step: Q-values ``(n, n_actions)`` and the next hidden state ``(n, rnn_hidden_dim)`` of ``n``
        observations whose entries had the hidden state ``hidden``."""
        hidden = self.rnn(self.embed(obs, agent_ids), hidden)
        return self.q_head(hidden), hidden

    def _predict(self, observation: PyTorchObs, deterministic: bool = True) -> th.Tensor:
        """Greedy actions from a zero hidden state (the first step of an episode; ``predict`` carries the state)."""
        first = observation if isinstance(observation, th.Tensor) else next(iter(observation.values()))
        hidden = th.zeros(first.shape[0], self.rnn_hidden_dim, device=first.device)
        return self(observation, hidden, entry_agent_ids(observation, self.n_agents, self.agent_id))[0].argmax(dim=1)

    def _get_constructor_parameters(self) -> dict[str, Any]:
        return {**super()._get_constructor_parameters(), "rnn_hidden_dim": self.rnn_hidden_dim}


def entry_agent_ids(observation: PyTorchObs, n_agents: int, agent_id: bool) -> th.Tensor | None:
    """The agent index of each of ``n`` per-entry observations, in the parameter-sharing vector environment's order
    (entry ``i`` is agent ``i % n_agents``); None when the network does not take it.

    :raise ValueError: with ``agent_id`` and ``n_agents > 1``, if ``n`` is not a whole number of teams
    """
    if not agent_id:
        return None
    first = observation if isinstance(observation, th.Tensor) else next(iter(observation.values()))
    n = first.shape[0]
    if n % n_agents:
        raise ValueError(f"the Q-network takes the agent's index (agent_id=True): predict needs the observations of "
                         f"whole teams in the vector environment's order (a multiple of n_agents={n_agents}), got {n}")
    return th.arange(n, device=first.device) % n_agents


class ValueDecompositionPolicy(BasePolicy):
    """Agent Q-network, mixer, and their target copies: what QMIX's and VDN's policies share.

    :param observation_space: one agent's observation space
    :param action_space: one agent's action space (``Discrete``)
    :param lr_schedule: learning rate schedule
    :param n_agents: agents per team (set by the algorithm)
    :param state_dim: size of the flat global state (set by the algorithm; 0 for VDN)
    :param mixer: ``"qmix"`` or ``"vdn"`` (set by the algorithm; None: the class's :attr:`fixed_mixer`, else
        ``"qmix"``); a subclass with a :attr:`fixed_mixer` takes that one only
    :param mixing_embed_dim: QMIX's mixing width
    :param hypernet_layers: QMIX's hypernetwork depth (1 or 2)
    :param hypernet_embed: QMIX's hypernetwork width
    :param agent_id: the agent network sees the one-hot agent index
    :param net_arch: the agent network's hidden layer sizes (default ``[64, 64]``)
    :param activation_fn: activation function
    :param features_extractor_class: features extractor of the agent network
    :param features_extractor_kwargs: its arguments
    :param normalize_images: divide image observations by 255
    :param optimizer_class: optimizer (of the agent network and the mixer together)
    :param optimizer_kwargs: its arguments (without the learning rate)
    :param recurrent: the agent network is a :class:`RecurrentAgentQNetwork` (set by the algorithm); its
        ``net_arch`` defaults to ``[64]``
    :param rnn_hidden_dim: its GRU's hidden size
    """

    #: the one mixer a subclass takes (QMIXPolicy's ``"qmix"``, VDNPolicy's ``"vdn"``); None: either
    fixed_mixer: ClassVar[str | None] = None
    q_net: AgentQNetwork | RecurrentAgentQNetwork
    q_net_target: AgentQNetwork | RecurrentAgentQNetwork

    def __init__(self, observation_space: spaces.Space, action_space: spaces.Discrete, lr_schedule: Schedule,
                 n_agents: int = 1, state_dim: int = 0, mixer: str | None = None, mixing_embed_dim: int = 32,
                 hypernet_layers: int = 2, hypernet_embed: int = 64, agent_id: bool = False,
                 net_arch: list[int] | None = None, activation_fn: type[nn.Module] = nn.ReLU,
                 features_extractor_class: type[BaseFeaturesExtractor] = FlattenExtractor,
                 features_extractor_kwargs: dict[str, Any] | None = None, normalize_images: bool = True,
                 optimizer_class: type[th.optim.Optimizer] = th.optim.Adam,
                 optimizer_kwargs: dict[str, Any] | None = None, recurrent: bool = False,
                 rnn_hidden_dim: int = 64) -> None:
        mixer = (self.fixed_mixer or "qmix") if mixer is None else mixer
        if self.fixed_mixer is not None and mixer != self.fixed_mixer:
            raise ValueError(f"{type(self).__name__}'s mixer is {self.fixed_mixer!r}, got mixer={mixer!r} (each of "
                             f"{list(MIXERS)} has its policy class; ValueDecompositionPolicy takes either)")
        super().__init__(observation_space, action_space, features_extractor_class, features_extractor_kwargs,
                         optimizer_class=optimizer_class, optimizer_kwargs=optimizer_kwargs,
                         normalize_images=normalize_images)
        self.recurrent, self.rnn_hidden_dim = bool(recurrent), int(rnn_hidden_dim)
        self.net_arch = ([64] if self.recurrent else [64, 64]) if net_arch is None else list(net_arch)
        self.activation_fn = activation_fn
        self.n_agents, self.state_dim, self.mixer_name = int(n_agents), int(state_dim), mixer
        self.mixer_kwargs = {"embed_dim": mixing_embed_dim, "hypernet_layers": hypernet_layers,
                             "hypernet_embed": hypernet_embed}
        self.agent_id = bool(agent_id)
        self.net_args = {"observation_space": self.observation_space, "action_space": self.action_space,
                         "net_arch": self.net_arch, "activation_fn": activation_fn, "normalize_images": normalize_images,
                         "n_agents": self.n_agents, "agent_id": self.agent_id}
        if self.recurrent:
            self.net_args["rnn_hidden_dim"] = self.rnn_hidden_dim
        self._build(lr_schedule)

    def _build(self, lr_schedule: Schedule) -> None:
        self.q_net, self.q_net_target = self.make_q_net(), self.make_q_net()
        self.mixer, self.mixer_target = self.make_mixer(), self.make_mixer()
        self.q_net_target.load_state_dict(self.q_net.state_dict())
        self.mixer_target.load_state_dict(self.mixer.state_dict())
        self.q_net_target.set_training_mode(False)
        self.mixer_target.train(False)
        self.optimizer = self.optimizer_class(  # type: ignore[call-arg]  # SB3 types the class as torch's base Optimizer (no lr)
            self.online_parameters(), lr=lr_schedule(1), **self.optimizer_kwargs)

    def make_q_net(self) -> AgentQNetwork | RecurrentAgentQNetwork:
        # a separate features extractor per network, as SB3's DQNPolicy
        net_args = self._update_features_extractor(self.net_args, features_extractor=None)
        return (RecurrentAgentQNetwork if self.recurrent else AgentQNetwork)(**net_args).to(self.device)

    def make_mixer(self) -> nn.Module:
        return make_mixer(self.mixer_name, self.n_agents, self.state_dim, **self.mixer_kwargs).to(self.device)

    def online_parameters(self) -> list[nn.Parameter]:
        """The trained parameters: the agent network's and the mixer's."""
        return [*self.q_net.parameters(), *self.mixer.parameters()]

    def update_targets(self, tau: float) -> None:
        """Polyak update of the target agent network and mixer (``tau=1``: copy)."""
        polyak_update(self.online_parameters(), [*self.q_net_target.parameters(), *self.mixer_target.parameters()], tau)
        # running statistics (batch norm) are copied, as SB3's DQN does
        online = [b for b in chain(self.q_net.buffers(), self.mixer.buffers()) if b.dtype.is_floating_point]
        target = [b for b in chain(self.q_net_target.buffers(), self.mixer_target.buffers()) if b.dtype.is_floating_point]
        if online:
            polyak_update(online, target, 1.0)

    def team_q_values(self, observations: th.Tensor, target: bool = False) -> th.Tensor:
        """Agent Q-values of team observations ``(batch, n_agents, *obs_shape)`` -> ``(batch, n_agents, n_actions)``."""
        if self.recurrent:
            raise ValueError("the recurrent agent network's Q-values need hidden states: use unroll and q_from_hidden")
        batch, n_agents = observations.shape[:2]
        net = self.q_net_target if target else self.q_net
        ids = th.arange(n_agents, device=observations.device).repeat(batch) if self.agent_id else None
        return net(observations.reshape(batch * n_agents, *observations.shape[2:]), ids).view(batch, n_agents, -1)

    # ------------------------------------------------------------------ the recurrent agent network over stretches
    def _embed_team(self, net: RecurrentAgentQNetwork, observations: th.Tensor) -> th.Tensor:
        """GRU inputs of observations ``(batch, length, n_agents, *obs_shape)`` -> ``(batch, length, n_agents, dim)``."""
        lead = observations.shape[:3]
        ids = th.arange(lead[2], device=observations.device).repeat(lead[0] * lead[1]) if self.agent_id else None
        return net.embed(observations.reshape(-1, *observations.shape[3:]), ids).view(*lead, -1)

    def unroll(self, observations: th.Tensor, episode_starts: th.Tensor, hidden: th.Tensor, target: bool = False,
               burn_in: int = 0) -> th.Tensor:
        """The hidden states after each step of stretches of team observations (recurrent agent network only).

        :param observations: ``(batch, length, n_agents, *obs_shape)``
        :param episode_starts: ``(batch, length, n_agents)``, 1 where an observation is an episode's first: the hidden
            state entering that step is zeroed
        :param hidden: ``(batch, n_agents, rnn_hidden_dim)``, the hidden state entering the first step
        :param target: unroll the target network
        :param burn_in: the first ``burn_in`` steps run without gradient (R2D2's burn-in: they only warm the state up)
        :return: ``(batch, length, n_agents, rnn_hidden_dim)``: ``h_t``, from which step ``t``'s Q-values are read
        """
        net = self.q_net_target if target else self.q_net
        assert isinstance(net, RecurrentAgentQNetwork)  # (recurrent agent network only)
        batch, length, n_agents = observations.shape[:3]
        grad = th.is_grad_enabled()
        with th.no_grad():  # the burn-in's inputs, then the rest's (with gradient if enabled)
            warm_up = [self._embed_team(net, observations[:, :burn_in])] if burn_in > 0 else []
        inputs = th.cat([*warm_up, self._embed_team(net, observations[:, burn_in:])], dim=1)
        keep = (1.0 - episode_starts.to(hidden.dtype)).reshape(batch, length, n_agents, 1)
        h, hiddens = hidden, []
        for t in range(length):
            with th.set_grad_enabled(grad and t >= burn_in):
                h = net.rnn(inputs[:, t].reshape(batch * n_agents, -1), (h * keep[:, t]).reshape(batch * n_agents, -1))
            h = h.view(batch, n_agents, -1)
            hiddens.append(h)
        return th.stack(hiddens, dim=1)

    def q_from_hidden(self, hiddens: th.Tensor, target: bool = False) -> th.Tensor:
        """Q-values ``(..., n_actions)`` read from hidden states ``(..., rnn_hidden_dim)`` by the Q-head."""
        net = self.q_net_target if target else self.q_net
        assert isinstance(net, RecurrentAgentQNetwork)  # (recurrent agent network only)
        return net.q_head(hiddens)

    def next_q_values(self, next_observations: th.Tensor, hiddens: th.Tensor, q_values: th.Tensor | None = None,
                      boundaries: th.Tensor | None = None, target: bool = False) -> th.Tensor:
        """Q-values of the next observations of stretches' rows: one more GRU step from each row's hidden state on its
        next observation (the terminal one at an episode's end: a truncated episode bootstraps from it with the
        episode's own hidden state).

        Within an episode the next observation is the next row's and that step is the unroll's own: given the rows'
        Q-values ``q_values``, only the ``boundaries`` rows (an episode starts in the next row) and the last row take the
        extra step, the others read the next row's Q-values (the same numbers, computed once).

        :param next_observations: ``(batch, length, n_agents, *obs_shape)``
        :param hiddens: ``(batch, length, n_agents, rnn_hidden_dim)``, ``unroll``'s
        :param q_values: ``(batch, length, n_agents, n_actions)``, the Q-values read from ``hiddens`` (None: every row
            takes the extra step)
        :param boundaries: ``(batch, length)`` bools, the rows followed by an episode start (with ``q_values``)
        :param target: the target network
        :return: ``(batch, length, n_agents, n_actions)``
        """
        net = self.q_net_target if target else self.q_net
        assert isinstance(net, RecurrentAgentQNetwork)  # (recurrent agent network only)

        def step(next_obs: th.Tensor, h: th.Tensor) -> th.Tensor:
            x = self._embed_team(net, next_obs)
            return net.q_head(net.rnn(x.reshape(-1, x.shape[-1]), h.reshape(-1, h.shape[-1]))).view(*h.shape[:-1], -1)

        if q_values is None:
            return step(next_observations, hiddens)
        assert boundaries is not None  # (given with q_values)
        extra = boundaries.clone()
        extra[:, -1] = True
        next_q = th.cat([q_values[:, 1:], q_values[:, -1:]], dim=1)
        rows = extra.nonzero(as_tuple=True)
        next_q[rows] = step(next_observations[rows].unsqueeze(1), hiddens[rows].unsqueeze(1)).squeeze(1)
        return next_q

    def predict(self, observation: np.ndarray | dict[str, np.ndarray], state: Any = None,
                episode_start: np.ndarray | None = None, deterministic: bool = False) -> tuple[np.ndarray, Any]:
        """Each entry's greedy action; with the recurrent agent network, from the hidden states ``state``
        (``(n, rnn_hidden_dim)``, zeros if None, zeroed where ``episode_start``), returning the next ones (as
        RecurrentPPO; without it, ``state`` is returned unchanged)."""
        if not self.recurrent:
            return super().predict(observation, state, episode_start, deterministic)
        self.set_training_mode(False)
        obs, vectorized = self.obs_to_tensor(observation)
        first = obs if isinstance(obs, th.Tensor) else next(iter(obs.values()))
        n = first.shape[0]
        hidden = np.zeros((n, self.rnn_hidden_dim), dtype=np.float32) if state is None else \
            np.asarray(state, dtype=np.float32)
        if hidden.shape != (n, self.rnn_hidden_dim):
            raise ValueError(f"state must be the hidden states of the {n} observations, shape ({n}, {self.rnn_hidden_dim}), "
                             f"got shape {hidden.shape}")
        if episode_start is not None:
            hidden = hidden * (1.0 - np.asarray(episode_start, dtype=np.float32).reshape(n, 1))
        with th.no_grad():
            q_values, next_hidden = self.q_net(obs, th.as_tensor(hidden, device=self.device),
                                               entry_agent_ids(obs, self.n_agents, self.agent_id))
        actions = q_values.argmax(dim=1).cpu().numpy()
        return (actions if vectorized else actions.squeeze(axis=0)), next_hidden.cpu().numpy()

    def forward(self, obs: PyTorchObs, deterministic: bool = True) -> th.Tensor:
        return self._predict(obs, deterministic=deterministic)

    def _predict(self, obs: PyTorchObs, deterministic: bool = True) -> th.Tensor:
        """Each entry's greedy action (entry ``i`` is agent ``i % n_agents``)."""
        return self.q_net._predict(obs, deterministic=deterministic)

    def set_training_mode(self, mode: bool) -> None:
        self.q_net.set_training_mode(mode)
        self.mixer.train(mode)
        self.training = mode

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data.update(n_agents=self.n_agents, state_dim=self.state_dim, mixer=self.mixer_name,
                    mixing_embed_dim=self.mixer_kwargs["embed_dim"], hypernet_layers=self.mixer_kwargs["hypernet_layers"],
                    hypernet_embed=self.mixer_kwargs["hypernet_embed"], agent_id=self.agent_id,
                    net_arch=self.net_arch, activation_fn=self.activation_fn, lr_schedule=self._dummy_schedule,
                    optimizer_class=self.optimizer_class, optimizer_kwargs=self.optimizer_kwargs,
                    features_extractor_class=self.features_extractor_class,
                    features_extractor_kwargs=self.features_extractor_kwargs, recurrent=self.recurrent,
                    rnn_hidden_dim=self.rnn_hidden_dim)
        return data


class QMIXPolicy(ValueDecompositionPolicy):
    """:class:`ValueDecompositionPolicy` with QMIX's mixing network (QMIX's ``MlpPolicy``); same arguments."""

    fixed_mixer = "qmix"


class VDNPolicy(ValueDecompositionPolicy):
    """:class:`ValueDecompositionPolicy` with the additive mixer (VDN's ``MlpPolicy``); same arguments."""

    fixed_mixer = "vdn"


MlpPolicy = QMIXPolicy
