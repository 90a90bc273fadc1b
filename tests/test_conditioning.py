"""``belief_conditioning``: how the networks read the told mode or the belief (concatenated, a head per mode mixed
by it, or FiLM), for OraclePPO, EM-PPO, EM-DDPG and EMCallback."""

import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from stable_baselines3.common.env_util import make_vec_env as sb3_make_vec_env
from stable_baselines3.common.torch_layers import MlpExtractor

from sb3_emmarl import EMPPO, OraclePPO
from sb3_emmarl.common.appended.conditioning import (
    ConditionedMlp,
    ConditionedMlpExtractor,
    ContextActorCriticPolicy,
    MixedHeads,
)
from sb3_emmarl.common.appended.initialization import tail_weight_norms, zero_tail_weights
from sb3_emmarl.common.mode_tasks import ModeCueEnv
from sb3_emmarl.common.vec_env import make_vec_env
from wildlife_reserve.reserve.modes import N_MODES

SMALL = {"n_uavs": 2, "grid_size": 20, "max_cycles": 5}
K = 4


def context_policy(conditioning: str, net_arch=None) -> ContextActorCriticPolicy:
    space = spaces.Box(-1.0, 1.0, (6 + K,), np.float32)
    return ContextActorCriticPolicy(space, spaces.Discrete(3), lambda _: 1e-3, net_arch=net_arch, context_dim=K,
                                    belief_conditioning=conditioning)


def with_context(obs: th.Tensor, context: th.Tensor) -> th.Tensor:
    return th.cat([obs[:, :-K], context.expand(len(obs), K)], dim=1)


@pytest.mark.parametrize("conditioning", ["mixture", "film"])
def test_a_conditioned_policy_starts_as_one_function_of_every_context_and_then_learns_to_read_it(conditioning):
    th.manual_seed(0)
    policy = context_policy(conditioning)
    assert isinstance(policy.mlp_extractor, ConditionedMlpExtractor)
    obs = th.rand(5, 6 + K) * 2 - 1
    contexts = [th.eye(K)[k] for k in range(K)] + [th.full((K,), 1 / K)]
    with th.no_grad():
        outputs = [(policy.get_distribution(with_context(obs, c)).distribution.probs,
                    policy.predict_values(with_context(obs, c))) for c in contexts]
    for probs, values in outputs[1:]:
        th.testing.assert_close(probs, outputs[0][0])
        th.testing.assert_close(values, outputs[0][1])
    # a few gradient steps towards values that depend on the context make the values differ by context
    targets = th.arange(K, dtype=th.float32)
    for _ in range(200):
        loss = sum((policy.predict_values(with_context(obs, th.eye(K)[k])) - targets[k]).pow(2).mean() for k in range(K))
        policy.optimizer.zero_grad()
        loss.backward()
        policy.optimizer.step()
    with th.no_grad():
        values = [float(policy.predict_values(with_context(obs, th.eye(K)[k])).mean()) for k in range(K)]
    assert values == pytest.approx(targets.tolist(), abs=0.3)


