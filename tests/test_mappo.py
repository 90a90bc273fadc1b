"""MAPPO: the decentralised actor and the state-reading critic, the state wrapper, value normalisation, SB3's
conventions (save/load, evaluate_policy on the plain environment, seeding, logging) and early failures."""

import warnings

import gymnasium
import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from pettingzoo import ParallelEnv
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.policies import ActorCriticPolicy

from sb3_emmarl.common.extractors import GraphAttentionExtractor
from sb3_emmarl.common.messages import NeighbourMessageWrapper
from sb3_emmarl.common.vec_env import make_vec_env
from sb3_emmarl.mappo import MAPPO, GlobalStateWrapper, MAPPOPolicy, ValueNorm
from wildlife_reserve import reserve_v1

SMALL = {"n_uavs": 2, "grid_size": 20, "max_cycles": 40}
FAST = {"n_steps": 20, "n_epochs": 2}


class TinyTeamWithoutState(ParallelEnv):
    """Each agent sees a random bit and is right when its action (0 or 1) matches it; the team reward is the share of
    agents that are right. No global state."""

    metadata = {"name": "tiny_team_v0", "render_modes": []}

    def __init__(self, n_agents: int = 2, max_cycles: int = 8, render_mode=None) -> None:
        self.possible_agents = [f"agent_{i}" for i in range(n_agents)]
        self.agents = list(self.possible_agents)
        self.max_cycles, self.render_mode = max_cycles, render_mode
        self.rng = np.random.default_rng()

    def observation_space(self, agent):
        return spaces.Box(-1.0, 1.0, (3,), np.float32)

    def action_space(self, agent):
        return spaces.Discrete(2)

    def _observations(self):
        return {a: np.array([self.bits[i], self.t / self.max_cycles, 0.0], np.float32) for i, a in enumerate(self.agents)}

    def reset(self, seed=None, options=None):
        if seed is not None:
            self.rng = np.random.default_rng(seed)
        self.agents, self.t = list(self.possible_agents), 0
        self.bits = self.rng.choice([-1.0, 1.0], len(self.agents))
        return self._observations(), {a: {} for a in self.agents}

    def step(self, actions):
        right = float(np.mean([actions[a] == (self.bits[i] > 0) for i, a in enumerate(self.agents)]))
        self.t += 1
        self.bits = self.rng.choice([-1.0, 1.0], len(self.agents))
        observations, done = self._observations(), self.t >= self.max_cycles
        agents = list(self.agents)
        if done:
            self.agents = []
        return (observations, dict.fromkeys(agents, right), dict.fromkeys(agents, False), dict.fromkeys(agents, done),
                {a: {} for a in agents})


class TinyTeam(TinyTeamWithoutState):
    """:class:`TinyTeamWithoutState` with a global state: every agent's bit and the time."""

    def __init__(self, n_agents: int = 2, max_cycles: int = 8, render_mode=None) -> None:
        super().__init__(n_agents, max_cycles, render_mode)
        self.state_space = spaces.Box(-1.0, 1.0, (n_agents + 1,), np.float32)

    def state(self):
        return np.concatenate([self.bits, [self.t / self.max_cycles]]).astype(np.float32)


def small_model(n_copies=2, seed=0, env_kwargs=SMALL, **kwargs):
    return MAPPO("MlpPolicy", make_vec_env(n_copies, seed=seed, env_kwargs=env_kwargs), seed=seed, **{**FAST, **kwargs})


def probabilities(model, observations):
    with th.no_grad():
        return model.policy.get_distribution(th.as_tensor(observations)).distribution.probs.numpy()


def values(model, observations):
    with th.no_grad():
        return model.policy.predict_values(th.as_tensor(observations)).numpy().ravel()


def test_actions_ignore_the_global_state_and_the_value_reads_it():
    model = small_model()
    model.learn(2 * model.n_steps * model.env.num_envs)  # trained a little: nothing is zero by chance
    obs = model.env.reset()
    layout = model.state_layout
    other = obs.copy()
    other[:, layout.obs_dim:] = np.random.default_rng(0).uniform(-1, 1, other[:, layout.obs_dim:].shape)
    np.testing.assert_array_equal(probabilities(model, other), probabilities(model, obs))
    np.testing.assert_array_equal(model.predict(other, deterministic=True)[0], model.predict(obs, deterministic=True)[0])
    assert np.all(np.abs(values(model, other) - values(model, obs)) > 1e-6)
    own = obs.copy()
    own[:, : layout.obs_dim] = np.random.default_rng(1).uniform(-1, 1, own[:, : layout.obs_dim].shape)
    assert not np.allclose(probabilities(model, own), probabilities(model, obs))  # the actor does read the observation
    # the agent id is read by the critic alone: changing only it changes the values, not the actions
    swapped = obs.copy()
    swapped[0, -layout.id_dim:], swapped[1, -layout.id_dim:] = obs[1, -layout.id_dim:], obs[0, -layout.id_dim:]
    np.testing.assert_array_equal(probabilities(model, swapped), probabilities(model, obs))
    assert not np.allclose(values(model, swapped), values(model, obs))


