"""EM-PPO and EM-DDPG: beliefs, fusion, the E-step, SB3's conventions, save/load, ablations, logging."""

import warnings
from dataclasses import replace

import numpy as np
import pytest
import torch as th
from stable_baselines3.common.env_util import make_vec_env as sb3_make_vec_env
from stable_baselines3.common.evaluation import evaluate_policy

from sb3_emmarl import EMDDPG, EMPPO
from sb3_emmarl.common.appended.initialization import zero_tail_weights
from sb3_emmarl.common.latent.belief import BeliefTracker, BeliefWrapper
from sb3_emmarl.common.latent.em import EStep, Transitions, episode_ids
from sb3_emmarl.common.latent.layout import LatentLayout
from sb3_emmarl.common.latent.metrics import align_components
from sb3_emmarl.common.latent.model import LatentModel, StepLikelihood
from sb3_emmarl.common.mode_tasks import ModeCueEnv, ModeDynamicsEnv
from sb3_emmarl.common.vec_env import make_vec_env
from wildlife_reserve import reserve_v1

SMALL = {"n_uavs": 3, "grid_size": 20, "max_cycles": 30}
#: The reserve's observation size with these settings.
OBS_DIM = reserve_v1.parallel_env(**SMALL).obs_dim


def task_env(task=ModeCueEnv, n=8, seed=0, **kwargs):
    return sb3_make_vec_env(lambda: task(**kwargs), n_envs=n, seed=seed)


@pytest.mark.parametrize("continuous", [False, True])
@pytest.mark.parametrize("k", [2, 5])
def test_policy_shapes_and_beliefs(continuous, k):
    env = make_vec_env(env_kwargs={**SMALL, "continuous_actions": continuous})
    algo = EMDDPG if continuous else EMPPO
    model = algo("MlpPolicy", env, latent_kwargs=dict(n_components=k), seed=0)
    obs = model.env.reset()
    layout = model.latent_layout
    assert obs.shape == (3, OBS_DIM + k) and layout.obs_dim == OBS_DIM and layout.total_dim == OBS_DIM + k
    extractor = model.policy.actor.features_extractor if continuous else model.policy.features_extractor
    assert extractor(th.as_tensor(obs)).shape == (3, OBS_DIM + k)
    np.testing.assert_allclose(model.posterior(obs).sum(-1), 1.0, rtol=1e-5)
    np.testing.assert_allclose(model.posterior(obs), np.exp(model.policy.latent_model.log_prior.numpy())[None].repeat(3, 0),
                               rtol=1e-5)  # nothing observed yet: the prior
    assert not np.shares_memory(model.posterior(obs), obs)  # kept beliefs must not pin whole observation arrays
    for observation in (obs, obs[:, :OBS_DIM]):  # with the belief, and plain
        actions, _ = model.predict(observation)
        assert actions.shape == ((3, 3) if continuous else (3,))
        assert all(model.action_space.contains(a) for a in actions)
    with pytest.raises(ValueError, match=f"observations must have {OBS_DIM} values"):
        model.predict(obs[:, :10])


def filtered(model, features, actions, temperature=1.0):
    """Brute force: log pi + beta * sum of every transition's log-likelihood, normalised."""
    with th.no_grad():
        log_lik = model.transition_log_likelihood(features[:-1], actions, features[1:]).sum(0)
        return th.log_softmax(model.log_prior + temperature * log_lik, -1).numpy()


