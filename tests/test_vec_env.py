"""The parameter-sharing vector environment, and each SuperSuit 3.11 SB3-adapter fault pinned down."""

import re
from functools import partial

import numpy as np
import pytest
from stable_baselines3 import PPO
from stable_baselines3.common.callbacks import BaseCallback

from sb3_emmarl.common.vec_env import ReserveVecEnv, SharedPolicyVecEnv, make_vec_env
from sb3_emmarl.common.vec_env.workers import POLL_SECONDS
from wildlife_reserve import reserve_v1

SMALL = {"n_uavs": 3, "grid_size": 20, "max_cycles": 25}


def rollout(venv, steps=60, seed=0):
    rng = np.random.default_rng(seed)
    obs = [venv.reset()]
    rewards, dones = [], []
    for _ in range(steps):
        o, r, d, _ = venv.step(rng.integers(0, 15, venv.num_envs))
        obs.append(o)
        rewards.append(r)
        dones.append(d)
    return np.array(obs), np.array(rewards), np.array(dones)


def test_index_layout_is_copy_major_then_agent():
    venv = make_vec_env(n_copies=3, seed=11, env_kwargs=SMALL)
    obs = venv.reset()
    assert venv.num_envs == 9 and venv.get_attr("n")[0] == 3
    for c in range(3):
        direct, _ = reserve_v1.parallel_env(**SMALL).reset(seed=11 + c)
        for a, agent in enumerate(["uav_0", "uav_1", "uav_2"]):
            np.testing.assert_array_equal(obs[c * 3 + a], direct[agent])


def test_ppo_seed_works_and_reproduces_exactly():
    # SuperSuit fault: PPO(..., seed=0) raised AttributeError (ConcatVecEnv has no seed).
    params = []
    for _ in range(2):
        model = PPO("MlpPolicy", make_vec_env(n_copies=2, env_kwargs=SMALL), n_steps=32, batch_size=64, n_epochs=1, seed=0)
        model.learn(2 * 3 * 32 * 2)
        params.append(np.concatenate([p.detach().numpy().ravel() for p in model.policy.parameters()]))
    np.testing.assert_array_equal(params[0], params[1])


def test_vec_env_seed_then_reset_reproduces_and_other_seeds_differ():
    # SuperSuit fault: reset(seed=...) / seed() raised AttributeError.
    runs = []
    for seed in (5, 5, 6):
        venv = make_vec_env(n_copies=2, env_kwargs=SMALL)
        assert venv.seed(seed) == [seed] * 3 + [seed + 1] * 3
        runs.append(rollout(venv))
    for a, b in zip(runs[0], runs[1]):
        np.testing.assert_array_equal(a, b)
    assert not np.array_equal(runs[0][0], runs[2][0])


def test_every_copy_plays_a_different_episode_even_unseeded():
    # SuperSuit fault: copies were clones of one environment, sharing its random state.
    def pre_seeded():
        env = reserve_v1.parallel_env(**SMALL)
        env.reset(seed=0)  # a random state that a clone would copy
        return env

    venv = SharedPolicyVecEnv(pre_seeded, n_copies=3)
    obs = venv.reset()
    copies = obs.reshape(3, 3, -1)
    assert not np.array_equal(copies[0], copies[1]) and not np.array_equal(copies[1], copies[2])
    seeded = make_vec_env(n_copies=3, seed=0, env_kwargs=SMALL).reset().reshape(3, 3, -1)
    assert not np.array_equal(seeded[0], seeded[1])


def test_time_limit_is_marked_as_truncation_and_termination_is_not():
    # SuperSuit fault: truncation reached SB3 as a plain done without TimeLimit.truncated.
    venv = make_vec_env(n_copies=2, seed=0, env_kwargs=SMALL)
    venv.reset()
    for _ in range(SMALL["max_cycles"]):
        _, _, dones, infos = venv.step(np.zeros(venv.num_envs, dtype=int))
        assert dones.dtype == bool
    assert dones.all()
    assert all(info["TimeLimit.truncated"] for info in infos)
    assert all("terminal_observation" in info and "metrics" in info for info in infos)
    # An episode that ends because every battery is empty is a termination, not a truncation.
    venv.reset()
    for battery in venv.get_attr("battery"):
        battery[:] = 1e-5
    _, _, dones, infos = venv.step(np.zeros(venv.num_envs, dtype=int))
    assert dones.all() and not any(info["TimeLimit.truncated"] for info in infos)


