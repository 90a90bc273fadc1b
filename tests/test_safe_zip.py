"""Model zips are checked before anything in them is unpickled (issue 52, item 3): every zip the zoo writes loads, a zip
whose pickles name a foreign global is refused with one line naming the entry and the global, before it runs."""

import os
import pickle
import shutil

import pytest
import torch as th
from fuzz_zoo import Touch, plant

from sb3_emmarl.common.checkpoints import list_checkpoints
from sb3_emmarl.common.model_files import load_model
from sb3_emmarl.common.trust.safe_zip import allowed_global, check_zip_pickles, pickle_globals
from sb3_emmarl.zoo.algos import ZOO_ALGOS
from sb3_emmarl.zoo.cli import enjoy_main, train_main

ENV = "WildlifeReserve-v1"
TINY = ["--env-kwargs", "n_uavs:2", "grid_size:20", "max_cycles:40"]
QUIET = ["--eval-freq", "-1", "--team-eval-episodes", "0", "--verbose", "0", "--seed", "0"]
ON_POLICY = ("ppo", "em_ppo", "oracle_ppo", "mappo", "ppo_gat", "ppo_transformer", "ppo_lstm", "cppo")


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """A tiny finished run of every zoo algorithm (with checkpoints)."""
    folder = tmp_path_factory.mktemp("zips")
    th.set_num_threads(1)
    for algo in sorted(ZOO_ALGOS):
        params = (["n_steps:16", "batch_size:32"] if algo in ON_POLICY else ["n_steps:4"] if algo == "a2c" else
                  ["learning_starts:8", "batch_size:8"])
        if algo == "mappo":
            params = ["n_steps:16"]
        assert train_main(["--algo", algo, "-n", "200", *TINY, *QUIET, "--save-freq", "64", "-f", str(folder),
                           "-params", *params]) == 0, algo
    return folder


def test_every_zip_the_zoo_writes_passes_the_check_and_loads(runs):
    for algo in sorted(ZOO_ALGOS):
        run = runs / algo / f"{ENV}_1"
        zips = [run / f"{ENV}.zip", *(path for _, path in list_checkpoints(run))]
        assert len(zips) >= 2, algo
        for path in zips:
            check_zip_pickles(path)
            load_model(ZOO_ALGOS[algo], path, candidates=ZOO_ALGOS, device="cpu")


def _tampered(source, target, entry, obj):
    """A copy of the zip ``source`` whose ``data`` entry ``entry`` is the pickle of ``obj``."""
    shutil.copyfile(source, target)
    plant(target, entry, pickle.dumps(obj))
    return target


def test_a_zip_with_a_foreign_global_is_refused_before_it_runs(runs, tmp_path, capsys):
    marker = tmp_path / "marker"
    run = runs / "ppo" / f"{ENV}_1"
    hostile = _tampered(run / f"{ENV}.zip", tmp_path / "hostile.zip", "lr_schedule", Touch(marker))
    with pytest.raises(ValueError, match=r"entry 'lr_schedule' names (posix|os)\.system"):
        check_zip_pickles(hostile)
    # -i: refused in one line before training (before the change, the algorithm check unpickled it: the marker)
    with pytest.raises(SystemExit) as exit_info:
        train_main(["--algo", "ppo", "-n", "64", *TINY, *QUIET, "-f", str(tmp_path / "logs"), "-i", str(hostile)])
    err = capsys.readouterr().err.strip()
    assert exit_info.value.code == 2 and len(err.splitlines()) == 1 and "system" in err and not marker.exists(), err
    # enjoy: the run's own model replaced by the hostile zip
    played = tmp_path / "played" / "ppo" / f"{ENV}_1"
    played.mkdir(parents=True)
    (played / ENV).mkdir()
    (played / ENV / "config.yml").write_text((run / ENV / "config.yml").read_text())
    (played / f"{ENV}.zip").write_bytes(hostile.read_bytes())
    assert enjoy_main(["--algo", "ppo", "-f", str(tmp_path / "played"), "--episodes", "1", "--no-record"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "lr_schedule" in err and not marker.exists(), err


def test_the_allow_list_refuses_what_writes_or_runs():
    for module, name in (("os", "system"), ("posix", "system"), ("builtins", "eval"), ("builtins", "getattr"),
                         ("torch", "save"), ("numpy", "save"), ("stable_baselines3.common.logger", "CSVOutputFormat"),
                         ("stable_baselines3.common.save_util", "save_to_zip_file"), ("sb3_emmarl.zoo.cli", "train_main"),
                         ("cloudpickle.cloudpickle", "_make_function"), ("subprocess", "Popen"), ("?", "?")):
        assert not allowed_global(module, name), (module, name)
    for module, name in (("gymnasium.spaces.box", "Box"), ("numpy", "dtype"), ("torch.nn.modules.activation", "ReLU"),
                         ("stable_baselines3.common.utils", "FloatSchedule"),
                         ("sb3_emmarl.common.latent.policies", "LatentActorCriticPolicy")):
        assert allowed_global(module, name), (module, name)
    # Globals by STACK_GLOBAL (protocol 4, names through the memo) and by GLOBAL (protocol 0) are both found.
    assert ("posix", "system") in pickle_globals(pickle.dumps([os.system, os.system], protocol=4))
    assert ("posix", "system") in pickle_globals(pickle.dumps(os.system, protocol=0))