@pytest.mark.parametrize("temperature", [1.0, 0.3])
def test_the_belief_is_the_exact_filtering_posterior_updated_one_step_at_a_time(temperature):
    th.manual_seed(0)
    layout = LatentLayout(obs_dim=5, feature_dim=3, action_dim=2, n_components=4)
    model = LatentModel(layout)
    model.set_prior(th.tensor([[0.1, 0.2, 0.3, 0.4]]))
    features, actions = th.randn(7, 3), th.randn(6, 2)
    tracker = BeliefTracker(1, 4, 3, 2, model=model, likelihood_temperature=temperature)
    tracker.start(np.array([0]), features[:1].numpy())
    np.testing.assert_allclose(tracker.log_beliefs()[0], model.log_prior.numpy(), atol=1e-6)
    for t in range(6):
        tracker.set_actions(actions[t:t + 1].numpy())
        tracker.advance(np.array([0]), features[t + 1:t + 2].numpy())
        expected = filtered(model, features[:t + 2], actions[:t + 1], temperature)
        np.testing.assert_allclose(tracker.log_beliefs()[0], expected, atol=1e-4)
    # The state round-trips, and a new episode forgets.
    clone = BeliefTracker(1, 4, 3, 2, model=model, likelihood_temperature=temperature)
    clone.set_state(tracker.get_state())
    np.testing.assert_array_equal(clone.log_beliefs(), tracker.log_beliefs())
    tracker.start(np.array([0]), features[:1].numpy())
    np.testing.assert_allclose(tracker.log_beliefs()[0], model.log_prior.numpy(), atol=1e-6)
    with pytest.raises(ValueError, match="belief state must have shape"):
        clone.set_state(np.zeros((2, 3)))


def test_the_beliefs_lean_decoder_follows_the_model_through_every_change():
    th.manual_seed(0)
    layout = LatentLayout(obs_dim=9, feature_dim=5, action_dim=3, n_components=4, decoder_hidden=(16, 8))
    model = LatentModel(layout)
    fast = StepLikelihood(model)
    x, a, y = th.randn(40, 5), th.randn(40, 3), th.randn(40, 5)

    def check():
        with th.no_grad():
            expected = model.transition_log_likelihood(x, a, y).double().numpy()
        np.testing.assert_allclose(fast.log_likelihood(x.numpy(), a.numpy(), y.numpy()), expected, rtol=1e-5, atol=1e-4)
        np.testing.assert_allclose(fast.prior(), model.log_prior.double().numpy(), atol=1e-7)

    check()
    optimizer = th.optim.Adam(model.parameters(), lr=0.1)
    model.watch(optimizer)  # (as the E-step does: its steps announce their writes)
    loss = -model.transition_log_likelihood(x, a, y).mean()
    optimizer.zero_grad()
    loss.backward()
    optimizer.step()  # in-place writes
    check()
    model.set_prior(th.tensor([[0.7, 0.1, 0.1, 0.1]]))
    model.split_component(3, 0, generator=th.Generator().manual_seed(1))
    check()
    other = LatentModel(layout)
    model.load_state_dict(other.state_dict())
    check()
    with th.no_grad():
        model.decoder_log_std.data = th.full((5,), 0.5)  # a tensor replaced, not written in place
    check()