class RecordRewards(BaseCallback):
    def _on_step(self) -> bool:
        self.locals.setdefault("raw", []).append(self.locals["rewards"].copy())
        self.raw = self.locals["raw"]
        return True


def test_ppo_bootstraps_at_the_time_limit():
    venv = make_vec_env(n_copies=1, seed=0, env_kwargs=SMALL)
    model = PPO("MlpPolicy", venv, n_steps=SMALL["max_cycles"], batch_size=25, n_epochs=1, gamma=0.9, seed=0)
    callback = RecordRewards()
    model.learn(SMALL["max_cycles"] * 3, callback=callback)
    raw = np.array(callback.raw)
    buffer = model.rollout_buffer.rewards
    # Inside the episode the buffer holds the raw rewards; at the cut it adds gamma * V(terminal obs).
    np.testing.assert_allclose(buffer[:-1], raw[:-1], rtol=1e-6)
    assert not np.allclose(buffer[-1], raw[-1])


def test_get_attr_set_attr_and_env_method_reach_the_copies():
    # SuperSuit fault: get_attr raised AttributeError.
    venv = make_vec_env(n_copies=2, seed=0, env_kwargs=SMALL)
    venv.reset()
    assert venv.get_attr("max_cycles") == [25] * 6
    assert venv.get_attr("render_mode") == [None] * 6
    venv.set_attr("max_cycles", 30, indices=[3])
    assert venv.get_attr("max_cycles") == [25, 25, 25, 30, 30, 30]
    states = venv.env_method("state", indices=[0, 3])
    assert len(states) == 2 and not np.array_equal(states[0], states[1])
    assert venv.env_is_wrapped(object) == [False] * 6


@pytest.mark.parametrize("vec_env_type", ["batched", "supersuit"])
def test_multiprocess_copies_match_in_process_copies(vec_env_type):
    # SuperSuit fault: with num_cpus > 1 the seeds collided across processes.
    in_process = rollout(make_vec_env(n_copies=4, seed=3, env_kwargs=SMALL), steps=30)
    venv = make_vec_env(n_copies=4, seed=3, env_kwargs=SMALL, num_cpus=2, vec_env_type=vec_env_type)
    try:
        multi = rollout(venv, steps=30)
        assert venv.get_attr("max_cycles") == [25] * 12
        if vec_env_type == "supersuit":
            with pytest.raises(NotImplementedError, match="num_cpus <= 1"):
                venv.env_method("state")
    finally:
        venv.close()
    for a, b in zip(in_process, multi):
        np.testing.assert_array_equal(a, b)
    copies = multi[0][0].reshape(4, 3, -1)
    assert all(not np.array_equal(copies[i], copies[j]) for i in range(4) for j in range(i + 1, 4))


@pytest.mark.parametrize("vec_env_type", ["batched", "supersuit"])
def test_reset_infos_are_one_dict_per_entry_with_worker_processes_too(vec_env_type):
    # SuperSuit fault: ProcConcatVec.reset returned each worker's compressed (index, info) pairs.
    from sb3_emmarl.common.mode_aware import ModeObservationWrapper

    in_process = make_vec_env(n_copies=4, seed=3, env_kwargs=SMALL, vec_env_wrapper=ModeObservationWrapper)
    venv = make_vec_env(n_copies=4, seed=3, env_kwargs=SMALL, num_cpus=2, vec_env_wrapper=ModeObservationWrapper,
                        vec_env_type=vec_env_type)
    try:
        multi, expected = venv.reset(), in_process.reset()
        infos = venv.unwrapped.reset_infos
        assert len(infos) == 12 and all(isinstance(info, dict) and "mode" in info for info in infos)
        assert infos == in_process.unwrapped.reset_infos
        np.testing.assert_array_equal(multi, expected)  # the true mode appended, as in one process
    finally:
        venv.close()


