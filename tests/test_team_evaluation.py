"""sb3_emmarl.evaluate_policy and sb3_emmarl.EvalCallback: SB3's evaluation counting team episodes on the
parameter-sharing vector environments (one team reward per episode of a copy), SB3's own elsewhere."""

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from sb3_contrib import RecurrentPPO
from stable_baselines3 import PPO
from stable_baselines3.common import evaluation as sb3_evaluation
from stable_baselines3.common.vec_env import DummyVecEnv

import sb3_emmarl
from sb3_emmarl import EMPPO, EvalCallback, OraclePPO, evaluate_policy
from sb3_emmarl.common.callbacks import AtomicEvalCallback
from sb3_emmarl.common.evaluation import evaluate_team
from sb3_emmarl.common.vec_env import make_vec_env
from wildlife_reserve import zone_patrol_v0

SMALL = {"n_uavs": 3, "grid_size": 20, "max_cycles": 30}


def reserve(n_copies, seed):
    return make_vec_env(n_copies, seed=seed, env_kwargs=SMALL)


def zone_patrol(n_copies, seed):
    return make_vec_env(n_copies, seed=seed, env_fn=zone_patrol_v0.parallel_env, vec_env_type="batched")


ENVS = {"reserve": reserve, "zone_patrol": zone_patrol}


def tiny(algo, make_env, policy="MlpPolicy", **kwargs):
    return algo(policy, make_env(2, 0), n_steps=32, batch_size=32, n_epochs=1, seed=0, **kwargs)


@pytest.mark.parametrize("env_name", list(ENVS))
@pytest.mark.parametrize("algo", [PPO, EMPPO])
def test_n_eval_episodes_are_team_episodes_equal_to_evaluate_teams(env_name, algo):
    make_env = ENVS[env_name]
    model = tiny(algo, make_env)
    rewards, lengths = evaluate_policy(model, make_env(4, 11), n_eval_episodes=8, return_episode_rewards=True)
    assert len(rewards) == len(lengths) == 8
    records = evaluate_team(model, 8, seed=11, deterministic=True, vec_env=make_env(4, 11))
    assert rewards == [r["team_reward"] for r in records]  # the same episodes, the same numbers
    assert np.std(rewards) > 0  # eight episodes, not the UAVs of one
    mean, std = evaluate_policy(model, make_env(4, 11), n_eval_episodes=8)
    assert (mean, std) == (np.mean(rewards), np.std(rewards))
    # Sampled actions: the same draws as evaluate_team's when torch's generator starts where it starts it.
    with th.random.fork_rng():
        th.manual_seed(11)
        sampled, _ = evaluate_policy(model, make_env(4, 11), n_eval_episodes=8, deterministic=False,
                                     return_episode_rewards=True)
    assert sampled == [r["team_reward"] for r in evaluate_team(model, 8, seed=11, vec_env=make_env(4, 11))]


@pytest.mark.parametrize("env_name", list(ENVS))
def test_every_uav_receives_the_team_reward_so_sb3s_own_count_is_of_uavs(env_name):
    make_env = ENVS[env_name]
    env = make_env(2, 3)
    per_copy = env.agents_per_copy
    env.reset()
    ended = 0
    while ended < 2 * env.num_envs:
        _, _, dones, infos = env.step(np.array([env.action_space.sample() for _ in range(env.num_envs)]))
        for i in np.flatnonzero(dones):
            team = infos[i - i % per_copy]["metrics"]["team_reward"]
            assert infos[i]["episode"]["r"] == pytest.approx(team, abs=1e-3)  # each UAV's return: the team's
            ended += 1
    model = tiny(PPO, make_env)
    sb3_rewards, _ = sb3_evaluation.evaluate_policy(model, make_env(1, 5), n_eval_episodes=per_copy,
                                                    return_episode_rewards=True)
    assert len(set(sb3_rewards)) == 1  # SB3's: the UAVs of one team episode, std 0
    ours, _ = evaluate_policy(model, make_env(1, 5), n_eval_episodes=per_copy, return_episode_rewards=True)
    assert ours[0] == pytest.approx(sb3_rewards[0], abs=1e-3) and len(set(ours)) > 1