@pytest.mark.parametrize("n_uavs", [1, 2, 3])
def test_shapes_and_the_wrapper_follow_the_team_size(n_uavs):
    kwargs = {**SMALL, "n_uavs": n_uavs, "max_cycles": 5}
    prototype = reserve_v1.parallel_env(**kwargs)
    obs_dim, state_dim = prototype.obs_dim, prototype.state_space.shape[0]
    model = small_model(env_kwargs=kwargs)
    n = 2 * n_uavs
    layout = model.state_layout
    assert (layout.obs_dim, layout.state_dim, layout.n_agents, layout.critic_dim) == (
        obs_dim, state_dim, n_uavs, obs_dim + state_dim + n_uavs)
    assert model.observation_space.shape == (layout.critic_dim,) and model.env.num_envs == n
    obs = model.env.reset()
    assert obs.shape == (n, layout.critic_dim)
    np.testing.assert_array_equal(obs[:, -n_uavs:], np.tile(np.eye(n_uavs), (2, 1)))  # the agents' one-hots
    states = model.env.env_method("state")
    np.testing.assert_array_equal(obs[:, obs_dim:obs_dim + state_dim], np.stack(states))
    for observation in (obs, obs[:, :obs_dim]):  # augmented and plain
        actions, _ = model.predict(observation)
        assert actions.shape == (n,) and all(model.action_space.contains(a) for a in actions)
    assert values(model, obs).shape == (n,)
    with pytest.raises(ValueError, match=f"observations must have {obs_dim} values"):
        model.predict(obs[:, :10])
    # every step the state matches the copies'; at an episode's end the terminal observation holds the last state
    ended = False
    for _ in range(kwargs["max_cycles"]):
        obs, _, dones, infos = model.env.step(np.zeros(n, dtype=int))
        np.testing.assert_array_equal(obs[:, obs_dim:obs_dim + state_dim], np.stack(model.env.env_method("state")))
        for i in np.flatnonzero(dones):
            terminal = infos[i]["terminal_observation"]
            assert terminal.shape == (layout.critic_dim,)
            np.testing.assert_array_equal(terminal[obs_dim:obs_dim + state_dim], infos[i]["terminal_state"])
            assert not np.array_equal(infos[i]["terminal_state"], infos[i]["state"])  # the new episode's
            ended = True
    assert ended


class TimeLimitValues(BaseCallback):
    """Records each step's raw rewards and, at episode ends, the critic's value of the terminal observation."""

    def __init__(self) -> None:
        super().__init__()
        self.raw, self.terminal_values = [], {}

    def _on_step(self) -> bool:
        self.raw.append(self.locals["rewards"].copy())
        for i, info in enumerate(self.locals["infos"]):
            if self.locals["dones"][i] and info.get("TimeLimit.truncated"):
                self.terminal_values[(len(self.raw) - 1, i)] = float(values(self.model, info["terminal_observation"][None])[0])
        return True


def test_episodes_cut_at_the_time_limit_are_bootstrapped_from_the_terminal_state():
    model = small_model(n_steps=SMALL["max_cycles"], gamma=0.9)
    callback = TimeLimitValues()
    model.learn(model.n_steps * model.env.num_envs, callback=callback)
    raw, buffer = np.array(callback.raw), model.rollout_buffer.rewards
    assert len(callback.terminal_values) == model.env.num_envs  # every entry's episode is cut at the last step
    expected = raw.copy()
    for (step, i), value in callback.terminal_values.items():
        expected[step, i] += 0.9 * value
    np.testing.assert_allclose(buffer, expected, rtol=1e-5)
    assert not np.allclose(buffer[-1], raw[-1])


def test_agent_id_is_optional():
    model = small_model(agent_id=False)
    layout = model.state_layout
    assert layout.id_dim == 0 and model.observation_space.shape == (layout.obs_dim + layout.state_dim,)
    model.learn(model.n_steps * model.env.num_envs)


