"""One command at a time in an output folder (issue 29, items 3 and 4): the lock of
:mod:`observer_gym.train.reports.folder_lock` between two processes, a killed holder's
lock freed by the kernel, and every command that writes an output folder refused with
one line and exit code 75 while another process holds it, writing nothing."""

from __future__ import annotations

import json
import os
import socket
from collections.abc import Iterator
from pathlib import Path

import pytest
from lock_holder import LockHolder

from observer_gym.train.cli import main
from observer_gym.train.reports.folder_lock import (
    FOLDER_BUSY_EXIT_CODE,
    LOCK_FILE,
    FolderBusyError,
    folder_lock,
)
from observer_gym.train.reports.outputs import output_folder


@pytest.fixture
def holder() -> Iterator[LockHolder]:
    process = LockHolder()
    yield process
    process.close()


def files(folder: Path) -> dict[str, bytes]:
    return {
        p.relative_to(folder).as_posix(): p.read_bytes() for p in folder.rglob("*") if p.is_file()
    }


def test_the_lock_records_its_holder_and_leaves_nothing_behind(tmp_path):
    with folder_lock(tmp_path, "sweep"):
        record = json.loads((tmp_path / LOCK_FILE).read_text())
        assert record["pid"] == os.getpid() and record["host"] == socket.gethostname()
        assert record["command"] == "sweep" and record["started"]
        with folder_lock(tmp_path, "sweep"):  # nests within a process
            assert (tmp_path / LOCK_FILE).exists()
        assert (tmp_path / LOCK_FILE).exists()  # still held by the outer block
    assert not (tmp_path / LOCK_FILE).exists()


def test_a_second_process_is_refused_naming_the_holder(tmp_path, holder):
    assert holder.take(tmp_path) == "held"
    with pytest.raises(FolderBusyError) as caught, folder_lock(tmp_path, "sweep"):
        pass
    message = str(caught.value)
    assert "\n" not in message
    assert f"{tmp_path} is in use by 'observer-gym lock-holder' (pid {holder.pid} on " in message
    assert "lock_holder.py" in message  # its command line
    assert caught.value.holder.pid == holder.pid
    holder.release(tmp_path)
    with folder_lock(tmp_path, "sweep"):  # free once released
        assert holder.take(tmp_path) == f"busy {os.getpid()}"
    assert holder.take(tmp_path) == "held"


def test_a_killed_holder_does_not_keep_the_folder_busy(tmp_path, holder):
    assert holder.take(tmp_path) == "held"
    holder.kill()  # SIGKILL: its lock file stays, its lock does not
    assert (tmp_path / LOCK_FILE).exists()
    with folder_lock(tmp_path, "train --resume"):
        assert json.loads((tmp_path / LOCK_FILE).read_text())["pid"] == os.getpid()
    assert not (tmp_path / LOCK_FILE).exists()


def test_output_folder_takes_the_lock_before_it_checks_or_writes(tmp_path, holder):
    out = tmp_path / "out"
    out.mkdir()
    assert holder.take(out) == "held"
    checked = []
    with pytest.raises(FolderBusyError), output_folder(out, "run", check=checked.append):
        pass
    assert checked == [] and set(files(out)) == {LOCK_FILE}  # no marker, no check
    holder.release(out)
    with output_folder(out, "run", check=checked.append):
        assert checked == [out]
    assert files(out) == {}


def test_a_refused_command_leaves_no_folder_it_made(tmp_path):
    """The folder is made for the lock; a check that refuses it removes it again."""

    def refuse(folder: Path) -> None:
        raise ValueError("no")

    with pytest.raises(ValueError), output_folder(tmp_path / "a" / "b", "run", check=refuse):
        pass
    assert not (tmp_path / "a").exists()


SWEEP = [
    "sweep", "--vary", "measurement_noise_px=0", "--observers", "oracle", "--controllers",
    "lqr", "--episodes", "1", "--steps", "3", "--no-progress",
]  # fmt: skip
RUN = ["run", "--observer", "oracle", "--controller", "lqr", "--episodes", "1", "--steps", "3",
       "--no-progress"]  # fmt: skip
COMPARE = ["compare", "--observers", "oracle", "--controllers", "lqr", "--episodes", "1",
           "--steps", "3", "--no-progress"]  # fmt: skip
TRAIN = ["train", "--algo", "ppo", "--obs", "state", "--timesteps", "64", "--n-envs", "1",
         "--vec-env", "dummy", "--hyperparam", "n_steps=64", "--hyperparam", "batch_size=64",
         "--no-progress"]  # fmt: skip
TRAIN_SEEDS = [*TRAIN, "--seeds", "0,1"]


@pytest.mark.parametrize(
    "argv", [SWEEP, RUN, COMPARE, TRAIN, TRAIN_SEEDS], ids=["sweep", "run", "compare", "train",
                                                           "train-seeds"]
)  # fmt: skip
def test_a_command_into_a_folder_another_process_holds_is_refused(argv, tmp_path, holder, capsys):
    """Today's commands ran into a folder another command was writing, mixing their
    files (a sweep's cells, a training run's progress.csv and eval.csv rows)."""
    out = tmp_path / "out"
    out.mkdir()
    assert holder.take(out) == "held"
    before = files(out)
    assert main([*argv, "--out", str(out)]) == FOLDER_BUSY_EXIT_CODE == 75
    (line,) = capsys.readouterr().err.splitlines()
    command = argv[0]
    assert line.startswith(f"observer-gym {command}: error: {out} is in use by ")
    assert f"'observer-gym lock-holder' (pid {holder.pid} on {socket.gethostname()}" in line
    assert files(out) == before  # nothing written


def test_another_thread_of_the_holder_is_refused_and_the_lock_outlives_it(tmp_path):
    import threading

    outcome: list[str] = []

    def second() -> None:
        try:
            with folder_lock(tmp_path, "sweep"):
                outcome.append("entered")
        except FolderBusyError:
            outcome.append("refused")

    with folder_lock(tmp_path, "sweep"):
        thread = threading.Thread(target=second)
        thread.start()
        thread.join()
        assert outcome == ["refused"]
        assert (tmp_path / LOCK_FILE).exists()  # the first thread still holds it
    assert not (tmp_path / LOCK_FILE).exists()


def test_a_training_folder_in_use_is_busy_before_any_check_of_its_contents(tmp_path, holder):
    # A run training in DIR has written config.json and a "running" state.json; a second
    # train --resume or train --out DIR is refused as busy (exit code 75), not by the checks
    # of what the first wrote (exit code 2).
    from observer_gym.train.rl.run_dir import check_new_run_folder, check_resumable

    (tmp_path / "config.json").write_text("{}")
    (tmp_path / "state.json").write_text(json.dumps({"status": "running", "pid": holder.pid}))
    assert holder.take(tmp_path) == "held"
    for check in (check_resumable, check_new_run_folder):
        with pytest.raises(FolderBusyError):
            check(tmp_path)
    argv = ["train", "--resume", str(tmp_path), "--timesteps", "10", "--no-progress"]
    assert main(argv) == FOLDER_BUSY_EXIT_CODE
    holder.release(tmp_path)
    with pytest.raises(ValueError):  # free again: the checks read the folder
        check_new_run_folder(tmp_path)
