"""One command at a time in an output folder: an exclusive lock on ``DIR/.observer-gym.lock``.

Every command that writes an output folder (``run``, ``evaluate``, ``compare``, ``sweep``,
``demo``, ``train``, ``train --resume``, ``train --seeds``) holds its folder's lock from
before it writes anything there until it ends, however it ends
(:func:`~observer_gym.train.reports.outputs.output_folder` takes it; a training run holds it
while it trains). A second command into the same folder is refused at once with
:class:`FolderBusyError`, which names the holder: its PID, host, command line and start
time, recorded in the lock file. The command line turns it into one line on stderr and
exit code :data:`FOLDER_BUSY_EXIT_CODE`.

The lock is ``fcntl.flock`` from the standard library: the kernel releases it when the
holding process ends, killed or not, so a dead run never keeps its folder busy (there is
no stale lock to detect), and no dependency is needed. The holder removes the lock file
when it releases the lock; a process that opened the old file in the meantime finds,
once it holds the lock, that the path no longer names that file, and tries again.

Within one thread the lock nests: a function that holds a folder's lock may call another
that takes it again. Another thread of the holder's process is refused like another
process. A process started from the holder does not share the lock: it is refused like
any other (a ``fork``ed child keeps the inherited descriptor, and with it the folder
locked, until it exits; the file is opened close-on-exec, so ``spawn`` and
``subprocess`` children do not inherit it). :func:`check_not_busy` asks without holding:
a command's checks call it first, so a folder in use is refused with this error even when
what the other command wrote would fail a check.

A lock file that is a symbolic link is refused (``O_NOFOLLOW``), never followed: the
command stops with an ``OSError`` naming it, and the link's target is left as it was.

Needs a POSIX system and a file system with ``flock`` (local disks, NFSv4); elsewhere
the command stops with an ``OSError`` naming the folder.
"""

from __future__ import annotations

import fcntl
import json
import os
import shlex
import socket
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from pathlib import Path

from observer_gym.envs.json_file import parse_json

LOCK_FILE = ".observer-gym.lock"
# The exit code of a command refused because another command holds its output folder:
# EX_TEMPFAIL of sysexits.h, "a temporary failure; the user is invited to retry".
FOLDER_BUSY_EXIT_CODE = 75
_READ_TRIES = 20  # a holder that has just taken the lock writes its record at once
_READ_PAUSE_S = 0.01
_SHOWN_ARGV = 160  # characters of the holder's command line in the message


@dataclass(frozen=True)
class LockHolder:
    """What a lock's holder records in the lock file."""

    pid: int
    host: str
    command: str  # the observer-gym command: "sweep", "train --resume", ...
    argv: str  # the process's command line
    started: str  # local time, YYYY-mm-dd HH:MM:SS

    @classmethod
    def this_process(cls, command: str) -> LockHolder:
        return cls(
            pid=os.getpid(),
            host=socket.gethostname(),
            command=command,
            argv=shlex.join(sys.argv),
            started=time.strftime("%Y-%m-%d %H:%M:%S"),
        )

    @classmethod
    def from_text(cls, text: str) -> LockHolder | None:
        """The record in ``text``, or None if it is not one."""
        try:
            data = parse_json(text, LOCK_FILE)
            holder = cls(**data)
        except (ValueError, TypeError):
            return None
        return holder if isinstance(holder.pid, int) else None

    def text(self) -> str:
        argv = self.argv if len(self.argv) <= _SHOWN_ARGV else self.argv[: _SHOWN_ARGV - 3] + "..."
        return (
            f"'observer-gym {self.command}' (pid {self.pid} on {self.host}, started "
            f"{self.started}: {argv})"
        )


class FolderBusyError(OSError):
    """Another command holds the output folder's lock (:func:`folder_lock`); nothing was
    written. ``folder`` and ``holder`` (None if its record could not be read) say which."""

    def __init__(self, folder: Path, holder: LockHolder | None) -> None:
        who = holder.text() if holder is not None else "another observer-gym command"
        super().__init__(
            f"{folder} is in use by {who}; wait until it ends, or use another output folder"
        )
        self.folder = folder
        self.holder = holder


@dataclass
class _Held:
    pid: int  # the process that took it (a forked child is not it)
    thread: int  # and its thread (threading.get_ident)
    fd: int
    depth: int


_HELD: dict[Path, _Held] = {}


