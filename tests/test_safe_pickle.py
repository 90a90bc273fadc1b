"""Pickles read as data only (issue 65, item 1): the gadgets that an allow-list of names lets through (functions that
call or deserialise what they are given, data types that allocate what an argument asks for, state set on a class)
are refused in one line before anything runs or is allocated, and what SB3 and numpy write reads back equal."""

import collections
import io
import pickle
import shutil
import struct
import zipfile

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from fuzz_zoo import Call, Touch, plant, write_data
from stable_baselines3 import PPO

from sb3_emmarl.common.model_files import check_model_file, load_model
from sb3_emmarl.common.trust.safe_pickle import MAX_BYTES, loads
from sb3_emmarl.common.trust.safe_zip import MAX_MEMBER_BYTES, safe_data_objects


def _torch_payload(marker) -> bytes:
    buffer = io.BytesIO()
    th.save(Touch(marker), buffer)
    return buffer.getvalue()


def _gadgets(marker):
    """(name, pickle) of each gadget family tried: torch, numpy, copyreg, builtins, the opcodes themselves."""
    import copyreg

    from numpy.random._pickle import __bit_generator_ctor, __generator_ctor, __randomstate_ctor
    from stable_baselines3.common.buffers import ReplayBuffer
    from stable_baselines3.common.utils import FloatSchedule
    from torch.storage import _load_from_bytes

    box = gym.spaces.Box(-1, 1, (2,))
    found = {
        "torch _load_from_bytes running a pickle": pickle.dumps(Call(_load_from_bytes, _torch_payload(marker))),
        "numpy __generator_ctor calling bytearray": pickle.dumps(Call(__generator_ctor, 10 ** 11, bytearray)),
        "numpy __randomstate_ctor calling a buffer": pickle.dumps(Call(__randomstate_ctor, 10 ** 9, ReplayBuffer)),
        "numpy __bit_generator_ctor building any class": pickle.dumps(Call(__bit_generator_ctor, ReplayBuffer)),
        "copyreg _reconstructor with a bytearray base": pickle.dumps(
            Call(copyreg._reconstructor, FloatSchedule, bytearray, 10 ** 11)),
        "bytearray of 10**11": pickle.dumps(Call(bytearray, 10 ** 11)),
        "list of range(10**10)": pickle.dumps(Call(list, range(10 ** 10))),
        "a policy-kind class called": pickle.dumps(Call(ReplayBuffer, 10 ** 12, box, box)),
        "numpy _reconstruct of 10**12 items": pickle.dumps(
            Call(np._core.multiarray._reconstruct, np.ndarray, (10 ** 6, 10 ** 6), b"b")),
        # BYTEARRAY8 declaring 100 GB, followed by nothing
        "BYTEARRAY8 of 100 GB": b"\x80\x05\x96" + struct.pack("<Q", 10 ** 11) + b".",
        # INST (protocol 0): builtins.bytearray called with 10**11
        "INST calling bytearray": b"(I100000000000\nibuiltins\nbytearray\n.",
        # BUILD on a class: setattr(FloatSchedule, "__call__", None) for the whole process
        "BUILD on a class": (b"\x80\x02cstable_baselines3.common.utils\nFloatSchedule\nN}X\x08\x00\x00\x00__call__N"
                             b"s\x86b."),
        # BUILD on a function the pickle may call (its defaults rewritten for the whole process), object named too
        "BUILD on a function": (b"\x80\x02cbuiltins\nobject\n0cnumpy._core.numeric\n_frombuffer\n"
                                b"N}X\x0c\x00\x00\x00__defaults__)s\x86b."),
    }
    return found


def test_every_gadget_is_refused_in_one_line_before_it_runs(tmp_path):
    marker = tmp_path / "marker"
    for name, blob in _gadgets(marker).items():
        with pytest.raises(ValueError) as error:
            loads(blob, f"entry {name!r}")
        message = str(error.value)
        assert "\n" not in message and message.startswith(f"entry {name!r}"), (name, message)
    assert not marker.exists()
    from stable_baselines3.common.utils import FloatSchedule

    assert "__call__" in FloatSchedule.__dict__  # the BUILD gadget left the class alone