def test_bad_arguments_fail_early():
    with pytest.raises(ValueError, match="n_copies must be an int >= 1, got 0"):
        make_vec_env(n_copies=0, env_kwargs=SMALL)
    with pytest.raises(ValueError, match="num_cpus must be an int >= 0"):
        make_vec_env(num_cpus=-1, env_kwargs=SMALL)
    with pytest.raises(ValueError, match="comm_loss must be in"):
        make_vec_env(env_kwargs={"comm_loss": 2.0})
    with pytest.raises(TypeError, match="n_drones"):
        make_vec_env(env_kwargs={"n_drones": 2})


def assert_same(a, b, where="") -> None:
    """Equal values, types and dtypes, recursively (VecMonitor's wall-clock ``episode["t"]`` excepted)."""
    if isinstance(a, dict):
        assert isinstance(b, dict) and set(a) == set(b), (where, set(a) ^ set(b))
        for key in a:
            if not (where.endswith("episode") and key == "t"):
                assert_same(a[key], b[key], f"{where}.{key}")
    elif isinstance(a, (list, tuple)):
        assert type(a) is type(b) and len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            assert_same(x, y, f"{where}[{i}]")
    elif isinstance(a, np.ndarray):
        assert isinstance(b, np.ndarray) and a.dtype == b.dtype and a.shape == b.shape, (where, a.dtype, b.dtype)
        np.testing.assert_array_equal(a, b, err_msg=where)
    else:
        assert type(a) is type(b) and a == b, (where, a, b)


def random_actions(venv, rng):
    if venv.action_space.shape != ():  # continuous
        return rng.uniform(-1.2, 1.2, (venv.num_envs, 3))
    return rng.integers(0, 15, venv.num_envs)


def record(vec_env_type, env_kwargs, steps, n_copies=2, with_state=False, num_cpus=0):
    venv = make_vec_env(n_copies, seed=11, env_kwargs=env_kwargs, vec_env_type=vec_env_type, with_state=with_state,
                        num_cpus=num_cpus)
    rng = np.random.default_rng(5)
    try:
        out = [venv.reset(), venv.unwrapped.reset_infos]
        out.extend(venv.step(random_actions(venv, rng)) for _ in range(steps))
    finally:
        venv.close()
    return out


@pytest.mark.parametrize("env_kwargs,with_state", [
    ({"max_cycles": 120}, True),
    ({"n_uavs": 1, "max_cycles": 90}, False),
    ({"n_uavs": 50, "grid_size": 200, "max_cycles": 150}, False),
    ({"continuous_actions": True, "max_cycles": 100}, True),
    ({"sensor_noise": 0.5, "max_cycles": 110}, False),
    ({"comm_loss": 0.4, "max_cycles": 130}, False),
    ({"adversarial": True, "max_cycles": 100}, True),
    ({"agent_ids": True, "continuous_actions": True, "max_cycles": 100}, False),
    ({"compass": True, "terrain_seed": None, "max_cycles": 100}, False),
], ids=["default", "one-uav", "50-uavs-200x200", "continuous", "sensor-noise", "comm-loss", "adversarial", "agent-ids",
        "compass-new-maps"])
def test_batched_and_supersuit_paths_give_identical_data(env_kwargs, with_state):
    """500 steps of random actions across several episode ends: observations, rewards, dones and every info
    (terminal observations, truncation flags, the mode, the links, the metrics, the state) are identical."""
    batched = record("batched", env_kwargs, 500, with_state=with_state)
    reference = record("supersuit", env_kwargs, 500, with_state=with_state)
    assert sum(int(step[2].any()) for step in reference[2:]) >= 3  # several automatic resets
    assert_same(batched, reference)