def test_fusion_keeps_the_newest_evidence_of_each_teammate_once_relayed_one_hop_per_step():
    tracker = BeliefTracker(6, 2, 1, 1, agents_per_copy=3)  # two copies of three agents, no model: set evidence by hand
    tracker.evidence[:] = [[1, 0], [0, 2], [3, 0], [0, 5], [7, 0], [0, 11]]

    def fused():
        return tracker.evidence + tracker.heard.sum(1)

    tracker.fuse([{"heard_from": (1,)}, {"heard_from": (2,)}, {}, {"heard_from": ()}, {"heard_from": (0, 2)}, {}])
    np.testing.assert_array_equal(fused()[0], [1, 2])  # its own and agent 1's: what 1 hears this step comes next step
    np.testing.assert_array_equal(fused()[1], [3, 2])
    np.testing.assert_array_equal(fused()[2], [3, 0])  # heard nobody
    np.testing.assert_array_equal(fused()[3], [0, 5])
    np.testing.assert_array_equal(fused()[4], [7, 16])  # agents 0 and 2 of the second copy: entries 3 and 5
    tracker.evidence[1] = [0, 4]  # agent 1 learns more; agent 0 keeps what it last heard until it hears again
    tracker.fuse([{}] * 6)
    np.testing.assert_array_equal(fused()[0], [1, 2])
    tracker.fuse([{"heard_from": (1,)}] + [{}] * 5)
    np.testing.assert_array_equal(fused()[0], [4, 4])  # 1's evidence replaced, not added; 2's relayed by 1, once
    tracker.evidence[2] = [5, 0]
    tracker.fuse([{"heard_from": (1, 2)}] + [{}] * 5)  # 2's newest version directly, and again (older) through 1
    np.testing.assert_array_equal(fused()[0], [6, 4])
    tracker.fuse([{"heard_from": (1,)}] + [{}] * 5)  # 1 passes on an older version of 2's than 0 holds: kept
    np.testing.assert_array_equal(fused()[0], [6, 4])
    tracker.fuse([{}, {"heard_from": (0,)}] + [{}] * 4)  # 1 never takes its own evidence back from a teammate
    np.testing.assert_array_equal(fused()[1], [6, 4])
    restored = BeliefTracker(6, 2, 1, 1, agents_per_copy=3)
    restored.clock = 1000  # the state is relative to the clock
    restored.set_state(tracker.get_state())
    tracker.fuse([{"heard_from": (1,)}] * 6)
    restored.fuse([{"heard_from": (1,)}] * 6)
    np.testing.assert_array_equal(restored.heard, tracker.heard)
    tracker.start(np.array([0]), np.zeros((1, 1)))  # a new episode for agent 0 alone: of what 1 passes on, only
    tracker.fuse([{"heard_from": (1,)}] + [{}] * 5)  # what dates from after it began is taken (1's own, not 2's)
    np.testing.assert_array_equal(tracker.heard[0].sum(0), tracker.evidence[1])
    off = BeliefTracker(3, 2, 1, 1, agents_per_copy=3, fusion=False)
    off.fuse([{"heard_from": (1, 2)}] * 3)
    assert not off.heard.any()


def evaluation_beliefs(model, env_kwargs, steps=30):
    venv = model.wrap_env(make_vec_env(env_kwargs=env_kwargs, seed=7))
    obs, beliefs = venv.reset(), []
    th.manual_seed(0)
    for _ in range(steps):
        obs, *_ = venv.step(model.predict(obs)[0])
        beliefs.append(model.posterior(obs))
    return np.array(beliefs)


def test_fusion_follows_the_links_and_changes_nothing_without_them():
    model = EMPPO("MlpPolicy", make_vec_env(env_kwargs=SMALL), n_steps=32, batch_size=32, seed=0,
                  latent_kwargs=dict(n_components=3))
    model.learn(96)  # a fitted decoder, so that evidence differs between agents
    for comm_loss, same in ((1.0, True), (0.0, False)):
        kwargs = {**SMALL, "comm_loss": comm_loss}
        model.latent_config = replace(model.latent_config, fusion=True)
        fused = evaluation_beliefs(model, kwargs)
        model.latent_config = replace(model.latent_config, fusion=False)
        alone = evaluation_beliefs(model, kwargs)
        assert np.array_equal(fused, alone) == same, comm_loss


def test_predict_with_a_state_equals_the_wrapped_environment_and_evaluate_policy_works_on_the_plain_one():
    model = EMPPO("MlpPolicy", task_env(ModeDynamicsEnv, n=4), n_steps=64, seed=0)
    model.learn(1024)
    plain, wrapped = task_env(ModeDynamicsEnv, n=3, seed=5), model.wrap_env(task_env(ModeDynamicsEnv, n=3, seed=5))
    obs_plain, obs_wrapped = plain.reset(), wrapped.reset()
    state, starts = None, np.ones(3, dtype=bool)
    for _ in range(60):  # more than two episodes of 25 steps: the state resets at episode starts
        actions, state = model.predict(obs_plain, state, starts, deterministic=True)
        np.testing.assert_allclose(np.exp(log_beliefs_of_state(model, state)), model.posterior(obs_wrapped), atol=1e-5)
        np.testing.assert_array_equal(actions, model.predict(obs_wrapped, deterministic=True)[0])
        obs_plain, _, starts, _ = plain.step(actions)
        obs_wrapped, *_ = wrapped.step(actions)
    mean_plain, _ = evaluate_policy(model, task_env(ModeDynamicsEnv, n=2, seed=9), n_eval_episodes=6, deterministic=True)
    mean_wrapped, _ = evaluate_policy(model, model.wrap_env(task_env(ModeDynamicsEnv, n=2, seed=9)), n_eval_episodes=6,
                                      deterministic=True)
    assert mean_plain == pytest.approx(mean_wrapped, rel=1e-5)


