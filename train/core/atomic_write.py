"""One file written atomically: through a temp file beside the target whose name carries
the writer's PID, then renamed onto it, with SIGINT and SIGTERM held until the file is in
place (:func:`~observer_gym.train.core.signals.signals_deferred`). A failed write raises
:class:`WriteError` and leaves the target as it was. The output folders built on this are
in :mod:`observer_gym.train.reports.outputs`."""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

from observer_gym.train.core.signals import signals_deferred


class WriteError(OSError):
    """A file could not be written: its path and why. The file is as it was before."""


def write_error(path: Path, exc: BaseException) -> WriteError:
    """The :class:`WriteError` for ``path`` failing with ``exc``, on one line."""
    return WriteError(f"could not write {path}: {' '.join(str(exc).split())}")


def temp_path_for(path: str | os.PathLike) -> Path:
    """The temp :func:`replace_atomically` writes ``path`` through: ``.NAME.tmp-PID``
    beside it (a writer that streams into the file before the rename, such as a rerun
    recording, opens this one)."""
    path = Path(path)
    return path.with_name(f".{path.name}.tmp-{os.getpid()}")


def replace_atomically(path: str | os.PathLike, write: Callable[[Path], Any]) -> None:
    """Write with ``write(tmp_path)`` then rename onto ``path`` (atomic on POSIX), with
    SIGINT and SIGTERM held until both are done
    (:func:`~observer_gym.train.core.signals.signals_deferred`). The temp is ``.NAME.tmp-PID``
    beside ``path``; if ``write`` or the rename fails, the temp is removed, ``path`` is as
    it was and :class:`WriteError` names it (an ``OSError`` from the file system, or a
    ``RuntimeError`` from PyTorch's zip writer, which reports a full disk so)."""
    path = Path(path)
    tmp = temp_path_for(path)
    with signals_deferred():
        try:
            write(tmp)
            os.replace(tmp, path)
        except (OSError, RuntimeError) as exc:
            raise write_error(path, exc) from exc
        finally:
            tmp.unlink(missing_ok=True)