def test_value_norm_statistics_on_a_hand_built_case():
    norm = ValueNorm(beta=0.9)
    assert norm.mean_std() == pytest.approx((0.0, 0.1))  # before any data: mean 0, the variance floor 1e-2
    first, second = np.array([1.0, 2.0, 3.0, 4.0]), np.array([10.0, 10.0])
    norm.update(first)
    assert norm.mean_std() == pytest.approx((2.5, np.sqrt(1.25)))  # debiased: the batch's own statistics
    norm.update(second)
    beta = 0.9
    debias = 1 - beta**2  # (1 - beta) (beta + 1)
    mean = (1 - beta) * (beta * first.mean() + second.mean()) / debias
    mean_sq = (1 - beta) * (beta * (first**2).mean() + (second**2).mean()) / debias
    assert norm.mean_std() == pytest.approx((mean, np.sqrt(mean_sq - mean**2)))
    assert float(norm.debiasing_term) == pytest.approx(debias)
    x = th.tensor([-3.0, 0.0, 7.5])
    np.testing.assert_allclose(norm.denormalize(norm.normalize(x)).numpy(), x.numpy(), atol=1e-5)
    np.testing.assert_allclose(norm.normalize(x).numpy(), ((x.numpy() - mean) / np.sqrt(mean_sq - mean**2)), rtol=1e-6)
    constant = ValueNorm()
    constant.update(np.full(8, 5.0))
    assert constant.mean_std() == pytest.approx((5.0, 0.1))  # the variance floor
    with pytest.raises(ValueError, match=r"value_norm_beta must be a number in the open interval \(0, 1\), got 1"):
        ValueNorm(beta=1)


def test_train_normalises_the_returns_of_the_rollout_and_values_come_back_in_their_units():
    model = small_model()
    model.learn(model.n_steps * model.env.num_envs)  # one rollout, one update
    returns = model.rollout_buffer.returns
    norm = model.policy.value_norm
    assert norm.mean_std() == pytest.approx((returns.mean(), returns.std()), rel=1e-5)
    obs = th.as_tensor(model.env.reset())
    mean, std = norm.mean_std()
    with th.no_grad():
        head = model.policy.value_net(model.policy.mlp_extractor.forward_critic(obs))
        np.testing.assert_allclose(model.policy.predict_values(obs).numpy(), head.numpy() * std + mean, rtol=1e-5)
        raw, _, _ = model.policy.evaluate_actions(obs, th.zeros(len(obs)))
        normalised, _, _ = model.policy.evaluate_actions_normalized(obs, th.zeros(len(obs)))
    np.testing.assert_allclose(raw.numpy(), normalised.numpy() * std + mean, rtol=1e-5)
    logged = model.logger.name_to_value
    assert logged["train/value_norm_mean"] == pytest.approx(mean) and logged["train/value_norm_std"] == pytest.approx(std)
    for key in ("train/value_loss", "train/explained_variance", "train/actor_grad_norm", "train/critic_grad_norm"):
        assert np.isfinite(logged[key])


def test_defaults_learn_without_warnings_and_log_to_tensorboard(tmp_path):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        model = MAPPO("MlpPolicy", make_vec_env(2, seed=0, env_kwargs=SMALL), tensorboard_log=str(tmp_path), seed=0)
        model.learn(2 * model.n_steps * model.env.num_envs)  # two rollouts: the first update is in the second dump
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    accumulator = EventAccumulator(str(next((tmp_path / "MAPPO_1").glob("events.out.tfevents.*"))))
    accumulator.Reload()
    tags = set(accumulator.Tags()["scalars"])
    expected = {"rollout/ep_rew_mean", "train/value_loss", "train/policy_gradient_loss", "train/explained_variance",
                "train/value_norm_mean", "train/value_norm_std", "train/actor_grad_norm", "train/critic_grad_norm"}
    assert expected <= tags, expected - tags