def test_what_sb3_and_numpy_write_reads_back_equal():
    generator = np.random.default_rng(3)
    generator.random(5)
    space = gym.spaces.Box(-1.0, 2.0, (3, 2), seed=7)
    values = {
        "space": space, "dict space": gym.spaces.Dict({"a": gym.spaces.Discrete(3), "b": space}),
        "arrays": [np.arange(6, dtype=np.float32).reshape(2, 3), np.array(["a", "bc"]), np.float64(2.5)],
        "generator": generator, "random state": np.random.RandomState(4), "deque": collections.deque([1, 2], 5),
        "ordered": collections.OrderedDict(a=1), "tensor": th.arange(4.0), "mixed": {1: (2, {3}, frozenset({4}))},
    }
    for name, value in values.items():
        back = loads(pickle.dumps(value, protocol=5), name)
        if name == "generator":
            assert back.random() == generator.random()
        elif name == "random state":
            assert back.randint(1000) == value.randint(1000)
        elif name == "tensor":
            assert th.equal(back, value)
        elif name == "arrays":
            assert all(np.array_equal(a, b) for a, b in zip(back, value))
        else:
            assert back == value, name
    assert loads(pickle.dumps(space), "space").sample() is not None


def _zip_with(source, target, entry=None, blob=None, data_text=None):
    """A copy of the zip ``source`` whose ``data`` entry ``entry`` is ``blob``, or whose ``data`` is ``data_text``."""
    shutil.copyfile(source, target)
    if data_text is None:
        plant(target, entry, blob)
    else:
        write_data(target, data_text)
    return target


@pytest.fixture(scope="module")
def model_zip(tmp_path_factory):
    path = tmp_path_factory.mktemp("model") / "ppo.zip"
    PPO("MlpPolicy", "CartPole-v1", n_steps=32, batch_size=32, seed=0).save(path)
    return path


def test_a_model_zip_with_a_gadget_is_refused_by_every_loader(model_zip, tmp_path):
    marker = tmp_path / "marker"
    blob = _gadgets(marker)["torch _load_from_bytes running a pickle"]
    hostile = _zip_with(model_zip, tmp_path / "hostile.zip", "lr_schedule", blob)
    for load in (check_model_file, safe_data_objects, lambda path: load_model(PPO, path, device="cpu")):
        with pytest.raises(ValueError, match="lr_schedule"):
            load(hostile)
    assert not marker.exists()
    model = load_model(PPO, model_zip, device="cpu")  # the untouched zip loads, its data equal to SB3's own reading
    assert model.observation_space == PPO.load(model_zip, device="cpu").observation_space


def test_zip_bombs_are_refused_before_they_are_read(model_zip, tmp_path):
    deep = _zip_with(model_zip, tmp_path / "deep.zip", None, data_text="[" * 200_000 + "]" * 200_000)
    with pytest.raises(ValueError, match=r"deep\.zip is not a readable model zip"):
        check_model_file(deep)
    large = tmp_path / "large.zip"
    large.write_bytes(model_zip.read_bytes())
    content = bytearray(large.read_bytes())
    end = content.rfind(b"PK\x05\x06")  # the end record holds where the central directory starts
    at = struct.unpack("<I", content[end + 16:end + 20])[0]  # the first member's record: its uncompressed size
    content[at + 24:at + 28] = struct.pack("<I", MAX_MEMBER_BYTES + 1)
    large.write_bytes(bytes(content))
    with pytest.raises(ValueError, match=r"is \d+ bytes uncompressed"):
        check_model_file(large)
    assert MAX_BYTES < MAX_MEMBER_BYTES * 2


def test_run_folder_pickles_read_as_data(tmp_path):
    from stable_baselines3 import DQN
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import VecNormalize

    from sb3_emmarl.common.trust.atomic_files import save_pickle
    from sb3_emmarl.common.trust.safe_pickle import load_data_pickle, load_vec_normalize

    venv = VecNormalize(make_vec_env("CartPole-v1", 2, seed=0))
    venv.reset()
    for _ in range(5):
        venv.step(np.array([0, 1]))
    save_pickle(tmp_path / "vecnormalize.pkl", venv)
    loaded = load_vec_normalize(tmp_path / "vecnormalize.pkl", make_vec_env("CartPole-v1", 2, seed=0))
    for name in ("mean", "var", "count"):
        assert np.array_equal(getattr(loaded.obs_rms, name), getattr(venv.obs_rms, name))
        assert np.array_equal(getattr(loaded.ret_rms, name), getattr(venv.ret_rms, name))
    model = DQN("MlpPolicy", "CartPole-v1", learning_starts=10, buffer_size=500, seed=0)
    model.learn(60)
    save_pickle(tmp_path / "replay_buffer.pkl", model.replay_buffer)
    buffer = load_data_pickle(tmp_path / "replay_buffer.pkl")
    assert buffer.size() == model.replay_buffer.size() and np.array_equal(buffer.observations,
                                                                          model.replay_buffer.observations)
    marker = tmp_path / "marker"
    (tmp_path / "hostile.pkl").write_bytes(pickle.dumps(Touch(marker)))
    for load in (load_data_pickle, lambda path: load_vec_normalize(path, None)):
        with pytest.raises(ValueError, match=r"hostile\.pkl: refusing to load: it names (posix|os)\.system"):
            load(tmp_path / "hostile.pkl")
    (tmp_path / "other.pkl").write_bytes(pickle.dumps({"mean": 1}))
    with pytest.raises(ValueError, match="does not hold VecNormalize statistics"):
        load_vec_normalize(tmp_path / "other.pkl", None)
    with pytest.raises(ValueError, match="is not a regular file"):
        load_data_pickle(tmp_path)
    assert not marker.exists()


