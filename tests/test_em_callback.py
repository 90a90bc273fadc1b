"""EMCallback: the EM belief for SB3's own algorithms (A2C, PPO, DQN, SAC), refitted between rollouts.

The learning claim (0.8 of the told learner on ModeCueEnv) is measured by ``benchmarks/em_callback.py``
(docs/lab/2026-12-06/em_callback.md); the case marked ``expensive`` is a one-seed check of it.
"""

import re
from pathlib import Path

import numpy as np
import pytest
import torch as th
from stable_baselines3 import A2C, DQN, PPO, SAC
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.evaluation import evaluate_policy

from sb3_emmarl import EMCallback
from sb3_emmarl.common.appended.wrapping import find_wrapper
from sb3_emmarl.common.latent.belief import BeliefWrapper
from sb3_emmarl.common.latent.policies import BeliefFeaturesExtractor
from sb3_emmarl.common.mode_tasks import ModeCueEnv, ModeDynamicsEnv

EM_PAGE = Path(__file__).resolve().parents[1] / "docs" / "em.md"


class ContinuousCue(ModeCueEnv):
    """ModeCueEnv with a Box action (the action's largest entry is the guess), for SAC."""

    def __init__(self) -> None:
        super().__init__(length=8)
        from gymnasium import spaces

        self.action_space = spaces.Box(-1.0, 1.0, (self.n_modes,), np.float32)

    def step(self, action):
        return super().step(int(np.argmax(action)))


def latent_values(callback):
    return [p.detach().clone() for p in callback.latent_model.parameters()]


def test_a2c_gets_a_belief_whose_e_step_reads_whole_episodes_across_rollouts():
    # 2 copies, 5 steps a rollout: the first E-step comes at the first rollout end at >= 128 agent-steps (130), on 65
    # steps of each copy: episodes of 32, 32 and 1 steps (6 episodes), every transition but the 2 terminal ones per copy
    callback = EMCallback(latent_kwargs=dict(e_step_every=128), seed=0)
    env = callback.wrap_env(make_vec_env(ModeCueEnv, n_envs=2, seed=0))
    model = A2C("MlpPolicy", env, policy_kwargs=callback.policy_kwargs, seed=0)
    assert isinstance(model.policy.features_extractor, BeliefFeaturesExtractor)
    assert model.observation_space.shape == (4 + 4,)
    before = latent_values(callback)
    model.learn(130, callback=callback)
    logged = model.logger.name_to_value
    assert logged["latent/n_episodes"] == 6 and logged["latent/n_transitions"] == 126
    assert any(not th.equal(a, b) for a, b in zip(before, latent_values(callback)))
    assert callback.e_step.n_updates == 1


def test_dqn_reads_the_replay_buffer_s_new_rows():
    # 1 copy, a rollout every 4 steps: at 100 agent-steps every row so far (terminal transitions included), 4 episodes
    callback = EMCallback(latent_kwargs=dict(e_step_every=100), seed=0)
    env = callback.wrap_env(make_vec_env(ModeCueEnv, n_envs=1, seed=0))
    model = DQN("MlpPolicy", env, policy_kwargs=callback.policy_kwargs, learning_starts=50, seed=0)
    model.learn(100, callback=callback)
    logged = model.logger.name_to_value
    assert logged["latent/n_transitions"] == 100 and logged["latent/n_episodes"] == 4


@pytest.mark.parametrize("algo", ["ppo", "sac"])
def test_other_algorithms_train_and_evaluate_with_the_belief(algo):
    callback = EMCallback(latent_kwargs=dict(e_step_every=64), seed=0)
    if algo == "ppo":
        env = callback.wrap_env(make_vec_env(ModeDynamicsEnv, n_envs=2, seed=0))
        model = PPO("MlpPolicy", env, n_steps=32, batch_size=32, policy_kwargs=callback.policy_kwargs, seed=0)
    else:
        env = callback.wrap_env(make_vec_env(ContinuousCue, n_envs=1, seed=0))
        model = SAC("MlpPolicy", env, learning_starts=16, policy_kwargs=callback.policy_kwargs, seed=0)
    model.learn(128, callback=callback)
    assert callback.e_step.n_updates >= 1
    eval_env = callback.wrap_env(make_vec_env(env.envs[0].unwrapped.__class__, n_envs=2, seed=1))
    assert find_wrapper(eval_env, BeliefWrapper).tracker.model is callback.latent_model
    mean, _ = evaluate_policy(model, eval_env, n_eval_episodes=2)
    assert np.isfinite(mean)


def test_the_belief_moves_with_the_evidence_once_fitted():
    callback = EMCallback(latent_kwargs=dict(e_step_every=256), seed=0)
    env = callback.wrap_env(make_vec_env(ModeCueEnv, n_envs=4, seed=0))
    A2C("MlpPolicy", env, policy_kwargs=callback.policy_kwargs, seed=0).learn(2048, callback=callback)
    venv = callback.wrap_env(make_vec_env(ModeCueEnv, n_envs=4, seed=3))
    obs = venv.reset()
    first = obs[:, -4:].copy()
    for _ in range(20):
        obs, *_ = venv.step(np.zeros(4, dtype=np.int64))
    # the first observation's belief is the prior, the same for every copy; 20 cues later one component leads
    assert np.allclose(first, first[0]) and (obs[:, -4:].max(1) > 0.75).all() and first.max() < 0.5


