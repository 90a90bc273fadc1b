"""The EM algorithms' latent settings as one validated record (LatentConfig), shared by EM-PPO, EM-DDPG and VDN+EM."""

import inspect
from dataclasses import replace
from pathlib import Path

import pytest
import torch as th

from sb3_emmarl import EMDDPG, EMPPO
from sb3_emmarl.common.latent.callback import EMCallback
from sb3_emmarl.common.latent.config import E_STEP_DEFAULTS, LatentConfig
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
    model = algo_class("MlpPolicy", env, latent_kwargs=dict(
        n_components=8, count_factors=(4, 2), likelihood_temperature=0.5, fusion=False, team_pooling=True,
        e_step_interval=3, e_step_kwargs={"window": 5}, decoder_hidden=(32,)))
    config = model.latent_config
    assert (config.n_components, config.count_factors, config.likelihood_temperature, config.fusion) == (8, (4, 2), 0.5,
                                                                                                       False)
    assert config.team_pooling and config.e_step_interval == 3 and config.decoder_hidden == (32,)
    assert config.e_step_kwargs["window"] == 5
    with pytest.raises(ValueError, match="n_components"):
        algo_class("MlpPolicy", env, latent_kwargs=dict(n_components=0))
    model.save(tmp_path / "model")
    assert algo_class.load(tmp_path / "model", env=make_vec_env(1, seed=0, env_kwargs=env_kwargs)).latent_config == config


# ---------------------------------------------------------------------------------------------- one surface, one owner
LATENT_OWNERS = [EMPPO, EMDDPG, EMVDN, EMCallback]


@pytest.mark.parametrize("owner", LATENT_OWNERS)
def test_every_latent_setting_is_one_argument_latent_kwargs(owner):
    parameters = inspect.signature(owner.__init__).parameters
    assert "latent_kwargs" in parameters and not set(parameters) & set(LatentConfig.names())
    if owner is not EMCallback:
        assert isinstance(owner.latent_defaults, LatentConfig)  # the algorithm's own defaults, one record


def test_each_algorithm_lays_its_settings_over_its_own_defaults():
    defaults = {EMPPO: (1, 2), EMDDPG: (200, 400), EMVDN: (500, 1000)}  # (e_step_interval, window)
    for algo_class, (interval, window) in defaults.items():
        config = algo_class.latent_defaults.updated({"e_step_kwargs": {"n_epochs": 3}})
        assert (config.e_step_interval, config.e_step_kwargs["window"], config.e_step_kwargs["n_epochs"]) == \
            (interval, window, 3)
        assert config.e_step_kwargs["batch_size"] == E_STEP_DEFAULTS["batch_size"]  # the E-step's defaults filled in


def test_the_settings_are_validated_once_per_model(monkeypatch):
    calls = []
    original = LatentConfig.__post_init__
    monkeypatch.setattr(LatentConfig, "__post_init__", lambda self: (calls.append(1), original(self))[1])
    env = make_vec_env(1, seed=0, env_kwargs=TINY)
    model = EMPPO("MlpPolicy", env, latent_kwargs={"n_components": 8, "likelihood_temperature": 0.5})
    assert len(calls) == 1
    # the E-step, the belief wrapper's tracker and predict read the one record
    tracker = model.get_env().tracker
    assert model.e_step.likelihood_temperature == tracker.likelihood_temperature == 0.5
    assert tracker.fusion is model.latent_config.fusion


@pytest.mark.parametrize("owner", [EMPPO, EMDDPG, EMVDN, EMCallback])
def test_a_latent_setting_given_on_its_own_is_refused_naming_latent_kwargs(owner):
    env = make_vec_env(1, seed=0, env_kwargs={**TINY, "continuous_actions": owner is EMDDPG})
    arguments = () if owner is EMCallback else ("MlpPolicy", env)
    with pytest.raises(TypeError, match=r"latent_kwargs=dict\(n_components=8\)"):
        owner(*arguments, n_components=8)
    with pytest.raises(TypeError, match="n_componentz"):
        owner(*arguments, n_componentz=8)


def test_unknown_fields_and_foreign_callback_fields_are_refused():
    with pytest.raises(ValueError, match=r"latent_kwargs keys must be among .*got \['n_componentz'\]"):
        EMPPO("MlpPolicy", make_vec_env(1, seed=0, env_kwargs=TINY), latent_kwargs={"n_componentz": 2})
    with pytest.raises(ValueError, match=r"latent_kwargs must be a LatentConfig or a dict"):
        EMPPO("MlpPolicy", make_vec_env(1, seed=0, env_kwargs=TINY), latent_kwargs=[("n_components", 2)])
    with pytest.raises(ValueError, match=r"\['e_step_interval'\] are settings of the algorithm"):
        EMCallback({"e_step_interval": 3})


def test_a_setting_set_as_an_attribute_is_refused_naming_latent_config():
    model = EMPPO("MlpPolicy", make_vec_env(1, seed=0, env_kwargs=TINY))
    with pytest.raises(AttributeError, match=r"dataclasses.replace\(model.latent_config, fusion=False\)"):
        model.fusion = False
    model.latent_config = replace(model.latent_config, fusion=False)  # what it says, and what evaluation then reads
    assert not model.wrap_env(make_vec_env(1, seed=0, env_kwargs=TINY)).tracker.fusion


def test_a_record_is_taken_whole():
    config = LatentConfig(n_components=2, e_step_interval=3)
    model = EMPPO("MlpPolicy", make_vec_env(1, seed=0, env_kwargs=TINY), latent_kwargs=config)
    assert model.latent_config == config.updated({}) and model.latent_layout.n_components == 2


def test_a_model_saved_with_its_settings_as_attributes_loads_them():
    """tests/data/em_ppo_0_21_0.zip keeps each setting as an attribute and the layout as policy_kwargs' latent_kwargs."""
    model = EMPPO.load(Path(__file__).parent / "data" / "em_ppo_0_21_0.zip")
    assert model.latent_config.decoder_hidden == (8,) and model.latent_config.n_components == 4
    assert "latent_layout" in model.policy_kwargs and "latent_kwargs" not in model.policy_kwargs
    assert not set(model.__dict__) & set(LatentConfig.names())


def test_a_callback_saved_with_its_settings_as_arguments_loads_them(tmp_path):
    from stable_baselines3.common.env_util import make_vec_env as sb3_make_vec_env

    from sb3_emmarl.common.mode_tasks import ModeCueEnv

    callback = EMCallback({"n_components": 3, "likelihood_temperature": 0.5, "e_step_every": 64}, seed=2)
    callback.wrap_env(sb3_make_vec_env(ModeCueEnv, n_envs=1, seed=0))
    callback.save(tmp_path / "em.pt")
    assert EMCallback.load(tmp_path / "em.pt").config == callback.config
    state = th.load(tmp_path / "em.pt", weights_only=True)
    state["arguments"] = {"n_components": 3, "likelihood_temperature": 0.5, "e_step_every": 64, "seed": 2,
                          "decoder_hidden": (64, 64)}  # as callbacks were saved before latent_kwargs
    th.save(state, tmp_path / "old.pt")
    old = EMCallback.load(tmp_path / "old.pt")
    assert old.config == callback.config and old.config.e_step_every == 64 and old.seed == 2
    state["arguments"] = {"latent_kwargs": {"n_components": 3, "likelihood_temperature": 0.5}, "e_step_every": 64,
                          "seed": 2}  # as saved while e_step_every was its own argument
    th.save(state, tmp_path / "old.pt")
    assert EMCallback.load(tmp_path / "old.pt").config == callback.config
