"""A command killed with SIGKILL takes its worker processes with it: ``sweep --workers``'
episode workers and ``train --seeds``' seed workers notice their parent is gone and end
(a seed as an interrupted run: its last checkpoint kept, its lock released), so
``train --resume`` then trains the seeds on."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from observer_gym.train.reports.parent_watch import end_with_parent
from observer_gym.train.rl.run_dir import latest_checkpoint

CLI = [sys.executable, "-m", "observer_gym.train.cli"]
GONE_WITHIN_S = 15.0  # bound on the workers' end after the parent's


def children(pid: int) -> list[int]:
    """The PIDs of ``pid``'s children (Linux: /proc/<pid>/task/*/children)."""
    found: list[int] = []
    for task in Path(f"/proc/{pid}/task").glob("*"):
        try:
            found += [int(p) for p in (task / "children").read_text().split()]
        except OSError:  # the task ended meanwhile
            pass
    return found


def cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return ""


def workers_of(pid: int) -> list[int]:
    """The spawned worker processes of ``pid`` (not multiprocessing's resource tracker)."""
    return [c for c in children(pid) if "spawn_main" in cmdline(c)]


def alive(pid: int) -> bool:
    """Whether ``pid`` runs (a zombie, ended but not reaped, does not)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] not in ("Z", "X")


def wait_until(condition, what: str, process: subprocess.Popen, timeout_s: float = 240.0):
    deadline = time.monotonic() + timeout_s
    while True:
        value = condition()
        if value:
            return value
        if process.poll() is not None:
            pytest.fail(f"the command ended before {what}: {process.stdout.read().decode()}")
        assert time.monotonic() < deadline, f"no {what} within {timeout_s} s"
        time.sleep(0.2)


def kill_parent_and_wait_for(workers: list[int], parent: subprocess.Popen) -> list[int]:
    """SIGKILL to the parent only; the workers still alive after GONE_WITHIN_S."""
    os.kill(parent.pid, signal.SIGKILL)
    parent.wait(timeout=30)
    deadline = time.monotonic() + GONE_WITHIN_S
    while any(alive(w) for w in workers) and time.monotonic() < deadline:
        time.sleep(0.1)
    return [w for w in workers if alive(w)]


def reap(pids: list[int]) -> None:
    """SIGKILL to the workers this test started that outlived their parent."""
    for pid in pids:
        if alive(pid):
            os.kill(pid, signal.SIGKILL)


def test_outside_a_spawned_process_nothing_is_watched():
    # the main process has no multiprocessing parent: no watching thread starts
    end_with_parent()
    assert "end-with-parent" not in [t.name for t in threading.enumerate()]


@pytest.mark.slow
def test_a_killed_sweep_leaves_no_workers(tmp_path):
    command = [
        *CLI, "sweep", "--env", "BallTable-v0", "--vary", "latency_s=0,0.02",
        "--observers", "oracle", "--controllers", "lqr", "--episodes", "100",
        "--workers", "2", "--out", str(tmp_path / "sweep"), "--no-progress",
    ]  # fmt: skip
    sweep = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    workers: list[int] = []
    try:
        workers = wait_until(
            lambda: (w := workers_of(sweep.pid)) and len(w) == 2 and w, "two workers", sweep
        )
        time.sleep(1.0)  # the workers are running episodes
        left = kill_parent_and_wait_for(workers, sweep)
        assert not left, f"workers {left} outlived the killed sweep"
    finally:
        if sweep.poll() is None:
            sweep.kill()
            sweep.wait()
        reap(workers)


@pytest.mark.slow
def test_killed_train_seeds_workers_end_and_resume_trains_them_on(tmp_path):
    out = tmp_path / "seeds"
    command = [
        *CLI, "train", "--env", "BallTable-v0", "--algo", "ppo", "--obs", "state",
        "--seeds", "0,1", "--workers", "2", "--timesteps", "1000000", "--n-envs", "1",
        "--vec-env", "dummy", "--hyperparam", "n_steps=128", "--hyperparam", "batch_size=64",
        "--hyperparam", "checkpoint_freq=128", "--hyperparam", "eval_freq=1000000",
        "--out", str(out), "--no-progress",
    ]  # fmt: skip
    train = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    seeds = [out / "seed_0", out / "seed_1"]
    workers: list[int] = []
    try:
        workers = wait_until(
            lambda: (w := workers_of(train.pid)) and len(w) == 2 and w, "two workers", train
        )
        wait_until(
            lambda: all(latest_checkpoint(s / "checkpoints") for s in seeds),
            "a checkpoint in every seed",
            train,
        )
        saved = {s: latest_checkpoint(s / "checkpoints")["timesteps"] for s in seeds}
        left = kill_parent_and_wait_for(workers, train)
        assert not left, f"workers {left} outlived the killed train --seeds"
    finally:
        if train.poll() is None:
            train.kill()
            train.wait()
        reap(workers)
    for seed in seeds:
        # each seed ended as an interrupted run: its checkpoints kept, no newer one lost
        assert json.loads((seed / "state.json").read_text())["status"] == "interrupted"
        assert latest_checkpoint(seed / "checkpoints")["timesteps"] >= saved[seed]
    target = max(latest_checkpoint(s / "checkpoints")["timesteps"] for s in seeds) + 128
    resumed = subprocess.run(
        [*CLI, "train", "--resume", str(out), "--timesteps", str(target), "--no-progress"],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert resumed.returncode == 0, resumed.stderr
    for seed in seeds:
        state = json.loads((seed / "state.json").read_text())
        assert state["status"] == "finished" and state["timesteps"] == target