def test_freeze_e_step_keeps_the_latent_model_and_the_seed_decides_it():
    runs = []
    for freeze in (True, False):
        callback = EMCallback(latent_kwargs=dict(e_step_every=64, freeze_e_step=freeze), seed=3)
        env = callback.wrap_env(make_vec_env(ModeCueEnv, n_envs=2, seed=0))
        before = latent_values(callback)
        A2C("MlpPolicy", env, policy_kwargs=callback.policy_kwargs, seed=0).learn(200, callback=callback)
        runs.append((before, latent_values(callback)))
    (frozen_before, frozen_after), (fitted_before, fitted_after) = runs
    assert all(th.equal(a, b) for a, b in zip(frozen_before, frozen_after))
    assert all(th.equal(a, b) for a, b in zip(frozen_before, fitted_before))  # the callback's seed alone
    assert any(not th.equal(a, b) for a, b in zip(fitted_before, fitted_after))


def test_a_saved_callback_gives_the_same_beliefs_and_trains_on_as_if_it_had_not_stopped(tmp_path):
    def trained(budget, callback=None, path=None):
        callback = callback or EMCallback(latent_kwargs=dict(e_step_every=100), seed=0)
        env = callback.wrap_env(make_vec_env(ModeCueEnv, n_envs=2, seed=0))
        A2C("MlpPolicy", env, policy_kwargs=callback.policy_kwargs, seed=0).learn(budget, callback=callback)
        if path is not None:
            callback.save(path)
        return callback

    def beliefs(callback):
        venv = callback.wrap_env(make_vec_env(ModeCueEnv, n_envs=2, seed=5))
        venv.reset()
        return np.concatenate([venv.step(np.zeros(2, dtype=np.int64))[0] for _ in range(10)])

    saved = trained(300, path=tmp_path / "em.pt")
    loaded = EMCallback.load(tmp_path / "em.pt")
    assert np.array_equal(beliefs(loaded), beliefs(saved))
    # the same E-step data and state: training on from either gives the same latent model (the policies differ: a
    # new A2C each time, the same for both)
    on_saved, on_loaded = trained(300, saved), trained(300, loaded)
    assert all(th.equal(a, b) for a, b in zip(latent_values(on_saved), latent_values(on_loaded)))
    with pytest.raises(ValueError, match="saved callback was made for"):
        EMCallback.load(tmp_path / "em.pt").wrap_env(make_vec_env(ModeDynamicsEnv, n_envs=1, seed=0))


def test_building_the_latent_model_leaves_torch_s_generator_alone():
    th.manual_seed(0)
    expected = th.rand(3)
    th.manual_seed(0)
    EMCallback(seed=5).wrap_env(make_vec_env(ModeCueEnv, n_envs=1, seed=0))
    assert th.equal(th.rand(3), expected)


def test_bad_use_fails_early_with_one_line():
    with pytest.raises(ValueError, match=r"e_step_every must be null or an int in \[1, "):
        EMCallback(latent_kwargs=dict(e_step_every=0))
    with pytest.raises(ValueError, match=r"every latent_kwargs\['e_step_every'\] agent-steps: an int >= 1, got None"):
        EMCallback(latent_kwargs=dict(e_step_every=None))
    with pytest.raises(TypeError, match=r"in latent_kwargs: latent_kwargs=dict\(e_step_every=100\)"):
        EMCallback(e_step_every=100)  # (its own argument until latent_kwargs held it)
    with pytest.raises(ValueError, match="n_components"):
        EMCallback(latent_kwargs=dict(n_components=0))
    with pytest.raises(ValueError, match=r"wrap_env\(env\) first"):
        _ = EMCallback().policy_kwargs
    callback = EMCallback()
    model = A2C("MlpPolicy", make_vec_env(ModeCueEnv, n_envs=1, seed=0))
    with pytest.raises(ValueError, match=r"callback.wrap_env\(env\)"):
        model.learn(10, callback=callback)
    callback = EMCallback()
    env = callback.wrap_env(make_vec_env(ModeCueEnv, n_envs=1, seed=0))
    with pytest.raises(ValueError, match="optimize_memory_usage=False"):
        DQN("MlpPolicy", env, optimize_memory_usage=True, replay_buffer_kwargs={"handle_timeout_termination": False}
            ).learn(10, callback=callback)
    with pytest.raises(ValueError, match="sizes"):
        callback.wrap_env(make_vec_env(ModeDynamicsEnv, n_envs=1, seed=0))


def em_example() -> str:
    text = EM_PAGE.read_text()
    section = text.split("## 11. Any SB3 algorithm: `EMCallback`", 1)[1]
    return section.split("```python\n", 1)[1].split("```", 1)[0]


def test_the_method_page_s_example_runs_as_written(capsys):
    code = em_example()
    assert len(code.strip().splitlines()) <= 14 and "EMCallback(" in code and "evaluate_policy(" in code
    scaled, n = re.subn(r"total_timesteps=[0-9_]+", "total_timesteps=80", code)
    assert n == 1, "the example must give its budget as total_timesteps=<number>, once"
    exec(compile(scaled, str(EM_PAGE), "exec"), {"__name__": "em_example"})
    assert re.search(r"\(np\.float64\([0-9.]+\), np\.float64\([0-9.]+\)\)", capsys.readouterr().out)


@pytest.mark.expensive
def test_a2c_with_the_callback_approaches_told_a2c_on_the_cue_task():
    callback = EMCallback(seed=0)
    env = callback.wrap_env(make_vec_env(ModeCueEnv, n_envs=8, seed=0))
    model = A2C("MlpPolicy", env, policy_kwargs=callback.policy_kwargs, seed=0).learn(50_000, callback=callback)
    mean, _ = evaluate_policy(model, callback.wrap_env(make_vec_env(ModeCueEnv, n_envs=4, seed=10_000)),
                              n_eval_episodes=100)
    assert mean >= 0.8 * 32  # told A2C earns 32 (docs/lab/2026-12-06/em_callback.md)
