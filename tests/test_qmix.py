"""QMIX and VDN: the mixers, the joint replay buffer, shapes, save/load, evaluation, seeding, argument checks, and
(expensive) the two-step matrix game of the QMIX paper."""

import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from matrix_game import ADDITIVE_OPTIMUM, OPTIMUM, PAYOFFS, TwoStepGame, greedy_return
from stable_baselines3.common.evaluation import evaluate_policy

from sb3_emmarl.common.vec_env import make_vec_env
from sb3_emmarl.qmix import QMIX, JointReplayBuffer, QMixer, RecurrentJointReplayBuffer, VDNMixer
from sb3_emmarl.vdn import VDN

TINY = {"n_uavs": 2, "grid_size": 20, "max_cycles": 40}
#: Small, fast settings for the reserve.
FAST = dict(learning_starts=40, batch_size=8, buffer_size=2000, train_freq=2, target_update_interval=40,
            policy_kwargs=dict(net_arch=[32]))
QMIX_FAST = dict(FAST, mixing_embed_dim=8, hypernet_embed=16)


def tiny_reserve(n_copies=2, seed=0, n_uavs=2, **kwargs):
    return make_vec_env(n_copies, seed=seed, env_kwargs={**TINY, "n_uavs": n_uavs}, **kwargs)


# ---------------------------------------------------------------------------------------------- mixers
@pytest.mark.parametrize("hypernet_layers", [1, 2])
@pytest.mark.parametrize("n_agents", [1, 3])
def test_the_qmix_mixer_never_decreases_when_one_agent_s_value_increases(hypernet_layers, n_agents):
    th.manual_seed(n_agents)
    mixer = QMixer(n_agents, state_dim=5, embed_dim=8, hypernet_layers=hypernet_layers, hypernet_embed=16)
    qs, states = 10 * th.randn(2000, n_agents), 3 * th.randn(2000, 5)
    base = mixer(qs, states)
    assert base.shape == (2000,)
    for agent in range(n_agents):
        raised = qs.clone()
        raised[:, agent] += 5 * th.rand(2000)
        assert (mixer(raised, states) >= base - 1e-5).all()
    qs.requires_grad_(True)
    mixer(qs, states).sum().backward()
    assert (qs.grad >= 0).all()


def test_the_vdn_mixer_is_the_sum():
    qs = th.randn(7, 3)
    assert th.allclose(VDNMixer()(qs, None), qs.sum(dim=1))


