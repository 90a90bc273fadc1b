"""EM-PPO and EM-DDPG: policy shapes, mode recovery by the E-step alone, save/load, ablations, logging."""

import numpy as np
import pytest
import torch as th
from stable_baselines3.common.vec_env import DummyVecEnv
from synthetic import ModeSpin

from sb3_emmarl import EMDDPG, EMPPO
from sb3_emmarl.common.latent.em import EStep, LatentBatch, transitions_from_rollout
from sb3_emmarl.common.latent.history import HistoryWrapper
from sb3_emmarl.common.latent.metrics import latent_report
from sb3_emmarl.common.latent.model import LatentModel
from sb3_emmarl.common.vec_env import make_vec_env
from wildlife_reserve import reserve_v0

SMALL = {"n_uavs": 3, "grid_size": 20, "max_cycles": 30}
#: The reserve's observation size with these settings.
OBS_DIM = reserve_v0.parallel_env(**SMALL).obs_dim


def synthetic_env(n=16, continuous=False, seed=0):
    venv = DummyVecEnv([lambda: ModeSpin(continuous=continuous)] * n)
    venv.seed(seed)
    return venv


@pytest.mark.parametrize("continuous", [False, True])
@pytest.mark.parametrize(("k", "h"), [(2, 1), (4, 8), (6, 3)])
def test_policy_shapes(continuous, k, h):
    env = make_vec_env(env_kwargs={**SMALL, "continuous_actions": continuous})
    algo = EMDDPG if continuous else EMPPO
    model = algo("MlpPolicy", env, n_components=k, history_length=h, seed=0)
    obs = model.env.reset()
    layout = model.layout
    assert obs.shape == (3, OBS_DIM + h * layout.step_dim) and layout.obs_dim == OBS_DIM
    extractor = model.policy.actor.features_extractor if continuous else model.policy.features_extractor
    features = extractor(th.as_tensor(obs))
    assert features.shape == (3, OBS_DIM + k)
    posterior = features[:, -k:]
    th.testing.assert_close(posterior.sum(-1), th.ones(3))
    np.testing.assert_allclose(model.posterior(obs), posterior.numpy(), rtol=1e-5)
    actions, _ = model.predict(obs)
    assert actions.shape == ((3, 3) if continuous else (3,))
    assert all(model.action_space.contains(a) for a in actions)


def collect(venv, steps, seed=0):
    """Random-action rollout of an augmented env: (n_steps, n_envs, dim) observations, episode starts and modes."""
    rng = np.random.default_rng(seed)
    obs = venv.reset()
    observations, starts, modes = [], [], []
    start = np.ones(venv.num_envs)
    for _ in range(steps):
        observations.append(obs)
        starts.append(start)
        modes.append([e.mode for e in venv.venv.envs])
        obs, _, dones, _ = venv.step(rng.integers(0, 3, venv.num_envs))
        start = dones.astype(float)
    return np.array(observations), np.array(starts), np.array(modes)


def test_the_e_step_alone_recovers_the_hidden_modes_and_the_elbo_rises():
    th.manual_seed(0)
    venv = HistoryWrapper(synthetic_env(), history_length=6)
    model = LatentModel(venv.layout, n_components=4)
    e_step = EStep(model, n_epochs=4, batch_size=256, window=3, learning_rate=3e-3)
    elbos = []
    for rollout in range(15):
        observations, starts, _ = collect(venv, 64, seed=rollout)
        e_step.add(transitions_from_rollout(venv.layout, observations, starts, agents_per_copy=1))
        elbos.append(e_step.step()["elbo"])
    assert elbos[-1] > elbos[0] + 1.0
    assert np.mean(np.diff(elbos) > 0) >= 0.6  # rising across E-steps, not just at the ends
    # Held-out episodes: align components to modes, then accuracy (from the 3rd step of an episode on).
    held_out = HistoryWrapper(synthetic_env(seed=99), history_length=6)
    observations, starts, modes = collect(held_out, 200, seed=1234)
    step_in_episode = np.zeros_like(starts)
    for t in range(1, len(starts)):
        step_in_episode[t] = np.where(starts[t] > 0, 0, step_in_episode[t - 1] + 1)
    keep = step_in_episode >= 3
    with th.no_grad():
        window = th.as_tensor(held_out.layout.split(observations[keep])[1])
        posterior = model.posterior(window).numpy()
    report = latent_report(posterior, modes[keep].astype(np.int64))
    assert report["latent_accuracy"] >= 0.9, report
    assert report["latent_nmi"] > 0.7


def snapshot(module):
    return {name: p.detach().clone() for name, p in module.state_dict().items()}


