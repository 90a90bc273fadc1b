"""VDN+EM: VDN whose agents see the EM belief (learn, predict with a state, evaluate_policy, save/load, bad input)."""

import numpy as np
import pytest
import torch as th
from stable_baselines3.common.evaluation import evaluate_policy

from sb3_emmarl import EMDDPG, EMVDN
from sb3_emmarl.common.appended.wrapping import find_wrapper
from sb3_emmarl.common.latent.belief import BeliefWrapper
from sb3_emmarl.common.vec_env import make_vec_env

TINY = {"n_uavs": 2, "grid_size": 20, "max_cycles": 40}
QUICK = {"learning_starts": 200, "buffer_size": 5000, "batch_size": 16,
         "latent_kwargs": {"e_step_interval": 5, "team_pooling": True, "n_components": 3}}


@pytest.fixture(scope="module")
def trained():
    th.set_num_threads(1)
    model = EMVDN("MlpPolicy", make_vec_env(2, seed=0, env_kwargs=TINY), seed=0, **QUICK)
    return model.learn(1600)


def test_the_e_step_runs_on_the_replay_rows_and_the_agents_see_the_belief(trained):
    assert trained.e_step.n_updates >= 3  # about 80 train() calls, an E-step every 5 (from the first full window)
    wrapper = find_wrapper(trained.get_env(), BeliefWrapper)
    assert wrapper is not None and trained.replay_buffer.observations.shape[-1] == wrapper.obs_dim + 3
    beliefs = trained.replay_buffer.observations[: trained.replay_buffer.pos, :, wrapper.obs_dim:]
    assert np.allclose(beliefs.sum(-1), 1.0, atol=1e-5) and beliefs.std() > 0  # beliefs moved away from uniform
    assert all(p.grad is None for p in trained.policy.latent_model.parameters())
    # the policy's optimizer leaves the latent model to the E-step
    optimized = {id(p) for group in trained.policy.optimizer.param_groups for p in group["params"]}
    assert not optimized & {id(p) for p in trained.policy.latent_model.parameters()}


def test_predict_carries_the_belief_and_explores_only_when_asked(trained):
    obs = make_vec_env(1, seed=3, env_kwargs=TINY).reset()
    actions, state = trained.predict(obs, deterministic=True)
    again, _ = trained.predict(obs, deterministic=True)
    assert actions.shape == (2,) and np.array_equal(actions, again) and state.shape[0] == 2
    trained.exploration_rate = 1.0
    try:
        sampled = np.stack([trained.predict(obs, state=state, episode_start=np.zeros(2, bool))[0] for _ in range(30)])
    finally:
        trained.exploration_rate = 0.0
    assert len(np.unique(sampled)) > 1
    reward, _ = evaluate_policy(trained, make_vec_env(1, seed=4, env_kwargs=TINY), n_eval_episodes=2)
    assert np.isfinite(reward)


def test_save_load_gives_the_same_actions_and_e_step(trained, tmp_path):
    trained.save(tmp_path / "vdn_em")
    loaded = EMVDN.load(tmp_path / "vdn_em", device="cpu")
    obs = np.random.default_rng(0).random((4, trained.latent_layout.obs_dim), dtype=np.float32)
    assert np.array_equal(trained.predict(obs, deterministic=True)[0], loaded.predict(obs, deterministic=True)[0])
    assert loaded.e_step.n_updates == trained.e_step.n_updates
    assert loaded._e_step_pos == trained._e_step_pos
    with_env = EMVDN.load(tmp_path / "vdn_em", env=make_vec_env(2, seed=1, env_kwargs=TINY), device="cpu")
    assert find_wrapper(with_env.get_env(), BeliefWrapper) is not None
    with_env.learn(200, reset_num_timesteps=False)


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"n_components": 0}, r"n_components must be an int in \[1, 64\]"),
    ({"exploration_final_eps": 1.5}, r"exploration_final_eps must be a number in \[0.0, 1.0\]"),
    ({"e_step_kwargs": {"window": 0}}, r"e_step_kwargs\['window'\] must be an int"),
    ({"e_step_kwargs": {"window": 10_001}}, r"e_step_kwargs\['window'\] must be an int in \[1, 10000\]"),
    ({"fusion": "yes"}, "fusion must be true or false"),
])
def test_bad_arguments_are_rejected(kwargs, message):
    arguments = kwargs if "exploration_final_eps" in kwargs else {"latent_kwargs": kwargs}
    with pytest.raises(ValueError, match=message):
        EMVDN("MlpPolicy", make_vec_env(1, seed=0, env_kwargs=TINY), **arguments)


def test_the_default_e_step_sees_as_many_steps_as_em_ddpgs():
    """Both default to an E-step every 2,000 steps on the last 4,000 at their zoo train_freq (4 and 10 vector steps)."""
    model = EMVDN("MlpPolicy", make_vec_env(1, seed=0, env_kwargs=TINY), train_freq=4)
    assert (model.latent_config.e_step_interval * 4, model.e_step.memory.maxlen * 4) == (2000, 4000)
    ddpg = EMDDPG("MlpPolicy", make_vec_env(1, seed=0, env_kwargs={**TINY, "continuous_actions": True}), train_freq=10)
    assert (ddpg.latent_config.e_step_interval * 10, ddpg.e_step.memory.maxlen * 10) == (2000, 4000)
    assert EMVDN("MlpPolicy", make_vec_env(1, seed=0, env_kwargs=TINY),
                 latent_kwargs=dict(e_step_kwargs={"window": 2000})).e_step.memory.maxlen == 2000
    # Whatever e_step_kwargs holds is checked before the default window joins it (EM-DDPG raised TypeError until 0.17.0).
    for algo, env_kwargs in ((EMVDN, TINY), (EMDDPG, {**TINY, "continuous_actions": True})):
        with pytest.raises(ValueError, match="e_step_kwargs must be a mapping"):
            algo("MlpPolicy", make_vec_env(1, seed=0, env_kwargs=env_kwargs), latent_kwargs=dict(e_step_kwargs="x"))