def log_beliefs_of_state(model, state):
    """The log-beliefs held in a ``predict`` state."""
    layout = model.latent_layout
    tracker = BeliefTracker(len(state), layout.n_components, layout.feature_dim, layout.action_dim,
                            model=model.policy.latent_model)
    tracker.set_state(state)
    return tracker.log_beliefs()


def random_transitions(venv, steps, counters, seed=0):
    """Random-action transitions of a plain vector env, as E-step data, with the true mode of each."""
    rng = np.random.default_rng(seed)
    obs = venv.reset()
    xs, acts, nexts, starts, modes = [], [], [], [], []
    start = np.ones(venv.num_envs, dtype=bool)
    for _ in range(steps):
        actions = rng.integers(0, 4, venv.num_envs)
        new_obs, _, dones, infos = venv.step(actions)
        following = np.array([info["terminal_observation"] if d else o for o, d, info in zip(new_obs, dones, infos)])
        xs.append(obs), acts.append(np.eye(4)[actions]), nexts.append(following), starts.append(start)
        modes.append([info["mode"] for info in infos])  # the transition's episode, even at its end
        obs, start = new_obs, dones
    ids = episode_ids(counters, np.array(starts))
    flat = lambda a: np.concatenate(a)  # noqa: E731
    return Transitions.from_numpy(flat(xs), flat(acts), flat(nexts), ids.ravel()), np.array(modes).ravel()


def test_the_e_step_alone_tells_the_mode_from_dynamics_and_its_likelihood_rises():
    th.manual_seed(0)
    venv = task_env(ModeDynamicsEnv, n=16)
    model = LatentModel(LatentLayout(obs_dim=2, feature_dim=2, action_dim=4, n_components=4))
    e_step = EStep(model, window=2)
    counters, likelihoods = np.zeros(16, dtype=np.int64), []
    for rollout in range(10):
        data, _ = random_transitions(venv, 50, counters, seed=rollout)
        e_step.add(data)
        likelihoods.append(e_step.step()["log_likelihood"])
    assert likelihoods[-1] > likelihoods[0] + 0.5 and np.mean(np.diff(likelihoods) > 0) >= 0.6
    held_out, modes = random_transitions(task_env(ModeDynamicsEnv, n=16, seed=99), 50, np.zeros(16, dtype=np.int64),
                                         seed=1234)
    log_r, index, _ = e_step.responsibilities(held_out)
    posterior = log_r.exp().numpy()[index.numpy()]
    mapping = align_components(posterior, modes)
    assert (mapping[posterior.argmax(1)] == modes).mean() >= 0.9


def test_a_component_is_re_seeded_once_its_prior_stays_starved_for_the_patience_asked():
    model = LatentModel(LatentLayout(obs_dim=2, feature_dim=2, action_dim=4, n_components=4))
    e_step = EStep(model, starved_share=0.5, starved_patience=3)  # starved below 0.5 / 4 = 0.125
    dips = [[0.1, 0.3, 0.3, 0.3], [0.2, 0.3, 0.25, 0.25], [0.1, 0.3, 0.3, 0.3], [0.1, 0.3, 0.3, 0.3]]
    for prior in dips:  # component 0 below it, back above, then below twice: never three E-steps in a row
        model.set_prior(th.tensor([prior]))
        assert e_step._revive_starved_components() == 0
    assert e_step.starved_steps.tolist() == [2, 0, 0, 0]
    state = e_step.state_dict()
    model.set_prior(th.tensor([[0.1, 0.5, 0.2, 0.2]]))
    assert e_step._revive_starved_components() == 1  # the third in a row: split off the busiest, component 1
    assert model.prior()[0] == pytest.approx(model.prior()[1]) and e_step.starved_steps.tolist() == [0, 0, 0, 0]
    e_step.load_state_dict(state)  # the count survives save and load
    assert e_step.starved_steps.tolist() == [2, 0, 0, 0]
    impatient = EStep(LatentModel(LatentLayout(obs_dim=2, feature_dim=2, action_dim=4, n_components=4)),
                      starved_share=0.5)  # the default: at the first E-step below it, as before
    impatient.model.set_prior(th.tensor([dips[0]]))
    assert impatient._revive_starved_components() == 1
    with pytest.raises(ValueError, match="starved_patience must be an int >= 1, got 0"):
        EStep(model, starved_patience=0)


