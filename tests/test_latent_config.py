"""The EM algorithms' latent settings as one validated record (LatentConfig), shared by EM-PPO, EM-DDPG and VDN+EM."""

import pytest

from sb3_emmarl import EMDDPG, EMPPO
from sb3_emmarl.common.latent.config import LatentConfig
from sb3_emmarl.common.vec_env import make_vec_env
from sb3_emmarl.vdn_em import EMVDN

TINY = {"n_uavs": 2, "grid_size": 20, "max_cycles": 20}


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"n_components": 0}, r"n_components must be an int in \[1, 64\], got 0"),
    ({"likelihood_temperature": 0.0}, "likelihood_temperature"),
    ({"estimator": "exact"}, "estimator"),
    ({"belief_input": "logits"}, "belief_input"),
    ({"fusion": "yes"}, "fusion"),
    ({"n_components": 8, "count_factors": (3, 2)}, r"count_factors \[3, 2\] must multiply to n_components = 8"),
    ({"e_step_kwargs": {"windows": 3}}, "windows"),
])
def test_bad_settings_are_refused_once_naming_the_field(kwargs, message):
    with pytest.raises(ValueError, match=message):
        LatentConfig(**kwargs)


def test_settings_are_normalised():
    config = LatentConfig(n_components=8, count_factors=[4, 2], decoder_hidden=[32], likelihood_temperature=1)
    assert config.count_factors == (4, 2) and config.decoder_hidden == (32,)
    assert isinstance(config.likelihood_temperature, float)


@pytest.mark.parametrize("algo_class", [EMPPO, EMDDPG, EMVDN])
def test_every_em_algorithm_keeps_the_record_it_was_given_and_loads_it_back(tmp_path, algo_class):
    env_kwargs = {**TINY, "continuous_actions": algo_class is EMDDPG}
    env = make_vec_env(1, seed=0, env_kwargs=env_kwargs)
    model = algo_class("MlpPolicy", env, n_components=8, count_factors=(4, 2), likelihood_temperature=0.5,
                       fusion=False, team_pooling=True, e_step_interval=3, e_step_kwargs={"window": 5},
                       decoder_hidden=(32,))
    config = model.latent_config
    assert (config.n_components, config.count_factors, config.likelihood_temperature, config.fusion) == (8, (4, 2), 0.5,
                                                                                                       False)
    assert config.team_pooling and config.e_step_interval == 3 and config.decoder_hidden == (32,)
    assert config.e_step_kwargs["window"] == 5
    with pytest.raises(ValueError, match="n_components"):
        algo_class("MlpPolicy", env, n_components=0)
    model.save(tmp_path / "model")
    assert algo_class.load(tmp_path / "model", env=make_vec_env(1, seed=0, env_kwargs=env_kwargs)).latent_config == config