# ---------------------------------------------------------------------------------------------- joint buffer
def _step(t, n_copies=2, n_agents=2):
    """Entry values coding (step, copy, agent): observation ``[t, copy, agent]``, action ``(t + copy + agent) % 3``,
    reward ``t + copy + agent / 10``."""
    obs = np.array([[t, i // n_agents, i % n_agents] for i in range(n_copies * n_agents)], dtype=np.float32)
    actions = np.array([(t + i // n_agents + i % n_agents) % 3 for i in range(n_copies * n_agents)])
    rewards = np.array([t + i // n_agents + (i % n_agents) / 10 for i in range(n_copies * n_agents)], dtype=np.float32)
    return obs, actions, rewards


def test_the_joint_buffer_regroups_entries_into_copies_with_their_states_and_episode_ends():
    n_agents = 2
    buffer = JointReplayBuffer(40, spaces.Box(-100, 100, (3,)), spaces.Discrete(3), device="cpu", n_envs=4,
                               n_agents=n_agents, state_shape=(2,))

    def state(t, copy):
        return np.array([t, copy], dtype=np.float32)

    buffer.observe_reset([{"state": state(0, i // n_agents)} for i in range(4)])
    for t in range(3):
        obs, actions, rewards = _step(t)
        next_obs, _, _ = _step(t + 1)
        infos = [{"state": state(t + 1, i // n_agents)} for i in range(4)]
        dones = np.zeros(4, dtype=bool)
        if t == 1:  # copy 0 terminates, copy 1 is truncated; both reset: their new episodes start at "step" 100
            dones[:] = True
            for i in range(4):
                infos[i] = {"state": state(100, i // n_agents), "terminal_state": state(t + 1, i // n_agents),
                            "TimeLimit.truncated": i // n_agents == 1}
        buffer.add(obs, next_obs, actions, rewards, dones, infos)  # next_obs: the terminal observations (as SB3)
    assert buffer.pos == 3
    np.random.seed(0)
    data = buffer._get_samples(np.repeat(np.arange(3), 20))
    assert data.observations.shape == (60, n_agents, 3) and data.actions.shape == (60, n_agents)
    assert data.states.shape == (60, 2) and data.rewards.shape == (60,) and data.dones.shape == (60,)
    t, copy = data.observations[:, 0, 0].numpy(), data.observations[:, 0, 1].numpy()
    assert set(zip(t.tolist(), copy.tolist())) == {(s, c) for s in range(3) for c in range(2)}
    assert (data.observations[:, :, 2] == th.arange(n_agents)).all()  # agents in order
    assert (data.observations[:, :, :2] == data.observations[:, :1, :2]).all()  # one step of one copy
    assert (data.next_observations[:, :, 0].numpy() == (t + 1)[:, None]).all()
    np.testing.assert_array_equal(data.states.numpy(), np.stack([np.where(t == 2, 100, t), copy], axis=1))
    np.testing.assert_array_equal(data.next_states.numpy(), np.stack([t + 1, copy], axis=1))
    expected_actions = (t[:, None] + copy[:, None] + np.arange(n_agents)) % 3
    np.testing.assert_array_equal(data.actions.numpy(), expected_actions)
    np.testing.assert_allclose(data.rewards.numpy(), t + copy + 0.05, rtol=1e-6)
    np.testing.assert_array_equal(data.dones.numpy(), ((t == 1) & (copy == 0)).astype(np.float32))


def test_the_joint_buffer_needs_the_reset_states_and_whole_teams():
    buffer = JointReplayBuffer(40, spaces.Box(-1, 1, (3,)), spaces.Discrete(3), device="cpu", n_envs=4, n_agents=2,
                               state_shape=(2,))
    obs, actions, rewards = _step(0)
    with pytest.raises(RuntimeError, match="observe_reset"):
        buffer.add(obs, obs, actions, rewards, np.zeros(4, bool), [{"state": np.zeros(2)}] * 4)
    buffer.observe_reset([{"state": np.zeros(2)}] * 4)
    with pytest.raises(ValueError, match="with_state=True"):
        buffer.add(obs, obs, actions, rewards, np.zeros(4, bool), [{}] * 4)
    with pytest.raises(ValueError, match="not whole teams of n_agents=3"):
        JointReplayBuffer(40, spaces.Box(-1, 1, (3,)), spaces.Discrete(3), n_envs=4, n_agents=3)


def test_the_stored_matrix_game_transitions_are_whole_team_steps_with_the_right_states():
    """Through SB3's rollouts (terminal observations substituted, automatic resets): every stored team transition of
    the deterministic game agrees with the game's rules."""
    model = QMIX("MlpPolicy", make_vec_env(3, seed=0, env_fn=TwoStepGame), learning_starts=10**6, buffer_size=600,
                 agent_id=True, seed=0)
    model.learn(300)
    np.random.seed(1)
    data = model.replay_buffer.sample(200)
    obs, next_obs = data.observations.numpy(), data.next_observations.numpy()
    states, next_states, actions = data.states.numpy(), data.next_states.numpy(), data.actions.numpy()
    assert (obs == states[:, None]).all() and (next_obs == next_states[:, None]).all()
    first = states[:, 0] == 1
    assert first.any() and (~first).any()
    np.testing.assert_array_equal(next_states[first].argmax(1), 1 + actions[first, 0])
    assert (data.dones.numpy() == ~first).all() and (data.rewards.numpy()[first] == 0).all()
    second = np.flatnonzero(~first)
    paid = [PAYOFFS[states[i].argmax()][actions[i, 0], actions[i, 1]] for i in second]
    np.testing.assert_array_equal(data.rewards.numpy()[second], paid)
    np.testing.assert_array_equal(next_states[second], states[second])  # the terminal state is the last state


# ---------------------------------------------------------------------------------------------- shapes, learning
@pytest.mark.parametrize("algo", [QMIX, VDN])
@pytest.mark.parametrize("n_uavs", [1, 2, 3])
def test_shapes_for_teams_of_one_two_and_three_agents(algo, n_uavs):
    env = tiny_reserve(2, n_uavs=n_uavs)
    kwargs = QMIX_FAST if algo is QMIX else FAST
    model = algo("MlpPolicy", env, agent_id=True, seed=0, **kwargs).learn(100 * n_uavs)
    assert model.n_agents == n_uavs and model.n_envs == 2 * n_uavs and model._n_updates > 0
    data = model.replay_buffer.sample(5)
    obs_dim = env.observation_space.shape[0]
    assert data.observations.shape == (5, n_uavs, obs_dim) and data.actions.shape == (5, n_uavs)
    q = model.policy.team_q_values(data.observations)
    assert q.shape == (5, n_uavs, env.action_space.n)
    if algo is QMIX:
        assert data.states.shape == (5, *env.unwrapped.state_space.shape)
        assert model.policy.mixer(q[..., 0], data.states).shape == (5,)
    else:
        assert data.states is None
    actions, _ = model.predict(env.reset(), deterministic=True)
    assert actions.shape == (2 * n_uavs,) and env.action_space.contains(int(actions[0]))


def test_the_default_reserve_works_with_defaults():
    model = QMIX("MlpPolicy", make_vec_env(4, seed=0))
    assert model.n_agents == 10 and model.state_shape == (194,) and model.n_envs == 40
    model.learning_starts = 0
    model.batch_size = 4
    model.learn(80)  # two vector steps, one update
    assert model._n_updates == 1


def test_double_q_targets_take_the_online_argmax_and_the_target_values():
    model = QMIX("MlpPolicy", make_vec_env(1, seed=0, env_fn=TwoStepGame), learning_starts=0, buffer_size=200,
                 agent_id=True, seed=0)
    model.learn(40)
    with th.no_grad():
        for p in model.policy.q_net_target.parameters():
            p.add_(th.randn_like(p))
    data = model.replay_buffer.sample(16)
    online = model.policy.team_q_values(data.next_observations)
    target = model.policy.team_q_values(data.next_observations, target=True)
    picked = target.gather(2, online.argmax(2, keepdim=True)).squeeze(-1)
    expected = data.rewards + (1 - data.dones) * model.gamma * model.policy.mixer_target(picked, data.next_states)
    np.testing.assert_allclose(model._targets(data, online).numpy(), expected.detach().numpy(), rtol=1e-5)
    model.double_q = False
    maximum = model.policy.mixer_target(target.max(2).values, data.next_states)
    np.testing.assert_allclose(model._targets(data, online).numpy(),
                               (data.rewards + (1 - data.dones) * model.gamma * maximum).detach().numpy(), rtol=1e-5)


def test_epsilon_follows_dqn_s_linear_schedule_and_applies_per_entry():
    model = VDN("MlpPolicy", tiny_reserve(2), exploration_fraction=0.5, exploration_final_eps=0.1, seed=0, **FAST)
    model.learn(400)
    assert model.exploration_rate == pytest.approx(0.1)
    obs = np.zeros((4000, model.observation_space.shape[0]), dtype=np.float32)
    greedy, _ = model.predict(obs, deterministic=True)
    model.exploration_rate = 0.5
    explored, _ = model.predict(obs, deterministic=False)
    changed = np.mean(explored != greedy)  # random actions differ from the greedy one 14 times in 15
    assert abs(changed - 0.5 * 14 / 15) < 0.04


# ---------------------------------------------------------------------------------------------- save, load, evaluate
@pytest.mark.parametrize("algo", [QMIX, VDN])
def test_save_and_load_give_the_same_actions_with_and_without_an_env(algo, tmp_path):
    env = tiny_reserve(2)
    kwargs = QMIX_FAST if algo is QMIX else FAST
    model = algo("MlpPolicy", env, agent_id=True, seed=0, **kwargs).learn(200)
    obs = env.reset()
    actions, _ = model.predict(obs, deterministic=True)
    model.save(tmp_path / "model")
    for loaded in (algo.load(tmp_path / "model"), algo.load(tmp_path / "model", env=tiny_reserve(2, seed=5))):
        assert type(loaded.policy) is type(model.policy) and loaded.n_agents == 2
        np.testing.assert_array_equal(loaded.predict(obs, deterministic=True)[0], actions)
    loaded.learn(100, reset_num_timesteps=False)  # trains on
    with pytest.raises(ValueError, match="teams of 3 agents"):
        algo.load(tmp_path / "model", env=tiny_reserve(1, n_uavs=3))


def test_evaluate_policy_works_on_the_plain_environment():
    model = QMIX("MlpPolicy", tiny_reserve(2), seed=0, **QMIX_FAST).learn(200)
    plain = tiny_reserve(1, seed=7)  # no global state in the infos, another number of copies
    mean, _ = evaluate_policy(model, plain, n_eval_episodes=2)
    assert np.isfinite(mean)
    assert "state" not in plain.unwrapped.reset_infos[0]


def test_the_same_seed_gives_the_same_run_and_another_seed_another():
    def run(seed):
        model = QMIX("MlpPolicy", tiny_reserve(2, seed=seed), seed=seed, **QMIX_FAST).learn(240)
        return th.cat([p.detach().flatten() for p in model.policy.parameters()]).numpy(), model.replay_buffer.actions

    (params_a, actions_a), (params_b, actions_b), (params_c, _) = run(3), run(3), run(4)
    np.testing.assert_array_equal(params_a, params_b)
    np.testing.assert_array_equal(actions_a, actions_b)
    assert not np.array_equal(params_a, params_c)


def test_tensorboard_logs_the_training_statistics(tmp_path):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    VDN("MlpPolicy", tiny_reserve(2), tensorboard_log=str(tmp_path), seed=0, **FAST).learn(400, log_interval=1)

    (events,) = tmp_path.glob("VDN_1/events.out.tfevents.*")
    tags = EventAccumulator(str(events)).Reload().Tags()["scalars"]
    assert {"train/loss", "train/q_taken_mean", "train/target_mean", "rollout/exploration_rate"} <= set(tags)


# ---------------------------------------------------------------------------------------------- bad arguments
class NoStateGame(TwoStepGame):
    state = None  # type: ignore[assignment]


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"mixing_embed_dim": 0}, r"mixing_embed_dim must be an int in \[1, 4096\], got 0"),
    ({"hypernet_embed": 2.5}, r"hypernet_embed must be an int in \[1, 4096\], got 2.5"),
    ({"hypernet_layers": 3}, r"hypernet_layers must be an int in \[1, 2\], got 3"),
    ({"exploration_final_eps": 1.5}, r"exploration_final_eps must be a number in \[0.0, 1.0\], got 1.5"),
    ({"exploration_initial_eps": -0.1}, r"exploration_initial_eps must be a number in \[0.0, 1.0\], got -0.1"),
    ({"gamma": 2}, r"gamma must be a number in \[0.0, 1.0\], got 2"),
    ({"double_q": "yes"}, r"double_q must be true or false, got 'yes'"),
    ({"batch_size": 0}, r"batch_size must be an int in \[1, 10000000\], got 0"),
    ({"learning_rate": "lin_1e-3"}, r"learning_rate must be a number in \(0.0, 10.0\] or a schedule"),
    ({"policy_kwargs": {"n_agents": 3}}, r"policy_kwargs may not set \['n_agents'\]"),
])
def test_bad_arguments_are_rejected_with_a_message(kwargs, message):
    with pytest.raises(ValueError, match=message):
        QMIX("MlpPolicy", make_vec_env(1, env_fn=TwoStepGame), **kwargs)


def test_environments_qmix_and_vdn_cannot_use_are_rejected():
    with pytest.raises(ValueError, match="NoStateGame has no state"):
        QMIX("MlpPolicy", make_vec_env(1, env_fn=NoStateGame))
    VDN("MlpPolicy", make_vec_env(1, env_fn=NoStateGame))  # the sum needs no state
    with pytest.raises(ValueError, match="QMIX needs the global state: give it the parameter-sharing"):
        QMIX("MlpPolicy", "CartPole-v1")
    with pytest.raises(ValueError, match=r"VDN needs Discrete actions, got the action space Box"):
        VDN("MlpPolicy", make_vec_env(1, env_kwargs={**TINY, "continuous_actions": True}))
    with pytest.raises(ValueError, match=r"VDN takes no \['mixing_embed_dim'\]"):
        VDN("MlpPolicy", make_vec_env(1, env_fn=TwoStepGame), mixing_embed_dim=8)
    model = QMIX("MlpPolicy", make_vec_env(1, env_fn=TwoStepGame), agent_id=True)
    with pytest.raises(ValueError, match=r"whole teams .* n_agents=2"):
        model.predict(np.zeros((3, 3), dtype=np.float32))


# ---------------------------------------------------------------------------------------------- the matrix game
def test_the_matrix_game_follows_pettingzoo_s_api_and_pays_as_in_the_paper():
    from pettingzoo.test import parallel_api_test

    parallel_api_test(TwoStepGame(), num_cycles=10)
    env = TwoStepGame()
    for first in (0, 1):
        for a_0 in (0, 1):
            for a_1 in (0, 1):
                obs, _ = env.reset()
                assert obs["agent_0"].tolist() == [1, 0, 0] == env.state().tolist()
                env.step({"agent_0": first, "agent_1": 1 - first})
                assert env.state().argmax() == 1 + first
                _, rewards, terminations, *_ = env.step({"agent_0": a_0, "agent_1": a_1})
                assert rewards["agent_1"] == (7 if first == 0 else [[0, 1], [1, 8]][a_0][a_1])
                assert all(terminations.values()) and not env.agents


@pytest.mark.expensive
def test_qmix_learns_the_optimum_and_vdn_the_additive_one_on_four_of_five_seeds():
    from scripts import load_benchmark

    bench = load_benchmark("matrix_game")
    for algo, expected in (("qmix", OPTIMUM), ("vdn", ADDITIVE_OPTIMUM)):
        returns = [bench.run(algo, seed) for seed in range(5)]
        assert sum(r == expected for r in returns) >= 4, (algo, returns)


def test_greedy_return_reads_the_joint_policy():
    class Fixed:
        def __init__(self, first, second):
            self.plan = [first, second]

        def predict(self, obs, deterministic=True):
            return np.array(self.plan[int(obs[0].argmax() > 0)]), None

    assert greedy_return(Fixed([1, 0], [1, 1])) == OPTIMUM
    assert greedy_return(Fixed([0, 0], [1, 0])) == ADDITIVE_OPTIMUM
    assert greedy_return(Fixed([1, 1], [0, 1])) == 1.0


# ---------------------------------------------------------------------------------------------- the recurrent option
#: Small recurrent settings for the reserve.
RNN_FAST = dict(FAST, policy_kwargs=dict(net_arch=[16]), recurrent=True, rnn_hidden_dim=8, sequence_length=5, burn_in=2)
RNN_QMIX = dict(RNN_FAST, mixing_embed_dim=8, hypernet_embed=16)


class CueGame(TwoStepGame):
    """A task that needs memory: both agents see a cue (0 or 1) on the first of three steps only, then a blank step,
    then each is paid half a point for naming the cue (``(a_0 == cue) / 2 + (a_1 == cue) / 2``). Without memory the
    best return is 0.5, with it 1. The global state is the step alone (one-hot): with the cue in it, recurrent QMIX's
    mixer explained the payoffs by the state and its agents' values stayed blind to the cue (0.45-0.6 on 6 seeds,
    where recurrent VDN reached 1), a weakness of state-conditioned mixing rather than of the memory."""

    metadata = {"name": "cue_game_v0", "render_modes": [], "is_parallelizable": True}

    def __init__(self, render_mode=None):
        super().__init__(render_mode)
        self._rng, self._t, self._cue = np.random.default_rng(), 0, 0

    def state(self):
        one_hot = np.zeros(3, dtype=np.float32)
        one_hot[min(self._t, 2)] = 1.0
        return one_hot

    def _observations(self):
        obs = np.zeros(3, dtype=np.float32)
        if self._t == 0:
            obs[self._cue] = 1.0
        elif self._t == 2:
            obs[2] = 1.0  # "answer now"
        return {agent: obs.copy() for agent in self.agents}

    def reset(self, seed=None, options=None):
        if seed is not None:
            self._rng = np.random.default_rng(seed)
        self.agents, self._t, self._cue = list(self.possible_agents), 0, int(self._rng.integers(2))
        return self._observations(), {agent: {} for agent in self.agents}

    def step(self, actions):
        done = self._t == 2
        reward = float(np.mean([int(actions[agent]) == self._cue for agent in self.possible_agents])) if done else 0.0
        self._t += 1
        observations = self._observations()
        rewards, infos = {agent: reward for agent in self.agents}, {agent: {} for agent in self.agents}
        terminations, truncations = {agent: done for agent in self.agents}, {agent: False for agent in self.agents}
        if done:
            self.agents = []
        return observations, rewards, terminations, truncations, infos


def _recurrent_buffer(rows=10, sequence_length=3):
    """A recurrent joint buffer of ``rows`` rows of 2 copies of 2 agents, states ``[t, copy]``."""
    buffer = RecurrentJointReplayBuffer(4 * rows, spaces.Box(-100, 100, (3,)), spaces.Discrete(3), device="cpu", n_envs=4,
                                        n_agents=2, state_shape=(2,), sequence_length=sequence_length, rnn_hidden_dim=2)
    buffer.observe_reset([{"state": np.array([0, i // 2], dtype=np.float32)} for i in range(4)])
    return buffer


def _fill(buffer, steps, ends):
    """``steps`` vector steps coded as ``_step``'s; copy ``c``'s episode terminates at the steps ``ends[c]``. The
    hidden state handed over with step ``t`` is ``[t, entry]``, zeroed at an episode's start (as the algorithm's)."""
    starts = np.ones(4, dtype=bool)
    for t in range(steps):
        obs, actions, rewards = _step(t)
        dones = np.array([t in ends[i // 2] for i in range(4)])
        infos = [{"state": np.array([t + 1, i // 2], dtype=np.float32)} for i in range(4)]
        for i in np.flatnonzero(dones):
            infos[i]["terminal_state"] = infos[i]["state"]
        hidden = np.stack([[t, i] for i in range(4)]).astype(np.float32) * ~starts[:, None]
        buffer.set_recurrent_inputs(hidden, starts)
        buffer.add(obs, _step(t + 1)[0], actions, rewards, dones, infos)
        starts = dones


def test_stretches_never_cross_the_write_position_and_flag_episode_starts():
    ends = ({1, 7, 11}, {4})  # copy 0's episodes terminate at steps 1, 7 and 11, copy 1's at step 4
    buffer = _recurrent_buffer(rows=10, sequence_length=3)
    obs, actions, rewards = _step(0)
    with pytest.raises(RuntimeError, match="set_recurrent_inputs"):
        buffer.add(obs, obs, actions, rewards, np.zeros(4, bool), [{"state": np.zeros(2)}] * 4)
    _fill(buffer, 2, ends)
    assert not buffer.can_sample()
    with pytest.raises(ValueError, match="fewer than sequence_length=3"):
        buffer.sample(4)

    def check(buffer, expected_first_steps):
        np.random.seed(0)
        data = buffer.sample(400)
        t = data.observations[:, :, 0, 0].numpy()  # (batch, 3): the steps of each stretch
        copy = data.observations[:, 0, 0, 1].numpy().astype(int)
        assert data.observations.shape == (400, 3, 2, 3) and data.hidden.shape == (400, 2, 2)
        assert data.states.shape == (400, 3, 2) and data.rewards.shape == (400, 3) and data.dones.shape == (400, 3)
        np.testing.assert_array_equal(t, t[:, :1] + np.arange(3))  # consecutive steps: never across the write position
        assert set(t[:, 0].astype(int)) == expected_first_steps  # and every such stretch is drawn
        assert (data.observations[:, :, :, 1].numpy() == copy[:, None, None]).all()  # of one copy
        assert (data.observations[:, :, :, 2].numpy() == np.arange(2)).all()  # its agents in order
        first_of_episode = np.array([[s == 0 or (s - 1) in ends[c] for s in row] for row, c in zip(t, copy)])
        np.testing.assert_array_equal(data.episode_starts.numpy(), np.repeat(first_of_episode[:, :, None], 2, axis=2))
        np.testing.assert_array_equal(data.dones.numpy(), [[s in ends[c] for s in row] for row, c in zip(t, copy)])
        np.testing.assert_array_equal(data.states[:, :, 0].numpy(), t)
        np.testing.assert_array_equal(data.next_observations[:, :, 0, 0].numpy(), t + 1)
        # the stored hidden state entering the first step: [t, entry], zero at an episode's start
        entries = copy[:, None] * 2 + np.arange(2)
        expected = np.stack([np.broadcast_to(t[:, :1], entries.shape), entries], axis=2) * ~first_of_episode[:, :1, None]
        np.testing.assert_array_equal(data.hidden.numpy(), expected)

    buffer = _recurrent_buffer(rows=10, sequence_length=3)
    _fill(buffer, 6, ends)  # 6 of 10 rows: stretches start at rows 0 to 3
    check(buffer, {0, 1, 2, 3})
    buffer = _recurrent_buffer(rows=10, sequence_length=3)
    _fill(buffer, 14, ends)  # full: the rows hold steps 4 to 13, the write position at step 4's row
    assert buffer.full and buffer.pos == 4
    check(buffer, set(range(4, 12)))  # (11, 12, 13) is the newest stretch; (12, 13, 4) would cross the write position


def test_the_rollouts_carry_each_entry_s_hidden_state_and_reset_it_at_episode_starts():
    """With the network fixed (no update yet), every stored hidden state is the network's state after the entry's
    previous step, or zero where an episode starts."""
    env = make_vec_env(2, seed=0, env_kwargs={**TINY, "max_cycles": 7})
    model = VDN("MlpPolicy", env, seed=0, **dict(RNN_FAST, learning_starts=10**6))
    model.learn(2 * 2 * 20)  # 20 vector steps: episodes of 7 steps end at steps 6 and 13
    buffer, policy = model.replay_buffer, model.policy
    starts, hidden = buffer.episode_starts[:20], buffer.hidden[:20]
    np.testing.assert_array_equal(np.flatnonzero(starts[:, 0]), [0, 7, 14])
    assert (starts == starts[:, :1]).all() and not hidden[starts].any() and np.abs(hidden[~starts]).min() > 0
    for t in range(19):
        _, leaving = policy.predict(buffer.observations[t], hidden[t], deterministic=True)
        np.testing.assert_allclose(np.where(starts[t + 1][:, None], 0.0, leaving), hidden[t + 1], atol=1e-6)
    assert np.array_equal(model._last_episode_starts, buffer.dones[19].astype(bool))


def test_predict_takes_and_returns_the_hidden_states():
    model = QMIX("MlpPolicy", tiny_reserve(2), seed=0, **RNN_QMIX)
    obs = model.get_env().reset()
    actions, state = model.predict(obs, deterministic=True)
    assert actions.shape == (4,) and state.shape == (4, 8) and state.dtype == np.float32
    np.testing.assert_array_equal(model.predict(obs, state=np.zeros((4, 8)), deterministic=True)[1], state)
    again, moved = model.predict(obs, state=state, deterministic=True)
    assert not np.allclose(moved, state) and again.shape == (4,)
    # episode_start zeroes the state of the entries it flags, only theirs
    flags = np.array([True, False, True, False])
    _, reset = model.predict(obs, state=moved, episode_start=flags, deterministic=True)
    np.testing.assert_allclose(reset[flags], state[flags], atol=1e-6)
    np.testing.assert_allclose(reset[~flags], model.predict(obs, state=moved, deterministic=True)[1][~flags])
    single, single_state = model.predict(obs[0], deterministic=True)  # one observation: an action, a (1, 8) state
    assert np.ndim(single) == 0 and single == actions[0] and single_state.shape == (1, 8)
    with pytest.raises(ValueError, match=r"state must be the hidden states of the 4 observations, shape \(4, 8\)"):
        model.predict(obs, state=np.zeros((4, 3)))


def test_the_unroll_matches_step_by_step_acting_and_the_targets_are_double_q():
    env = make_vec_env(2, seed=0, env_kwargs={**TINY, "max_cycles": 6})
    model = QMIX("MlpPolicy", env, seed=0, **dict(RNN_QMIX, learning_starts=0))
    model.learn(2 * 2 * 30)
    with th.no_grad():  # a target network that differs from the online one
        for p in model.policy.q_net_target.parameters():
            p.add_(0.1 * th.randn_like(p))
    np.random.seed(0)
    data = model.replay_buffer.sample(6)
    assert data.episode_starts[:, 1:].any()  # stretches of 5 rows across episodes of 6 steps
    policy, b = model.policy, model.burn_in
    for burn_in in (0, b):  # no gradient through the burn-in: the stored state gets none
        start = data.hidden.clone().requires_grad_(True)
        policy.unroll(data.observations, data.episode_starts, start, burn_in=burn_in)[:, b:].sum().backward()
        assert (start.grad is None) == (burn_in > 0)
    hiddens = policy.unroll(data.observations, data.episode_starts, data.hidden, burn_in=b)
    h = data.hidden
    for t in range(data.observations.shape[1]):  # the same as acting one step at a time
        acted = [policy.predict(data.observations[i, t].numpy(), h[i].numpy(), data.episode_starts[i, t].numpy(),
                                deterministic=True)[1] for i in range(6)]
        h = th.as_tensor(np.stack(acted))
        np.testing.assert_allclose(hiddens[:, t].detach().numpy(), h.numpy(), atol=1e-5)
    # within an episode, one more step on the next observation is the next row's Q-values (which the loss reads)
    next_q = policy.next_q_values(data.next_observations, hiddens)
    within = (data.episode_starts[:, 1:, 0] == 0).numpy()
    np.testing.assert_allclose(next_q[:, :-1].detach().numpy()[within],
                               policy.q_from_hidden(hiddens[:, 1:]).detach().numpy()[within], atol=1e-5)
    shortcut = policy.next_q_values(data.next_observations, hiddens, policy.q_from_hidden(hiddens),
                                    th.cat([~th.as_tensor(within), th.ones(6, 1, dtype=th.bool)], dim=1))
    np.testing.assert_allclose(shortcut.detach().numpy(), next_q.detach().numpy(), atol=1e-5)
    # y = r + gamma (1 - terminated) Q_tot^-(target's values of the online network's argmax) on the trained rows
    target_next = policy.next_q_values(data.next_observations,
                                       policy.unroll(data.observations, data.episode_starts, data.hidden, target=True),
                                       target=True)[:, b:]
    picked = target_next.gather(3, next_q[:, b:].argmax(3, keepdim=True)).squeeze(-1)
    mixed = policy.mixer_target(picked.reshape(-1, 2), data.next_states[:, b:].reshape(-1, data.next_states.shape[-1]))
    expected = data.rewards[:, b:] + (1 - data.dones[:, b:]) * model.gamma * mixed.view(6, -1)
    np.testing.assert_allclose(model._sequence_targets(data, hiddens[:, b:], policy.q_from_hidden(hiddens[:, b:])).numpy(),
                               expected.detach().numpy(), rtol=1e-5, atol=1e-6)
    loss, stats = model._sequence_loss(data)
    assert loss.requires_grad and np.isfinite(loss.item()) and model._n_updates > 0
    assert stats["target_mean"] == pytest.approx(expected.mean().item(), rel=1e-5)


@pytest.mark.parametrize("algo", [QMIX, VDN])
def test_recurrent_save_and_load_give_the_same_actions_with_the_same_state(algo, tmp_path):
    kwargs = RNN_QMIX if algo is QMIX else RNN_FAST
    model = algo("MlpPolicy", tiny_reserve(2), agent_id=True, seed=0, **kwargs).learn(200)
    model.save(tmp_path / "model")
    np.testing.assert_array_equal(algo.load(tmp_path / "model")._last_hidden, model._last_hidden)  # as _last_obs
    env = tiny_reserve(2, seed=3)
    for loaded in (algo.load(tmp_path / "model"), algo.load(tmp_path / "model", env=tiny_reserve(2, seed=5))):
        assert loaded.recurrent and loaded.rnn_hidden_dim == 8 and (loaded.sequence_length, loaded.burn_in) == (5, 2)
        assert loaded.policy.q_net.rnn.hidden_size == 8 and isinstance(loaded.replay_buffer, RecurrentJointReplayBuffer)
        obs, state, loaded_state = env.reset(), None, None
        for _ in range(5):
            actions, state = model.predict(obs, state=state, deterministic=True)
            loaded_actions, loaded_state = loaded.predict(obs, state=loaded_state, deterministic=True)
            np.testing.assert_array_equal(loaded_actions, actions)
            np.testing.assert_allclose(loaded_state, state, atol=1e-6)
            obs, *_ = env.step(actions)
    loaded.learn(100, reset_num_timesteps=False)  # trains on, the hidden states reset with the new environment
    assert loaded._last_hidden.shape == (4, 8)


def test_recurrent_qmix_runs_on_the_reserve_and_evaluate_policy_passes_the_state():
    model = QMIX("MlpPolicy", tiny_reserve(2), seed=0, **RNN_QMIX).learn(200)
    assert model._n_updates > 0 and model.replay_buffer.hidden.shape[1:] == (4, 8)
    mean, _ = evaluate_policy(model, tiny_reserve(1, seed=7), n_eval_episodes=2)
    assert np.isfinite(mean)


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"sequence_length": 0}, r"sequence_length must be an int in \[1, 10000\], got 0"),
    ({"burn_in": -1}, r"burn_in must be an int in \[0, 9999\], got -1"),
    ({"sequence_length": 4, "burn_in": 4}, r"burn_in must be smaller than sequence_length=4 .*got 4"),
    ({"rnn_hidden_dim": 0}, r"rnn_hidden_dim must be an int in \[1, 4096\], got 0"),
    ({"rnn_hidden_dim": 5000}, r"rnn_hidden_dim must be an int in \[1, 4096\], got 5000"),
    ({"recurrent": 1}, r"recurrent must be true or false, got 1"),
    ({"buffer_size": 40, "sequence_length": 30}, r"sequence_length=30 is longer than the buffer's 20 rows"),
    ({"policy_kwargs": {"rnn_hidden_dim": 8}}, r"policy_kwargs may not set \['rnn_hidden_dim'\]"),
])
def test_bad_recurrent_arguments_are_rejected_with_a_message(kwargs, message):
    with pytest.raises(ValueError, match=message):
        QMIX("MlpPolicy", make_vec_env(1, env_fn=TwoStepGame), **{"recurrent": True, **kwargs})


#: Settings that learn the cue game in 2400 agent-steps (about a second).
CUE_SETTINGS = dict(learning_starts=240, buffer_size=3000, batch_size=16, train_freq=1, target_update_interval=200,
                    exploration_fraction=0.5, learning_rate=1e-3, policy_kwargs=dict(net_arch=[16]))


@pytest.mark.parametrize(("algo", "recurrent"), [(QMIX, True), (VDN, True), (VDN, False)])
def test_the_gru_agents_remember_the_cue_and_the_mlp_agents_cannot(algo, recurrent):
    extra = dict(mixing_embed_dim=8, hypernet_embed=16) if algo is QMIX else {}
    if recurrent:
        extra.update(recurrent=True, rnn_hidden_dim=16, sequence_length=4, burn_in=1)
    model = algo("MlpPolicy", make_vec_env(4, seed=0, env_fn=CueGame), seed=0, **CUE_SETTINGS, **extra).learn(2400)
    mean, _ = evaluate_policy(model, make_vec_env(4, seed=100, env_fn=CueGame), n_eval_episodes=40)
    assert mean == 1.0 if recurrent else mean <= 0.7


def test_recurrent_qmix_learns_the_matrix_game_s_optimum():
    """The benchmark's settings (full exploration, a hidden layer of 64, mixing width 8 with linear hypernetworks)
    with a GRU of 64 on stretches of 3 rows (across episodes of 2 steps) with a burn-in of 1, two copies of the game,
    an update every vector step, 4000 agent-steps: 8 on seeds 0 to 4 (seed 0 here, about 5 s)."""
    from scripts import load_benchmark

    settings = dict(load_benchmark("matrix_game").settings(1.0), buffer_size=4000, batch_size=32, train_freq=1,
                    policy_kwargs=dict(net_arch=[64]))
    model = QMIX("MlpPolicy", make_vec_env(2, seed=0, env_fn=TwoStepGame), mixing_embed_dim=8, hypernet_layers=1,
                 recurrent=True, rnn_hidden_dim=64, sequence_length=3, burn_in=1, seed=0, **settings).learn(4000)
    env = TwoStepGame()
    observations, _ = env.reset()
    total, state, start = 0.0, None, np.ones(2, dtype=bool)
    while env.agents:
        obs = np.stack([observations[agent] for agent in env.possible_agents])
        actions, state = model.predict(obs, state=state, episode_start=start, deterministic=True)
        observations, rewards, *_ = env.step({agent: int(a) for agent, a in zip(env.possible_agents, actions)})
        total, start = total + rewards["agent_0"], np.zeros(2, dtype=bool)
    assert total == OPTIMUM