def test_episode_ids_continue_across_rollouts_and_pool_teams():
    counters = np.zeros(4, dtype=np.int64)
    starts = np.array([[1, 1, 1, 1], [0, 0, 0, 0], [1, 1, 0, 0]], dtype=bool)
    first = episode_ids(counters, starts)
    assert first[0].tolist() != first[2].tolist()[:2] + first[0].tolist()[2:]
    assert len(np.unique(first)) == 6 and (first[1] == first[0]).all() and (first[2, 2:] == first[0, 2:]).all()
    second = episode_ids(counters, np.zeros((2, 4), dtype=bool))  # the next rollout continues the same episodes
    assert (second == first[2]).all()
    pooled = episode_ids(np.zeros(4, dtype=np.int64), starts, agents_per_copy=2, team_pooling=True)
    assert (pooled[:, 0] == pooled[:, 1]).all() and (pooled[:, 2] == pooled[:, 3]).all()
    assert len(np.unique(pooled)) == 3  # copy 0's two episodes, copy 1's one


def test_the_e_step_sees_whole_episodes_across_rollouts():
    model = EMPPO("MlpPolicy", task_env(ModeCueEnv, n=4), n_steps=8, latent_kwargs=dict(e_step_kwargs={"window": 8}), seed=0)
    model.learn(4 * 8 * 8)  # 64 steps per entry: two episodes of 32, over eight rollouts
    log_r, _, _ = model.e_step.responsibilities(model.e_step._data())
    assert len(log_r) == 2 * 4


def snapshot(module):
    return {name: value.clone() for name, value in module.state_dict().items()}


def changed(before, module):
    return {name for name, value in module.state_dict().items() if not th.equal(before[name], value)}


def policy_without_latent(names):
    return {n for n in names if not n.startswith("latent_model.")}


@pytest.mark.parametrize("algo", [EMPPO, EMDDPG])
def test_each_ablation_freezes_exactly_what_it_names(algo):
    continuous = algo is EMDDPG
    settings = {"n_steps": 32, "batch_size": 64} if not continuous else {"learning_starts": 50}
    latent_settings = {} if not continuous else {"e_step_interval": 2}

    def run(**switches):
        env = make_vec_env(n_copies=2, seed=0, env_kwargs={**SMALL, "continuous_actions": continuous})
        model = algo("MlpPolicy", env, seed=0, **settings, latent_kwargs={**latent_settings, **switches})
        before = snapshot(model.policy)
        model.learn(600)
        return model, changed(before, model.policy)

    model, moved = run()
    latent = {n for n in snapshot(model.policy) if n.startswith("latent_model.")}
    decoder = {n for n in latent if n.startswith("latent_model.decoder")}
    assert decoder and decoder <= moved and policy_without_latent(moved)  # both halves learn by default
    _, moved = run(freeze_e_step=True)
    assert not moved & latent and policy_without_latent(moved)  # decoder and prior unchanged
    _, moved = run(freeze_m_step=True)
    assert decoder <= moved <= latent  # only the latent model changed
    model, moved = run(use_latent=False)
    assert model.policy.latent_model is None and model.e_step is None
    assert not any(n.startswith("latent_model.") for n in snapshot(model.policy)) and moved
    feature_dim = model.policy.actor.features_extractor.features_dim if continuous else \
        model.policy.features_extractor.features_dim
    assert feature_dim == OBS_DIM  # the observation alone; the networks are otherwise the same