def test_the_mixture_is_the_context_weighted_sum_of_its_heads_and_film_scales_and_shifts_each_unit():
    th.manual_seed(1)
    mixture = ConditionedMlp(3 + K, [8], th.nn.Tanh, K, "mixture")
    x = th.rand(2, 3)
    weights = th.tensor([0.1, 0.2, 0.3, 0.4])
    heads = MixedHeads(8, 3, K)  # in the place of SB3's action head: K heads, one per component
    own = [th.nn.Linear(8, 3) for _ in range(K)]
    with th.no_grad():
        heads.heads.weight.copy_(th.cat([h.weight for h in own]))
        heads.heads.bias.copy_(th.cat([h.bias for h in own]))
        expected = sum(w * h(mixture.trunk(x)) for w, h in zip(weights, own))
        th.testing.assert_close(heads(mixture(th.cat([x, weights.expand(2, K)], dim=1))), expected)
        alike = MixedHeads.alike(own[0], K)
        th.testing.assert_close(alike(mixture(th.cat([x, th.eye(K)[2].expand(2, K)], dim=1))), own[0](mixture.trunk(x)))
    film = ConditionedMlp(3 + K, [8, 5], th.nn.ReLU, K, "film")
    with th.no_grad():
        for layer in film.films:
            layer.weight.zero_()
            layer.bias.copy_(th.cat([th.full((layer.out_features // 2,), 1.0), th.full((layer.out_features // 2,), 0.5)]))
    hidden = th.relu(film.layers[0](x)) * 2 + 0.5
    th.testing.assert_close(film(th.cat([x, weights.expand(2, K)], dim=1)), th.relu(film.layers[1](hidden)) * 2 + 0.5)


def test_concat_builds_sb3_s_networks_and_the_zero_start_applies_to_it_only():
    assert type(context_policy("concat").mlp_extractor) is MlpExtractor
    film = context_policy("film")
    assert not zero_tail_weights(film, K)  # FiLM starts blind by its own initialisation
    with pytest.raises(ValueError, match="read it apart"):
        tail_weight_norms(film, K)


@pytest.mark.parametrize("kwargs, message", [
    (dict(conditioning="attention"), r"belief_conditioning must be one of \['concat', 'mixture', 'film'\], got 'attention'"),
    (dict(conditioning="film", net_arch=[]), "needs at least one hidden layer per network"),
    (dict(conditioning="mixture", net_arch=dict(pi=[8], vf=[])), "needs at least one hidden layer per network"),
])
def test_bad_conditionings_are_refused_with_a_message(kwargs, message):
    with pytest.raises(ValueError, match=message):
        context_policy(kwargs["conditioning"], kwargs.get("net_arch"))


def cue_env():
    return sb3_make_vec_env(lambda: ModeCueEnv(length=10), n_envs=2, seed=0)


@pytest.mark.parametrize("conditioning", ["mixture", "film"])
def test_em_ppo_reads_its_belief_through_the_conditioning_and_saves_and_loads_it(tmp_path, conditioning):
    model = EMPPO("MlpPolicy", cue_env(), n_steps=32, batch_size=32, seed=0,
                  policy_kwargs=dict(belief_conditioning=conditioning))
    assert isinstance(model.policy.mlp_extractor, ConditionedMlpExtractor)
    assert model.policy.mlp_extractor.policy_net.n_context == K
    model.learn(128)
    model.save(tmp_path / "model.zip")
    loaded = EMPPO.load(tmp_path / "model.zip")
    assert loaded.policy.belief_conditioning == conditioning
    obs = np.eye(K, dtype=np.float32)[[0, 1, 2]]
    actions, state = model.predict(obs, deterministic=True)
    loaded_actions, loaded_state = loaded.predict(obs, deterministic=True)
    assert np.array_equal(actions, loaded_actions) and np.allclose(state, loaded_state)


def test_em_ppo_s_mixture_needs_a_belief_that_weighs_its_networks():
    with pytest.raises(ValueError, match="needs belief_input 'probabilities' or 'map', got 'both'"):
        EMPPO("MlpPolicy", cue_env(), latent_kwargs=dict(belief_input="both"),
              policy_kwargs=dict(belief_conditioning="mixture"))


def test_oracle_ppo_reads_the_told_mode_through_the_conditioning(tmp_path):
    venv = make_vec_env(2, seed=0, env_kwargs=SMALL)
    model = OraclePPO("MlpPolicy", venv, n_steps=16, batch_size=32, seed=0,
                      policy_kwargs=dict(belief_conditioning="mixture"))
    assert model.policy.context_dim == N_MODES
    heads = model.policy.action_net
    assert isinstance(heads, MixedHeads) and heads.n_context == N_MODES
    assert heads.in_features == model.policy.mlp_extractor.policy_net.trunk[-2].out_features
    assert {id(p) for p in model.policy.optimizer.param_groups[0]["params"]} == {id(p) for p in model.policy.parameters()}
    model.learn(32)
    model.save(tmp_path / "oracle.zip")
    assert OraclePPO.load(tmp_path / "oracle.zip", env=venv).policy.belief_conditioning == "mixture"
    with pytest.raises(ValueError, match="needs SB3's FlattenExtractor and belief_conditioning 'concat'"):
        OraclePPO("MlpPolicy", venv, mode_input="policy", policy_kwargs=dict(belief_conditioning="film"))


@pytest.mark.parametrize("conditioning", ["mixture", "film"])
def test_em_ddpg_s_actor_and_critics_read_the_belief_through_the_conditioning(tmp_path, conditioning):
    from sb3_emmarl import EMDDPG
    from sb3_emmarl.common.appended.conditioning import ConditionedCritic, ConditionedHead

    env = sb3_make_vec_env("Pendulum-v1", n_envs=1, seed=0)
    model = EMDDPG("MlpPolicy", env, seed=0, learning_starts=32, policy_kwargs=dict(belief_conditioning=conditioning))
    assert isinstance(model.actor.mu[0], ConditionedHead) and isinstance(model.critic, ConditionedCritic)
    obs = th.as_tensor(model.env.reset()).repeat(K, 1)
    obs[:, -K:] = th.eye(K)  # every component's one-hot: the networks start as one function of all
    actions = th.zeros(K, 1)
    with th.no_grad():
        assert th.allclose(model.actor(obs), model.actor(obs[:1]).expand(K, -1))
        assert th.allclose(model.critic(obs, actions)[0], model.critic(obs[:1], actions[:1])[0].expand(K, -1))
    model.learn(64)
    model.save(tmp_path / "ddpg.zip")
    loaded = EMDDPG.load(tmp_path / "ddpg.zip")
    assert loaded.policy.belief_conditioning == conditioning
    with th.no_grad():
        th.testing.assert_close(loaded.actor(obs), model.actor(obs))
        th.testing.assert_close(loaded.critic.q1_forward(obs, actions), model.critic.q1_forward(obs, actions))


def test_em_callback_gives_a_conditioned_actor_critic_policy():
    from stable_baselines3 import A2C

    from sb3_emmarl.common.latent.callback import EMCallback

    callback = EMCallback(seed=0)
    venv = callback.wrap_env(cue_env())
    policy, kwargs = callback.conditioned_policy("film")
    model = A2C(policy, venv, seed=0, policy_kwargs=kwargs)
    assert model.policy.context_dim == K and isinstance(model.policy.mlp_extractor, ConditionedMlpExtractor)
    model.learn(64, callback=callback)
    assert callback.e_step is not None


def test_a_zoo_yaml_s_policy_kwargs_take_it_and_a_bad_value_is_refused_naming_it():
    from sb3_emmarl.common.trust.validation import parse_policy_kwargs

    assert parse_policy_kwargs("dict(belief_conditioning='film', net_arch=[64])")["belief_conditioning"] == "film"
    with pytest.raises(ValueError, match=r"policy_kwargs belief_conditioning must be one of \['concat', 'mixture', 'film'\]"):
        parse_policy_kwargs("dict(belief_conditioning='attention')")
