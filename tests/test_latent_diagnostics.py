"""Whether a policy reads its belief, and whether the latent components keep their identity (diagnostics.py)."""

import numpy as np
import pytest
import torch as th
from stable_baselines3.common.env_util import make_vec_env

from sb3_emmarl import EMPPO
from sb3_emmarl.common.appended.initialization import zero_tail_weights
from sb3_emmarl.common.latent.diagnostics import assignment_agreement, belief_entropy, belief_use, permute_beliefs
from sb3_emmarl.common.mode_tasks import ModeCueEnv


def test_permuting_moves_each_component_s_mass_on_and_leaves_the_observation():
    obs = np.array([[5.0, 6.0, 0.7, 0.2, 0.1]])
    np.testing.assert_allclose(permute_beliefs(obs, 3), [[5.0, 6.0, 0.1, 0.7, 0.2]])
    np.testing.assert_allclose(permute_beliefs(th.as_tensor(obs), 3, shift=2).numpy(), [[5.0, 6.0, 0.2, 0.1, 0.7]])
    np.testing.assert_allclose(obs, [[5.0, 6.0, 0.7, 0.2, 0.1]])  # a copy


def test_assignment_agreement_tells_relabelling_from_reassignment():
    assert assignment_agreement([0, 0, 1, 1, 2], [1, 1, 0, 0, 2], 3) == (pytest.approx(0.2), pytest.approx(1.0))
    assert assignment_agreement([0, 0, 1, 1], [0, 1, 1, 1], 2) == (pytest.approx(0.75), pytest.approx(0.75))
    assert assignment_agreement([], [], 4) == (1.0, 1.0)
    with pytest.raises(ValueError, match=r"assignments must lie in \[0, 2\)"):
        assignment_agreement([0, 2], [0, 1], 2)
    with pytest.raises(ValueError, match="1-D arrays of one shape"):
        assignment_agreement([0, 1], [0], 2)


def test_belief_entropy_is_log_k_for_uniform_and_zero_for_one_hot_beliefs():
    assert belief_entropy(np.full((3, 4), 0.25)) == pytest.approx(np.log(4))
    assert belief_entropy(np.eye(4)) == pytest.approx(0.0)


def test_belief_use_is_zero_for_a_policy_blind_to_its_belief_and_positive_for_one_that_reads_it():
    model = EMPPO("MlpPolicy", make_vec_env(ModeCueEnv, n_envs=2, seed=0), seed=0)
    k = model.latent_layout.n_components
    rng = np.random.default_rng(0)
    beliefs = rng.dirichlet(np.ones(k) * 0.2, size=64).astype(np.float32)
    obs = np.concatenate([np.eye(4, dtype=np.float32)[rng.integers(4, size=64)], beliefs], axis=1)
    with th.no_grad():  # (SB3 starts the action head at a gain of 0.01: every input moves the actions little)
        model.policy.action_net.weight.mul_(100.0)
    assert belief_use(model.policy, obs, k) > 1e-4
    assert zero_tail_weights(model.policy, k)
    assert belief_use(model.policy, obs, k) == pytest.approx(0.0, abs=1e-9)
    assert belief_use(model.policy, obs, 1) == 0.0


def test_em_ppo_logs_belief_use_belief_entropy_and_the_e_step_s_assignment_agreement():
    model = EMPPO("MlpPolicy", make_vec_env(ModeCueEnv, n_envs=2, seed=0), n_steps=64, batch_size=64, seed=0)
    model.learn(64 * 2 * 2)
    logged = model.logger.name_to_value
    for key in ("latent/belief_use", "latent/belief_entropy", "latent/assignment_kept", "latent/assignment_matched"):
        assert key in logged, key
    assert 0.0 <= logged["latent/assignment_kept"] <= logged["latent/assignment_matched"] <= 1.0
    assert 0.0 <= logged["latent/belief_entropy"] <= np.log(model.latent_layout.n_components) + 1e-6


def test_the_belief_reaches_the_networks_as_probabilities_as_the_most_likely_one_hot_or_both():
    from gymnasium import spaces

    from sb3_emmarl.common.latent.policies import BeliefFeaturesExtractor

    space = spaces.Box(-1.0, 1.0, (5,), np.float32)
    obs = th.tensor([[0.5, -0.5, 0.2, 0.7, 0.1]])
    expected = {"probabilities": [[0.5, -0.5, 0.2, 0.7, 0.1]], "map": [[0.5, -0.5, 0.0, 1.0, 0.0]],
                "both": [[0.5, -0.5, 0.2, 0.7, 0.1, 0.0, 1.0, 0.0]]}
    for form, values in expected.items():
        extractor = BeliefFeaturesExtractor(space, 2, belief_input=form)
        np.testing.assert_allclose(extractor(obs).numpy(), values, atol=1e-6)
        assert extractor.features_dim == len(values[0]) and extractor.belief_width == len(values[0]) - 2
    dropped = BeliefFeaturesExtractor(space, 2, keep=2, belief_input="both")  # the no-latent ablation
    np.testing.assert_allclose(dropped(obs).numpy(), [[0.5, -0.5]])
    with pytest.raises(ValueError, match=r"belief_input must be one of \['probabilities', 'map', 'both'\]"):
        BeliefFeaturesExtractor(space, 2, belief_input="log")


@pytest.mark.parametrize("form", ["map", "both"])
def test_em_ppo_with_another_belief_input_trains_saves_and_loads_it(form, tmp_path):
    model = EMPPO("MlpPolicy", make_vec_env(ModeCueEnv, n_envs=2, seed=0), n_steps=32, batch_size=64, seed=0,
                  latent_kwargs=dict(belief_input=form), zero_belief_weights=True)
    width = model.policy.features_extractor.belief_width
    assert width == (8 if form == "both" else 4)
    first = dict(model.policy.mlp_extractor.policy_net.named_parameters())["0.weight"]
    assert th.all(first[:, -width:] == 0)  # every input from the belief starts at zero weight
    model.learn(128)
    model.save(tmp_path / "model")
    loaded = EMPPO.load(tmp_path / "model")
    assert loaded.policy.features_extractor.belief_input == form
    obs = np.tile(np.eye(4, dtype=np.float32)[:1], (3, 1))
    np.testing.assert_array_equal(model.predict(obs, deterministic=True)[0], loaded.predict(obs, deterministic=True)[0])
    with pytest.raises(ValueError, match="belief_input"):
        EMPPO("MlpPolicy", make_vec_env(ModeCueEnv, n_envs=2, seed=0), latent_kwargs=dict(belief_input="log"))