@pytest.mark.parametrize("algo", [EMPPO, EMDDPG])
def test_save_load_gives_the_same_actions_and_beliefs(algo, tmp_path):
    continuous = algo is EMDDPG
    settings = {"n_steps": 32, "batch_size": 64} if not continuous else {"learning_starts": 50,
                                                                         "latent_kwargs": {"e_step_interval": 2}}
    kwargs = {**SMALL, "continuous_actions": continuous}
    model = algo("MlpPolicy", make_vec_env(n_copies=2, seed=0, env_kwargs=kwargs), seed=0, **settings)
    model.learn(500)
    model.save(tmp_path / "model")
    loaded = algo.load(tmp_path / "model", env=make_vec_env(n_copies=2, seed=0, env_kwargs=kwargs), device="cpu")
    assert isinstance(loaded.env, BeliefWrapper) and loaded.env.tracker.model is loaded.policy.latent_model
    th.testing.assert_close(model.policy.latent_model.log_prior, loaded.policy.latent_model.log_prior)
    without_env = algo.load(tmp_path / "model", device="cpu")
    for other in (loaded, without_env):
        states = [None, None]
        plain = make_vec_env(n_copies=2, seed=3, env_kwargs=kwargs)
        obs, starts = plain.reset(), np.ones(6, dtype=bool)
        for _ in range(5):
            (a, states[0]), (b, states[1]) = (m.predict(obs, s, starts, deterministic=True)
                                              for m, s in ((model, states[0]), (other, states[1])))
            np.testing.assert_array_equal(a, b)
            np.testing.assert_allclose(states[0], states[1], rtol=1e-6)
            obs, _, starts, _ = plain.step(a)
    loaded.learn(200)  # and it trains on


def test_defaults_work_on_any_sb3_vector_environment_without_warnings(tmp_path):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        model = EMPPO("MlpPolicy", task_env(ModeCueEnv, n=3), tensorboard_log=str(tmp_path), seed=0)
        model.learn(3 * 128 * 2)
    assert model.e_step.n_updates == 2
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    events = next(tmp_path.rglob("events.out.tfevents.*"))
    accumulator = EventAccumulator(str(events))
    accumulator.Reload()
    tags = set(accumulator.Tags()["scalars"])
    expected = {f"latent/{k}" for k in ("log_likelihood", "prior_entropy", "posterior_entropy", "n_episodes")}
    assert expected <= tags, expected - tags


def test_gumbel_estimator_anneals_and_team_pooling_runs():
    env = make_vec_env(n_copies=2, seed=0, env_kwargs=SMALL)
    model = EMPPO("MlpPolicy", env, n_steps=32, batch_size=64, seed=0,
                  latent_kwargs=dict(estimator="gumbel", team_pooling=True, e_step_kwargs={"anneal_rate": 0.5}))
    model.learn(3 * 32 * 6)
    assert model.e_step.n_updates == 3
    assert model.e_step.temperature == pytest.approx(np.exp(-1.5))