def test_save_load_gives_the_same_actions_and_values(tmp_path):
    model = small_model()
    model.learn(2 * model.n_steps * model.env.num_envs)
    model.save(tmp_path / "mappo")
    obs = model.env.reset()
    plain = obs[:, : model.state_layout.obs_dim]
    th.manual_seed(0)
    expected = model.predict(plain, deterministic=True)[0]
    alone = MAPPO.load(tmp_path / "mappo")  # no environment: acts on plain observations
    np.testing.assert_array_equal(alone.predict(plain, deterministic=True)[0], expected)
    np.testing.assert_array_equal(probabilities(alone, obs), probabilities(model, obs))
    np.testing.assert_array_equal(values(alone, obs), values(model, obs))
    assert alone.policy.value_norm.mean_std() == model.policy.value_norm.mean_std()
    loaded = MAPPO.load(tmp_path / "mappo", env=make_vec_env(2, seed=0, env_kwargs=SMALL))  # a plain environment
    assert isinstance(loaded.env, GlobalStateWrapper) and loaded.agent_id and loaded.huber_delta == 10.0
    np.testing.assert_array_equal(loaded.predict(plain, deterministic=True)[0], expected)
    np.testing.assert_array_equal(values(loaded, obs), values(model, obs))
    loaded.learn(loaded.n_steps * loaded.env.num_envs)  # and trains on
    loaded.set_env(make_vec_env(2, seed=1, env_kwargs=SMALL))
    assert isinstance(loaded.env, GlobalStateWrapper)


def test_evaluate_policy_runs_on_the_plain_environment():
    model = small_model()
    env = make_vec_env(1, seed=3, env_kwargs=SMALL)
    mean, std = evaluate_policy(model, env, n_eval_episodes=2)
    assert np.isfinite(mean) and np.isfinite(std)


def test_any_pettingzoo_environment_with_a_state_and_it_learns():
    env = make_vec_env(4, seed=0, env_fn=TinyTeam, env_kwargs={"n_agents": 2})
    model = MAPPO("MlpPolicy", env, n_steps=16, n_epochs=5, seed=0)
    assert model.state_layout.critic_dim == 3 + 3 + 2
    evaluation = make_vec_env(1, seed=100, env_fn=TinyTeam, env_kwargs={"n_agents": 2})
    model.learn(2560)
    mean, _ = evaluate_policy(model, evaluation, n_eval_episodes=20)
    assert mean >= 7.5  # 8 steps, the reward is the share of agents right: 4 by chance, 8 at best


def test_same_seed_same_parameters():
    def run():
        model = small_model(n_copies=1, seed=7)
        model.learn(2 * model.n_steps * model.env.num_envs)
        return {k: v.clone() for k, v in model.policy.state_dict().items()}

    first, second = run(), run()
    assert first.keys() == second.keys()
    for key in first:
        assert th.equal(first[key], second[key]), key


def test_bad_arguments_are_rejected_with_a_message():
    with pytest.raises(ValueError, match=r"MAPPO needs the environment's global state.*TinyTeamWithoutState has no state"):
        MAPPO("MlpPolicy", make_vec_env(1, env_fn=TinyTeamWithoutState))
    with pytest.raises(ValueError, match=r"MAPPO needs the environment's global state.*got DummyVecEnv"):
        MAPPO("MlpPolicy", gymnasium.make("CartPole-v1"))
    with pytest.raises(ValueError, match="env must be the parameter-sharing vector environment"):
        MAPPO("MlpPolicy", None)
    env = make_vec_env(1, seed=0, env_kwargs=SMALL)
    bad = {"value_norm_beta": (1.0, r"value_norm_beta must be a number in \(0.0, 1.0\), got 1.0"),
           "huber_delta": (0.0, r"huber_delta must be null or a number in \(0.0, 1000000.0\], got 0.0"),
           "agent_id": ("yes", "agent_id must be true or false, got 'yes'"),
           "use_value_norm": (1, "use_value_norm must be true or false, got 1"),
           "n_epochs": (0, r"n_epochs must be an int in \[1, 1000\], got 0"),
           "batch_size": (1, "batch_size must be an int >= 2"),
           "clip_range_vf": (-0.1, r"clip_range_vf must be null or a number in \(0.0, 10.0\] or a schedule, got -0.1"),
           "learning_rate": ("lin_0.001", "learning_rate must be a number in .* or a schedule, got 'lin_0.001'"),
           "policy_kwargs": ({"state_layout": {"obs_dim": 1}}, r"policy_kwargs\['state_layout'\] is set by MAPPO")}
    for name, (value, message) in bad.items():
        with pytest.raises(ValueError, match=message):
            MAPPO("MlpPolicy", env, **{name: value})
    with pytest.raises(ValueError, match="policy must be 'MlpPolicy' or a MAPPOPolicy subclass, got ActorCriticPolicy"):
        MAPPO(ActorCriticPolicy, env)
    layout = NeighbourMessageWrapper(make_vec_env(1, env_kwargs=SMALL)).layout  # an extractor of messages, none sent
    with pytest.raises(ValueError, match=f"observation_space must be a flat Box of {layout.total_dim} floats"):
        MAPPO(MAPPOPolicy, env, policy_kwargs={"features_extractor_class": GraphAttentionExtractor,
                                               "features_extractor_kwargs": {"layout": layout}})
    model = MAPPO("MlpPolicy", env, agent_id=True)
    with pytest.raises(ValueError, match="GlobalStateWrapper has agent_id=True, but agent_id=False"):
        MAPPO("MlpPolicy", model.env, agent_id=False)


