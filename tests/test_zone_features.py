"""EM's zone features: what the latent model reads of ZonePatrol's observations (its evidence plug-in,
``zone_evidence.zone_features``)."""

import numpy as np
import pytest

from sb3_emmarl import EMPPO
from sb3_emmarl.common.latent.evidence import evidence_from_spec, evidence_of
from sb3_emmarl.common.latent.zone_evidence import zone_features
from sb3_emmarl.common.vec_env import make_vec_env
from wildlife_reserve import zone_patrol_v0


def zone_map(**kwargs):
    return zone_patrol_v0.parallel_env(**kwargs).zone_map


@pytest.mark.parametrize("kwargs", [{}, {"grid_size": 20, "zone_size": 5, "window_radius": 3, "n_uavs": 3}])
def test_each_zone_s_tracks_and_cells_in_the_window_are_counted_where_they_lie(kwargs):
    """Against a count made on the world's own map: for random UAV cells (map edges included) and random tracks."""
    env = zone_patrol_v0.parallel_env(**kwargs)
    env.reset(seed=0)
    world, cfg = env.world, env.config
    fn, dim = zone_features(env.zone_map)
    assert dim == 10
    rng = np.random.default_rng(1)
    g, r, size = cfg.grid_size, cfg.window_radius, cfg.zone_size
    for _ in range(20):
        world.positions[0] = rng.integers(g, size=(cfg.n_uavs, 2))
        world.positions[0, 0] = rng.choice([0, g - 1], size=2)  # a corner: part of the window off the map
        world.tracks[0] = rng.integers(cfg.track_life + 1, size=(g, g)) * (rng.random((g, g)) < 0.3)
        obs = world.observations()[0]
        features = fn(obs)
        for u, (row, col) in enumerate(world.positions[0]):
            window = np.zeros((g, g), dtype=bool)
            window[max(row - r, 0):row + r + 1, max(col - r, 0):col + r + 1] = True
            for z, (top, left) in enumerate(cfg.zone_origins()):
                zone = np.zeros((g, g), dtype=bool)
                zone[top:top + size, left:left + size] = True
                marked = (window & zone & (world.tracks[0] > 0)).sum()
                assert features[u, z] == pytest.approx(min(marked, 5) / 5)
                assert features[u, 4 + z] == pytest.approx((window & zone).sum() / (2 * r + 1) ** 2)
            assert features[u, 8] == pytest.approx(obs[u, env.zone_map["visibility"]])


def test_the_zone_readings_are_features_when_the_observation_has_them():
    env = zone_patrol_v0.parallel_env(zone_cue=0.5)
    env.reset(seed=0)
    obs = env.world.observations()[0]
    fn, dim = zone_features(env.zone_map)
    assert dim == 14 and env.zone_map["cues"] == [79, 83]
    np.testing.assert_array_equal(fn(obs)[:, 10:], obs[:, 79:83])
    assert zone_map()["cues"] is None


def test_detections_in_the_window_are_counted():
    env = zone_patrol_v0.parallel_env()
    env.reset(seed=0)
    obs = env.world.observations()[0]
    cells = env.config.window_cells
    obs[0, cells:2 * cells] = 0.0
    obs[0, cells + 3] = obs[0, cells + 7] = 1.0
    assert zone_features(env.zone_map)[0](obs)[0, 9] == 2.0


def test_the_latent_model_reads_zone_features_on_zone_patrol_and_keeps_them_when_loaded(tmp_path):
    venv = make_vec_env(2, seed=0, env_fn=zone_patrol_v0.parallel_env, vec_env_type="batched")
    evidence = evidence_of(venv)
    spec, dim = evidence.spec, evidence.feature_dim
    assert spec["kind"] == "zones" and dim == 10 and evidence.counts is None
    obs = venv.reset()
    rebuilt = evidence_from_spec(spec)
    np.testing.assert_array_equal(rebuilt.features(obs), evidence.features(obs))
    assert rebuilt.feature_dim == dim
    model = EMPPO("MlpPolicy", venv, n_steps=16, batch_size=32, n_epochs=1, latent_kwargs=dict(n_components=8), seed=0)
    assert model.latent_layout.feature_dim == 10 and model.evidence_spec["kind"] == "zones"
    model.learn(64)
    model.save(tmp_path / "em")
    loaded = EMPPO.load(tmp_path / "em", env=model.get_env())
    assert loaded.evidence_spec == model.evidence_spec and loaded.latent_layout == model.latent_layout
    probe = model.get_env().reset()
    np.testing.assert_array_equal(loaded.predict(probe, deterministic=True)[0], model.predict(probe, deterministic=True)[0])


def test_an_environment_without_a_zone_map_gets_the_generic_features():
    from stable_baselines3.common.env_util import make_vec_env as sb3_make_vec_env

    from sb3_emmarl.common.mode_tasks import ModeCueEnv

    assert evidence_of(sb3_make_vec_env(ModeCueEnv, n_envs=2)).spec["kind"] == "generic"


def test_an_unknown_feature_kind_is_refused_naming_the_kinds():
    with pytest.raises(ValueError, match="'reserve', 'zones' or 'generic'"):
        evidence_from_spec({"kind": "maps", "obs_dim": 3})
