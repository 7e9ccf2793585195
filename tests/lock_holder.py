"""A second process for the output-folder lock's tests: it takes and releases folders'
locks (:func:`observer_gym.train.reports.folder_lock.folder_lock`) when told on stdin.

Run as a script, it reads one command a line, ``take DIR``, ``release DIR`` or ``quit``,
and answers each with one line: ``held``, ``busy PID`` (the holder's PID, ``?`` if its
record was unreadable) or ``released``. :class:`LockHolder` drives it from a test.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from contextlib import ExitStack
from pathlib import Path


class LockHolder:
    """The script in a child process: :meth:`take`, :meth:`release`, :meth:`kill`."""

    def __init__(self) -> None:
        self.process = subprocess.Popen(
            [sys.executable, __file__],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            bufsize=1,
        )

    @property
    def pid(self) -> int:
        return self.process.pid

    def _ask(self, line: str) -> str:
        assert self.process.stdin is not None and self.process.stdout is not None
        self.process.stdin.write(line + "\n")
        self.process.stdin.flush()
        answer = self.process.stdout.readline().strip()
        assert answer, f"the lock holder ended (exit code {self.process.poll()})"
        return answer

    def take(self, folder: Path) -> str:
        """``held``, or ``busy PID``."""
        return self._ask(f"take {folder}")

    def release(self, folder: Path) -> None:
        assert self._ask(f"release {folder}") == "released"

    def kill(self) -> None:
        """SIGKILL: the process cannot release anything itself."""
        os.kill(self.process.pid, signal.SIGKILL)
        self.process.wait()
        for stream in (self.process.stdin, self.process.stdout):
            if stream is not None:
                stream.close()

    def close(self) -> None:
        if self.process.poll() is None:
            self.kill()


def _serve() -> None:
    from observer_gym.train.reports.folder_lock import FolderBusyError, folder_lock

    held: dict[str, ExitStack] = {}
    for line in sys.stdin:
        verb, _, folder = line.strip().partition(" ")
        if verb == "take":
            stack = ExitStack()
            try:
                stack.enter_context(folder_lock(folder, "lock-holder"))
            except FolderBusyError as exc:
                print(f"busy {exc.holder.pid if exc.holder else '?'}", flush=True)
                continue
            held[folder] = stack
            print("held", flush=True)
        elif verb == "release":
            held.pop(folder).close()
            print("released", flush=True)
        else:
            return


if __name__ == "__main__":
    _serve()
