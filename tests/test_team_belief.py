"""The team belief: evidence reach, the team-scope (centralised) ablation, and the latent model's readings."""

import numpy as np
import pytest
import torch as th

from sb3_emmarl import EMPPO
from sb3_emmarl.common.latent.belief import BeliefTracker
from sb3_emmarl.common.latent.layout import LatentLayout
from sb3_emmarl.common.latent.model import LatentModel, StepLikelihood
from sb3_emmarl.common.vec_env import make_vec_env
from wildlife_reserve import zone_patrol_v1
from wildlife_reserve.zone_patrol.posterior import reading_log_likelihoods, zone_posterior
from wildlife_reserve.zone_patrol.world import ZonePatrolConfig


def test_evidence_reach_counts_each_teammates_transitions_in_the_belief_once():
    tracker = BeliefTracker(3, 2, 1, 1, agents_per_copy=3)  # one copy of three agents
    np.testing.assert_array_equal(tracker.evidence_reach(), [1, 1, 1])  # before the first step: nothing is missing
    tracker.fuse([{"heard_from": (1,)}, {}, {}])  # step 1: agent 0 hears 1's one transition
    np.testing.assert_allclose(tracker.evidence_reach(), [2 / 3, 1 / 3, 1 / 3])
    tracker.fuse([{}, {"heard_from": (2,)}, {}])  # step 2: 0 still holds 1's version of step 1; 1 hears 2's two
    np.testing.assert_allclose(tracker.evidence_reach(), [(2 + 1) / 6, (2 + 2) / 6, 1 / 3])
    tracker.fuse([{"heard_from": (1,)}, {}, {}])  # step 3: 1 relays 2's version of step 2 with its own of step 3
    np.testing.assert_allclose(tracker.evidence_reach()[0], (3 + 3 + 2) / 9)
    tracker.start(np.arange(3), np.zeros((3, 1)))  # a new episode: nothing heard yet
    tracker.fuse([{}] * 3)
    np.testing.assert_allclose(tracker.evidence_reach(), [1 / 3] * 3)
    assert BeliefTracker(2, 2, 1, 1).evidence_reach().tolist() == [1.0, 1.0]  # a team of one


@pytest.mark.parametrize("fusion, reach", [(True, 2 / 3), ("team", 1.0), (False, 1 / 3)])
def test_the_team_scope_hears_every_teammate_whatever_the_links(fusion, reach):
    tracker = BeliefTracker(6, 2, 1, 1, agents_per_copy=3, fusion=fusion)  # two copies of three agents
    tracker.evidence[:] = [[1, 0], [0, 2], [3, 0], [0, 5], [7, 0], [0, 11]]
    for _ in range(3):
        tracker.fuse([{"heard_from": (1,)}, {}, {}, {}, {}, {}])
    np.testing.assert_allclose(tracker.evidence_reach()[0], reach)
    fused = tracker.evidence + tracker.heard.sum(1)
    if fusion == "team":  # every teammate of its own copy, none of the other's
        np.testing.assert_array_equal(fused, [[4, 2]] * 3 + [[7, 16]] * 3)
    with pytest.raises(ValueError, match="fusion must be true or false or one of \\['team'\\], got 'all'"):
        BeliefTracker(3, 2, 1, 1, agents_per_copy=3, fusion="all")