def _read_holder(fd: int) -> LockHolder | None:
    """The holder's record in the lock file open as ``fd`` (None if there is none yet)."""
    for _ in range(_READ_TRIES):
        os.lseek(fd, 0, os.SEEK_SET)
        text = os.read(fd, 1 << 16).decode("utf-8", errors="replace")
        holder = LockHolder.from_text(text)
        if holder is not None:
            return holder
        time.sleep(_READ_PAUSE_S)
    return None


def _acquire(folder: Path, command: str) -> int:
    """Open and lock ``folder``'s lock file and write this process's record in it; the
    open file. :class:`FolderBusyError` if another process holds it."""
    path = folder / LOCK_FILE
    while True:
        try:  # O_NOFOLLOW: a link there is refused, never followed (nor its target cut)
            fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC | os.O_NOFOLLOW, 0o644)
        except OSError as exc:
            if path.is_symlink():
                raise OSError(
                    f"could not lock {folder}: {path} is a symbolic link, which is never "
                    "followed; remove it"
                ) from exc
            raise OSError(f"could not lock {folder}: {exc.strerror or exc}") from exc
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _read_holder(fd)
            os.close(fd)
            raise FolderBusyError(folder, holder) from None
        except OSError as exc:
            os.close(fd)
            raise OSError(f"could not lock {folder}: {exc.strerror or exc}") from exc
        try:
            here = os.lstat(path)
            mine = os.fstat(fd)
            same = (here.st_dev, here.st_ino) == (mine.st_dev, mine.st_ino)
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)  # the holder before removed that file as it released it: again
    try:
        record = json.dumps(asdict(LockHolder.this_process(command))).encode()
        os.ftruncate(fd, 0)
        os.write(fd, record)
    except OSError as exc:
        _release(path, fd)
        raise OSError(f"could not lock {folder}: {exc.strerror or exc}") from exc
    return fd


def _release(path: Path, fd: int) -> None:
    """Remove the lock file (while holding it), then release it."""
    try:
        path.unlink(missing_ok=True)
    finally:
        os.close(fd)


def _held_by_this_thread(folder: Path, key: Path) -> _Held | None:
    """This thread's hold of ``folder`` (``key``: its resolved path), None if this process
    holds none (a forked child's inherited record is not its own); FolderBusyError if
    another thread of this process holds it."""
    held = _HELD.get(key)
    if held is None or held.pid != os.getpid():
        return None
    if held.thread != threading.get_ident():
        raise FolderBusyError(folder, _read_holder(held.fd))
    return held


@contextmanager
def folder_lock(folder: str | os.PathLike, command: str) -> Iterator[None]:
    """Hold ``folder``'s lock (it must exist) for the block's duration, recording this
    process and ``command`` in ``folder/.observer-gym.lock``; released (and the file
    removed) when the block ends, however it ends, and by the kernel if the process dies.

    Raises:
        FolderBusyError: another process holds it (naming which); nothing was written.
        OSError: the lock file cannot be made or locked there (naming the folder).
    """
    folder = Path(folder)
    key = folder.resolve()
    held = _held_by_this_thread(folder, key)
    if held is not None:
        held.depth += 1
        try:
            yield
        finally:
            held.depth -= 1
        return
    fd = _acquire(folder, command)
    _HELD[key] = _Held(os.getpid(), threading.get_ident(), fd, 1)
    try:
        yield
    finally:
        del _HELD[key]
        _release(folder / LOCK_FILE, fd)


def check_not_busy(folder: str | os.PathLike) -> None:
    """:class:`FolderBusyError` if another process (or thread) holds ``folder``'s lock now;
    nothing if it is free or this thread holds it. A check, not a hold: the lock is
    released at once (the command takes it for good before it writes)."""
    folder = Path(folder)
    if _held_by_this_thread(folder, folder.resolve()) is not None:
        return
    try:
        fd = os.open(folder / LOCK_FILE, os.O_RDWR | os.O_CLOEXEC | os.O_NOFOLLOW)
    except OSError:  # no lock file (nobody holds it), a link, no folder: the lock says more
        return
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        raise FolderBusyError(folder, _read_holder(fd)) from None
    except OSError:
        return  # no flock there: folder_lock reports it when the command takes the lock
    finally:
        os.close(fd)  # releases the lock if this took it; the file stays for its holder
