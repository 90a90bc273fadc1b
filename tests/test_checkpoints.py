"""Atomic files, checked loading, and training that resumes from a checkpoint exactly as if it had not stopped."""

import io
import pickle
import zipfile

import numpy as np
import pytest
import torch as th
from stable_baselines3 import A2C, PPO
from stable_baselines3.common.utils import set_random_seed

from sb3_emmarl import EMPPO, MessagePPO
from sb3_emmarl.common.checkpoints import (
    TRAINING_STATE,
    ResumableCheckpointCallback,
    companion,
    list_checkpoints,
)
from sb3_emmarl.common.model_files import check_model_file, check_saved_algorithm, load_model
from sb3_emmarl.common.training_state import load_training_state, restore_training_state
from sb3_emmarl.common.trust.atomic_files import save_model, write_atomic, write_text
from sb3_emmarl.common.trust.pickling import dumps, rebuild_view
from sb3_emmarl.common.trust.safe_pickle import ENV_STATE_MODULES, loads
from sb3_emmarl.common.vec_env import FiniteCheck, make_vec_env
from sb3_emmarl.zoo.algos import ZOO_ALGOS

TINY = {"n_uavs": 2, "grid_size": 20, "max_cycles": 50}


def build(algo, seed=3, num_cpus=0, **kwargs):
    set_random_seed(seed)
    env = make_vec_env(2, seed=seed, env_kwargs=TINY, num_cpus=num_cpus)
    return algo("MlpPolicy", env, n_steps=32, batch_size=64, seed=seed, **kwargs)


def test_a_failed_write_keeps_the_previous_file(tmp_path):
    path = tmp_path / "file.txt"
    write_text(path, "complete")

    def crash(file):
        file.write(b"half")
        raise KeyboardInterrupt  # a kill in the middle of writing

    with pytest.raises(KeyboardInterrupt):
        write_atomic(path, crash)
    assert path.read_text() == "complete"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file.txt"]


def test_truncated_or_foreign_zips_are_refused_with_the_file_named(tmp_path):
    model = build(PPO)
    path = save_model(model, tmp_path / "model")
    assert path.name == "model.zip" and check_model_file(path) == path
    truncated = tmp_path / "truncated.zip"
    truncated.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    with pytest.raises(ValueError, match=r"truncated\.zip is incomplete or corrupt"):
        check_model_file(truncated)
    with pytest.raises(ValueError, match=r"truncated\.zip is incomplete or corrupt"):
        load_model(PPO, truncated)
    other = tmp_path / "other.zip"
    with zipfile.ZipFile(other, "w") as archive:
        archive.writestr("readme.txt", "not a model")
    with pytest.raises(ValueError, match="is not a Stable-Baselines3 model"):
        check_model_file(other)
    with pytest.raises(ValueError, match="no model file"):
        check_model_file(tmp_path / "missing.zip")
    with pytest.raises(ValueError, match=r"state\.pkl is not a readable pickle"):
        (tmp_path / "state.pkl").write_bytes(pickle.dumps({"a": np.zeros(100)})[:50])
        load_training_state(tmp_path / "state.pkl")
    with pytest.raises(ValueError, match=r"state\.pkl is not a training state"):
        (tmp_path / "state.pkl").write_bytes(pickle.dumps({"a": np.zeros(100)}))
        load_training_state(tmp_path / "state.pkl")


def test_a_zip_of_another_algorithm_is_refused(tmp_path):
    ppo = save_model(build(PPO), tmp_path / "ppo")
    em = save_model(build(EMPPO), tmp_path / "em")
    check_saved_algorithm(ppo, PPO, ZOO_ALGOS)
    check_saved_algorithm(em, EMPPO, ZOO_ALGOS)
    with pytest.raises(ValueError, match="was not saved by A2C: its settings fit"):
        check_saved_algorithm(ppo, A2C, ZOO_ALGOS)
    with pytest.raises(ValueError, match="was not saved by EMPPO"):
        check_saved_algorithm(ppo, EMPPO, ZOO_ALGOS)
    with pytest.raises(ValueError, match="was not saved by PPO"):
        load_model(PPO, em, candidates=ZOO_ALGOS)


