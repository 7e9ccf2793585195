"""Runs killed with SIGKILL, and runs that fail: what the next command into the folder
finds and says (stale temps removed, the killed run reported), an empty ``--out``
refused, and no empty output folder left behind."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import textwrap
import time

import pytest

from observer_gym.train.cli import main
from observer_gym.train.experiments import compare, demo, run
from observer_gym.train.experiments.evaluate import evaluate_agent
from observer_gym.train.experiments.run import run_experiment
from observer_gym.train.reports.outputs import OutputFolderWarning, writer_identity
from observer_gym.train.rl.run_dir import latest_checkpoint, read_state

CLI = [sys.executable, "-m", "observer_gym.train.cli"]
RUN_ONE = ["--observer", "oracle", "--controller", "lqr", "--episodes", "1", "--steps", "5"]


def _start(command: list[str]) -> subprocess.Popen:
    return subprocess.Popen(
        command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, start_new_session=True
    )


def _wait_for(process: subprocess.Popen, ready, what: str, timeout_s: float = 120) -> None:
    deadline = time.monotonic() + timeout_s
    while not ready():
        assert process.poll() is None, process.stdout.read().decode()
        assert time.monotonic() < deadline, f"no {what} within {timeout_s} s"
        time.sleep(0.1)


def _sigkill(process: subprocess.Popen) -> None:
    """SIGKILL to the process group (the trainer and any workers), then reap it."""
    os.killpg(process.pid, signal.SIGKILL)
    process.wait(timeout=30)
    assert process.returncode == -signal.SIGKILL


def _dead_pid() -> int:
    """The PID of a process that has exited and been reaped."""
    process = subprocess.Popen([sys.executable, "-c", "pass"])
    process.wait()
    return process.pid


# A writer stuck in write_json_atomic between writing its temp and renaming it.
STUCK_WRITER = textwrap.dedent(
    """
    import os, sys, time
    from observer_gym.train.reports.outputs import write_json_atomic
    os.replace = lambda src, dst: (print("stuck", flush=True), time.sleep(600))
    write_json_atomic(sys.argv[1], {"a": 1})
    """
)


def test_a_later_run_removes_the_temps_of_a_killed_writer(tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    writer = _start([sys.executable, "-c", STUCK_WRITER, str(out / "results.json")])
    _wait_for(writer, lambda: list(out.glob(".results.json.*.tmp")), "temp file")
    _sigkill(writer)
    temps = list(out.glob(".results.json.*.tmp"))
    assert len(temps) == 1
    # a live writer's temp is left alone
    alive = out / f".summary.json.{os.getpid()}.abcdefgh.tmp"
    alive.write_text("{")

    assert main(["run", *RUN_ONE, "--out", str(out), "--no-progress"]) == 0
    assert not temps[0].exists() and alive.exists()
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1, err
    assert err[0].startswith("observer-gym run: warning: removed 1 temp file(s) in ")
    assert temps[0].name in err[0]
    assert json.loads((out / "results.json").read_text())["config"]["episodes"] == 1


# A trainer that blocks while saving its second checkpoint's model (after writing it to
# its temp file), so SIGKILL catches it holding a temp and a state.json saying running.
STUCK_TRAINER = textwrap.dedent(
    """
    import os, sys, time
    import observer_gym.train.reports.outputs as outputs
    from observer_gym.train.cli import main
    real = os.replace
    def replace(src, dst):
        name = os.path.basename(str(dst))
        latest = os.path.join(os.path.dirname(str(dst)), "latest.json")
        if name.startswith("model_") and os.path.exists(latest):
            print("stuck", flush=True)
            time.sleep(600)
        return real(src, dst)
    outputs.os.replace = replace
    sys.exit(main(sys.argv[1:]))
    """
)


@pytest.mark.slow  # a training killed and resumed (33 s at load 7)
def test_a_killed_training_run_is_reported_and_its_temps_removed(tmp_path, capfd):
    out = tmp_path / "run"
    command = [
        sys.executable, "-c", STUCK_TRAINER, "train", "--algo", "ppo", "--obs", "state",
        "--timesteps", "100000", "--n-envs", "1", "--hyperparam", "n_steps=256",
        "--hyperparam", "checkpoint_freq=256", "--hyperparam", "eval_freq=100000",
        "--out", str(out), "--no-progress",
    ]  # fmt: skip
    trainer = _start(command)
    checkpoints = out / "checkpoints"
    # Stuck in the second checkpoint: the first one is saved (latest.json), a temp is open.
    _wait_for(
        trainer,
        lambda: (
            (checkpoints / "latest.json").exists() and list(checkpoints.glob(".model_*.zip.tmp-*"))
        ),
        "checkpoint temp after a saved checkpoint",
    )
    _sigkill(trainer)
    (temp,) = checkpoints.glob(".model_*.zip.tmp-*")
    assert temp.name.endswith(f".tmp-{trainer.pid}")
    recorded = json.loads((out / "state.json").read_text())
    assert recorded["status"] == "running"  # nothing could rewrite it
    assert recorded["writer"]["pid"] == trainer.pid
    assert recorded["writer"]["host"] == socket.gethostname()
    assert read_state(out)["status"] == "killed"
    saved = latest_checkpoint(checkpoints)["timesteps"]

    with pytest.warns(OutputFolderWarning, match=f"was killed.*pid {trainer.pid}") as caught:
        evaluate_agent(out, episodes=1, out_dir=tmp_path / "eval", steps=3, progress=False)
    assert f"evaluating its latest checkpoint ({saved} steps)" in str(caught[0].message)
    assert temp.exists()  # evaluate reads the run's folder, it does not tidy it

    capfd.readouterr()
    target = saved + 256
    assert main(["train", "--resume", str(out), "--timesteps", str(target), "--no-progress"]) == 0
    err = capfd.readouterr().err.splitlines()
    warned = [line for line in err if line.startswith("observer-gym train: warning: ")]
    assert len(warned) == 2, err
    assert f"was killed: its state.json says running but pid {trainer.pid}" in warned[0]
    assert f"resuming from its checkpoint at {saved} steps" in warned[0]
    assert "removed 1 temp file(s)" in warned[1] and temp.name in warned[1]
    assert not temp.exists()
    assert not list(out.rglob(".*tmp*"))
    state = read_state(out)
    assert state["status"] == "finished" and state["timesteps"] == target


@pytest.mark.slow  # kills a command line process and runs the next: 2.6 s (load ~2)
def test_a_killed_run_into_a_folder_is_reported_by_the_next(tmp_path, capsys):
    out = tmp_path / "out"
    command = [
        *CLI, "run", "--observer", "oracle", "--controller", "lqr", "--episodes", "1000",
        "--out", str(out), "--no-progress",
    ]  # fmt: skip
    process = _start(command)
    _wait_for(process, lambda: list(out.glob(".observer-gym-running-*.json")), "marker")
    _sigkill(process)
    assert not (out / "results.json").exists()

    assert main(["run", *RUN_ONE, "--out", str(out), "--no-progress"]) == 0
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1, err
    assert err[0].startswith(
        f"observer-gym run: warning: an earlier 'observer-gym run' into {out} "
        f"(pid {process.pid} on {socket.gethostname()}, started "
    )
    assert "was killed before it finished" in err[0]
    assert (out / "results.json").is_file()
    assert not list(out.glob(".observer-gym-running-*"))  # the finished run's went too
    assert main(["run", *RUN_ONE, "--out", str(out), "--no-progress"]) == 0
    assert capsys.readouterr().err == ""  # nothing left to report


def test_read_state_tells_a_killed_run_from_a_running_one(tmp_path):
    def state(writer: dict | None, status: str = "running") -> str:
        record = {"status": status, "timesteps": 0, "target_timesteps": 10}
        if writer is not None:
            record["writer"] = writer
        (tmp_path / "state.json").write_text(json.dumps(record))
        return read_state(tmp_path)["status"]

    me = writer_identity()
    assert state(me) == "running"
    assert state({**me, "pid": _dead_pid()}) == "killed"
    if me["pid_start"] is not None:  # Linux: a PID taken by another process
        assert state({**me, "pid_start": me["pid_start"] - 1}) == "killed"
    assert state({**me, "host": "another-host.invalid", "pid": _dead_pid()}) == "running"
    assert state(None) == "killed"  # no writer recorded: nothing can still write it
    assert state({**me, "pid": _dead_pid()}, status="interrupted") == "interrupted"
    assert read_state(tmp_path / "nothing") is None


@pytest.mark.parametrize(
    "argv",
    [
        ["run", *RUN_ONE, "--out", ""],
        ["compare", "--observers", "oracle", "--controllers", "lqr", "--out", ""],
        ["train", "--algo", "ppo", "--obs", "state", "--out", " "],
        ["demo", "--out", ""],
        ["evaluate", "--model", ""],
        ["train", "--resume", ""],
    ],
    ids=["run", "compare", "train", "demo", "evaluate-model", "train-resume"],
)
def test_an_empty_folder_argument_is_a_usage_error(argv, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    result = subprocess.run([*CLI, *argv], capture_output=True, text=True, timeout=120)
    assert result.returncode == 2, result.stderr
    lines = result.stderr.splitlines()
    assert len(lines) == 1, result.stderr
    option = argv[argv.index("") - 1] if "" in argv else "--out"
    assert lines[0].startswith(f"observer-gym {argv[0]}: error: argument {option}: ")
    assert "expected a folder, got an empty path" in lines[0]
    assert result.stdout == ""
    assert list(tmp_path.iterdir()) == []


def _fail(*args, **kwargs):
    raise RuntimeError("failed before writing anything")


@pytest.mark.parametrize("command", ["run", "compare", "demo"])
def test_a_failed_run_leaves_no_empty_folder(command, tmp_path, monkeypatch):
    if command == "run":
        monkeypatch.setattr(run, "run_episodes", _fail)
        go = lambda out: run_experiment("BallTable-v0", "oracle", "lqr", 1, 0, out)  # noqa: E731
    elif command == "compare":
        monkeypatch.setattr(compare, "run_pairs", _fail)
        go = lambda out: compare.run_comparison(  # noqa: E731
            "BallTable-v0", ["oracle"], ["lqr"], [0], out, progress=False
        )
    else:
        monkeypatch.setattr(demo, "make_controller", _fail)
        go = lambda out: demo.run_demo(out, seconds=0.1, progress=False)  # noqa: E731

    with pytest.raises(RuntimeError, match="before writing anything"):
        go(tmp_path / "new" / "out")
    assert list(tmp_path.iterdir()) == []  # both levels it created are gone

    kept = tmp_path / "kept"
    kept.mkdir()
    with pytest.raises(RuntimeError, match="before writing anything"):
        go(kept)
    assert kept.is_dir() and list(kept.iterdir()) == []  # not its folder: it stays

    other = tmp_path / "other"
    with pytest.raises(RuntimeError, match="before writing anything"):
        go(other / "sub")
    assert not other.exists()
    (other / "sub").mkdir(parents=True)
    (other / "note.txt").write_text("not the run's")
    with pytest.raises(RuntimeError, match="before writing anything"):
        go(other / "sub" / "out")
    assert sorted(p.name for p in other.iterdir()) == ["note.txt", "sub"]
    assert list((other / "sub").iterdir()) == []  # existed before: stays


def test_a_failed_training_run_leaves_no_empty_folder(tmp_path, monkeypatch):
    from observer_gym.train.rl import training

    monkeypatch.setattr(training, "write_config", _fail)  # config.json: its first write
    with pytest.raises(RuntimeError, match="before writing anything"):
        training.train_agent("BallTable-v0", "ppo", "state", tmp_path / "a" / "run")
    assert list(tmp_path.iterdir()) == []