def test_batched_path_is_the_default_for_the_reserve():
    assert isinstance(make_vec_env(env_kwargs=SMALL).unwrapped, ReserveVecEnv)
    assert type(make_vec_env(env_kwargs=SMALL, vec_env_type="supersuit").unwrapped) is SharedPolicyVecEnv
    split = make_vec_env(2, env_kwargs=SMALL, num_cpus=2)
    try:
        assert isinstance(split.unwrapped, ReserveVecEnv) and len(split.unwrapped.venv.processes) == 1
    finally:
        split.close()
    with pytest.raises(ValueError, match="vec_env_type must be one of \\['batched', 'supersuit'\\] or None, got 'fast'"):
        make_vec_env(env_kwargs=SMALL, vec_env_type="fast")
    venv = make_vec_env(env_kwargs=SMALL)
    venv.reset()
    with pytest.raises(ValueError, match="discrete actions must be 3 ints in \\[0, 14\\]"):
        venv.step(np.array([0, 1, 15]))


@pytest.mark.parametrize("env_kwargs,with_state,num_cpus", [
    ({"max_cycles": 60}, True, 2),
    ({"continuous_actions": True, "adversarial": True, "max_cycles": 50}, False, 3),
], ids=["default-state-2-processes", "continuous-adversarial-3-processes"])
def test_batched_copies_split_over_processes_give_the_same_data(env_kwargs, with_state, num_cpus):
    """The copies stepped by this process and worker processes at once: the same data as all in this process,
    across automatic resets (each copy draws from its own generators, wherever it lives)."""
    split = record("batched", env_kwargs, 150, n_copies=3, with_state=with_state, num_cpus=num_cpus)
    assert sum(int(step[2].any()) for step in split[2:]) >= 2
    assert_same(split, record("batched", env_kwargs, 150, n_copies=3, with_state=with_state))


def test_a_polled_receive_reads_every_message_rung_or_not():
    import multiprocessing
    import time

    from sb3_emmarl.common.vec_env.workers import _receive_polled

    sender, receiver = multiprocessing.Pipe()
    bell = np.zeros(2, dtype=np.int64)
    sender.send("rung")
    bell[0] += 1
    start = time.perf_counter()
    assert _receive_polled(receiver, bell, 0, 0, 30.0) == "rung"  # the bell ends the polling at once
    assert time.perf_counter() - start < 10.0
    sender.send("unrung")  # no bell: read from the pipe once the polling gives up
    start = time.perf_counter()
    assert _receive_polled(receiver, bell, 0, 1, 0.05) == "unrung"
    assert time.perf_counter() - start >= 0.05
    sender.send("blocking")
    assert _receive_polled(receiver, bell, 0, 1, 0.0) == "blocking"


def test_the_doorbells_count_every_message_and_polling_needs_a_cpu_per_process():
    import os
    import time

    venv = make_vec_env(2, seed=0, env_kwargs=SMALL, num_cpus=2)
    try:
        split = venv.unwrapped.venv

        def settled():  # the worker rings after its reply is sent: wait for the ring of the last reply read
            deadline = time.monotonic() + 10.0
            while split._bells[0, 1] < split._received[0] and time.monotonic() < deadline:
                time.sleep(0.001)
            return split._bells.tolist()

        venv.reset()
        (sent, replied), = settled()
        assert replied == sent + 1 and split._received == [replied]  # every command answered, start-up included
        for _ in range(30):  # across automatic resets (25 steps)
            venv.step(np.zeros(6, dtype=np.int64))
        venv.get_attr("t")
        assert settled() == [[sent + 31, replied + 31]] and split._received == [replied + 31]
        cpus = len(os.sched_getaffinity(0))
        assert split.poll_seconds == (POLL_SECONDS if cpus >= 2 else 0.0)
    finally:
        venv.close()
    blocking = ReserveVecEnv(partial(reserve_v1.parallel_env, **SMALL), n_copies=2, num_cpus=2, poll_seconds=0)
    try:
        assert blocking.venv.poll_seconds == 0.0
        blocking.seed(0)
        blocking.reset()
        blocking.step(np.zeros(6, dtype=np.int64))
    finally:
        blocking.close()
    for bad in (-1.0, float("nan"), float("inf"), "0.1", True):
        with pytest.raises(ValueError, match=f"poll_seconds must be None or a finite number >= 0, got {bad!r}"):
            ReserveVecEnv(partial(reserve_v1.parallel_env, **SMALL), n_copies=2, num_cpus=2, poll_seconds=bad)