def test_weights_that_are_not_the_models_are_refused_in_one_line(model_zip, tmp_path):
    other = tmp_path / "other.zip"
    PPO("MlpPolicy", "CartPole-v1", policy_kwargs={"net_arch": [7]}).save(other)
    for name, weights in (("foreign", zipfile.ZipFile(other).read("policy.pth")), ("garbage", b"not torch")):
        with zipfile.ZipFile(model_zip) as source, zipfile.ZipFile(tmp_path / f"{name}.zip", "w") as target:
            for member in source.namelist():
                target.writestr(member, weights if member == "policy.pth" else source.read(member))
        with pytest.raises(ValueError, match=rf"{name}\.zip does not load into PPO \(its weights") as error:
            load_model(PPO, tmp_path / f"{name}.zip", device="cpu")
        assert "\n" not in str(error.value)


def test_training_states_read_as_the_environments_data(tmp_path):
    """A training state holds the reserve copies mid-episode: read back as data (instances of the environments'
    classes only, :data:`ENV_STATE_MODULES`) they continue exactly; a function of those modules, a class outside them,
    or copies of another kind are refused in one line."""
    from stable_baselines3.common.logger import Logger

    from sb3_emmarl.common.training_state import load_training_state
    from sb3_emmarl.common.trust.atomic_files import save_pickle
    from sb3_emmarl.common.trust.safe_pickle import ENV_STATE_MODULES
    from sb3_emmarl.common.vec_env import make_vec_env

    kwargs = {"n_uavs": 2, "grid_size": 20, "max_cycles": 40}
    venv, twin = (make_vec_env(2, seed=3, env_kwargs=kwargs) for _ in range(2))
    venv.reset()
    actions = np.random.default_rng(0).integers(0, venv.action_space.n, size=(7, venv.num_envs))
    for step in actions[:4]:
        venv.step(step)
    save_pickle(tmp_path / "state.pkl", {"num_timesteps": 4, "torch_rng": th.get_rng_state(),
                                         "numpy_rng": np.random.get_state(), "python_rng": (3, (1, 2), None),
                                         "env": [venv.get_state()]})
    state = load_training_state(tmp_path / "state.pkl")
    twin.reset()
    twin.set_state(state["env"][0])
    for step in actions[4:]:
        assert all(np.array_equal(a, b) for a, b in zip(venv.step(step)[:3], twin.step(step)[:3]))
    marker = tmp_path / "marker"
    logger = Logger.__new__(Logger)
    logger.__dict__.update(dir=str(marker), output_formats=[])
    refused = {"it names sb3_emmarl.common.vec_env.make_vec_env, which is not a class": Call(make_vec_env,
                                                                                           Touch(marker)),
               "it names stable_baselines3.common.logger.Logger": {"venv": logger},
               "it names (posix|os).system": Touch(marker)}
    for message, obj in refused.items():
        with pytest.raises(ValueError, match=f"copies: refusing to load: {message}"):
            twin.set_state(pickle.dumps(obj))
        with pytest.raises(ValueError, match=message):
            loads(pickle.dumps(obj), "state", class_modules=ENV_STATE_MODULES)
    with pytest.raises(ValueError, match="holds dict copies, this environment SteppedCopies"):
        twin.set_state(pickle.dumps({"venv": {}, "copy_seeds": [], "never_reset": [], "reset_infos": []}))
    assert not marker.exists()


def test_a_class_read_under_the_name_it_had_before_it_moved():
    from sb3_emmarl.common.appended.extractor import SplitFeaturesExtractor

    # a protocol-2 GLOBAL opcode naming the class where model zips of 0.22.0 name it
    old = pickle.dumps(SplitFeaturesExtractor, protocol=2).replace(
        b"sb3_emmarl.common.appended.extractor", b"sb3_emmarl.common.extractors")
    assert b"sb3_emmarl.common.extractors\nSplitFeaturesExtractor" in old
    assert loads(old, "an old model") is SplitFeaturesExtractor
