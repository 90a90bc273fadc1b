"""The neighbour-message wrapper and the graph-attention and transformer extractors (table 6 baselines)."""

import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from stable_baselines3 import PPO
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.torch_layers import FlattenExtractor

from sb3_emmarl.common.appended.extractor import SplitFeaturesExtractor
from sb3_emmarl.common.extractors import (
    EXTRACTORS,
    GraphAttentionExtractor,
    TransformerExtractor,
    message_policy_kwargs,
    split_observation,
)
from sb3_emmarl.common.messages import EDGE_DIM, MESSAGE_DIM, MessageLayout, NeighbourMessageWrapper, message_summary
from sb3_emmarl.common.vec_env import make_vec_env

SMALL = {"n_uavs": 3, "grid_size": 20, "max_cycles": 40}


def wrapped(n_uavs=3, n_copies=1, seed=0, **kwargs):
    return NeighbourMessageWrapper(make_vec_env(n_copies=n_copies, seed=seed, env_kwargs={**SMALL, "n_uavs": n_uavs,
                                                                                          **kwargs}))


def collect(venv, steps, seed=0):
    rng = np.random.default_rng(seed)
    obs, infos = [venv.reset()], [venv.reset_infos]
    for _ in range(steps):
        o, _, _, info = venv.step(rng.integers(0, venv.action_space.n, venv.num_envs))
        obs.append(o)
        infos.append(info)
    return obs, infos


def slots_of(obs, layout):
    return obs[..., layout.obs_dim:].reshape(*obs.shape[:-1], layout.n_slots, layout.slot_dim)


def extractor(kind, layout, space, **kwargs):
    th.manual_seed(0)
    cls = GraphAttentionExtractor if kind == "gat" else TransformerExtractor
    return cls(space, layout, features_dim=32, **kwargs).eval()


def test_layout_and_sizes_do_not_depend_on_team_size():
    sizes = set()
    for n in (1, 2, 3, 5):
        venv = wrapped(n)
        obs = venv.reset()
        lay = venv.layout
        assert obs.shape == (n, lay.total_dim) and lay.slot_dim == EDGE_DIM + MESSAGE_DIM == 20
        assert lay.total_dim == lay.obs_dim + 8 * 20
        assert not slots_of(obs, lay)[..., 3].any()  # nobody heard at reset
        sizes.add(lay.total_dim)
        assert MessageLayout.from_dict(lay.to_dict()) == lay
    assert len(sizes) == 1
    with pytest.raises(ValueError, match="max_messages"):
        NeighbourMessageWrapper(make_vec_env(env_kwargs=SMALL), max_messages=0)


def test_messages_hand_checked_against_links_and_positions():
    venv = wrapped(3, n_copies=2, seed=3)
    lay = venv.layout
    rng = np.random.default_rng(1)
    venv.reset()
    checked = 0
    for _ in range(30):
        obs, _, dones, infos = venv.step(rng.integers(0, 15, venv.num_envs))
        if dones.any():
            continue
        raw = obs[:, :lay.obs_dim]
        for i, info in enumerate(infos):
            base = i - i % 3
            senders = info["heard_from"]
            slots = slots_of(obs[i], lay)
            assert slots[:, 3].sum() == len(senders)
            for k, j in enumerate(sorted(senders, key=lambda j: np.hypot(*(raw[base + j, 343:345] - raw[i, 343:345])))):
                sender = raw[base + j]
                np.testing.assert_allclose(slots[k, EDGE_DIM:], message_summary(sender[None], lay)[0], rtol=1e-6)
                np.testing.assert_allclose(slots[k, EDGE_DIM:EDGE_DIM + 6], sender[343:349])  # own features
                window = sender[:343].reshape(7, 49).mean(1)
                np.testing.assert_allclose(slots[k, EDGE_DIM + 6:EDGE_DIM + 13], window, rtol=1e-5)
                maps = sender[361:553].reshape(3, 64).mean(1)
                np.testing.assert_allclose(slots[k, EDGE_DIM + 13:], maps, rtol=1e-5, atol=1e-7)
                # sign: the sender's row/col minus the receiver's, in cells (grid 20: 19 per unit) / comm_radius (20)
                expected = (sender[343:345] - raw[i, 343:345]) * 19.0 / 20.0
                np.testing.assert_allclose(slots[k, :2], expected, atol=1e-5)
                np.testing.assert_allclose(slots[k, 2], np.hypot(*expected), atol=1e-5)
                checked += 1
    assert checked > 10