def test_the_state_switched_on_reaches_the_worker_processes():
    from sb3_emmarl.common.vec_env import STATE_KEY, require_state

    venv = make_vec_env(3, seed=2, env_kwargs=SMALL, num_cpus=2)
    reference = make_vec_env(3, seed=2, env_kwargs=SMALL, with_state=True)
    try:
        assert require_state(venv, "MAPPO") == reference.unwrapped.state_space
        venv.reset(), reference.reset()
        assert_same(venv.unwrapped.reset_infos, reference.unwrapped.reset_infos)
        actions = np.arange(9) % 15
        infos, expected = venv.step(actions)[3], reference.step(actions)[3]
        assert all(STATE_KEY in info for info in infos)
        assert_same(infos, expected)
    finally:
        venv.close()


def test_get_attr_set_attr_and_env_method_reach_the_copies_in_worker_processes():
    split = make_vec_env(3, seed=5, env_kwargs=SMALL, num_cpus=2)
    local = make_vec_env(3, seed=5, env_kwargs=SMALL)
    try:
        for venv in (split, local):
            venv.reset()
            venv.step(np.arange(9) % 15)
        indices = [8, 0, 4, 7]  # copies 2 (a worker's), 0, 1 (this process's) and 2 again, in the order asked
        assert_same(split.get_attr("uav_pos", indices), local.get_attr("uav_pos", indices))
        assert_same(split.env_method("state", indices=indices), local.env_method("state", indices=indices))
        split.set_attr("max_cycles", 7, indices=[6])
        assert split.get_attr("max_cycles") == [25] * 6 + [7] * 3
        with pytest.raises(AttributeError, match="n_drones"):
            split.get_attr("n_drones", indices=[0, 8])
        with pytest.raises(AttributeError, match="n_drones"):
            split.get_attr("n_drones", indices=[8])  # raised in the worker, which carries on
        split.step(np.zeros(9, dtype=np.int64))
    finally:
        split.close()


def test_a_copy_that_cannot_be_built_in_a_worker_is_reported_and_no_worker_is_left():
    import multiprocessing
    import os

    parent = os.getpid()

    def build():
        if os.getpid() != parent:
            raise ValueError("no reserve in this process")
        return reserve_v1.parallel_env(**SMALL)

    with pytest.raises(RuntimeError, match=r"(?s)reserve copies 1-1 failed.*no reserve in this process"):
        ReserveVecEnv(build, n_copies=2, num_cpus=2)
    assert not [p for p in multiprocessing.active_children() if p.name.startswith("reserve-copies")]


def test_a_checkpoint_of_split_copies_restores_into_any_number_of_processes():
    def play(venv, steps, seed):  # the unwrapped environment: VecMonitor's running returns are not its state
        rng = np.random.default_rng(seed)
        return [venv.unwrapped.step(random_actions(venv, rng)) for _ in range(steps)]

    kwargs = {"n_copies": 3, "seed": 4, "env_kwargs": {**SMALL, "max_cycles": 20}}
    venvs = [make_vec_env(**kwargs, num_cpus=2), make_vec_env(**kwargs), make_vec_env(**kwargs, num_cpus=3)]
    try:
        source = venvs[0]
        source.reset()
        play(source, 30, seed=0)
        state = source.unwrapped.get_state()
        for venv in venvs[1:]:
            venv.reset()
            venv.unwrapped.set_state(state)
        expected = play(source, 30, seed=1)
        for venv in venvs[1:]:
            assert_same(play(venv, 30, seed=1), expected)
        restored = make_vec_env(**{**kwargs, "n_copies": 2}, num_cpus=2)
        try:
            with pytest.raises(ValueError, match="the checkpoint holds 3 reserve copies, this environment 2"):
                restored.unwrapped.set_state(state)
        finally:
            restored.close()
    finally:
        for venv in venvs:
            venv.close()


