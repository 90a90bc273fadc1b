"""One way to wrap an algorithm's environment (sb3_emmarl.common.appended.wrapping), and the value-decomposition
policies' mixer."""

import numpy as np
import pytest
from gymnasium import spaces
from stable_baselines3.common.utils import ConstantSchedule

from sb3_emmarl import EMPPO, MessagePPO, OraclePPO
from sb3_emmarl.common.appended.wrapping import WrapsObservations
from sb3_emmarl.common.vec_env import make_vec_env
from sb3_emmarl.qmix.policies import QMIXPolicy, ValueDecompositionPolicy, VDNPolicy

SMALL = {"n_uavs": 2, "grid_size": 20, "max_cycles": 10}
ALGOS = {"oracle": OraclePPO, "message": MessagePPO, "em_ppo": EMPPO}


@pytest.mark.parametrize("algo", sorted(ALGOS))
def test_set_env_load_and_wrap_env_give_the_environment_training_had(algo, tmp_path):
    model_class = ALGOS[algo]
    assert issubclass(model_class, WrapsObservations)
    model = model_class("MlpPolicy", make_vec_env(1, seed=0, env_kwargs=SMALL), n_steps=16, batch_size=16, seed=0)
    width = model.observation_space.shape[-1]
    plain = make_vec_env(1, seed=1, env_kwargs=SMALL)
    assert plain.observation_space.shape[-1] < width
    model.set_env(make_vec_env(1, seed=1, env_kwargs=SMALL))
    assert model.get_env().observation_space.shape[-1] == width
    wrapped = model.wrap_env(make_vec_env(1, seed=1, env_kwargs=SMALL))
    assert wrapped.observation_space.shape[-1] == width
    assert model.wrap_env(wrapped) is wrapped  # an environment already wrapped is kept
    model.save(tmp_path / "model.zip")
    loaded = model_class.load(tmp_path / "model.zip", env=make_vec_env(1, seed=1, env_kwargs=SMALL))
    assert loaded.get_env().observation_space.shape[-1] == width
    obs = wrapped.reset()
    np.testing.assert_array_equal(loaded.predict(obs, deterministic=True)[0], model.predict(obs, deterministic=True)[0])
    if algo == "em_ppo":  # the EM algorithms act on plain observations too, carrying the belief in the state
        actions, state = model.predict(plain.reset(), deterministic=True)
        assert actions.shape == (2,) and state is not None
    else:
        with pytest.raises(ValueError, match=rf"{model_class.__name__} acts on observations of {width} values"):
            model.predict(plain.reset())


def test_each_value_decomposition_policy_takes_its_own_mixer():
    obs_space, action_space = spaces.Box(-1, 1, (3,), np.float32), spaces.Discrete(2)
    args = (obs_space, action_space, ConstantSchedule(1e-3))
    assert QMIXPolicy(*args, n_agents=2, state_dim=4).mixer_name == "qmix"
    assert VDNPolicy(*args, n_agents=2).mixer_name == "vdn"
    assert VDNPolicy(*args, n_agents=2, mixer="vdn").mixer_name == "vdn"
    assert ValueDecompositionPolicy(*args, n_agents=2, mixer="vdn").mixer_name == "vdn"
    assert ValueDecompositionPolicy(*args, n_agents=2, state_dim=4).mixer_name == "qmix"
    with pytest.raises(ValueError, match=r"VDNPolicy's mixer is 'vdn', got mixer='qmix'"):
        VDNPolicy(*args, n_agents=2, mixer="qmix")
    with pytest.raises(ValueError, match=r"QMIXPolicy's mixer is 'qmix', got mixer='vdn'"):
        QMIXPolicy(*args, n_agents=2, mixer="vdn")
