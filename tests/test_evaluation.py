"""evaluate_team, the random reference policy and the team-metrics callback."""

import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from stable_baselines3 import PPO
from stable_baselines3.common.logger import configure

from sb3_emmarl.common.callbacks import TeamMetricsCallback
from sb3_emmarl.common.centralized import CentralizedReserveEnv
from sb3_emmarl.common.evaluation import RandomPolicy, evaluate_team, is_centralized
from sb3_emmarl.common.metrics import TEAM_METRICS
from sb3_emmarl.common.vec_env import make_vec_env
from wildlife_reserve import reserve_v1

SMALL = {"n_uavs": 3, "grid_size": 20, "max_cycles": 30}


def test_records_one_episode_each_with_every_metric_and_the_mode():
    records = evaluate_team(RandomPolicy(spaces.Discrete(15), seed=0), n_episodes=3, seed=4, env_kwargs=SMALL)
    assert [r["episode"] for r in records] == [0, 1, 2] and {r["seed"] for r in records} == {4}
    assert all(set(TEAM_METRICS) | {"mode"} <= set(r) for r in records)
    assert all(r["episode_length"] == 30 for r in records)


def test_episodes_match_what_the_reserve_plays_from_that_seed():
    records = evaluate_team(RandomPolicy(spaces.Discrete(15), seed=0), n_episodes=3, seed=4, env_kwargs=SMALL)
    env = reserve_v1.parallel_env(**SMALL)
    env.reset(seed=4)
    modes = [env.mode]
    for _ in range(2):
        env.reset()
        modes.append(env.mode)
    assert [r["mode"] for r in records] == modes  # the same sequence of episodes, whatever the policy


def test_same_policy_same_seed_same_records_and_another_seed_differs():
    def run(seed):
        return evaluate_team(RandomPolicy(spaces.Discrete(15), seed=1), n_episodes=2, seed=seed, env_kwargs=SMALL)

    assert run(3) == run(3)
    assert run(3) != run(4)


def test_a_trained_model_is_evaluated_reproducibly_with_sampled_or_argmax_actions():
    model = PPO("MlpPolicy", make_vec_env(env_kwargs=SMALL), n_steps=32, batch_size=48, n_epochs=1, seed=0)
    model.learn(96)
    assert not is_centralized(model, SMALL)
    assert evaluate_team(model, 2, seed=9, env_kwargs=SMALL) == evaluate_team(model, 2, seed=9, env_kwargs=SMALL)
    argmax = evaluate_team(model, 2, seed=9, env_kwargs=SMALL, deterministic=True)
    assert argmax == evaluate_team(model, 2, seed=9, env_kwargs=SMALL, deterministic=True)
    state = th.random.get_rng_state()
    evaluate_team(model, 1, seed=9, env_kwargs=SMALL)
    assert th.equal(state, th.random.get_rng_state())  # the caller's torch generator is left as it was


def test_evaluations_in_threads_of_one_process_give_what_each_gives_alone():
    from concurrent.futures import ThreadPoolExecutor

    model = PPO("MlpPolicy", make_vec_env(env_kwargs=SMALL), n_steps=32, batch_size=48, n_epochs=1, seed=0)
    model.learn(96)
    alone = [evaluate_team(model, 4, seed=seed, env_kwargs=SMALL) for seed in (9, 10)]
    with ThreadPoolExecutor(max_workers=2) as pool:  # as the zoo's comparisons evaluate runs
        together = list(pool.map(lambda seed: evaluate_team(model, 4, seed=seed, env_kwargs=SMALL), (9, 10)))
    assert together == alone


def test_the_centralised_view_is_detected_and_evaluated():
    model = PPO("MlpPolicy", CentralizedReserveEnv(**SMALL), n_steps=32, batch_size=32, n_epochs=1, seed=0)
    assert is_centralized(model, SMALL)
    records = evaluate_team(model, 2, seed=0, env_kwargs=SMALL)
    assert len(records) == 2 and records[0]["episode_length"] == 30


def test_random_policy_covers_every_action_space_and_rejects_others():
    for space in (spaces.Discrete(15), spaces.MultiDiscrete([15, 15]), spaces.Box(-1, 1, (3,), np.float32)):
        actions, _ = RandomPolicy(space, seed=0).predict(np.zeros((4, 2)))
        assert len(actions) == 4 and all(space.contains(a) for a in actions)
    with pytest.raises(ValueError, match="RandomPolicy supports"):
        RandomPolicy(spaces.MultiBinary(3)).predict(np.zeros((1, 2)))
    with pytest.raises(ValueError, match="n_episodes must be >= 1"):
        evaluate_team(RandomPolicy(spaces.Discrete(15)), n_episodes=0)


def test_team_metrics_callback_counts_each_copy_once(tmp_path):
    model = PPO("MlpPolicy", make_vec_env(n_copies=2, env_kwargs=SMALL), n_steps=30, batch_size=60, seed=0)
    model.set_logger(configure(str(tmp_path), ["csv"]))
    callback = TeamMetricsCallback()
    callback.init_callback(model)
    assert callback.agents_per_copy == 3
    infos = [{"metrics": dict.fromkeys(TEAM_METRICS, float(i))} for i in range(6)]
    callback.update_locals({"dones": np.ones(6, dtype=bool), "infos": infos})
    callback.on_step()
    # Copies start at indices 0 and 3: the mean is over those two records only.
    assert model.logger.name_to_value["reserve/detection_rate"] == pytest.approx(1.5)
    assert model.logger.name_to_count["reserve/detection_rate"] == 2


def test_models_loaded_in_one_thread_leave_another_threads_evaluation_as_it_is_alone(tmp_path):
    import threading

    from sb3_emmarl.common.evaluation import load_for_evaluation

    model = PPO("MlpPolicy", make_vec_env(env_kwargs=SMALL), n_steps=32, batch_size=48, n_epochs=1, seed=0)
    model.learn(96)
    model.save(tmp_path / "model.zip")
    alone = evaluate_team(model, 3, seed=9, env_kwargs=SMALL)
    result: list = []
    evaluation = threading.Thread(target=lambda: result.append(evaluate_team(model, 3, seed=9, env_kwargs=SMALL)))
    evaluation.start()
    loads = 0
    while evaluation.is_alive() or loads == 0:  # as the zoo's comparisons load the next run while one evaluates
        load_for_evaluation(PPO, tmp_path / "model.zip", device="cpu")
        loads += 1
    evaluation.join()
    assert result == [alone]
