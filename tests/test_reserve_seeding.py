"""Determinism: the same seed gives the same episodes, another seed does not."""

import numpy as np
from gymnasium.utils.env_checker import data_equivalence

from wildlife_reserve import reserve_v1


def rollout(seed, steps=500, **kwargs):
    env = reserve_v1.parallel_env(**kwargs)
    obs, infos = env.reset(seed=seed)
    for i, agent in enumerate(env.possible_agents):
        env.action_space(agent).seed(seed + i)
    trace = [(obs, infos)]
    for _ in range(steps):
        if not env.agents:  # episodes end at max_cycles (200): go on with an unseeded reset
            trace.append(env.reset())
            continue
        actions = {a: env.action_space(a).sample() for a in env.agents}
        trace.append(env.step(actions))
    return trace


def test_same_seed_same_observations_rewards_and_infos_over_500_steps():
    first, second = rollout(7), rollout(7)
    assert len(first) == len(second) == 501
    for a, b in zip(first, second):
        assert data_equivalence(a, b)
    assert any("metrics" in step[-1]["uav_0"] for step in first[1:])  # an episode ended on the way


def test_same_seed_same_episodes_with_every_condition_on():
    kwargs = {"continuous_actions": True, "sensor_noise": 0.3, "comm_loss": 0.3, "adversarial": True, "terrain_seed": None}
    for a, b in zip(rollout(3, steps=250, **kwargs), rollout(3, steps=250, **kwargs)):
        assert data_equivalence(a, b)


def test_another_seed_differs():
    first, other = rollout(7, steps=50), rollout(8, steps=50)
    assert not all(data_equivalence(a, b) for a, b in zip(first, other))
    obs_a = np.stack([first[-1][0][a] for a in first[-1][0]])
    obs_b = np.stack([other[-1][0][a] for a in other[-1][0]])
    assert not np.array_equal(obs_a, obs_b)


def test_unseeded_resets_after_a_seed_differ_but_repeat():
    env = reserve_v1.parallel_env()
    env.reset(seed=5)
    first_positions = env.uav_pos.copy()
    env.reset()
    assert not np.array_equal(env.uav_pos, first_positions)
    env.reset(seed=5)
    assert np.array_equal(env.uav_pos, first_positions)


def test_terrain_seed_fixes_the_map_and_none_redraws_it():
    fixed = reserve_v1.parallel_env(grid_size=40)
    fixed.reset(seed=0)
    terrain = fixed.terrain.copy()
    fixed.reset(seed=1)
    assert np.array_equal(fixed.terrain, terrain)
    drawn = reserve_v1.parallel_env(grid_size=40, terrain_seed=None)
    drawn.reset(seed=0)
    first = drawn.terrain.copy()
    drawn.reset(seed=1)
    assert not np.array_equal(drawn.terrain, first)
    drawn.reset(seed=0)
    assert np.array_equal(drawn.terrain, first)