def changed(before, module):
    return {name for name, value in module.state_dict().items() if not th.equal(before[name], value)}


def policy_without_latent(names):
    return {n for n in names if not n.startswith("latent_model.")}


@pytest.mark.parametrize("algo", [EMPPO, EMDDPG])
def test_each_ablation_freezes_exactly_what_it_names(algo):
    continuous = algo is EMDDPG
    settings = {"n_steps": 32, "batch_size": 64} if not continuous else {"learning_starts": 50, "e_step_interval": 2}

    def run(**switches):
        env = make_vec_env(n_copies=2, seed=0, env_kwargs={**SMALL, "continuous_actions": continuous})
        model = algo("MlpPolicy", env, seed=0, **settings, **switches)
        before = snapshot(model.policy)
        model.learn(600)
        return model, changed(before, model.policy)

    model, moved = run()
    latent = {n for n in snapshot(model.policy) if n.startswith("latent_model.")}
    assert latent and latent <= moved and policy_without_latent(moved)  # both halves learn by default
    _, moved = run(freeze_e_step=True)
    assert not moved & latent and policy_without_latent(moved)  # encoder, decoder and prior unchanged
    _, moved = run(freeze_m_step=True)
    assert moved == latent  # only the latent model changed
    model, moved = run(use_latent=False)
    assert model.policy.latent_model is None and model.e_step is None
    assert not any(n.startswith("latent_model.") for n in snapshot(model.policy)) and moved
    feature_dim = model.policy.actor.features_extractor.features_dim if continuous else \
        model.policy.features_extractor.features_dim
    assert feature_dim == OBS_DIM  # the observation alone; the networks are otherwise the same


@pytest.mark.parametrize("algo", [EMPPO, EMDDPG])
def test_save_load_gives_the_same_actions_and_posteriors(algo, tmp_path):
    continuous = algo is EMDDPG
    settings = {"n_steps": 32, "batch_size": 64} if not continuous else {"learning_starts": 50, "e_step_interval": 2}
    env = make_vec_env(n_copies=2, seed=0, env_kwargs={**SMALL, "continuous_actions": continuous})
    model = algo("MlpPolicy", env, seed=0, **settings)
    model.learn(500)
    obs = model.env.reset()
    for _ in range(5):
        obs, *_ = model.env.step(model.predict(obs)[0])
    model.save(tmp_path / "model")
    raw_env = make_vec_env(n_copies=2, seed=0, env_kwargs={**SMALL, "continuous_actions": continuous})
    loaded = algo.load(tmp_path / "model", env=raw_env, device="cpu")
    np.testing.assert_array_equal(model.predict(obs, deterministic=True)[0], loaded.predict(obs, deterministic=True)[0])
    np.testing.assert_allclose(model.posterior(obs), loaded.posterior(obs), rtol=1e-6)
    th.testing.assert_close(model.policy.latent_model.log_prior, loaded.policy.latent_model.log_prior)
    assert loaded.env.observation_space.shape == model.env.observation_space.shape  # the history wrapper came back
    loaded.learn(200)  # and it trains on


def test_works_on_any_sb3_vector_environment_with_defaults(tmp_path):
    model = EMPPO("MlpPolicy", synthetic_env(n=4), n_steps=32, batch_size=64, tensorboard_log=str(tmp_path), seed=0)
    model.learn(512)  # 4 rollouts of 4 x 32 steps: one E-step with the default interval of 4
    assert model.e_step.n_updates == 1
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    events = next(tmp_path.rglob("events.out.tfevents.*"))
    accumulator = EventAccumulator(str(events))
    accumulator.Reload()
    tags = set(accumulator.Tags()["scalars"])
    expected = {f"latent/{k}" for k in ("elbo", "recon", "kl", "prior_entropy", "posterior_entropy", "temperature")}
    assert expected <= tags, expected - tags


def test_gumbel_estimator_anneals_and_team_pooling_runs():
    env = make_vec_env(n_copies=2, seed=0, env_kwargs=SMALL)
    model = EMPPO("MlpPolicy", env, n_steps=32, batch_size=64, estimator="gumbel", team_pooling=True, seed=0,
                  e_step_interval=1, e_step_kwargs={"anneal_rate": 0.5})
    model.learn(3 * 32 * 6)
    assert model.e_step.n_updates == 3
    assert model.e_step.temperature == pytest.approx(np.exp(-1.5))