def _plain_first_layer(features, norm, linear):
    return linear(features if norm is None else norm(features))


@pytest.mark.parametrize("layer_norm", [True, False])
def test_the_critic_s_first_layer_once_per_state_equals_the_plain_layer_and_its_gradients(layer_norm):
    from sb3_emmarl.mappo.policies import first_layer_once_per_state, state_groups

    gen = th.Generator().manual_seed(0)
    obs, states, ids = th.randn(12, 5, generator=gen), th.randn(3, 7, generator=gen), th.eye(4).repeat(3, 1)
    features = th.cat([obs, states.repeat_interleave(4, 0), ids], dim=1)[th.randperm(12, generator=gen)]  # 3 copies x 4
    norm = th.nn.LayerNorm(16) if layer_norm else None
    linear = th.nn.Linear(16, 6)
    if norm is not None:
        with th.no_grad():  # (not LayerNorm's initial 1 and 0: the rewriting must carry gamma and beta)
            norm.weight.uniform_(0.5, 1.5, generator=gen)
            norm.bias.uniform_(-0.5, 0.5, generator=gen)
    probe = th.randn(7, 2, generator=gen)
    groups = state_groups(features[:, 5:12], probe)
    assert groups is not None and len(groups[0]) == 3
    modules = [m for m in (norm, linear) if m is not None]
    outputs, grads = [], []
    for shared in (False, True):
        for module in modules:
            module.zero_grad()
        out = (first_layer_once_per_state(features, 5, 12, norm, linear, *groups) if shared
               else _plain_first_layer(features, norm, linear))
        out.sin().sum().backward()
        outputs.append(out.detach())
        grads.append([p.grad.clone() for m in modules for p in m.parameters()])
    th.testing.assert_close(outputs[1], outputs[0], rtol=1e-5, atol=1e-5)
    for shared_grad, plain_grad in zip(grads[1], grads[0]):
        th.testing.assert_close(shared_grad, plain_grad, rtol=1e-4, atol=1e-5)


def test_states_that_differ_are_never_grouped_and_too_few_copies_are_not_worth_grouping():
    from sb3_emmarl.mappo.policies import state_groups

    gen = th.Generator().manual_seed(1)
    states = th.randn(4, 6, generator=gen).repeat_interleave(3, 0)
    assert state_groups(states, th.randn(6, 2, generator=gen)) is not None
    blind = th.zeros(6, 2)  # every state projects to the same key: the row-by-row check refuses the merge
    assert state_groups(states, blind) is None
    assert state_groups(th.randn(8, 6, generator=gen), th.randn(6, 2, generator=gen)) is None  # all different


def test_mappo_s_whole_rollout_epochs_use_the_groups_and_train_as_the_plain_critic_would():
    """Two MAPPO runs from the same seed, one with the critic's first layer always plain: the same actions while the
    parameters agree to rounding, and parameters equal to float32 rounding after the updates."""
    from sb3_emmarl.mappo import policies

    def trained(shared: bool):
        env = make_vec_env(2, seed=0, env_kwargs={"n_uavs": 3, "grid_size": 20, "max_cycles": 20}, with_state=True)
        model = MAPPO("MlpPolicy", env, n_steps=64, n_epochs=3, seed=0, policy_kwargs={"net_arch": [32]})
        if not shared:
            model.policy.mlp_extractor.state_columns = None
        calls = []
        original = policies.first_layer_once_per_state
        policies.first_layer_once_per_state = lambda *args: calls.append(len(args[0])) or original(*args)
        try:
            model.learn(768)
        finally:
            policies.first_layer_once_per_state = original
        return model, calls

    shared, calls = trained(True)
    plain, none = trained(False)
    assert calls == [384] * 6 and none == []  # 2 rollouts x 3 epochs over 2 copies x 3 UAVs x 64 steps
    for (name, a), (_, b) in zip(shared.policy.state_dict().items(), plain.policy.state_dict().items()):
        th.testing.assert_close(a, b, rtol=1e-4, atol=1e-5, msg=name)