def test_a_worker_failure_or_death_is_raised_in_the_main_process_and_close_stops_the_workers():
    venv = make_vec_env(3, seed=0, env_kwargs=SMALL, num_cpus=2)
    processes = list(venv.unwrapped.venv.processes)
    venv.reset()
    actions = np.zeros(9, dtype=np.int64)
    actions[-1] = 15  # out of range, for a copy of the worker
    with pytest.raises(RuntimeError, match=r"(?s)worker process of reserve copies 2-2 failed.*discrete actions must be"):
        venv.step(actions)
    venv.close()
    assert not any(process.is_alive() for process in processes)

    venv = make_vec_env(3, seed=0, env_kwargs=SMALL, num_cpus=2)
    try:
        venv.reset()
        venv.unwrapped.venv.processes[0].kill()
        venv.unwrapped.venv.processes[0].join(5)
        with pytest.raises(RuntimeError, match="worker process of reserve copies 2-2 died"):
            venv.step(np.zeros(9, dtype=np.int64))
    finally:
        venv.close()


def test_the_train_speed_benchmark_runs_end_to_end_on_a_tiny_budget(capsys):
    from scripts import load_benchmark

    train_speed = load_benchmark("train_speed")
    assert train_speed.main(["-n", "256", "--rounds", "1", "--algos", "ppo", "--step-agent-steps", "100",
                             "--copies", "1", "3", "--large-teams", "20", "--team-sizes", "2", "--team-n", "512",
                             "--floor-threads", "1", "--floor-turns", "1"]) == 0
    out = capsys.readouterr().out
    assert "outside networks" in out and "zero-cost" in out and "batched" in out and "subproc" in out
    assert "median seconds per turn by phase" in out and any(line.startswith("ppo zero-cost") for line in out.splitlines())
    rows = [line.split() for line in out.splitlines()]
    assert [row[:2] for row in rows if row[:2] in (["1", "10"], ["3", "10"], ["1", "20"])] == \
        [["1", "10"], ["3", "10"], ["1", "20"]]
    split = next(row for row in rows if row[:2] == ["3", "10"])  # subproc and blocking measured at 3 copies
    assert len(split) == 9 and all(float(value.replace(",", "")) > 0 for value in split[2:5])
    assert next(row for row in rows if row[:2] == ["1", "10"])[3:5] == ["nan", "nan"]
    assert any(row[:1] == ["2"] and row[3] == "1.00" for row in rows)  # the zoo run, against itself
    lines = out.splitlines()
    floor = lines[next(i for i, line in enumerate(lines) if "min per 10M" in line) + 1].split()
    rollout = int(re.search(r"one rollout of ([\d,]+) agent-steps", out).group(1).replace(",", ""))
    seconds, per_step, minutes = (float(value) for value in floor[1:])  # one thread: s per rollout, us, minutes
    assert floor[0] == "1" and seconds > 0 and per_step == pytest.approx(seconds / rollout * 1e6, rel=1e-2)
    assert minutes == pytest.approx(per_step * 10_000_000 / 1e6 / 60, rel=1e-2)


def test_the_train_speed_benchmark_rejects_a_bad_thread_count(capsys):
    from scripts import load_benchmark

    with pytest.raises(SystemExit) as exit_info:
        load_benchmark("train_speed").main(["--num-threads", "0"])
    assert exit_info.value.code == 2 and "--num-threads must be >= 1, got 0" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exit_info:
        load_benchmark("train_speed").main(["--step-turns", "0"])
    assert exit_info.value.code == 2 and "--step-turns must be >= 1, got 0" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exit_info:
        load_benchmark("train_speed").main(["--floor-threads", "1", "0"])
    assert exit_info.value.code == 2 and "--floor-threads must be >= 1, got [1, 0]" in capsys.readouterr().err