def test_readings_are_modelled_by_their_means_alone_and_the_lean_copy_agrees():
    th.manual_seed(0)
    layout = LatentLayout(obs_dim=4, feature_dim=3, action_dim=2, n_components=2, reading_features=(2,))
    model = LatentModel(layout)
    with th.no_grad():
        model.decoder_bias.copy_(th.tensor([[0.0, 0.0, -1.0], [0.0, 0.0, 1.0]]))
        model.decoder_log_std.zero_()
        model.decoder_shared.bias.zero_()
    model.mark_changed()
    x, a = th.randn(5, 3), th.randn(5, 2)
    nxt = th.randn(5, 3)
    means = model.component_means(x, a)
    np.testing.assert_allclose(means[:, :, 2].detach(), [[-1.0, 1.0]] * 5, atol=1e-6)  # neither x_t nor the trunk
    other = model.component_means(th.randn(5, 3), th.randn(5, 2))
    np.testing.assert_allclose(other[:, :, 2].detach(), means[:, :, 2].detach(), atol=1e-6)
    exact = model.transition_log_likelihood(x, a, nxt).detach().numpy()
    lean = StepLikelihood(model).log_likelihood(x.numpy(), a.numpy(), nxt.numpy())
    np.testing.assert_allclose(lean, exact, rtol=1e-5, atol=1e-5)
    with th.no_grad():  # components that differ in the reading's mean alone
        model.decoder_weight.zero_()
    model.mark_changed()
    exact = model.transition_log_likelihood(x, a, nxt).detach().numpy()
    np.testing.assert_allclose(exact[:, 1] - exact[:, 0], 2 * nxt[:, 2].numpy(), rtol=1e-5, atol=1e-5)  # its ratio
    tempered = StepLikelihood(model).log_likelihood(x.numpy(), a.numpy(), nxt.numpy(), temperature=0.1)
    np.testing.assert_allclose(tempered[:, 1] - tempered[:, 0], 2 * nxt[:, 2].numpy(), rtol=1e-4, atol=1e-4)
    with th.no_grad():  # the transition features' terms are tempered, the reading's not
        parts = -0.5 * ((nxt[:, None, :] - model.component_means(x, a)) / model.log_std().exp()).square() \
            - model.log_std() - 0.5 * np.log(2 * np.pi)
    expected = 0.1 * parts[:, :, :2].sum(-1) + parts[:, :, 2]
    np.testing.assert_allclose(tempered, expected.numpy(), rtol=1e-4, atol=1e-4)
    with pytest.raises(ValueError, match="reading_features must be distinct feature indices in \\[0, 2\\], got \\(3,\\)"):
        LatentLayout(obs_dim=4, feature_dim=3, action_dim=2, n_components=2, reading_features=(3,))
    assert LatentLayout.from_dict(layout.to_dict()) == layout
    assert "reading_features" not in LatentLayout(obs_dim=4, feature_dim=3, action_dim=2, n_components=2).to_dict()


def test_the_exact_posterior_of_the_readings_is_the_gaussian_one():
    env = zone_patrol_v1.parallel_env()
    config = env.config
    observations, _ = env.reset(seed=3)
    obs = np.stack(list(observations.values()))
    log_lik = reading_log_likelihoods(config, obs)
    assert log_lik.shape == (4, 8)
    world = env.world
    zone = config.zone_cue * np.clip(world.cues[0], -4, 4)  # (n, 4)
    visibility = np.clip(world.visibility[0], -3, 4)
    weather = np.stack([-(visibility - 1) ** 2, -visibility ** 2], 1) / 2
    np.testing.assert_allclose(log_lik, (zone[:, :, None] + weather[:, None, :]).reshape(4, 8), rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(zone_posterior(config.zone_cue, world.cues[0].sum(0)),
                               np.exp(zone.sum(0)) / np.exp(zone.sum(0)).sum(), rtol=1e-6)
    no_cue = ZonePatrolConfig(zone_cue=0.0)
    assert np.ptp(reading_log_likelihoods(no_cue, np.zeros((1, no_cue.obs_dim))).reshape(4, 2), axis=0).max() == 0


def test_em_ppo_on_zone_patrol_models_its_readings_and_logs_the_evidence_reach(tmp_path):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    from sb3_emmarl.common.callbacks import LatentMetricsCallback
    from sb3_emmarl.common.evaluation import evaluate_team

    venv = make_vec_env(2, seed=0, env_fn=zone_patrol_v1.parallel_env, vec_env_type="batched")
    model = EMPPO("MlpPolicy", venv, n_steps=64, batch_size=128, latent_kwargs=dict(n_components=8), seed=0,
                  tensorboard_log=str(tmp_path))
    assert model.latent_layout.reading_features == (8, 10, 11, 12, 13)  # the visibility and the four zone readings
    model.learn(2 * 4 * 64 * 2, callback=LatentMetricsCallback())
    accumulator = EventAccumulator(str(next(tmp_path.rglob("events.out.tfevents.*"))))
    accumulator.Reload()
    for key in ("latent/evidence_reach_25", "latent/evidence_reach_50", "latent/evidence_reach_100"):
        values = [e.value for e in accumulator.Scalars(key)]
        assert values and all(0.25 <= v <= 1.0 for v in values), key
    records = evaluate_team(model, 2, seed=1, env_id="ZonePatrol-v1")
    assert all(0.25 <= r["evidence_reach_50"] <= 1.0 for r in records)
    team = EMPPO("MlpPolicy", make_vec_env(1, seed=0, env_fn=zone_patrol_v1.parallel_env, vec_env_type="batched"),
                 n_steps=64, batch_size=64, latent_kwargs=dict(n_components=8, fusion="team"), seed=0)
    assert all(r["evidence_reach_50"] == 1.0 for r in evaluate_team(team, 1, seed=1, env_id="ZonePatrol-v1"))