def test_the_m_step_sees_the_beliefs_the_actions_were_drawn_with(monkeypatch):
    """The E-step after every rollout changes the decoder before PPO's update, yet the update's first log-probs
    equal the rollout's: the buffer holds the beliefs of collection time."""
    from stable_baselines3 import PPO

    checked = []

    def check(self):
        buffer = self.rollout_buffer
        obs = th.as_tensor(buffer.observations.reshape(-1, buffer.observations.shape[-1]))
        with th.no_grad():
            _, log_prob, _ = self.policy.evaluate_actions(obs, th.as_tensor(buffer.actions.reshape(-1)))
        np.testing.assert_allclose(log_prob.numpy(), buffer.log_probs.reshape(-1), atol=1e-5)
        checked.append(True)

    monkeypatch.setattr(PPO, "train", check)
    model = EMPPO("MlpPolicy", make_vec_env(n_copies=2, seed=0, env_kwargs=SMALL), n_steps=32, seed=0)
    model.learn(2 * 3 * 32 * 2)
    assert len(checked) == 2 and model.e_step.n_updates == 2


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"n_components": 0}, r"n_components must be an int in \[1, 64\], got 0"),
        ({"estimator": "mc"}, r"estimator must be one of \['enumerate', 'gumbel'\], got 'mc'"),
        ({"e_step_kwargs": {"epochs": 3}}, r"e_step_kwargs keys must be among"),
        ({"e_step_kwargs": {"n_epochs": 0}}, r"e_step_kwargs\['n_epochs'\] must be an int in \[1, 1000\], got 0"),
        ({"e_step_kwargs": {"learning_rate": float("inf")}}, r"e_step_kwargs\['learning_rate'\] must be a number"),
        ({"likelihood_temperature": 0.0}, r"likelihood_temperature must be a number in \(0.0, 100.0\], got 0.0"),
        ({"fusion": "no"}, "fusion must be true or false or one of \\['team'\\], got 'no'"),
        ({"decoder_hidden": "64"}, "decoder_hidden must be a list of layer sizes"),
        ({"decoder_hidden": [64, -1]}, r"decoder_hidden\[1\] must be an int in \[1, 4096\], got -1"),
        ({"e_step_interval": 0}, r"e_step_interval must be an int in \[1, 10000\], got 0"),
        ({"e_step_kwargs": {"starved_patience": 0}}, r"e_step_kwargs\['starved_patience'\] must be an int in \[1, "),
        ({"zero_belief_weights": 1}, "zero_belief_weights must be true or false, got 1"),
    ],
)
def test_bad_em_settings_are_rejected(kwargs, message):
    arguments = kwargs if "zero_belief_weights" in kwargs else {"latent_kwargs": kwargs}
    with pytest.raises(ValueError, match=message):
        EMPPO("MlpPolicy", make_vec_env(env_kwargs=SMALL), **arguments)


def test_zero_belief_weights_starts_em_ppo_as_the_same_function_of_every_belief(tmp_path):
    venv = make_vec_env(env_kwargs=SMALL)
    model = EMPPO("MlpPolicy", venv, n_steps=8, batch_size=24, latent_kwargs=dict(n_components=4), seed=0,
                  zero_belief_weights=True)
    obs = th.as_tensor(model.get_env().reset())
    outputs = []
    for belief in th.eye(4):
        with th.no_grad():
            seen = th.cat([obs[:, :-4], belief.expand(len(obs), 4)], dim=1)
            outputs.append((model.policy.get_distribution(seen).distribution.probs, model.policy.predict_values(seen)))
    for probs, values in outputs[1:]:
        th.testing.assert_close(probs, outputs[0][0])
        th.testing.assert_close(values, outputs[0][1])
    model.learn(48)
    learned = model.policy.mlp_extractor.value_net[0].weight[:, -4:]
    assert (learned != 0).any()  # the gradient reaches them
    model.save(tmp_path / "model")
    loaded = EMPPO.load(tmp_path / "model", device="cpu")
    assert loaded.zero_belief_weights
    th.testing.assert_close(loaded.policy.mlp_extractor.value_net[0].weight[:, -4:], learned)  # loading keeps them
    orthogonal = EMPPO("MlpPolicy", venv, n_steps=8, batch_size=24, latent_kwargs=dict(n_components=4), seed=0)  # the default
    assert (orthogonal.policy.mlp_extractor.policy_net[0].weight[:, -4:] != 0).any(dim=1).all()