@pytest.mark.parametrize("k", [1, 3, 5])
def test_episodes_are_divided_among_the_copies_as_sb3_divides_them_among_entries(k):
    model = tiny(PPO, reserve)
    calls = []
    rewards, lengths = evaluate_policy(model, reserve(2, 7), n_eval_episodes=k, return_episode_rewards=True,
                                       callback=lambda local, _: calls.append(local["i"]))
    assert len(rewards) == len(lengths) == k and set(lengths) == {SMALL["max_cycles"]}
    assert all(isinstance(r, float) for r in rewards) and all(isinstance(n, int) for n in lengths)
    per_copy = SMALL["n_uavs"]
    targets = [(k + c) // 2 for c in range(2)]  # copy c plays (k + c) // n_copies episodes
    assert [calls.count(c * per_copy) for c in range(2)] == [t * SMALL["max_cycles"] for t in targets]
    assert set(calls) <= {0, per_copy}  # called once per copy (its first entry), not once per UAV


def test_a_recurrent_policy_gets_its_state_and_episode_starts_back():
    model = tiny(RecurrentPPO, reserve, "MlpLstmPolicy", policy_kwargs={"lstm_hidden_size": 8, "n_lstm_layers": 1})
    rewards, _ = evaluate_policy(model, reserve(2, 4), n_eval_episodes=4, return_episode_rewards=True)
    assert rewards == [r["team_reward"] for r in evaluate_team(model, 4, seed=4, deterministic=True,
                                                               vec_env=reserve(2, 4))]


def test_a_model_that_wraps_its_environment_is_evaluated_on_the_plain_one():
    model = tiny(OraclePPO, reserve)
    with pytest.raises(ValueError, match=r"model.wrap_env\(env\)"):
        sb3_evaluation.evaluate_policy(model, reserve(1, 2), n_eval_episodes=1)
    plain = evaluate_policy(model, reserve(2, 2), n_eval_episodes=4, return_episode_rewards=True)
    assert plain == evaluate_policy(model, model.wrap_env(reserve(2, 2)), n_eval_episodes=4,
                                    return_episode_rewards=True)


@pytest.mark.parametrize("vectorised", [False, True])
def test_an_ordinary_environment_gets_sb3s_result_exactly(vectorised):
    def env(seed):
        if vectorised:
            venv = DummyVecEnv([lambda: gym.make("CartPole-v1") for _ in range(2)])
            venv.seed(seed)
            return venv
        single = gym.make("CartPole-v1")
        single.reset(seed=seed)
        return single

    model = PPO("MlpPolicy", "CartPole-v1", n_steps=64, batch_size=64, n_epochs=1, seed=0)
    for kwargs in ({}, {"return_episode_rewards": True}, {"deterministic": False}):
        th.manual_seed(1)
        ours = evaluate_policy(model, env(3), n_eval_episodes=3, warn=False, **kwargs)
        th.manual_seed(1)
        theirs = sb3_evaluation.evaluate_policy(model, env(3), n_eval_episodes=3, warn=False, **kwargs)
        assert ours == theirs


def test_sb3s_parameter_names_and_order_with_the_rarely_positional_tail_by_keyword():
    import inspect

    ours, theirs = (inspect.signature(f).parameters for f in (evaluate_policy, sb3_evaluation.evaluate_policy))
    assert list(ours) == list(theirs)
    assert [name for name, p in ours.items() if p.kind is p.POSITIONAL_OR_KEYWORD] == list(theirs)[:4]
    model = tiny(PPO, reserve)
    by_keyword = evaluate_policy(model, reserve(2, 3), n_eval_episodes=2, deterministic=True)
    assert evaluate_policy(model, reserve(2, 3), 2) == by_keyword  # SB3's calls by position still work
    assert evaluate_policy(model, reserve(2, 3), 2, True) == by_keyword
    with pytest.raises(TypeError):
        evaluate_policy(model, reserve(2, 3), 2, True, False)  # render and after: by keyword


@pytest.mark.parametrize("bad", [0, -2, 2.5, True, "3", None])
def test_a_bad_episode_count_is_refused_with_a_message(bad):
    model = tiny(PPO, reserve)
    with pytest.raises(ValueError, match=f"n_eval_episodes must be a whole number >= 1, got {bad!r}"):
        evaluate_policy(model, reserve(1, 0), n_eval_episodes=bad)
    with pytest.raises(ValueError, match="n_eval_episodes must be a whole number >= 1"):
        evaluate_policy(model, gym.make("CartPole-v1"), n_eval_episodes=bad)
    with pytest.raises(ValueError, match="n_eval_episodes must be a whole number >= 1"):
        EvalCallback(reserve(1, 0), n_eval_episodes=bad)


def test_reward_threshold_and_a_vector_environment_of_broken_copies():
    model = tiny(PPO, reserve)
    with pytest.raises(AssertionError, match="Mean reward below threshold"):
        evaluate_policy(model, reserve(1, 0), n_eval_episodes=1, reward_threshold=1e9)
    venv = DummyVecEnv([lambda: gym.make("CartPole-v1") for _ in range(3)])
    venv.agents_per_copy = 2
    with pytest.raises(ValueError, match="3 entries, not a whole number of copies of 2 agents"):
        evaluate_policy(PPO("MlpPolicy", venv, n_steps=64, batch_size=64), venv)


@pytest.mark.parametrize("algo", [PPO, EMPPO])
def test_eval_callback_logs_team_episodes(tmp_path, algo, recwarn):
    assert sb3_emmarl.EvalCallback is EvalCallback and issubclass(AtomicEvalCallback, EvalCallback)
    model = tiny(algo, reserve)
    callback = EvalCallback(reserve(2, 9), n_eval_episodes=4, eval_freq=32, log_path=str(tmp_path), verbose=0)
    model.learn(2 * 32 * 6, callback=callback)  # two rollouts of 32 steps: two evaluations
    evaluations = np.load(tmp_path / "evaluations.npz")
    assert evaluations["results"].shape == evaluations["ep_lengths"].shape == (2, 4)
    assert np.std(evaluations["results"][-1]) > 0  # four team episodes, not the UAVs of one
    # The first evaluation ran at the end of the first rollout, before any update: on the model as built.
    first = evaluate_policy(tiny(algo, reserve), reserve(2, 9), n_eval_episodes=4, return_episode_rewards=True)[0]
    assert evaluations["results"][0].tolist() == first
    assert callback.last_mean_reward == pytest.approx(np.mean(evaluations["results"][-1]))
    assert not [w for w in recwarn if "not of the same type" in str(w.message)]  # EM: wrapped as training is


def test_the_zoos_periodic_evaluations_are_team_episodes(tmp_path):
    from sb3_emmarl.zoo.cli import train_main

    assert train_main(["--algo", "em_ppo", "-n", "256", "--seed", "0", "-f", str(tmp_path), "--eval-freq", "128",
                       "--eval-episodes", "4", "--team-eval-episodes", "0", "--verbose", "0", "-params", "n_steps:32",
                       "batch_size:32", "--env-kwargs", "n_uavs:2", "grid_size:20", "max_cycles:30"]) == 0
    evaluations = np.load(tmp_path / "em_ppo" / "WildlifeReserve-v1_1" / "evaluations.npz")
    assert evaluations["results"].shape == (2, 4)  # two evaluations of four team episodes
    # SB3's would score the two UAVs of each of two episodes here: two pairs of equal rewards
    assert all(len(set(row)) == 4 for row in evaluations["results"].tolist())


def test_optunas_trials_are_scored_on_team_episodes(tmp_path, monkeypatch):
    import rl_zoo3.exp_manager

    from sb3_emmarl.common import callbacks
    from sb3_emmarl.zoo.cli import train_main
    from sb3_emmarl.zoo.exp_manager import TeamTrialEvalCallback

    scored = []

    def recording(*args, **kwargs):
        scored.append(evaluate_policy(*args, **kwargs)[0])
        return scored[-1], [0] * len(scored[-1])

    monkeypatch.setattr(callbacks, "evaluate_policy", recording)
    monkeypatch.setattr(rl_zoo3.exp_manager, "TrialEvalCallback", rl_zoo3.exp_manager.TrialEvalCallback)
    assert train_main(["--algo", "ppo", "-optimize", "--n-trials", "1", "-n", "256", "--n-evaluations", "1",
                       "--sampler", "random", "--pruner", "none", "-f", str(tmp_path), "--verbose", "0",
                       "--eval-episodes", "3", "--no-optim-plots", "--env-kwargs", "n_uavs:2", "grid_size:20",
                       "max_cycles:30"]) == 0
    assert rl_zoo3.exp_manager.TrialEvalCallback is TeamTrialEvalCallback
    assert scored and all(len(set(rewards)) == 3 for rewards in scored)  # three team episodes, not UAVs of fewer