def test_the_m_step_sees_the_posteriors_the_actions_were_drawn_with(monkeypatch):
    """An E-step after every rollout changes the encoder before PPO's update, yet the update's first log-probs
    equal the rollout's: the networks read the posteriors of collection time."""
    from stable_baselines3 import PPO

    checked = []

    def check(self):
        buffer = self.rollout_buffer
        obs = th.as_tensor(buffer.observations.reshape(-1, buffer.observations.shape[-1]))
        actions = th.as_tensor(buffer.actions.reshape(-1))
        with th.no_grad():
            _, log_prob, _ = self.policy.evaluate_actions(obs, actions)
            current = self.posterior(buffer.observations.reshape(len(obs), -1))
        stored = buffer.observations.reshape(len(obs), -1)[:, OBS_DIM:OBS_DIM + self.n_components]
        assert np.abs(current - stored).max() > 1e-4  # the E-step did move the encoder
        np.testing.assert_allclose(log_prob.numpy(), buffer.log_probs.reshape(-1), atol=1e-5)
        checked.append(True)

    monkeypatch.setattr(PPO, "train", check)
    model = EMPPO("MlpPolicy", make_vec_env(n_copies=2, seed=0, env_kwargs=SMALL), n_steps=32, batch_size=64,
                  e_step_interval=1, seed=0)
    model.learn(2 * 3 * 32 * 2)
    assert len(checked) == 2 and model.e_step.n_updates == 2


def test_team_pooled_e_steps_keep_each_group_in_one_minibatch():
    layout = HistoryWrapper(synthetic_env(n=2), history_length=2).layout
    e_step = EStep(LatentModel(layout, n_components=2), batch_size=20, max_samples=50, team_pooling=True)
    groups = th.arange(70) // 7  # 10 groups of 7
    e_step.add(LatentBatch(th.randn(70, 2, layout.step_dim), th.randn(70, layout.step_dim), groups))
    data = e_step._data()
    kept = data.groups.unique(return_counts=True)[1]
    assert len(data) == 49 and (kept == 7).all()  # whole groups, as many as fit in max_samples
    batches = e_step._minibatches(data)
    assert sorted(th.cat(batches).tolist()) == list(range(49))
    for idx in batches:
        assert (data.groups[idx].unique(return_counts=True)[1] == 7).all()


def test_team_pooling_multiplies_posteriors_and_divides_the_prior():
    layout = HistoryWrapper(synthetic_env(n=2), history_length=2).layout
    model = LatentModel(layout, n_components=3)
    log_q = th.log(th.tensor([[0.6, 0.3, 0.1], [0.5, 0.25, 0.25], [0.2, 0.2, 0.6]]))
    pooled = model.pool(log_q, th.tensor([0, 0, 1])).exp()
    expected = th.tensor([0.6 * 0.5, 0.3 * 0.25, 0.1 * 0.25]) * 3  # prior uniform: divide once by 1/3
    th.testing.assert_close(pooled[0], expected / expected.sum())
    th.testing.assert_close(pooled[1], pooled[0])
    th.testing.assert_close(pooled[2], log_q[2].exp())


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"n_components": 0}, "n_components must be an int >= 1"),
        ({"history_length": 0}, "history_length must be an int >= 1"),
        ({"estimator": "mc"}, "estimator must be 'enumerate' or 'gumbel'"),
        ({"e_step_kwargs": {"epochs": 3}}, r"e_step_kwargs keys must be among"),
    ],
)
def test_bad_em_settings_are_rejected(kwargs, message):
    with pytest.raises(ValueError, match=message):
        EMPPO("MlpPolicy", make_vec_env(env_kwargs=SMALL), **kwargs)


def test_evaluate_team_reports_latent_accuracy_for_em_models():
    from sb3_emmarl.common.evaluation import evaluate_team

    model = EMPPO("MlpPolicy", make_vec_env(n_copies=2, env_kwargs=SMALL), n_steps=32, batch_size=64, n_components=8, seed=0)
    model.learn(256)
    records = evaluate_team(model, 3, seed=1, env_kwargs=SMALL)
    assert records == evaluate_team(model, 3, seed=1, env_kwargs=SMALL)
    for record in records:
        assert 0.0 <= record["latent_accuracy"] <= 1.0 and record["latent_kl"] >= 0.0
        assert 0.0 <= record["latent_nmi"] <= 1.0
    assert len({r["latent_nmi"] for r in records}) == 1  # one alignment over all evaluated episodes


