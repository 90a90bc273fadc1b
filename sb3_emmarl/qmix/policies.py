"""The policies of QMIX and VDN: one agent Q-network shared by every agent, its target, the mixer and its target.

The agent network is SB3's ``QNetwork`` pattern: a features extractor (``make_features_extractor``, so that
another extractor, e.g. the EM belief's, can slot in), optionally the agent's index as a one-hot vector appended
to the features (``agent_id``, EPyMARL's ``obs_agent_id``), then an MLP to one value per action. Acting is
decentralised: each entry's greedy action on its own Q-values (``predict`` on per-entry observations); the mixer
is used in training only.
"""

from __future__ import annotations

from itertools import chain
from typing import Any

import torch as th
from gymnasium import spaces
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor, FlattenExtractor, create_mlp
from stable_baselines3.common.type_aliases import PyTorchObs, Schedule
from stable_baselines3.common.utils import polyak_update
from torch import nn
from torch.nn import functional as F

from sb3_emmarl.qmix.mixers import make_mixer


class AgentQNetwork(BasePolicy):
    """The shared agent network: observation (and one-hot agent index) -> one Q-value per action.

    :param observation_space: one agent's observation space
    :param action_space: one agent's action space (``Discrete``)
    :param features_extractor: the features extractor
    :param features_dim: its output size
    :param n_agents: agents per team (the size of the one-hot index)
    :param agent_id: append the one-hot agent index to the features
    :param net_arch: hidden layer sizes
    :param activation_fn: activation function
    :param normalize_images: divide image observations by 255
    """

    action_space: spaces.Discrete

    def __init__(self, observation_space: spaces.Space, action_space: spaces.Discrete,
                 features_extractor: BaseFeaturesExtractor, features_dim: int, n_agents: int = 1,
                 agent_id: bool = False, net_arch: list[int] | None = None,
                 activation_fn: type[nn.Module] = nn.ReLU, normalize_images: bool = True) -> None:
        super().__init__(observation_space, action_space, features_extractor=features_extractor,
                         normalize_images=normalize_images)
        self.net_arch = [64, 64] if net_arch is None else list(net_arch)
        self.activation_fn, self.features_dim = activation_fn, features_dim
        self.n_agents, self.agent_id = int(n_agents), bool(agent_id)
        input_dim = features_dim + (self.n_agents if self.agent_id else 0)
        self.q_net = nn.Sequential(*create_mlp(input_dim, int(action_space.n), self.net_arch, activation_fn))

    def forward(self, obs: PyTorchObs, agent_ids: th.Tensor | None = None) -> th.Tensor:
        """Q-values ``(n, n_actions)`` of ``n`` observations made by the agents ``agent_ids`` (``(n,)`` ints; needed
        with ``agent_id``)."""
        features = self.extract_features(obs, self.features_extractor)
        if self.agent_id:
            if agent_ids is None:
                raise ValueError("this Q-network takes the agent's index (agent_id=True): pass agent_ids")
            features = th.cat([features, F.one_hot(agent_ids.long(), self.n_agents).to(features.dtype)], dim=-1)
        return self.q_net(features)

    def _predict(self, observation: PyTorchObs, deterministic: bool = True) -> th.Tensor:
        return self(observation, entry_agent_ids(observation, self.n_agents, self.agent_id)).argmax(dim=1)

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data.update(net_arch=self.net_arch, features_dim=self.features_dim, activation_fn=self.activation_fn,
                    features_extractor=self.features_extractor, n_agents=self.n_agents, agent_id=self.agent_id)
        return data


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
    :param mixer: ``"qmix"`` or ``"vdn"`` (set by the algorithm)
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
    """

    q_net: AgentQNetwork
    q_net_target: AgentQNetwork

    def __init__(self, observation_space: spaces.Space, action_space: spaces.Discrete, lr_schedule: Schedule,
                 n_agents: int = 1, state_dim: int = 0, mixer: str = "qmix", mixing_embed_dim: int = 32,
                 hypernet_layers: int = 2, hypernet_embed: int = 64, agent_id: bool = False,
                 net_arch: list[int] | None = None, activation_fn: type[nn.Module] = nn.ReLU,
                 features_extractor_class: type[BaseFeaturesExtractor] = FlattenExtractor,
                 features_extractor_kwargs: dict[str, Any] | None = None, normalize_images: bool = True,
                 optimizer_class: type[th.optim.Optimizer] = th.optim.Adam,
                 optimizer_kwargs: dict[str, Any] | None = None) -> None:
        super().__init__(observation_space, action_space, features_extractor_class, features_extractor_kwargs,
                         optimizer_class=optimizer_class, optimizer_kwargs=optimizer_kwargs,
                         normalize_images=normalize_images)
        self.net_arch = [64, 64] if net_arch is None else list(net_arch)
        self.activation_fn = activation_fn
        self.n_agents, self.state_dim, self.mixer_name = int(n_agents), int(state_dim), mixer
        self.mixer_kwargs = {"embed_dim": mixing_embed_dim, "hypernet_layers": hypernet_layers,
                             "hypernet_embed": hypernet_embed}
        self.agent_id = bool(agent_id)
        self.net_args = {"observation_space": self.observation_space, "action_space": self.action_space,
                         "net_arch": self.net_arch, "activation_fn": activation_fn, "normalize_images": normalize_images,
                         "n_agents": self.n_agents, "agent_id": self.agent_id}
        self._build(lr_schedule)

    def _build(self, lr_schedule: Schedule) -> None:
        self.q_net, self.q_net_target = self.make_q_net(), self.make_q_net()
        self.mixer, self.mixer_target = self.make_mixer(), self.make_mixer()
        self.q_net_target.load_state_dict(self.q_net.state_dict())
        self.mixer_target.load_state_dict(self.mixer.state_dict())
        self.q_net_target.set_training_mode(False)
        self.mixer_target.train(False)
        self.optimizer = self.optimizer_class(self.online_parameters(), lr=lr_schedule(1), **self.optimizer_kwargs)

    def make_q_net(self) -> AgentQNetwork:
        # a separate features extractor per network, as SB3's DQNPolicy
        net_args = self._update_features_extractor(self.net_args, features_extractor=None)
        return AgentQNetwork(**net_args).to(self.device)

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
        batch, n_agents = observations.shape[:2]
        net = self.q_net_target if target else self.q_net
        ids = th.arange(n_agents, device=observations.device).repeat(batch) if self.agent_id else None
        return net(observations.reshape(batch * n_agents, *observations.shape[2:]), ids).view(batch, n_agents, -1)

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
                    features_extractor_kwargs=self.features_extractor_kwargs)
        return data


class QMIXPolicy(ValueDecompositionPolicy):
    """:class:`ValueDecompositionPolicy` with QMIX's mixing network (QMIX's ``MlpPolicy``); same arguments."""

    def __init__(self, observation_space: spaces.Space, action_space: spaces.Discrete, lr_schedule: Schedule,
                 *args: Any, mixer: str = "qmix", **kwargs: Any) -> None:
        if mixer != "qmix":
            raise ValueError(f"QMIXPolicy's mixer is 'qmix', got mixer={mixer!r} (VDNPolicy's is 'vdn')")
        super().__init__(observation_space, action_space, lr_schedule, *args, mixer=mixer, **kwargs)


class VDNPolicy(ValueDecompositionPolicy):
    """:class:`ValueDecompositionPolicy` with the additive mixer (VDN's ``MlpPolicy``); same arguments."""

    def __init__(self, observation_space: spaces.Space, action_space: spaces.Discrete, lr_schedule: Schedule,
                 *args: Any, mixer: str = "vdn", **kwargs: Any) -> None:
        if mixer != "vdn":
            raise ValueError(f"VDNPolicy's mixer is 'vdn', got mixer={mixer!r} (QMIXPolicy's is 'qmix')")
        super().__init__(observation_space, action_space, lr_schedule, *args, mixer=mixer, **kwargs)


MlpPolicy = QMIXPolicy
