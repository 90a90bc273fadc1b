"""A full disk or an unwritable path ends a command with one line naming it, keeps the previous checkpoint whole and
leaves no partial file (issue 65, item 3); ENOSPC is injected where the checkpoints flush to disk."""

import errno
import os

import torch as th

from sb3_emmarl import cli
from sb3_emmarl.common.checkpoints import check_checkpoint, list_checkpoints
from sb3_emmarl.common.trust import atomic_files
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

    monkeypatch.setattr(atomic_files.os, "fsync", fsync)
    assert train_main([*RUN, "-n", "3000", "--save-freq", "500", "-f", str(tmp_path)]) == 1
    err = capsys.readouterr().err
    assert "training stopped at step" in err and "rl_model_training_state_2048_steps.pkl: No space left on device" in err
    assert "--resume" in err
    assert [steps for steps, _ in list_checkpoints(run)] == [1024]
    check_checkpoint(run / "rl_model_1024_steps.zip")
    assert not list(run.rglob(".*.tmp")) and not (run / f"{ENV}.zip").exists()
    monkeypatch.setattr(atomic_files.os, "fsync", real_fsync)  # space again
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


def test_a_checkpoint_whose_zip_cannot_be_written_leaves_no_companion(tmp_path, monkeypatch, capsys):
    th.set_num_threads(1)
    real_fsync, run = os.fsync, tmp_path / "ppo" / f"{ENV}_1"

    def fsync(fd):
        if "rl_model_2048_steps.zip" in os.readlink(f"/proc/self/fd/{fd}"):  # the step's training state is written
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        real_fsync(fd)

    monkeypatch.setattr(atomic_files.os, "fsync", fsync)
    assert train_main([*RUN, "-n", "3000", "--save-freq", "500", "-f", str(tmp_path)]) == 1
    assert "rl_model_2048_steps.zip: No space left on device" in capsys.readouterr().err
    assert sorted(path.name for path in run.glob("rl_model_*")) == ["rl_model_1024_steps.zip",
                                                                    "rl_model_training_state_1024_steps.pkl"]


def test_a_full_disk_under_tensorboard_ends_training_in_one_line(tmp_path, monkeypatch, capsys):
    """Tensorboard writes from a thread of its own, which hands the error to the training thread: the line names
    where the logs go (the thread's own traceback: the next test)."""
    from tensorboard.summary.writer.record_writer import RecordWriter

    th.set_num_threads(1)
    writes = []

    def write(self, data):
        writes.append(len(data))
        if len(writes) > 3:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(RecordWriter, "write", write)
    assert train_main([*RUN, "-n", "6000", "--save-freq", "500", "-f", str(tmp_path / "logs"),
                       "-tb", str(tmp_path / "tb")]) == 1
    err = capsys.readouterr().err
    assert "Traceback" not in err and "Exception in thread" not in err, err
    assert f"No space left on device (writing the logs under {tmp_path / 'tb'} or" in err, err


def test_only_the_tensorboard_writers_failure_goes_unprinted(monkeypatch):
    import threading

    from sb3_emmarl.zoo import cli as zoo_cli

    class _AsyncWriterThread(threading.Thread):  # (tensorboard's writer thread, by its class name)
        def run(self):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    printed = []
    monkeypatch.setattr(threading, "excepthook", lambda args: printed.append(args.exc_type))
    with zoo_cli._writer_thread_failures_quiet():
        for thread in (_AsyncWriterThread(), threading.Thread(target=lambda: 1 / 0)):
            thread.start()
            thread.join()
    assert printed == [ZeroDivisionError]
    thread = _AsyncWriterThread()  # (outside training, printed as ever)
    thread.start()
    thread.join()
    assert printed == [ZeroDivisionError, OSError]


def test_a_full_disk_under_the_experiment_store_is_an_os_error_naming_it(tmp_path, monkeypatch):
    import sqlite3

    import pytest

    from sb3_emmarl.experiments.store import ResultStore

    store = ResultStore(tmp_path / "results.sqlite")
    connect = store._connect

    class FullDisk:  # SQLite on a full disk: the commit fails and SQLite has rolled the transaction back
        def __init__(self):
            self.db = connect()
            self.close = self.db.close

        @property
        def in_transaction(self):
            return self.db.in_transaction

        def execute(self, sql, *args):
            if sql == "COMMIT":
                self.db.execute("ROLLBACK")
                error = sqlite3.OperationalError("database or disk is full")
                error.sqlite_errorcode = sqlite3.SQLITE_FULL
                raise error
            return self.db.execute(sql, *args)

    monkeypatch.setattr(store, "_connect", FullDisk)
    with pytest.raises(OSError) as info, store._transaction() as db:
        db.execute("CREATE TABLE more (x)")
    assert info.value.errno == errno.ENOSPC and info.value.filename == str(tmp_path / "results.sqlite")
    assert cli.os_error_text(info.value) == f"{tmp_path / 'results.sqlite'}: No space left on device (database or " \
                                            "disk is full)"
    monkeypatch.setattr(store, "_connect", connect)
    assert store.rows("tiny", "quick") == []  # the store is whole


def test_every_atomic_write_keeps_the_previous_file_and_names_the_path(tmp_path, monkeypatch):
    """Checkpoints, GIFs and MP4s (``recording``), figures (``plots``, the experiments' reports), JSON results and
    configs all go through ``write_atomic``: a write that fails leaves the previous file whole and no partial one."""
    import pytest

    path = tmp_path / "patrol.gif"
    atomic_files.write_text(path, "the previous recording")

    def fill(file):
        file.write(b"half a GIF")
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))  # (what a write on a full disk raises: no file named)

    with pytest.raises(OSError) as info:
        atomic_files.write_atomic(path, fill)
    assert cli.os_error_text(info.value) == f"{path}: No space left on device"
    assert path.read_text() == "the previous recording" and sorted(tmp_path.iterdir()) == [path]