def test_wrapper_steps_and_rewrites_terminal_observations():
    venv = wrapped(3, n_copies=2, max_cycles=8)
    obs, infos = collect(venv, 10)
    lay = venv.layout
    terminal = [info for step in infos[1:] for info in step if "terminal_observation" in info]
    assert len(terminal) == 6
    assert all(t["terminal_observation"].shape == (lay.total_dim,) for t in terminal)
    assert any(slots_of(t["terminal_observation"], lay)[:, 3].any() for t in terminal)
    assert any(slots_of(o, lay)[..., 3].any() for o in obs)
    state = venv.get_state()  # the last step's links, for checkpoints
    assert state == [tuple(info["heard_from"]) for info in infos[-1]] and any(state)
    other = wrapped(3, n_copies=2, max_cycles=8)
    other.set_state(state)
    assert other.get_state() == state
    with pytest.raises(ValueError, match="saved links are for 6 entries, this environment has 3"):
        wrapped(3).set_state(state)


def test_comm_loss_masks_every_neighbour():
    venv = wrapped(5, comm_loss=1.0)
    obs, _ = collect(venv, 15)
    assert not any(slots_of(o, venv.layout)[..., 3].any() for o in obs)
    assert not any(slots_of(o, venv.layout).any() for o in obs)


@pytest.fixture(scope="module")
def samples():
    venv = wrapped(5, n_copies=2, seed=1)
    obs, _ = collect(venv, 30)
    obs = np.concatenate(obs)
    present = slots_of(obs, venv.layout)[..., 3].sum(1)
    assert (present >= 2).any() and (present < 8).all()
    return venv, th.as_tensor(obs)


@pytest.mark.parametrize("kind", ["gat", "transformer"])
def test_extractor_ignores_slot_order_and_absent_slots(kind, samples):
    venv, obs = samples
    lay = venv.layout
    model = extractor(kind, lay, venv.observation_space, **({"n_rounds": 2} if kind == "gat" else {}))
    with th.no_grad():
        out = model(obs)
        assert out.shape == (len(obs), 32) and th.isfinite(out).all()
        slots = obs[:, lay.obs_dim:].reshape(len(obs), lay.n_slots, lay.slot_dim)
        perm = slots[:, th.randperm(lay.n_slots, generator=th.Generator().manual_seed(2))]
        shuffled = th.cat([obs[:, :lay.obs_dim], perm.reshape(len(obs), -1)], dim=1)
        th.testing.assert_close(model(shuffled), out, atol=1e-5, rtol=1e-5)
        # Change what absent slots hold (present flag stays 0): the same output.
        noisy = slots.clone()
        absent = noisy[..., 3] == 0
        noisy[absent] = th.randn(int(absent.sum()), lay.slot_dim) * 5
        noisy[..., 3] = th.where(absent, th.zeros(()), noisy[..., 3])
        th.testing.assert_close(model(th.cat([obs[:, :lay.obs_dim], noisy.reshape(len(obs), -1)], 1)), out,
                                atol=1e-5, rtol=1e-5)
        # Masking a present neighbour equals removing it (and a real neighbour matters).
        row = int(th.nonzero(slots[:, :, 3].sum(1) >= 2)[0])
        masked = slots[row:row + 1].clone()
        masked[0, 0, 3] = 0.0
        removed = th.cat([masked[:, 1:], th.zeros(1, 1, lay.slot_dim)], dim=1)
        as_obs = lambda s: th.cat([obs[row:row + 1, :lay.obs_dim], s.reshape(1, -1)], 1)  # noqa: E731
        th.testing.assert_close(model(as_obs(masked)), model(as_obs(removed)), atol=1e-5, rtol=1e-5)
        assert not th.allclose(model(as_obs(masked)), out[row:row + 1], atol=1e-5)


def test_gat_with_no_neighbour_has_zero_aggregate(samples):
    venv, obs = samples
    lay = venv.layout
    model = extractor("gat", lay, venv.observation_space)
    alone = obs.clone()
    alone[:, lay.obs_dim:] = 0.0
    own, edges, present, messages = split_observation(alone, lay)
    with th.no_grad():
        h_i = model.encoder(message_summary(own, lay))
        aggregate, _ = model.rounds[0](h_i, model.encoder(messages), edges, present)
    assert th.count_nonzero(aggregate) == 0


