"""Killed parents with workers: a process running episodes in a worker pool
(:func:`~observer_gym.train.experiments.episode.iter_episodes`, as ``run``, ``compare``,
``sweep`` and ``benchmark`` do) is killed with SIGKILL at a random moment (before, while
or after its workers start); no process it started outlives it by more than a bounded
time. Every process of its session is watched, so a worker that was still starting when
the parent died counts too."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest
from fuzzlib import record
from hypothesis import given, note, settings
from hypothesis import strategies as st

GONE_WITHIN_S = 15.0

# The parent: episodes that each sleep 30 s (time.sleep is the "run" function: picklable
# by reference, so the workers import nothing of the episode code).
PARENT = textwrap.dedent(
    """
    import sys, time
    from observer_gym.train.experiments.episode import iter_episodes
    for _ in iter_episodes([30.0] * 8, workers=int(sys.argv[1]), run=time.sleep):
        pass
    """
)


def session_members(sid: int) -> list[int]:
    """The live processes of session ``sid`` (Linux /proc; zombies are not live)."""
    members = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        # fields: state ppid pgrp session ...
        if int(fields[3]) == sid and fields[0] not in ("Z", "X"):
            members.append(int(stat.parent.name))
    return members


@pytest.mark.slow
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
@given(workers=st.integers(2, 3), delay_s=st.floats(0.0, 4.0))
@settings(max_examples=max(3, settings().max_examples // 10))
def test_no_worker_outlives_a_killed_parent(workers, delay_s):
    parent = subprocess.Popen(
        [sys.executable, "-c", PARENT, str(workers)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,  # its own session: every process it starts is found
    )
    sid = parent.pid
    try:
        time.sleep(delay_s)
        started = [p for p in session_members(sid) if p != parent.pid]
        note(f"{len(started)} processes besides the parent after {delay_s:.2f} s")
        os.kill(parent.pid, signal.SIGKILL)
        parent.wait(timeout=30)
        deadline = time.monotonic() + GONE_WITHIN_S
        while session_members(sid) and time.monotonic() < deadline:
            time.sleep(0.1)
        left = session_members(sid)
        assert not left, f"{left} outlived the killed parent ({workers} workers)"
        record("killed parent with workers", accepted=True)
    finally:
        if parent.poll() is None:
            parent.kill()
            parent.wait()
        for pid in session_members(sid):  # only this test's processes: its own session
            os.kill(pid, signal.SIGKILL)