def test_pickled_views_stay_views():
    base = np.zeros((2, 3, 4))
    holder = {"base": base, "first": base[0], "flat": base.reshape(-1)}
    copy = holder
    for round_trip in range(3):  # a checkpoint of a resumed run pickles unpickled arrays (they own bytes buffers)
        copy = pickle.loads(dumps(copy))
        copy["first"][1, 2] = 5.0 + round_trip
        copy["flat"][0] = 7.0 + round_trip
        assert copy["base"][0, 1, 2] == 5.0 + round_trip and copy["base"][0, 0, 0] == 7.0 + round_trip


def test_views_pickled_before_the_pickling_module_still_load(monkeypatch):
    """Checkpoints of 0.20 rebuilt their numpy views with sb3_emmarl.common.checkpoints._view (since removed): the
    training-state loader still reads them, as data."""
    import sb3_emmarl.common.checkpoints as checkpoints

    def _view(*args):
        return rebuild_view(*args)

    _view.__module__, _view.__qualname__ = checkpoints.__name__, "_view"
    monkeypatch.setattr(checkpoints, "_view", _view, raising=False)

    class OldPickler(pickle.Pickler):  # (what checkpoints.py's pickler wrote, protocol 5)
        def reducer_override(self, obj):
            if type(obj) is np.ndarray and obj.base is not None:
                return _view, (obj.base, obj.__array_interface__["data"][0] - obj.base.__array_interface__["data"][0],
                               obj.shape, obj.strides, obj.dtype, True)
            return NotImplemented

    base = np.arange(12.0).reshape(3, 4)
    buffer = io.BytesIO()
    OldPickler(buffer, protocol=pickle.HIGHEST_PROTOCOL).dump(base.reshape(-1)[4:8])
    old = buffer.getvalue()
    assert b"sb3_emmarl.common.checkpoints" in old and b"_view" in old
    monkeypatch.delattr(checkpoints, "_view")
    view = loads(old, "an old checkpoint", class_modules=ENV_STATE_MODULES)  # (how training states are read)
    assert np.array_equal(view, [4.0, 5.0, 6.0, 7.0]) and view.base is not None


@pytest.mark.parametrize("algo,num_cpus", [(PPO, 0), (EMPPO, 0), (MessagePPO, 0), (PPO, 2)],
                         ids=["PPO", "EMPPO", "MessagePPO", "PPO-worker-process"])
def test_a_resumed_run_equals_the_uninterrupted_run(tmp_path, algo, num_cpus):
    """Checkpoints hold the model, the random generators and the reserves mid-episode: continuing from one gives
    exactly the parameters of the run that never stopped (EM-PPO: with its E-step's optimizer, counters and data;
    MessagePPO: with the links its message wrapper keeps; a run whose reserves were split over a worker process
    resumes in one process)."""
    th.set_num_threads(1)
    kwargs = {"latent_kwargs": {"e_step_interval": 1}} if algo is EMPPO else {}
    total = 32 * 4 * 5
    model = build(algo, num_cpus=num_cpus, **kwargs)
    model.learn(total, callback=ResumableCheckpointCallback(32, str(tmp_path / "a")))
    model.get_env().close()
    reference = {k: v.clone() for k, v in model.policy.state_dict().items()}
    steps, path = list_checkpoints(tmp_path / "a")[1]
    assert steps == 256 and companion(path, TRAINING_STATE).is_file()
    set_random_seed(99)  # whatever the new process's generators hold
    resumed = algo.load(path, env=make_vec_env(2, seed=0, env_kwargs=TINY), force_reset=False)
    if algo is EMPPO:
        assert resumed.e_step.n_updates == 2 and len(resumed.e_step.memory) == 2
    restore_training_state(resumed, load_training_state(companion(path, TRAINING_STATE)))
    resumed.learn(total - resumed.num_timesteps, reset_num_timesteps=False)
    assert resumed.num_timesteps == total
    for key, value in resumed.policy.state_dict().items():
        assert th.equal(value, reference[key]), key


