"""QMIX and VDN: the mixers, the joint replay buffer, shapes, save/load, evaluation, seeding, argument checks, and
(expensive) the two-step matrix game of the QMIX paper."""

import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from matrix_game import ADDITIVE_OPTIMUM, OPTIMUM, PAYOFFS, TwoStepGame, greedy_return
from stable_baselines3.common.evaluation import evaluate_policy

from sb3_emmarl.common.vec_env import make_vec_env
from sb3_emmarl.qmix import QMIX, JointReplayBuffer, QMixer, VDNMixer
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
    ({"learning_rate": "lin_1e-3"}, r"learning_rate must be a number in \(0, 10\] or a schedule"),
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