def test_bad_arguments():
    venv = wrapped(2)
    with pytest.raises(ValueError, match="kind"):
        message_policy_kwargs(venv, kind="lstm")
    with pytest.raises(ValueError, match="NeighbourMessageWrapper"):
        message_policy_kwargs(make_vec_env(env_kwargs=SMALL))
    with pytest.raises(ValueError, match="n_rounds"):
        GraphAttentionExtractor(venv.observation_space, venv.layout, n_rounds=3)
    with pytest.raises(ValueError, match="observation_space"):
        TransformerExtractor(make_vec_env(env_kwargs=SMALL).observation_space, venv.layout)


@pytest.mark.parametrize("kind", ["gat", "transformer"])
def test_ppo_trains_saves_loads_and_runs_on_a_larger_team(kind, tmp_path):
    venv = wrapped(3, seed=0)
    model = PPO("MlpPolicy", venv, n_steps=32, batch_size=48, n_epochs=1, seed=0,
                policy_kwargs=message_policy_kwargs(venv, kind, features_dim=32, net_arch=[32]))
    model.learn(2 * 3 * 32)
    model.save(tmp_path / "model")
    loaded = PPO.load(tmp_path / "model", device="cpu")
    assert isinstance(loaded.policy.features_extractor, type(model.policy.features_extractor))
    obs, _ = collect(wrapped(3, seed=5), 6)
    for o in obs:
        np.testing.assert_array_equal(model.predict(o, deterministic=True)[0], loaded.predict(o, deterministic=True)[0])
    bigger = wrapped(5, seed=7)
    assert bigger.observation_space.shape == venv.observation_space.shape
    obs = bigger.reset()
    for _ in range(10):
        obs, _, _, _ = bigger.step(loaded.predict(obs, deterministic=True)[0])
    assert obs.shape == (5, venv.layout.total_dim)


def test_message_ppo_wraps_every_environment_and_runs_on_other_team_sizes(tmp_path):
    """MessagePPO (the zoo's ppo_gat / ppo_transformer): trained with 10 UAVs, it acts unchanged with 20 and 50."""
    from stable_baselines3.common.evaluation import evaluate_policy

    from sb3_emmarl.common.evaluation import evaluate_team
    from sb3_emmarl.message_ppo import MessagePPO

    short = {"max_cycles": 10}
    model = MessagePPO("MlpPolicy", make_vec_env(1, seed=0, env_kwargs=short), extractor="gat", n_steps=16,
                       batch_size=80, n_epochs=1, seed=0).learn(160)
    for n_uavs in (20, 50):
        records = evaluate_team(model, 1, seed=1, env_kwargs={**short, "n_uavs": n_uavs})
        assert len(records) == 1 and np.isfinite(records[0]["team_reward"])
    reward, _ = evaluate_policy(model, model.wrap_env(make_vec_env(1, seed=2, env_kwargs=short)), n_eval_episodes=1)
    assert np.isfinite(reward)
    model.save(tmp_path / "gat")
    loaded = MessagePPO.load(tmp_path / "gat", env=make_vec_env(1, seed=3, env_kwargs={**short, "n_uavs": 20}))
    obs = loaded.get_env().reset()
    assert obs.shape == (20, model.observation_space.shape[0])
    assert np.array_equal(loaded.predict(obs, deterministic=True)[0], model.predict(obs, deterministic=True)[0])
    with pytest.raises(ValueError, match=r"extractor must be one of \['gat', 'transformer'\], got 'cnn'"):
        MessagePPO("MlpPolicy", make_vec_env(1, seed=0, env_kwargs=short), extractor="cnn")