def test_em_save_load_keeps_the_e_step_state(tmp_path):
    model = build(EMPPO, latent_kwargs=dict(e_step_interval=1))
    model.learn(32 * 4 * 2)
    # No E-step gradient is left on the latent model (PPO's gradient clipping runs over all the policy's parameters).
    assert all(p.grad is None for p in model.policy.latent_model.parameters())
    path = save_model(model, tmp_path / "em")
    loaded = EMPPO.load(path, device="cpu")
    assert loaded.e_step.n_updates == model.e_step.n_updates == 2
    assert loaded._n_rollouts == 2 and np.array_equal(loaded._episode_counters, model._episode_counters)
    assert th.equal(loaded.e_step.generator.get_state(), model.e_step.generator.get_state())
    for a, b in zip(loaded.e_step.memory, model.e_step.memory):
        assert th.equal(a.features, b.features) and th.equal(a.episodes, b.episodes)
    assert model.e_step.count_table and loaded.e_step.count_table.keys() == model.e_step.count_table.keys()
    assert all(th.equal(loaded.e_step.count_table[k], v) for k, v in model.e_step.count_table.items())
    saved, fresh = loaded.e_step.optimizer.state_dict()["state"], model.e_step.optimizer.state_dict()["state"]
    assert saved.keys() == fresh.keys() and all(th.equal(saved[k]["exp_avg"], fresh[k]["exp_avg"]) for k in saved)



def test_the_e_step_state_is_saved_with_torch_not_in_the_json_data(tmp_path):
    model = build(EMPPO, latent_kwargs=dict(e_step_interval=1))
    model.learn(32 * 4 * 2)
    path = save_model(model, tmp_path / "em")
    with zipfile.ZipFile(path) as archive:
        assert "e_step.pth" in archive.namelist()
        assert "_e_step_state" not in archive.read("data").decode()


def test_a_model_saved_with_the_e_step_state_in_its_data_still_loads(tmp_path, monkeypatch):
    """Archives written before 0.17.0 keep the E-step's state among the pickled data, not as ``e_step.pth``."""
    model = build(EMPPO, latent_kwargs=dict(e_step_interval=1))
    model.learn(32 * 4 * 2)
    model._e_step_state = model.e_step.state_dict()
    monkeypatch.setattr(EMPPO, "_get_torch_save_params", PPO._get_torch_save_params)
    path = save_model(model, tmp_path / "old")
    monkeypatch.undo()
    del model._e_step_state
    with zipfile.ZipFile(path) as archive:
        assert "e_step.pth" not in archive.namelist() and "_e_step_state" in archive.read("data").decode()
    loaded = EMPPO.load(path, device="cpu")
    assert loaded.e_step.n_updates == model.e_step.n_updates == 2 and not hasattr(loaded, "_e_step_state")
    for a, b in zip(loaded.e_step.memory, model.e_step.memory, strict=True):
        assert th.equal(a.features, b.features)
    loaded.set_parameters(path, device="cpu")  # a path too, not only the dict load() passes

def test_finite_check_names_the_quantity_and_the_step():
    env = FiniteCheck(make_vec_env(1, seed=0, env_kwargs=TINY))
    env.reset()
    actions = np.zeros(2, dtype=np.int64)
    env.step(actions)
    inner = env.venv

    def step_wait():
        observations, rewards, dones, infos = inner.__class__.step_wait(inner)
        rewards[1] = np.nan
        return observations, rewards, dones, infos

    inner.step_wait = step_wait
    with pytest.raises(ValueError, match=r"non-finite rewards \(nan\) at step 2 of the vector environment, "
                                         r"entries \[1\]; they come from the environment"):
        env.step(actions)
    with pytest.raises(ValueError, match=r"non-finite actions \(inf\).*the policy"):
        FiniteCheck(make_vec_env(1, seed=0, env_kwargs={**TINY, "continuous_actions": True})).step_async(
            np.full((2, 3), np.inf, dtype=np.float32))


def test_eval_callback_files_are_atomic(tmp_path):
    from sb3_emmarl.common.callbacks import AtomicEvalCallback

    model = build(PPO)
    callback = AtomicEvalCallback(make_vec_env(1, seed=9, env_kwargs=TINY), n_eval_episodes=1, eval_freq=32,
                                  log_path=str(tmp_path), best_model_save_path=str(tmp_path), deterministic=False)
    model.learn(32 * 4 * 2, callback=callback)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["best_model.zip", "evaluations.npz"]
    assert len(np.load(tmp_path / "evaluations.npz")["timesteps"]) == 2
    check_model_file(tmp_path / "best_model.zip")