@pytest.mark.parametrize("algo", ["em_ppo", "em_ddpg"])
def test_the_zoo_trains_and_evaluates_em_algorithms(algo, tmp_path):
    import json

    from sb3_emmarl.zoo.cli import train_main

    params = ["n_steps:32", "batch_size:64"] if algo == "em_ppo" else ["learning_starts:60", "e_step_interval:2"]
    assert train_main(["--algo", algo, "-n", "300", "--seed", "0", "-f", str(tmp_path), "--eval-freq", "150",
                       "--eval-episodes", "1", "--team-eval-episodes", "2", "--verbose", "0", "-params", *params,
                       "--env-kwargs", "n_uavs:2", "grid_size:20", "max_cycles:30"]) == 0
    run = tmp_path / algo / "WildlifeReserve-v0_1"
    records = json.loads((run / "team_eval.json").read_text())
    assert len(records) == 2 and "latent_accuracy" in records[0]
    assert (run / "best_model.zip").is_file()


def test_the_method_page_states_the_defaults_the_code_has():
    import inspect
    from pathlib import Path

    from sb3_emmarl.common.latent.algorithm import E_STEP_DEFAULTS

    page = (Path(__file__).resolve().parents[1] / "docs" / "em.md").read_text()
    rows = {line.split("|")[1].strip().strip("`"): line.split("|")[2].strip() for line in page.splitlines()
            if line.startswith("| `")}
    for key, value in E_STEP_DEFAULTS.items():
        stated = rows[key].split()[0]
        assert float(stated) == value, (key, rows[key])
    signature = inspect.signature(EMPPO).parameters
    for name in ("n_components", "history_length", "encoder_hidden", "e_step_interval"):
        assert rows[name].startswith(str(signature[name].default)), (name, rows[name])


def test_the_elbo_is_tight_at_the_exact_posterior_and_lower_elsewhere():
    """ELBO(q) = log p(D) - KL(q || p(z | D)): equal to the log-evidence at q = responsibilities, below it otherwise."""
    th.manual_seed(0)
    layout = HistoryWrapper(synthetic_env(n=2), history_length=3).layout
    model = LatentModel(layout, n_components=3)
    model.set_prior(th.tensor([[0.5, 0.3, 0.2]]))
    window, next_slot = th.randn(6, 3, layout.step_dim), th.randn(6, layout.step_dim)
    window[..., -1] = 1.0  # every slot is a real step
    next_slot[:, -1] = 1.0
    with th.no_grad():
        log_lik = model.stretch_log_likelihood(window, next_slot)
        evidence = th.logsumexp(log_lik + model.log_prior, dim=-1)
        exact = model.elbo(window, next_slot, log_q=model.responsibilities(window, next_slot))
        encoder = model.elbo(window, next_slot)
    th.testing.assert_close(exact["elbo"], evidence, rtol=1e-4, atol=1e-3)
    th.testing.assert_close(exact["elbo"], exact["recon"] - exact["kl"])
    assert (encoder["elbo"] < evidence - 1e-4).all()
    th.testing.assert_close(encoder["elbo"], model.elbo(window, next_slot, log_likelihood=log_lik)["elbo"])


def test_em_ddpg_computes_each_sample_posterior_once_with_the_same_result():
    """The default LatentReplayBuffer writes the posterior into the samples; the update equals the one that runs
    the encoder inside every network (a plain ReplayBuffer), with far fewer encoder passes."""
    from stable_baselines3.common.buffers import ReplayBuffer

    from sb3_emmarl.em_ddpg.buffers import LatentReplayBuffer

    def run(**kwargs):
        env = make_vec_env(n_copies=1, seed=0, env_kwargs={**SMALL, "continuous_actions": True})
        model = EMDDPG("MlpPolicy", env, seed=0, learning_starts=60, e_step_interval=2, **kwargs)
        calls = []
        forward = model.policy.latent_model.posterior_logits
        model.policy.latent_model.posterior_logits = lambda window: calls.append(len(window)) or forward(window)
        model.learn(300)
        return model, sum(n == model.batch_size for n in calls)

    shared, shared_passes = run()
    plain, plain_passes = run(replay_buffer_class=ReplayBuffer)
    assert isinstance(shared.replay_buffer, LatentReplayBuffer) and shared.replay_buffer.on_sample is None
    for (name, a), b in zip(shared.policy.state_dict().items(), plain.policy.state_dict().values()):
        th.testing.assert_close(a, b, msg=name)
    assert 0 < shared_passes and 2 * shared_passes < plain_passes


def test_the_e_step_defaults_are_estep_s_own():
    import inspect

    from sb3_emmarl.common.latent.algorithm import E_STEP_DEFAULTS

    parameters = inspect.signature(EStep).parameters
    assert {key: parameters[key].default for key in E_STEP_DEFAULTS} == E_STEP_DEFAULTS
