"""The mixture-ceiling study (docs/lab/studies/): the episodes (and reading counts) it plays, the told E-step, the script."""

import numpy as np
import pytest
from scripts import load_study


@pytest.fixture(scope="module")
def ceiling():
    return load_study("mixture_ceiling")


@pytest.fixture(scope="module")
def played(ceiling):
    reader = ceiling.build("em_ppo", seed=0, n_copies=1)
    return reader, ceiling.collect(reader, n_episodes=3, n_copies=2, seed=5)


def test_episodes_are_whole_and_consistent(ceiling, played):
    reader, episodes = played
    n_uavs, length = 10, 200
    assert len(np.unique(episodes.team_episode)) == 4  # 3 rounded up to whole rounds of 2 copies
    assert len(episodes.features) == 4 * n_uavs * length
    for team in np.unique(episodes.team_episode):
        rows = episodes.team_episode == team
        assert len(np.unique(episodes.mode[rows])) == 1  # one mode per episode
        assert len(np.unique(episodes.uav_episode[rows])) == n_uavs
        for uav in np.unique(episodes.uav_episode[rows]):
            mine = np.flatnonzero(episodes.uav_episode == uav)
            np.testing.assert_array_equal(episodes.step[mine], np.arange(length))
            # each transition starts where the previous one ended
            np.testing.assert_array_equal(episodes.features[mine[1:]], episodes.next_features[mine[:-1]])
    assert episodes.features.shape[1] == reader.latent_layout.feature_dim
    assert episodes.actions.shape[1] == reader.latent_layout.action_dim
    np.testing.assert_array_equal(episodes.actions.sum(axis=1), 1.0)  # one-hot discrete actions
    # the reading counts: one unit per UAV-episode, summed up to each point, so never falling from one to the next
    units = 4 * n_uavs
    assert episodes.counts.shape[:3] == (units, 3, 3) and episodes.exposure.shape[:2] == (units, 3)
    assert len(np.unique(episodes.count_uav)) == units
    assert np.all(np.diff(episodes.counts, axis=1) >= 0) and np.all(np.diff(episodes.exposure, axis=1) >= 0)
    assert np.all(np.diff(episodes.exposure.sum(axis=-1), axis=1) > 0)
    for uav, team, mode in zip(episodes.count_uav, episodes.count_team, episodes.count_mode):
        rows = episodes.uav_episode == uav
        assert np.all(episodes.team_episode[rows] == team) and np.all(episodes.mode[rows] == mode)
    counts, exposure, modes = ceiling.team_totals(episodes, 1)
    assert counts.shape[0] == 4 and np.allclose(counts.sum(), episodes.counts[:, 1].sum())
    assert np.allclose(exposure.sum(), episodes.exposure[:, 1].sum()) and sorted(modes) == sorted(episodes.count_mode[::10])


def test_the_told_e_step_holds_every_episode_at_its_true_mode(ceiling, played):
    reader, episodes = played
    data = episodes.transitions(team=True)
    modes = dict(zip(episodes.team_episode.tolist(), episodes.mode.tolist()))
    e_step = ceiling.ToldEStep(modes, latent_model=reader.policy.latent_model, n_epochs=1, window=1)
    log_r, index, _ = e_step.responsibilities(data)
    told = log_r.exp().argmax(dim=1)
    np.testing.assert_array_equal(told[index].numpy(), episodes.mode)
    assert float(log_r.exp().max(dim=1).values.min()) > 0.999
    e_step.add(data)
    e_step.step()  # fits without error, and the prior is the modes' shares
    shares = np.bincount(list(modes.values()), minlength=8) / len(modes)
    np.testing.assert_allclose(reader.policy.latent_model.prior().numpy(), np.maximum(shares, 1e-4) /
                               np.maximum(shares, 1e-4).sum(), atol=1e-4)


def test_the_script_prints_every_row_and_rejects_bad_arguments(ceiling, capsys):
    assert ceiling.main(["--train-episodes", "2", "--test-episodes", "2", "--e-steps", "1", "--seeds", "0",
                         "--n-copies", "2"]) == 0
    out = capsys.readouterr().out
    rows = [line.split() for line in out.splitlines() if line.startswith(("transitions ", "counts "))]
    assert len(rows) == 16  # 2 models x 2 fittings x 2 sources x 2 targets
    for row in rows:
        values = [float(v) for v in row if v.replace(".", "", 1).isdigit()]
        assert len(values) == 6 and all(0.0 <= v <= 1.0 for v in values)
    with pytest.raises(SystemExit):
        ceiling.main(["--e-steps", "0"])
    assert "--e-steps must be >= 1, got 0" in capsys.readouterr().err