@pytest.mark.parametrize("algo", ["em_ppo", "mappo", "qmix"])
def test_what_is_built_on_the_vector_environment_gives_the_same_on_both_paths(algo):
    """EM beliefs, MAPPO's state (switched on after construction), QMIX's joint buffer, team evaluation: trained on
    either path from the same seed, the same parameters and the same team metrics."""
    from stable_baselines3.common.utils import set_random_seed

    from sb3_emmarl import EMPPO, MAPPO, QMIX
    from sb3_emmarl.common.evaluation import evaluate_team

    fast = {"em_ppo": (EMPPO, {"n_steps": 16, "batch_size": 48}), "mappo": (MAPPO, {"n_steps": 16, "n_epochs": 1}),
            "qmix": (QMIX, {"learning_starts": 20, "batch_size": 4, "buffer_size": 200})}
    cls, kwargs = fast[algo]
    params, metrics = [], []
    for path in ("batched", "supersuit"):
        set_random_seed(0)
        venv = make_vec_env(2, seed=3, env_kwargs=SMALL, vec_env_type=path)
        model = cls("MlpPolicy", venv, seed=0, **kwargs).learn(96)
        params.append({k: v.clone() for k, v in model.policy.state_dict().items()})
        eval_env = make_vec_env(1, seed=9, env_kwargs=SMALL, vec_env_type=path)
        metrics.append(evaluate_team(model, 2, seed=9, vec_env=eval_env))
    for key, value in params[0].items():
        assert (value == params[1][key]).all(), key
    assert metrics[0] == metrics[1]


def test_the_zero_cost_environment_has_the_reserves_spaces_and_no_render_mode():
    """The training benchmark's reference: the reserve's spaces and entries, and no warning from SB3 about rendering."""
    import warnings

    from scripts import load_benchmark

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        zero = load_benchmark("train_speed").zero_cost_like("ppo", n_copies=2)
    reserve = make_vec_env(2, seed=0)
    assert (zero.num_envs, zero.observation_space, zero.action_space, zero.render_mode) == \
        (reserve.num_envs, reserve.observation_space, reserve.action_space, None)


def test_a_users_parallel_env_without_a_render_mode_attribute_works():
    """PettingZoo does not require ``render_mode``; SuperSuit reads it: an environment without one still vectorises."""
    from gymnasium import spaces
    from pettingzoo.utils.env import ParallelEnv

    class TwoStep(ParallelEnv):
        metadata = {"name": "two_step"}

        def __init__(self, **_):
            self.possible_agents = ["a", "b"]

        def observation_space(self, agent):
            return spaces.Box(-1.0, 1.0, (2,), np.float32)

        def action_space(self, agent):
            return spaces.Discrete(2)

        def reset(self, seed=None, options=None):
            self.agents, self.t = list(self.possible_agents), 0
            return {a: np.zeros(2, np.float32) for a in self.agents}, {a: {} for a in self.agents}

        def step(self, actions):
            self.t += 1
            obs = {a: np.full(2, self.t / 2, np.float32) for a in self.agents}
            done = {a: self.t >= 2 for a in self.agents}
            if self.t >= 2:
                self.agents = []
            return obs, dict.fromkeys(obs, 1.0), done, dict.fromkeys(obs, False), {a: {} for a in obs}

    assert not hasattr(TwoStep(), "render_mode")
    venv = make_vec_env(2, seed=0, env_fn=TwoStep, vec_env_type="supersuit")
    assert venv.reset().shape == (4, 2)
    _, rewards, dones, _ = venv.step(np.zeros(4, dtype=int))
    assert rewards.tolist() == [1.0] * 4 and not dones.any()
    assert venv.step(np.zeros(4, dtype=int))[2].all()
    venv.close()