def test_evaluate_team_reports_latent_metrics_over_the_episode():
    from sb3_emmarl.common.evaluation import evaluate_team

    model = EMPPO("MlpPolicy", make_vec_env(n_copies=2, env_kwargs=SMALL), n_steps=32, batch_size=64, seed=0,
                  latent_kwargs=dict(n_components=8))
    model.learn(256)
    records = evaluate_team(model, 3, seed=1, env_kwargs=SMALL)
    assert records == evaluate_team(model, 3, seed=1, env_kwargs=SMALL)
    for record in records:
        for key in ("latent_accuracy", "latent_accuracy_25", "latent_accuracy_50", "latent_accuracy_100"):
            assert 0.0 <= record[key] <= 1.0
        for key in ("evidence_reach_25", "evidence_reach_50", "evidence_reach_100"):  # the reserve's links
            assert 1 / SMALL["n_uavs"] <= record[key] <= 1.0
        assert record["latent_kl"] >= 0.0 and 0.0 <= record["latent_nmi"] <= 1.0
    assert len({r["latent_nmi"] for r in records}) == 1  # one alignment over all evaluated episodes
    assert len({r["belief_use"] for r in records}) == 1 and records[0]["belief_use"] > 0.0
    zero_tail_weights(model.policy, 8)  # a policy blind to its belief
    assert all(r["belief_use"] == pytest.approx(0.0, abs=1e-9) for r in evaluate_team(model, 2, seed=1, env_kwargs=SMALL))


@pytest.mark.parametrize("algo", ["em_ppo", "em_ddpg"])
def test_the_zoo_trains_and_evaluates_em_algorithms(algo, tmp_path):
    import json

    from sb3_emmarl.zoo.cli import train_main

    params = ["n_steps:32", "batch_size:64"] if algo == "em_ppo" else ["learning_starts:60",
                                                                        "latent_kwargs:dict(e_step_interval=2)"]
    assert train_main(["--algo", algo, "-n", "300", "--seed", "0", "-f", str(tmp_path), "--eval-freq", "150",
                       "--eval-episodes", "1", "--team-eval-episodes", "2", "--verbose", "0", "-params", *params,
                       "--env-kwargs", "n_uavs:2", "grid_size:20", "max_cycles:30"]) == 0
    run = tmp_path / algo / "WildlifeReserve-v1_1"
    records = json.loads((run / "team_eval.json").read_text())
    assert len(records) == 2 and "latent_accuracy_50" in records[0]
    assert (run / "best_model.zip").is_file()


def test_the_method_page_states_the_defaults_the_code_has():
    from pathlib import Path

    from sb3_emmarl.common.latent.config import E_STEP_DEFAULTS

    page = (Path(__file__).resolve().parents[1] / "docs" / "em.md").read_text()
    rows = {line.split("|")[1].strip().strip("`"): line.split("|")[2].strip() for line in page.splitlines()
            if line.startswith("| `")}
    for key, value in E_STEP_DEFAULTS.items():
        stated = rows[key].split()[0]
        assert float(stated) == value, (key, rows[key])
    for name in ("n_components", "likelihood_temperature", "fusion", "e_step_interval"):
        assert rows[name].startswith(str(getattr(EMPPO.latent_defaults, name))), (name, rows[name])


def test_the_e_step_defaults_are_estep_s_own():
    import inspect

    from sb3_emmarl.common.latent.config import E_STEP_DEFAULTS

    parameters = inspect.signature(EStep).parameters
    assert {key: parameters[key].default for key in E_STEP_DEFAULTS} == E_STEP_DEFAULTS


def test_training_logs_latent_accuracy_over_the_episode(tmp_path):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    from sb3_emmarl.common.callbacks import LatentMetricsCallback

    model = EMPPO("MlpPolicy", task_env(ModeCueEnv, n=4), tensorboard_log=str(tmp_path), seed=0)
    model.learn(4 * 128 * 3, callback=LatentMetricsCallback())
    accumulator = EventAccumulator(str(next(tmp_path.rglob("events.out.tfevents.*"))))
    accumulator.Reload()
    for key in ("latent/accuracy_25", "latent/accuracy_50", "latent/accuracy_100", "latent/nmi"):
        values = [e.value for e in accumulator.Scalars(key)]
        assert values and all(0.0 <= v <= 1.0 for v in values), key


def test_every_e_step_default_has_a_validation_rule():
    from sb3_emmarl.common.latent.config import E_STEP_DEFAULTS
    from sb3_emmarl.common.trust.validation import E_STEP_RULES

    assert set(E_STEP_RULES) == set(E_STEP_DEFAULTS)
    for name, value in E_STEP_DEFAULTS.items():
        assert E_STEP_RULES[name](name, value) == value
