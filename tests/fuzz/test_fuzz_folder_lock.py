"""Two processes taking and releasing output folders' locks in random interleavings:
this process and a second one (tests/lock_holder.py), over two folders, with the second
sometimes killed (SIGKILL) while it holds locks, and sometimes racing this one for a
free folder. At every step at most one process holds a folder, a process is refused
exactly when the other holds it (naming that process), a killed holder's folders are
free at once, and a released folder keeps no lock file."""

from __future__ import annotations

import json
import os
import shutil
import tempfile
import time
from contextlib import ExitStack
from pathlib import Path

import pytest
from fuzzlib import record
from hypothesis import given, note
from hypothesis import strategies as st
from lock_holder import LockHolder

from observer_gym.train.reports.folder_lock import LOCK_FILE, FolderBusyError, folder_lock

FOLDERS = ("a", "b")
ACTIONS = ["here take", "here release", "there take", "there release", "race"]
steps = st.lists(
    st.tuples(
        # a kill restarts the second process (0.3 s): rarer than the rest
        st.sampled_from(ACTIONS * 3 + ["there kill"]),
        st.sampled_from(FOLDERS),
        st.floats(0.0, 0.002),  # race: this process's delay after the other was told
    ),
    min_size=1,
    max_size=10,
)


class Other:
    """The second process, restarted after a kill."""

    def __init__(self) -> None:
        self.holder = LockHolder()

    def restart(self) -> None:
        self.holder.kill()
        self.holder = LockHolder()


@pytest.fixture(scope="module")
def other():
    process = Other()
    yield process
    process.holder.close()


@given(steps)
def test_two_processes_never_hold_one_folder(other, plan):
    root = Path(tempfile.mkdtemp(prefix="fuzz-lock-"))
    folders = {name: root / name for name in FOLDERS}
    for folder in folders.values():
        folder.mkdir()
    owner: dict[str, str | None] = dict.fromkeys(FOLDERS)
    here: dict[str, ExitStack] = {}
    try:
        for action, name, delay in plan:
            folder = folders[name]
            note(f"{action} {name} (owner {owner[name]})")
            if action == "here take" and owner[name] != "here":
                stack = ExitStack()
                try:
                    stack.enter_context(folder_lock(folder, "fuzz"))
                except FolderBusyError as exc:
                    record("lock: take", accepted=False)
                    assert owner[name] == "there" and exc.holder.pid == other.holder.pid
                    continue
                record("lock: take", accepted=True)
                assert owner[name] is None
                here[name], owner[name] = stack, "here"
            elif action == "here release" and owner[name] == "here":
                here.pop(name).close()
                owner[name] = None
            elif action == "there take" and owner[name] != "there":
                answer = other.holder.take(folder)
                record("lock: take", accepted=answer == "held")
                if owner[name] == "here":
                    assert answer == f"busy {os.getpid()}"
                else:
                    assert answer == "held"
                    owner[name] = "there"
            elif action == "there release" and owner[name] == "there":
                other.holder.release(folder)
                owner[name] = None
            elif action == "there kill":
                other.restart()  # its locks go with it
                owner = {k: (None if v == "there" else v) for k, v in owner.items()}
            elif action == "race" and owner[name] is None:
                # both ask for the free folder at once: exactly one gets it
                assert other.holder.process.stdin is not None
                other.holder.process.stdin.write(f"take {folder}\n")
                other.holder.process.stdin.flush()
                time.sleep(delay)
                stack = ExitStack()
                try:
                    stack.enter_context(folder_lock(folder, "fuzz"))
                    mine = True
                except FolderBusyError:
                    mine = False
                answer = other.holder.process.stdout.readline().strip()
                record("lock: race won here", accepted=mine)
                assert mine != (answer == "held"), (mine, answer)
                if mine:
                    here[name], owner[name] = stack, "here"
                else:
                    owner[name] = "there"
            # the model holds: a held folder's lock file names its holder
            for key, who in owner.items():
                path = folders[key] / LOCK_FILE
                if who is not None:
                    pid = os.getpid() if who == "here" else other.holder.pid
                    assert json.loads(path.read_text())["pid"] == pid
    finally:
        for stack in here.values():
            stack.close()
        for key, who in owner.items():
            if who == "there":
                other.holder.release(folders[key])
        leftover = [p for p in root.rglob(LOCK_FILE)]
        shutil.rmtree(root, ignore_errors=True)
    # released by both (a killed holder's file may stay: the next holder removes it)
    if not any(action == "there kill" for action, _, _ in plan):
        assert leftover == []
