"""QMIX (Rashid et al. 2018) as an SB3 off-policy algorithm over the parameter-sharing vector environment.

What it computes: every agent's ``Q_a(o_a, u_a)`` with one shared network (optionally told the agent's index), the
team value ``Q_tot = f(Q_1(o_1, u_1), ..., Q_n(o_n, u_n); s)`` of a monotonic mixing network ``f`` whose weights
are non-negative functions of the global state ``s`` (:class:`~sb3_emmarl.qmix.mixers.QMixer`), and the loss
``(Q_tot(o, u, s) - y)^2`` with ``y = r + gamma (1 - terminated) Q_tot^-(o', u*, s')`` on team transitions of
the replay buffer (:class:`~sb3_emmarl.qmix.buffers.JointReplayBuffer`), where the target networks ``^-`` (agent
network and mixer) evaluate ``u*``, each agent's greedy action under the *online* agent network (double Q), and
``r`` is the team reward. Monotonicity makes the joint greedy action the agents' individual greedy actions, so
each agent acts on its own Q-values (epsilon-greedy in training).

It reuses SB3's machinery: ``OffPolicyAlgorithm``'s rollouts (``learning_starts``, ``train_freq``,
``gradient_steps``, episode logging, save/load) and DQN's linear epsilon schedule and target updates
(``target_update_interval`` in agent-steps, ``tau`` for Polyak updates). Vector entry ``i`` is agent
``i % n_agents`` of copy ``i // n_agents``, so ``num_timesteps`` counts agent-steps, as for DQN on the same
environment.

With ``recurrent=True`` the agent network is a GRU (EPyMARL's ``RNNAgent``, ``rnn_hidden_dim`` units; see
:class:`~sb3_emmarl.qmix.policies.RecurrentAgentQNetwork`): rollouts carry each vector entry's hidden state
(zeroed at episode starts; ``predict(obs, state, episode_start)`` takes and returns it, as RecurrentPPO), the
buffer (:class:`~sb3_emmarl.qmix.buffers.RecurrentJointReplayBuffer`) stores it with each row and samples
``batch_size`` stretches of ``sequence_length`` consecutive rows of one copy, and the loss unrolls the online and
target networks over each stretch from the stored hidden state (R2D2's "stored state"), zeroing it where an episode
starts, with no loss and no gradient on the first ``burn_in`` steps. Every row of a stretch is a whole transition
with its own next observation and state, so rows on both sides of an episode's end are trained on (the hidden state
resets at the start flag) and nothing is masked but the burn-in: the next Q-values of row ``t`` are one more GRU
step from row ``t``'s hidden state on its next observation (the terminal one at an episode's end).

Departures from the paper and EPyMARL (``src/learners/q_learner.py``):

- transitions or stretches, not episodes: the buffer keeps single team transitions and samples ``batch_size`` of
  them, or with ``recurrent=True`` ``batch_size`` stretches of ``sequence_length`` rows with a stored initial
  hidden state and a burn-in (EPyMARL samples ``batch_size`` whole episodes and unrolls from a zero state);
  the default agent network is an MLP on the current observation (EPyMARL's ``use_rnn: False``);
- every agent explores on its own coin (as EPyMARL), where SB3's DQN draws one coin for the whole vector;
- the optimizer is Adam (EPyMARL's; the paper used RMSprop), gradients clipped at ``max_grad_norm``;
- the team reward is the mean of the copy's agents' rewards (the team reward itself on the reserve with
  ``shaping=0``); no reward standardisation.
"""

from __future__ import annotations

from typing import Any, ClassVar, TypeVar, cast

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.base_class import BaseAlgorithm, maybe_make_env
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback, Schedule
from stable_baselines3.common.utils import LinearSchedule
from stable_baselines3.common.vec_env import VecEnv
from torch.nn import functional as F

from sb3_emmarl.common.trust.validation import RULES, no_schedule_string
from sb3_emmarl.common.vec_env import SharedPolicyVecEnv, require_state
from sb3_emmarl.qmix.buffers import (
    JointReplayBuffer,
    JointReplaySamples,
    JointSequenceSamples,
    RecurrentJointReplayBuffer,
)
from sb3_emmarl.qmix.policies import QMIXPolicy, ValueDecompositionPolicy