def test_split_extractor_runs_the_inner_extractor_on_the_head_and_appends_the_rest(samples):
    """What EM-PPO (observation + belief) and MAPPO (observation + state + id) build around a user's extractor."""
    venv, obs = samples
    layout = venv.layout
    tail = th.rand(len(obs), 5)
    augmented = th.cat([obs, tail], dim=1)
    space = spaces.Box(-np.inf, np.inf, (augmented.shape[1],), np.float32)
    th.manual_seed(0)
    split = SplitFeaturesExtractor(space, layout.total_dim, GraphAttentionExtractor,
                                   {"layout": layout, "features_dim": 32}).eval()
    assert isinstance(split.inner, GraphAttentionExtractor) and split.features_dim == 32 + 5
    with th.no_grad():
        out = split(augmented)
        th.testing.assert_close(out[:, :32], split.inner(obs))
    th.testing.assert_close(out[:, 32:], tail)
    flat = SplitFeaturesExtractor(space, layout.total_dim, FlattenExtractor, keep=layout.total_dim + 2)
    assert flat.features_dim == layout.total_dim + 2
    th.testing.assert_close(flat(augmented), augmented[:, :layout.total_dim + 2])
    for head, keep in ((0, None), (10, 5), (10, augmented.shape[1] + 1)):
        with pytest.raises(ValueError, match="need 0 < head_dim <= keep"):
            SplitFeaturesExtractor(space, head, keep=keep)
    with pytest.raises(ValueError, match="flat Box"):
        SplitFeaturesExtractor(spaces.Box(0, 1, (2, 3)), 2)


@pytest.mark.parametrize("algo,kind", [("em_ppo", "gat"), ("mappo", "transformer"), ("em_ddpg", "gat"),
                                       ("vdn_em", "gat")])
def test_em_algorithms_and_mappo_take_the_message_extractors(algo, kind, tmp_path):
    """The same policy_kwargs as PPO's: the extractor reads the wrapped observation, the belief (or MAPPO's state)
    follows its features; trained, saved, loaded (same actions) and evaluated by SB3 on the plain wrapped env."""
    from sb3_emmarl import EMDDPG, EMPPO, EMVDN, MAPPO

    continuous = algo == "em_ddpg"
    env_kwargs = {**SMALL, "max_cycles": 20, "continuous_actions": continuous}

    def env(seed):
        return NeighbourMessageWrapper(make_vec_env(1, seed=seed, env_kwargs=env_kwargs, with_state=algo == "mappo"))

    venv = env(0)
    policy_kwargs = message_policy_kwargs(venv, kind, features_dim=24, net_arch=[32])
    cls = {"em_ppo": EMPPO, "mappo": MAPPO, "em_ddpg": EMDDPG, "vdn_em": EMVDN}[algo]
    off_policy = algo in ("em_ddpg", "vdn_em")
    fast = {"learning_starts": 30, "batch_size": 16, "buffer_size": 1000} if off_policy else \
        {"n_steps": 20, "batch_size": 30, "n_epochs": 1}
    model = cls("MlpPolicy", venv, seed=0, policy_kwargs=policy_kwargs, **fast)
    policy = model.policy
    extractor = {"em_ddpg": lambda: policy.actor.features_extractor,
                 "vdn_em": lambda: policy.q_net.features_extractor}.get(algo, lambda: policy.features_extractor)()
    assert isinstance(extractor, SplitFeaturesExtractor) and isinstance(extractor.inner, EXTRACTORS[kind])
    assert extractor.head_dim == venv.layout.total_dim
    if algo == "mappo":  # actor and critic have their own extractor; clipping groups keep them apart
        assert policy.pi_features_extractor is not policy.vf_features_extractor
        critic = {id(p) for p in policy.critic_parameters()}
        assert all(id(p) in critic for p in policy.vf_features_extractor.parameters())
        assert not any(id(p) in critic for p in policy.pi_features_extractor.parameters())
    else:  # the belief follows the extractor's features
        assert extractor.features_dim == 24 + policy.latent_layout.n_components
    model.learn(60)
    model.save(tmp_path / algo)
    loaded = cls.load(tmp_path / algo, env=env(0), device="cpu")
    plain = env(4)
    obs = plain.reset()
    state, starts = None, np.ones(plain.num_envs, dtype=bool)
    loaded_state = None
    for _ in range(5):
        actions, state = model.predict(obs, state, starts, deterministic=True)
        again, loaded_state = loaded.predict(obs, loaded_state, starts, deterministic=True)
        np.testing.assert_allclose(actions, again, atol=1e-6)
        obs, _, starts, _ = plain.step(actions)
    reward, _ = evaluate_policy(loaded, env(5), n_eval_episodes=1)
    assert np.isfinite(reward)
