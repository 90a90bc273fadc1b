"""A full disk or an unwritable path ends a command with one line naming it, keeps the previous checkpoint whole and
leaves no partial file (issue 65, item 3); ENOSPC is injected where the checkpoints flush to disk."""

import errno
import os

import torch as th

from sb3_emmarl import cli
from sb3_emmarl.common import checkpoints
from sb3_emmarl.common.checkpoints import check_checkpoint, list_checkpoints
from sb3_emmarl.zoo.cli import train_main

ENV = "WildlifeReserve-v1"
RUN = ["--algo", "ppo", "--env-kwargs", "n_uavs:2", "grid_size:20", "max_cycles:40", "--eval-freq", "-1",
       "--team-eval-episodes", "0", "--verbose", "0", "--seed", "1"]


def test_a_full_disk_mid_training_keeps_the_last_checkpoint_and_the_run_resumes(tmp_path, monkeypatch, capsys):
    th.set_num_threads(1)
    real_fsync, run = os.fsync, tmp_path / "ppo" / f"{ENV}_1"

    def fsync(fd):
        if (run / "rl_model_1024_steps.zip").exists():  # the first checkpoint is whole; then the disk is full
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        real_fsync(fd)

    monkeypatch.setattr(checkpoints.os, "fsync", fsync)
    assert train_main([*RUN, "-n", "3000", "--save-freq", "500", "-f", str(tmp_path)]) == 1
    err = capsys.readouterr().err
    assert "training stopped at step" in err and "No space left on device" in err and "--resume" in err
    assert [steps for steps, _ in list_checkpoints(run)] == [1024]
    check_checkpoint(run / "rl_model_1024_steps.zip")
    assert not list(run.rglob(".*.tmp")) and not (run / f"{ENV}.zip").exists()
    monkeypatch.setattr(checkpoints.os, "fsync", real_fsync)  # space again
    assert train_main(["--algo", "ppo", "--resume", str(run), "--verbose", "0"]) == 0
    assert (run / f"{ENV}.zip").is_file()


def _full_disk(argv):
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), "logs/run/model.zip")


def _read_only(argv):
    raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), "/read-only/patrol.gif")


def test_a_command_that_cannot_write_says_so_in_one_line(monkeypatch, capsys):
    for function, expected in (("_full_disk", "logs/run/model.zip: No space left on device"),
                               ("_read_only", "/read-only/patrol.gif: Permission denied")):
        monkeypatch.setitem(cli.COMMANDS, "plot", cli.Command(f"{__name__}:{function}", ""))
        assert cli.main(["plot"]) == 1
        err = capsys.readouterr().err.strip()
        assert err == f"emmarl plot: error: {expected}", err