SelfQMIX = TypeVar("SelfQMIX", bound="QMIX")


def _check(name: str, value: Any) -> Any:
    """``value`` checked by the zoo's rule for ``name`` (a ValueError naming the argument, the value and what is
    allowed); the zoo's ``lin_<value>`` schedule strings are for YAML files, not for the constructor."""
    rule = no_schedule_string(RULES[name]) if name == "learning_rate" else RULES[name]
    return rule(name, value)


def team_layout(env: VecEnv, needs_state: bool, who: str) -> tuple[int, tuple[int, ...] | None]:
    """Agents per copy and the global state's shape of ``env`` (switching the state on if ``needs_state``).

    :raise ValueError: for non-Discrete actions, entries that are not whole teams, or (``needs_state``) an environment
        without ``state()``
    """
    if not isinstance(env.action_space, spaces.Discrete):
        raise ValueError(f"{who} needs Discrete actions, got the action space {env.action_space}")
    inner = env.unwrapped
    n_agents = int(inner.agents_per_copy) if isinstance(inner, SharedPolicyVecEnv) else 1
    if env.num_envs % n_agents:
        raise ValueError(f"{who}: the environment's {env.num_envs} entries are not whole teams of {n_agents} agents")
    if not needs_state:
        return n_agents, None
    state_space = require_state(env, who)
    if not isinstance(state_space, spaces.Box):
        raise ValueError(f"{who} needs a Box state space, got {state_space}")
    return n_agents, tuple(int(d) for d in state_space.shape)


