"""Every stock baseline trains on the reserve, saves, loads and predicts the same actions."""

import numpy as np
import pytest
from stable_baselines3.common.noise import NormalActionNoise
from stable_baselines3.common.vec_env import DummyVecEnv

from sb3_emmarl.common.centralized import CentralizedReserveEnv
from sb3_emmarl.common.vec_env import make_vec_env
from sb3_emmarl.zoo.algos import CENTRALIZED_ALGOS, LATENT_ALGOS, SHARED_ALGOS, ZOO_ALGOS

SMALL = {"n_uavs": 3, "grid_size": 20, "max_cycles": 40}
CONTINUOUS = {"ddpg", "td3"}
SETTINGS = {
    "ppo": {"n_steps": 64, "batch_size": 96, "n_epochs": 2},
    "a2c": {"n_steps": 8},
    "dqn": {"learning_starts": 500, "buffer_size": 5000, "batch_size": 64, "train_freq": 4},
    "ddpg": {"learning_starts": 500, "buffer_size": 5000, "batch_size": 64, "train_freq": 8, "gradient_steps": 2},
    "td3": {"learning_starts": 500, "buffer_size": 5000, "batch_size": 64, "train_freq": 8, "gradient_steps": 2},
    "ppo_lstm": {"n_steps": 64, "batch_size": 96, "n_epochs": 2, "policy_kwargs": {"lstm_hidden_size": 16}},
    "cppo": {"n_steps": 64, "batch_size": 64, "n_epochs": 2},
    "oracle_ppo": {"n_steps": 64, "batch_size": 96, "n_epochs": 2},
    "mappo": {"n_steps": 64, "batch_size": 96, "n_epochs": 2},
    "qmix": {"learning_starts": 500, "buffer_size": 5000, "batch_size": 32, "train_freq": 4},
    "vdn": {"learning_starts": 500, "buffer_size": 5000, "batch_size": 32, "train_freq": 4},
    "ppo_gat": {"n_steps": 64, "batch_size": 96, "n_epochs": 2, "extractor": "gat"},
    "ppo_transformer": {"n_steps": 64, "batch_size": 96, "n_epochs": 2, "extractor": "transformer"},
}


def build(name):
    kwargs = {**SMALL, "continuous_actions": name in CONTINUOUS}
    if name in CENTRALIZED_ALGOS:
        env = DummyVecEnv([lambda: CentralizedReserveEnv(**kwargs)] * 2)
    else:
        env = make_vec_env(n_copies=2, env_kwargs=kwargs)
    settings = dict(SETTINGS[name])
    if name in CONTINUOUS:
        settings["action_noise"] = NormalActionNoise(np.zeros(3), 0.2 * np.ones(3))
    policy = "MlpLstmPolicy" if name == "ppo_lstm" else "MlpPolicy"
    model = ZOO_ALGOS[name](policy, env, seed=0, **settings)
    # The oracle reads the true mode from its environment's infos, the message policies what teammates sent: they act
    # on their own wrapped environments.
    return model, model.get_env() if name in ("oracle_ppo", "ppo_gat", "ppo_transformer") else env


def test_every_stock_baseline_is_covered():
    # The EM algorithms have their own tests (tests/test_em.py).
    assert set(SETTINGS) == set(ZOO_ALGOS) - set(LATENT_ALGOS)
    assert set(ZOO_ALGOS) == set(SHARED_ALGOS) | set(CENTRALIZED_ALGOS)


@pytest.mark.parametrize("name", sorted(SETTINGS))
def test_baseline_trains_saves_loads_and_predicts_the_same(name, tmp_path):
    model, env = build(name)
    model.learn(3000)
    assert model.num_timesteps >= 3000
    observations = env.reset()
    starts = np.ones(env.num_envs, dtype=bool)
    before, state = model.predict(observations, episode_start=starts, deterministic=True)
    assert env.action_space.contains(before[0])
    model.save(tmp_path / name)
    loaded = ZOO_ALGOS[name].load(tmp_path / name, device="cpu")
    after, loaded_state = loaded.predict(observations, episode_start=starts, deterministic=True)
    np.testing.assert_array_equal(before, after)
    if name == "ppo_lstm":  # the recurrent state round-trips too
        np.testing.assert_allclose(state[0], loaded_state[0], rtol=1e-6)
        observations, *_ = env.step(before)
        nxt, _ = model.predict(observations, state=state, episode_start=~starts, deterministic=True)
        loaded_nxt, _ = loaded.predict(observations, state=loaded_state, episode_start=~starts, deterministic=True)
        np.testing.assert_array_equal(nxt, loaded_nxt)