class QMIX(OffPolicyAlgorithm):
    """QMIX: parameter-shared agent Q-networks mixed into the team value by a monotonic, state-conditioned network.

    :param policy: ``"MlpPolicy"`` or a :class:`~sb3_emmarl.qmix.policies.QMIXPolicy` subclass
    :param env: the parameter-sharing vector environment (:func:`~sb3_emmarl.common.vec_env.make_vec_env`) of a
        PettingZoo environment with homogeneous agents, ``Discrete`` actions and ``state()``; its global state is
        switched on here (``require_state``)
    :param learning_rate: Adam's learning rate (or schedule)
    :param buffer_size: agent-transitions kept (as SB3's; ``buffer_size / n_agents`` team transitions)
    :param learning_starts: agent-steps of uniformly random actions before learning starts
    :param batch_size: team transitions per gradient step
    :param tau: target update coefficient (1: hard copy)
    :param gamma: discount factor
    :param train_freq: vector steps (or ``(n, "step")``) between updates
    :param gradient_steps: gradient steps per update (-1: as many as agent-steps collected)
    :param target_update_interval: agent-steps between target updates (as DQN's)
    :param exploration_fraction: fraction of the training over which epsilon goes from initial to final
    :param exploration_initial_eps: initial epsilon
    :param exploration_final_eps: final epsilon
    :param max_grad_norm: gradient clipping (L2 norm over agent network and mixer)
    :param double_q: the online agent network picks the next actions, the target evaluates them (False: target max)
    :param agent_id: the agent network also sees the agent's index, one-hot (then ``predict`` needs whole teams
        of observations in the vector environment's order)
    :param mixing_embed_dim: width of the mixing network
    :param hypernet_embed: hidden width of two-layer hypernetworks
    :param hypernet_layers: 1 (linear hypernetworks, the paper) or 2 (EPyMARL)
    :param recurrent: a GRU agent network trained on stretches of ``sequence_length`` rows (see the module
        docstring); ``predict`` then takes and returns the hidden states. ``batch_size`` counts stretches, and
        ``net_arch`` (the layers before the GRU) defaults to ``[64]``
    :param rnn_hidden_dim: the GRU's hidden size (EPyMARL's ``hidden_dim``), with ``recurrent``
    :param sequence_length: rows (team steps) per sampled stretch, with ``recurrent``
    :param burn_in: first steps of each stretch that only warm the hidden state up (no loss, no gradient), with
        ``recurrent``; in ``[0, sequence_length - 1]``
    :param stats_window_size: episodes averaged in the rollout logs
    :param tensorboard_log: tensorboard folder
    :param policy_kwargs: policy arguments (``net_arch``, ``activation_fn``, ``features_extractor_class``, ...)
    :param verbose: verbosity
    :param seed: seed
    :param device: torch device
    :param _init_setup_model: build the networks now
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {"MlpPolicy": QMIXPolicy}
    #: the mixer (``"qmix"`` or ``"vdn"``) and whether it needs the global state
    mixer_type: ClassVar[str] = "qmix"
    needs_state: ClassVar[bool] = True
    exploration_schedule: Schedule
    policy: ValueDecompositionPolicy
    replay_buffer: JointReplayBuffer
    action_space: spaces.Discrete  # (supported_action_spaces)

    def __init__(
        self,
        policy: str | type[ValueDecompositionPolicy],
        env: GymEnv | str | None,
        learning_rate: float | Schedule = 5e-4,
        buffer_size: int = 200_000,
        learning_starts: int = 10_000,
        batch_size: int = 32,
        tau: float = 1.0,
        gamma: float = 0.99,
        train_freq: int | tuple[int, str] = 4,
        gradient_steps: int = 1,
        target_update_interval: int = 2000,
        exploration_fraction: float = 0.1,
        exploration_initial_eps: float = 1.0,
        exploration_final_eps: float = 0.05,
        max_grad_norm: float = 10.0,
        double_q: bool = True,
        agent_id: bool = False,
        mixing_embed_dim: int = 32,
        hypernet_embed: int = 64,
        hypernet_layers: int = 2,
        recurrent: bool = False,
        rnn_hidden_dim: int = 64,
        sequence_length: int = 16,
        burn_in: int = 4,
        stats_window_size: int = 100,
        tensorboard_log: str | None = None,
        policy_kwargs: dict[str, Any] | None = None,
        verbose: int = 0,
        seed: int | None = None,
        device: th.device | str = "auto",
        _init_setup_model: bool = True,
    ) -> None:
        for name, value in (("learning_rate", learning_rate), ("buffer_size", buffer_size),
                            ("learning_starts", learning_starts), ("batch_size", batch_size), ("tau", tau),
                            ("gamma", gamma), ("train_freq", train_freq), ("gradient_steps", gradient_steps),
                            ("target_update_interval", target_update_interval),
                            ("exploration_fraction", exploration_fraction),
                            ("exploration_initial_eps", exploration_initial_eps),
                            ("exploration_final_eps", exploration_final_eps), ("max_grad_norm", max_grad_norm),
                            ("double_q", double_q), ("agent_id", agent_id),
                            ("mixing_embed_dim", mixing_embed_dim), ("hypernet_embed", hypernet_embed),
                            ("hypernet_layers", hypernet_layers), ("recurrent", recurrent),
                            ("rnn_hidden_dim", rnn_hidden_dim), ("sequence_length", sequence_length),
                            ("burn_in", burn_in), ("stats_window_size", stats_window_size)):
            _check(name, value)
        if burn_in >= sequence_length:
            raise ValueError(f"burn_in must be smaller than sequence_length={sequence_length} (a stretch needs a step to "
                             f"train on), got {burn_in}")
        policy_kwargs = dict(policy_kwargs or {})
        own = sorted(set(policy_kwargs) & {"n_agents", "state_dim", "mixer", "mixing_embed_dim", "hypernet_embed",
                                           "hypernet_layers", "agent_id", "recurrent", "rnn_hidden_dim"})
        if own:
            raise ValueError(f"policy_kwargs may not set {own}: they are {type(self).__name__}'s own arguments or come "
                             "from the environment")
        self.n_agents, self.state_shape = 1, None
        if env is not None:
            env = BaseAlgorithm._wrap_env(maybe_make_env(env, verbose), verbose)
            self.n_agents, self.state_shape = team_layout(env, self.needs_state, type(self).__name__)
        policy_kwargs.update(n_agents=self.n_agents, state_dim=int(np.prod(self.state_shape or (0,))), mixer=self.mixer_type,
                             mixing_embed_dim=mixing_embed_dim, hypernet_embed=hypernet_embed,
                             hypernet_layers=hypernet_layers, agent_id=bool(agent_id))
        buffer_kwargs: dict[str, Any] = {"n_agents": self.n_agents, "state_shape": self.state_shape}
        if recurrent:
            policy_kwargs.update(recurrent=True, rnn_hidden_dim=rnn_hidden_dim)
            buffer_kwargs.update(sequence_length=sequence_length, rnn_hidden_dim=rnn_hidden_dim)
        super().__init__(  # (env is None when loading: SB3 takes it, though its annotation leaves None out)
            policy, cast(GymEnv, env), learning_rate, buffer_size, learning_starts, batch_size, tau, gamma, train_freq,
            gradient_steps,
            action_noise=None, replay_buffer_class=RecurrentJointReplayBuffer if recurrent else JointReplayBuffer,
            replay_buffer_kwargs=buffer_kwargs,
            optimize_memory_usage=False, policy_kwargs=policy_kwargs, stats_window_size=stats_window_size,
            tensorboard_log=tensorboard_log, verbose=verbose, device=device, seed=seed, sde_support=False,
            supported_action_spaces=(spaces.Discrete,), support_multi_env=True,
        )
        self.target_update_interval = target_update_interval
        self.exploration_fraction = exploration_fraction
        self.exploration_initial_eps = exploration_initial_eps
        self.exploration_final_eps = exploration_final_eps
        self.max_grad_norm = max_grad_norm
        self.double_q = bool(double_q)
        self.agent_id = bool(agent_id)
        self.mixing_embed_dim, self.hypernet_embed, self.hypernet_layers = mixing_embed_dim, hypernet_embed, hypernet_layers
        self.recurrent, self.rnn_hidden_dim = bool(recurrent), rnn_hidden_dim
        self.sequence_length, self.burn_in = sequence_length, burn_in
        #: ``(n_envs, rnn_hidden_dim)``: the hidden states entering the next step of ``_last_obs`` (recurrent; kept with
        #: the model, as ``_last_obs``), before the ``_last_episode_starts`` reset
        self._last_hidden: np.ndarray | None = None
        #: the hidden states of the step under way, ``(entering, leaving)`` (recurrent; not saved)
        self._step_hidden: tuple[np.ndarray, np.ndarray] | None = None
        self.exploration_rate = 0.0
        self._n_calls = 0
        #: ``(n_copies, *state_shape)``: the global states of ``_last_obs`` (kept with the model, as ``_last_obs``)
        self._last_states: np.ndarray | None = None
        if _init_setup_model:
            self._setup_model()

    def _setup_model(self) -> None:
        if self.state_shape is not None:  # a loaded model's is a list
            self.state_shape = tuple(int(d) for d in self.state_shape)
        if self.env is not None:  # loading with an environment: it must be the saved model's kind of team
            n_agents, state_shape = team_layout(self.env, self.needs_state, type(self).__name__)
            if (n_agents, state_shape) != (self.n_agents, self.state_shape):
                raise ValueError(f"the environment has teams of {n_agents} agents with states of shape {state_shape}; "
                                 f"the model was built for {self.n_agents} agents and states of shape {self.state_shape}")
        super()._setup_model()
        self.q_net, self.q_net_target = self.policy.q_net, self.policy.q_net_target
        self.mixer, self.mixer_target = self.policy.mixer, self.policy.mixer_target
        self.exploration_schedule = LinearSchedule(self.exploration_initial_eps, self.exploration_final_eps,
                                                   self.exploration_fraction)
        if self._last_states is not None:
            self.replay_buffer.last_states = self._last_states.copy()

    def set_env(self, env: GymEnv, force_reset: bool = True) -> None:
        """As SB3's ``set_env``, for an environment of the model's kind of team (its global state switched on)."""
        venv = self._wrap_env(env, self.verbose)
        if team_layout(venv, self.needs_state, type(self).__name__) != (self.n_agents, self.state_shape):
            raise ValueError(f"the environment's teams differ from the model's ({self.n_agents} agents, states of shape "
                             f"{self.state_shape})")
        super().set_env(venv, force_reset=force_reset)

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "q_net", "q_net_target", "mixer", "mixer_target", "_step_hidden"]

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        return ["policy", "policy.optimizer"], []

    # ------------------------------------------------------------------ rollouts
    def _setup_learn(self, total_timesteps: int, callback: MaybeCallback = None, reset_num_timesteps: bool = True,
                     tb_log_name: str = "run", progress_bar: bool = False) -> tuple[int, BaseCallback]:
        resets = reset_num_timesteps or self._last_obs is None
        result = super()._setup_learn(total_timesteps, callback, reset_num_timesteps, tb_log_name, progress_bar)
        if resets and self.state_shape is not None:  # the environment was reset: the buffer reads the new states
            assert self.env is not None  # (SB3's _setup_learn needs one)
            self.replay_buffer.observe_reset(self.env.unwrapped.reset_infos)
        elif self.replay_buffer.last_states is None and self._last_states is not None:
            self.replay_buffer.last_states = self._last_states.copy()
        self._last_states = self.replay_buffer.last_states
        if self.recurrent and (resets or self._last_hidden is None
                               or self._last_hidden.shape != (self.n_envs, self.rnn_hidden_dim)):
            self._last_hidden = np.zeros((self.n_envs, self.rnn_hidden_dim), dtype=np.float32)
        return result

    def _sample_action(self, learning_starts: int, action_noise: Any = None, n_envs: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """SB3's, and with the recurrent agent network the hidden states' step: the network runs on every step (also
        before ``learning_starts``, whose actions are uniformly random) so that the stored hidden states are the ones it
        had on each observation."""
        if not self.recurrent:
            return super()._sample_action(learning_starts, action_noise, n_envs)
        assert self._last_hidden is not None and self._last_obs is not None  # (set by _setup_learn)
        entering = self._last_hidden * (1.0 - np.asarray(self._last_episode_starts, dtype=np.float32)[:, None])
        greedy, leaving = self.policy.predict(self._last_obs, entering, None, deterministic=True)
        self._step_hidden = (entering, leaving)
        if self.num_timesteps < learning_starts:
            actions = np.array([self.action_space.sample() for _ in range(n_envs)])
        else:
            actions = self._explore(greedy)
        return actions, actions

    def _store_transition(self, replay_buffer: ReplayBuffer, buffer_action: np.ndarray,
                          new_obs: np.ndarray | dict[str, np.ndarray], reward: np.ndarray, dones: np.ndarray,
                          infos: list[dict[str, Any]]) -> None:
        assert isinstance(replay_buffer, JointReplayBuffer)  # (the model's own)
        step_hidden = self._step_hidden
        if self.recurrent:
            assert isinstance(replay_buffer, RecurrentJointReplayBuffer)  # (the recurrent agent network's)
            assert step_hidden is not None and self._last_episode_starts is not None  # (set by _sample_action, learn)
            replay_buffer.set_recurrent_inputs(step_hidden[0], self._last_episode_starts)
        super()._store_transition(replay_buffer, buffer_action, new_obs, reward, dones, infos)
        self._last_states = replay_buffer.last_states
        if self.recurrent:  # the next step's: the hidden states the network left, reset where an episode ended
            assert step_hidden is not None
            self._last_hidden, self._step_hidden = step_hidden[1], None
            self._last_episode_starts = np.asarray(dones, dtype=bool).copy()

    def _on_step(self) -> None:
        """After every vector step (as DQN): target update every ``target_update_interval`` agent-steps, epsilon."""
        self._n_calls += 1
        if self._n_calls % max(self.target_update_interval // self.n_envs, 1) == 0:
            self.policy.update_targets(self.tau)
        self.exploration_rate = self.exploration_schedule(self._current_progress_remaining)
        self.logger.record("rollout/exploration_rate", self.exploration_rate)

    def predict(self, observation: np.ndarray | dict[str, np.ndarray], state: tuple[np.ndarray, ...] | None = None,
                episode_start: np.ndarray | None = None,
                deterministic: bool = False) -> tuple[np.ndarray, tuple[np.ndarray, ...] | None]:
        """Each entry's greedy action on its own Q-values; unless ``deterministic``, each entry independently takes a
        uniformly random action with probability ``exploration_rate`` (the current epsilon).

        :param observation: per-entry observations ``(n, *obs_shape)`` or one observation (with ``agent_id``: a
            whole number of teams, in the vector environment's order)
        :param state: with ``recurrent``: the hidden states ``(n, rnn_hidden_dim)`` (None: zeros, an episode's first
            step); otherwise unused
        :param episode_start: with ``recurrent``: ``(n,)`` flags of the entries whose episode starts (their hidden state
            is zeroed); otherwise unused
        :param deterministic: greedy actions only
        :return: the actions and the next hidden states (without ``recurrent``: ``state``)
        """
        actions, state = self.policy.predict(observation, state, episode_start, deterministic)
        return (actions if deterministic else self._explore(actions)), state

    def _explore(self, actions: np.ndarray) -> np.ndarray:
        """Epsilon-greedy: each action independently replaced by a uniformly random one with probability
        ``exploration_rate`` (a subclass whose ``predict`` computes its actions otherwise, e.g. with a belief, applies
        this to them)."""
        if self.exploration_rate <= 0:
            return actions
        flat = np.array(actions).reshape(-1)
        explore = np.random.rand(flat.size) < self.exploration_rate
        flat[explore] = np.random.randint(0, int(self.action_space.n), size=int(explore.sum()))
        return flat.reshape(np.shape(actions))

    # ------------------------------------------------------------------ training
    def _targets(self, data: JointReplaySamples, next_online: th.Tensor) -> th.Tensor:
        """``y = r + gamma (1 - terminated) Q_tot^-(o', u*, s')``, ``(batch,)``: the target networks evaluate ``u*``,
        the agents' greedy next actions under the online network's ``next_online`` Q-values (double Q), or their own
        greedy actions (``double_q=False``)."""
        with th.no_grad():
            next_target = self.policy.team_q_values(data.next_observations, target=True)
            return self._bootstrap(data.rewards, data.dones, next_online, next_target, data.next_states)

    def _bootstrap(self, rewards: th.Tensor, dones: th.Tensor, next_online: th.Tensor, next_target: th.Tensor,
                   next_states: th.Tensor | None) -> th.Tensor:
        """``r + gamma (1 - terminated) Q_tot^-(o', u*, s')`` ``(batch,)`` from the next Q-values ``(batch, n_agents,
        n_actions)`` of the online network (which picks ``u*``, double Q) and of the target network."""
        if self.double_q:
            next_chosen = next_target.gather(2, next_online.argmax(dim=2, keepdim=True)).squeeze(-1)
        else:
            next_chosen = next_target.max(dim=2).values
        next_tot = self.policy.mixer_target(next_chosen, next_states)
        return rewards + (1.0 - dones) * self.gamma * next_tot

    def _loss(self, data: JointReplaySamples) -> tuple[th.Tensor, dict[str, float]]:
        """The squared TD error of a batch of team transitions (as the paper and EPyMARL) and its statistics."""
        batch = data.actions.shape[0]
        # one forward pass of the online network over observations and next observations
        q_all = self.policy.team_q_values(th.cat([data.observations, data.next_observations]))
        q_values, next_online = q_all[:batch], q_all[batch:].detach()
        chosen = q_values.gather(2, data.actions.unsqueeze(-1)).squeeze(-1)  # (batch, n_agents)
        targets = self._targets(data, next_online)
        q_tot = self.policy.mixer(chosen, data.states)
        loss = F.mse_loss(q_tot, targets)
        stats = {"q_taken_mean": chosen.mean().item(), "q_tot_mean": q_tot.mean().item(),
                 "target_mean": targets.mean().item(), "td_error_abs": (q_tot - targets).abs().mean().item()}
        return loss, stats

    def _sequence_targets(self, data: JointSequenceSamples, online_hiddens: th.Tensor,
                          online_q: th.Tensor) -> th.Tensor:
        """The targets ``(batch, length - burn_in)`` of the stretches' trained rows: the target network unrolled over the
        same stretch from the same stored state, one more step on each row's next observation (read from the next row
        within an episode); ``u*`` picked by the online network's next Q-values likewise, from its hidden states
        ``online_hiddens`` and Q-values ``online_q`` of the trained rows (double Q)."""
        b = self.burn_in
        with th.no_grad():
            next_observations = data.next_observations[:, b:]
            boundaries = (data.episode_starts[:, b + 1:] > 0).any(dim=2)  # an episode starts in the next row
            boundaries = th.cat([boundaries, th.ones_like(boundaries[:, :1])], dim=1)
            next_online = self.policy.next_q_values(next_observations, online_hiddens, online_q.detach(), boundaries)
            target_hiddens = self.policy.unroll(data.observations, data.episode_starts, data.hidden, target=True)[:, b:]
            next_target = self.policy.next_q_values(next_observations, target_hiddens,
                                                    self.policy.q_from_hidden(target_hiddens, target=True), boundaries,
                                                    target=True)
            batch, length, n_agents, n_actions = next_online.shape
            next_states = None if data.next_states is None else data.next_states[:, b:].reshape(batch * length, -1)
            targets = self._bootstrap(data.rewards[:, b:].reshape(-1), data.dones[:, b:].reshape(-1),
                                      next_online.reshape(-1, n_agents, n_actions),
                                      next_target.reshape(-1, n_agents, n_actions), next_states)
            return targets.view(batch, length)

    def _sequence_loss(self, data: JointSequenceSamples) -> tuple[th.Tensor, dict[str, float]]:
        """The squared TD error over the stretches' rows after the burn-in (none is masked otherwise: see the module
        docstring) and its statistics."""
        b = self.burn_in
        hiddens = self.policy.unroll(data.observations, data.episode_starts, data.hidden, burn_in=b)[:, b:]
        q_values = self.policy.q_from_hidden(hiddens)
        chosen = q_values.gather(3, data.actions[:, b:].unsqueeze(-1)).squeeze(-1)
        targets = self._sequence_targets(data, hiddens, q_values).reshape(-1)
        states = None if data.states is None else data.states[:, b:].reshape(targets.shape[0], -1)
        q_tot = self.policy.mixer(chosen.reshape(targets.shape[0], -1), states)
        loss = F.mse_loss(q_tot, targets)
        stats = {"q_taken_mean": chosen.mean().item(), "q_tot_mean": q_tot.mean().item(),
                 "target_mean": targets.mean().item(), "td_error_abs": (q_tot - targets).abs().mean().item()}
        return loss, stats

    def train(self, gradient_steps: int, batch_size: int = 32) -> None:
        """``gradient_steps`` TD updates on ``batch_size`` team transitions each (``recurrent``: stretches; none until
        the buffer holds one stretch)."""
        self.policy.set_training_mode(True)
        self._update_learning_rate(self.policy.optimizer)
        if self.recurrent:
            assert isinstance(self.replay_buffer, RecurrentJointReplayBuffer)  # (the recurrent agent network's)
            if not self.replay_buffer.can_sample():
                return
        losses, norms, stats = [], [], []
        for _ in range(gradient_steps):
            data = self.replay_buffer.sample(batch_size, env=self._vec_normalize_env)
            # (stretches from the recurrent buffer, team transitions from the joint one: SB3 annotates its own samples)
            loss, step_stats = (self._sequence_loss(cast(JointSequenceSamples, data)) if self.recurrent
                                else self._loss(cast(JointReplaySamples, data)))
            self.policy.optimizer.zero_grad()
            loss.backward()
            norms.append(th.nn.utils.clip_grad_norm_(self.policy.online_parameters(), self.max_grad_norm).item())
            self.policy.optimizer.step()
            losses.append(loss.item())
            stats.append(step_stats)
        self._n_updates += gradient_steps
        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        self.logger.record("train/loss", float(np.mean(losses)))
        self.logger.record("train/grad_norm", float(np.mean(norms)))
        for key in stats[0]:
            self.logger.record(f"train/{key}", float(np.mean([s[key] for s in stats])))

    def learn(self: SelfQMIX, total_timesteps: int, callback: MaybeCallback = None, log_interval: int = 4,
              tb_log_name: str = "QMIX", reset_num_timesteps: bool = True, progress_bar: bool = False) -> SelfQMIX:
        return super().learn(total_timesteps, callback=callback, log_interval=log_interval, tb_log_name=tb_log_name,
                             reset_num_timesteps=reset_num_timesteps, progress_bar=progress_bar)

