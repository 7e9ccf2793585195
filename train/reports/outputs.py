"""What the commands leave behind: JSON and files written atomically, package versions,
text tables; and the output folder's upkeep after a run that was killed.

Atomic writes go through a temp file beside the target whose name carries the writer's
PID (:data:`TEMP_PATTERNS`), with SIGINT and SIGTERM held until the file is in place
(:func:`~observer_gym.train.core.signals.signals_deferred`); a failed write raises
:class:`~observer_gym.train.core.atomic_write.WriteError` and leaves the target as it was
(:mod:`observer_gym.train.core.atomic_write`). A report of several files is staged
and moved into place as a set (:func:`output_set`). A run killed with SIGKILL (or a power
cut) cannot remove its temps, nor say that it stopped; :func:`output_folder` therefore,
when a command starts writing into a folder, removes the temps there whose writer process
is gone and reports any earlier run into the folder that never finished (its marker file
remains), with an :class:`OutputFolderWarning` each.

One command at a time: :func:`output_folder` first takes the folder's lock
(:func:`~observer_gym.train.reports.folder_lock.folder_lock`; a second command into the
folder gets :class:`~observer_gym.train.reports.folder_lock.FolderBusyError`), then runs
the command's check of what the folder holds (``check``: :func:`check_folder_kind`, a
sweep's arguments, no training run yet), so a check and the writes it allows are never
separated by another command's writes.

Whether a writer is gone (:func:`writer_alive`): each writer records its PID, its host
name and, on Linux, its process start time (:func:`writer_identity`). On the same host it
is alive while a process with that PID exists, is not a zombie and (when both are known)
has the recorded start time, so a PID reused by another program does not count; a writer
on another host cannot be checked from here and is taken as alive.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import socket
import tempfile
import time
import warnings
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from datetime import datetime
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np

from observer_gym.envs.json_file import read_json
from observer_gym.train.core.atomic_write import WriteError, replace_atomically, write_error
from observer_gym.train.core.messages import OneLineWarning
from observer_gym.train.core.signals import signals_deferred
from observer_gym.train.reports.folder_lock import folder_lock

# The distributions that decide what an experiment computes.
# what package_versions records for a distribution that is not installed
NOT_INSTALLED = "not installed"
VERSIONED_PACKAGES = (
    "observer-gym",
    "gymnasium",
    "pybullet",
    "numpy",
    "opencv-python-headless",
    "control",
    "osqp",
    "stable-baselines3",
    "torch",
)


def default_out_dir(command: str) -> Path:
    """``observer-gym-out/<command>-YYYYmmdd-HHMMSS-PID`` under the current directory (the
    process id keeps two commands started in the same second apart)."""
    stamp = f"{datetime.now():%Y%m%d-%H%M%S}"
    return Path.cwd() / "observer-gym-out" / f"{command}-{stamp}-{os.getpid()}"


def package_versions(names: Iterable[str] = VERSIONED_PACKAGES) -> dict[str, str]:
    """Installed version of each distribution in ``names`` ("not installed" if missing)."""
    versions = {}
    for name in names:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = NOT_INSTALLED
    return versions


def to_jsonable(value: Any) -> Any:
    """``value`` with NumPy arrays and scalars, tuples and paths turned into JSON types."""
    if isinstance(value, Mapping):
        return {str(k): to_jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [to_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return to_jsonable(value.tolist())
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, Path):
        return str(value)
    return value


def _unwritable(value: Any, where: str) -> tuple[str, Any] | None:
    """The first place in ``value`` (JSON types) that JSON cannot hold, and its value."""
    if isinstance(value, dict):
        items = ((f"{where}.{key}" if where else str(key), v) for key, v in value.items())
    elif isinstance(value, list):
        items = ((f"{where}[{k}]", v) for k, v in enumerate(value))
    elif isinstance(value, float):
        return None if np.isfinite(value) else (where, value)
    elif value is None or isinstance(value, str | int):
        return None
    else:
        return where, value
    return next((bad for place, v in items if (bad := _unwritable(v, place))), None)


def json_text(data: Any) -> str:
    """``data`` as the JSON text :func:`write_json_atomic` writes (NumPy values converted
    by :func:`to_jsonable`, indented).

    Raises:
        ValueError: naming the first value JSON cannot hold (NaN, infinity, an object)
            and where it is (``cells[1].statistics.mean``); an undefined number must be
            None.
    """
    data = to_jsonable(data)
    try:
        return json.dumps(data, indent=2, allow_nan=False) + "\n"
    except (ValueError, TypeError):
        where, value = _unwritable(data, "") or ("", data)
        raise ValueError(
            f"{where or 'the data'} is {value!r}, which JSON cannot hold (an undefined "
            "number is None)"
        ) from None


class OutputFolderError(ValueError):
    """An output folder that cannot take a command's results: another command's, another
    sweep's, a training run already there. The command line says so in one line, exit
    code 2."""


class OutputFolderWarning(OneLineWarning):
    """What a command found in a folder it uses that an earlier, killed run left there:
    temp files it removed, a run that never finished."""


# The temp files of the atomic writes: write_json_atomic's ".NAME.PID.XXXXXXXX.tmp" (before
# PIDs were recorded ".NAME.XXXXXXXX.tmp", the writer unknown), replace_atomically's
# ".NAME.tmp-PID" and output_set's staging folder ".outputs.tmp-PID"; the group "pid" is
# the writer's.
TEMP_PATTERNS = (
    re.compile(r"^\..+?\.(?:(?P<pid>\d+)\.)?[a-z0-9_]{8}\.tmp$"),
    re.compile(r"^\..+\.tmp-(?P<pid>\d+)$"),
)
# The marker a command keeps in its output folder while it writes there (output_folder).
MARKER_PATTERN = re.compile(r"^\.observer-gym-running-(?P<pid>\d+)\.json$")


def _process_stat(pid: int) -> list[str] | None:
    """The fields of ``/proc/PID/stat`` after the command name (state first), or None
    where that cannot be read (no such process, no /proc)."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    return text[text.rfind(")") + 2 :].split()


def _process_start(pid: int) -> int | None:
    """The start time of process ``pid`` (clock ticks after boot, Linux), else None."""
    stat = _process_stat(pid)
    return None if stat is None or len(stat) < 20 else int(stat[19])


def writer_identity() -> dict[str, Any]:
    """This process as a writer records itself: ``pid``, ``host`` and ``pid_start`` (its
    start time on Linux, None elsewhere)."""
    pid = os.getpid()
    return {"pid": pid, "host": socket.gethostname(), "pid_start": _process_start(pid)}


def process_alive(pid: int, start: int | None = None) -> bool:
    """Whether process ``pid`` of this host runs (exists and is no zombie) and, if
    ``start`` is given and known here, started at that time (so it is not a reused PID)."""
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass  # another user's process: it exists
    stat = _process_stat(pid)
    if stat is None:
        return True  # no /proc here: existence is all we know
    if stat[0] in ("Z", "X"):
        return False  # a zombie: it has exited, only its parent has not reaped it
    return start is None or len(stat) < 20 or int(stat[19]) == start


def writer_alive(record: Mapping[str, Any]) -> bool:
    """Whether the writer ``record`` names (:func:`writer_identity`'s keys) still runs:
    checked on this host (:func:`process_alive`); a writer on another host is taken as
    alive (it cannot be checked from here), one without a PID as gone."""
    pid = record.get("pid")
    if not isinstance(pid, int):
        return False
    if record.get("host", socket.gethostname()) != socket.gethostname():
        return True
    return process_alive(pid, record.get("pid_start"))


def remove_stale_temps(folder: str | os.PathLike, all_temps: bool = False) -> list[Path]:
    """Remove the atomic writes' temp files and staging folders (:data:`TEMP_PATTERNS`) in
    ``folder`` and its subfolders whose writer process is gone (a temp without a PID counts
    as gone), or all of them with ``all_temps``; warns (:class:`OutputFolderWarning`)
    naming how many, and returns their paths."""
    folder = Path(folder)
    removed = []
    for path in sorted(folder.rglob(".*")) if folder.is_dir() else []:
        match = next((m for p in TEMP_PATTERNS if (m := p.match(path.name))), None)
        if match is None or path.is_symlink() or not (path.is_file() or path.is_dir()):
            continue  # (a path inside a staging folder removed just before is gone)
        pid = match["pid"]
        if not all_temps and pid is not None and process_alive(int(pid)):
            continue
        if path.is_dir():  # output_set's staging folder
            shutil.rmtree(path, ignore_errors=True)
        else:
            path.unlink(missing_ok=True)
        removed.append(path)
    if removed:
        names = ", ".join(p.relative_to(folder).as_posix() for p in removed[:3])
        more = f" and {len(removed) - 3} more" if len(removed) > 3 else ""
        warnings.warn(
            f"removed {len(removed)} temp file(s) in {folder} left by a run that was killed "
            f"while writing: {names}{more}",
            OutputFolderWarning,
            stacklevel=2,
        )
    return removed


def check_writable_folder(folder: str | os.PathLike, what: str) -> Path:
    """``folder``, created if needed, once a file could be made in it (a probe, removed);
    else WriteError "cannot write WHAT: REASON" (one line). Then removes the temps there of
    writers that are gone (:func:`remove_stale_temps`). For a command's up-front check
    of where it will write, before anything runs."""
    path = Path(folder)
    try:
        path.mkdir(parents=True, exist_ok=True)
        probe = path / f".write-probe.tmp-{os.getpid()}"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as exc:
        raise WriteError(f"cannot write {what}: {exc.strerror or exc}") from exc
    remove_stale_temps(path)
    return path


def _report_killed_runs(folder: Path) -> None:
    """Warn of each earlier run whose marker is in ``folder`` but whose writer is gone
    (killed before it finished), and remove its marker."""
    for path in sorted(folder.glob(".observer-gym-running-*.json")):
        if MARKER_PATTERN.match(path.name) is None:
            continue
        try:
            record = read_json(path)
        except (OSError, ValueError):
            record = {}
        if not isinstance(record, dict):
            record = {}
        if writer_alive(record):
            continue  # still writing (or on another host): its marker stays
        warnings.warn(
            f"an earlier 'observer-gym {record.get('command', '?')}' into {folder} "
            f"(pid {record.get('pid', '?')} on {record.get('host', '?')}, started "
            f"{record.get('started', '?')}) was killed before it finished; what it left "
            "there is incomplete and may be overwritten",
            OutputFolderWarning,
            stacklevel=3,
        )
        path.unlink(missing_ok=True)


def make_dirs(path: str | os.PathLike) -> list[Path]:
    """Create the folder ``path`` and its missing parents; returns those it created,
    outermost first."""
    path = Path(path)
    missing = []
    level = path
    while not level.exists() and level != level.parent:
        missing.append(level)
        level = level.parent
    path.mkdir(parents=True, exist_ok=True)
    return missing[::-1]


def remove_if_empty(created: Sequence[Path]) -> None:
    """Remove the folders ``created`` (outermost first, as :func:`make_dirs` returns them)
    innermost first while they are empty; the first one that is not stops it."""
    for folder in reversed(created):
        try:
            folder.rmdir()
        except OSError:  # not empty (or already gone): it and its parents stay
            return


def folder_kind(path: str | os.PathLike) -> str | None:
    """Which command's results ``path`` holds, from the files they leave: "benchmark"
    (``benchmark.json``), "sweep"
    (``sweep.json`` or ``cells/``), "train" (a run's ``config.json``, or ``seeds.json`` of
    ``train --seeds``), "compare" (a ``results.json`` with pairs), "run" (one of ``run`` or
    ``evaluate``), "demo" (``summary.json``); None for a new or empty folder, or one
    holding none of these."""
    path = Path(path)
    if (path / "benchmark.json").exists():
        return "benchmark"
    if (path / "sweep.json").exists() or (path / "cells").is_dir():
        return "sweep"
    if (path / "config.json").exists() or (path / "seeds.json").exists():
        return "train"
    results = path / "results.json"
    if results.exists():
        try:
            data = read_json(results)
        except (OSError, ValueError):
            return "unknown"
        if isinstance(data, dict) and "pairs" in data:
            return "compare"
        if isinstance(data, dict) and "cells" in data:
            return "sweep"
        return "run"
    if (path / "summary.json").exists():
        return "demo"
    return None


def check_folder_kind(path: str | os.PathLike, command: str) -> None:
    """:class:`OutputFolderError` (a ValueError), one line, if ``path`` holds another
    command's results than ``command``'s ("run" and "evaluate" write the same kind):
    writing there would mix the two or overwrite the other's."""
    kind = folder_kind(path)
    same = {"run": "run", "evaluate": "run"}.get(command, command)
    if kind is not None and kind != same:
        other = (
            "an unreadable results.json" if kind == "unknown" else f"'observer-gym {kind}' results"
        )
        raise OutputFolderError(f"{path} holds {other}; use another output folder")


@contextmanager
def output_folder(
    path: str | os.PathLike,
    command: str,
    marker: bool = True,
    all_temps: bool = False,
    check: Callable[[Path], None] | None = None,
) -> Iterator[Path]:
    """The folder a command writes into, for the ``with`` block's duration, held by this
    process alone.

    Creates ``path`` (and missing parents) and takes its lock
    (:func:`~observer_gym.train.reports.folder_lock.folder_lock`, ``command`` recorded in
    it; :class:`~observer_gym.train.reports.folder_lock.FolderBusyError` if another
    process holds it), held until the block ends, however it ends. Then, before anything
    is written, ``check(path)`` if given (it raises to refuse the folder: what it holds
    cannot change until the lock is released); reports earlier runs into it that were
    killed (their marker remains) and removes stale temps (:func:`remove_stale_temps`,
    with ``all_temps``), each with an :class:`OutputFolderWarning`. With ``marker``,
    keeps ``.observer-gym-running-<PID>.json`` (:func:`writer_identity`, ``command``, the
    start time) in it until the block ends, however it ends. If the lock, the check or
    the block raises (an error, Ctrl-C), the empty subfolders made in the block (a run's
    ``frames/``) and then the folders this created are removed while empty, so a run
    that fails before writing anything leaves no folder behind; a folder that was there
    stays.
    """
    path = Path(path)
    created = make_dirs(path)
    try:
        with folder_lock(path, command):
            if check is not None:
                check(path)
            existing = {p for p in path.rglob("*") if p.is_dir()}
            _report_killed_runs(path)
            remove_stale_temps(path, all_temps)
            marker_path = path / f".observer-gym-running-{os.getpid()}.json"
            if marker:
                record = {
                    **writer_identity(),
                    "command": command,
                    "started": time.strftime("%Y-%m-%d %H:%M:%S"),
                }
                write_json_atomic(marker_path, record)
            try:
                yield path
            except BaseException:
                if marker:
                    marker_path.unlink(missing_ok=True)
                for parent, folders, _ in os.walk(path, topdown=False):
                    for folder in (Path(parent) / name for name in folders):
                        if folder not in existing:
                            try:
                                folder.rmdir()
                            except OSError:  # not empty: something was written there
                                pass
                raise
            if marker:
                marker_path.unlink(missing_ok=True)
    except BaseException:
        remove_if_empty(created)
        raise


def write_text_atomic(path: str | os.PathLike, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` as :func:`replace_atomically` does."""
    replace_atomically(path, lambda tmp: tmp.write_text(text, encoding="utf-8"))


def write_json_atomic(path: str | os.PathLike, data: Any) -> None:
    """Write ``data`` as JSON to a temp file beside ``path`` (``.NAME.PID.XXXXXXXX.tmp``),
    then rename it into place, with SIGINT and SIGTERM held until both are done
    (:func:`~observer_gym.train.core.signals.signals_deferred`).

    A reader sees the old file or the whole new one, never half of it. NumPy values are
    converted (:func:`to_jsonable`); NaN and infinity raise ``ValueError`` (they are not
    JSON), before anything is written, so undefined numbers must be given as None. A
    failed write raises :class:`WriteError` and leaves ``path`` as it was. No temp file
    is left behind unless the process is killed while writing
    (:func:`remove_stale_temps` removes it then).
    """
    path = Path(path)
    text = json_text(data)
    with signals_deferred():
        try:
            fd, tmp_name = tempfile.mkstemp(
                dir=path.parent, prefix=f".{path.name}.{os.getpid()}.", suffix=".tmp"
            )
        except OSError as exc:
            raise write_error(path, exc) from exc
        try:
            with os.fdopen(fd, "w") as f:
                f.write(text)
            os.chmod(tmp_name, 0o644)  # mkstemp makes it owner-only
            os.replace(tmp_name, path)
        except OSError as exc:
            raise write_error(path, exc) from exc
        finally:
            Path(tmp_name).unlink(missing_ok=True)


@contextmanager
def output_set(
    out_dir: str | os.PathLike, last: Sequence[str] = ("results.json",)
) -> Iterator[Path]:
    """A staging folder, ``out_dir/.outputs.tmp-PID``, to write a set of outputs into as
    into ``out_dir``; they reach ``out_dir`` together or not at all.

    If the block ends normally, every file written there is renamed to the same place in
    ``out_dir`` (subfolders made as needed; the names in ``last`` after the others), with
    SIGINT and SIGTERM held until all are in place. If it raises (a bad value, a full disk,
    Ctrl-C), the staging folder is removed and ``out_dir`` keeps the files it had: a reader
    finds the earlier set or the new one, not a part of each.
    """
    out_dir = Path(out_dir)
    staging = out_dir / f".outputs.tmp-{os.getpid()}"
    try:
        staging.mkdir()
    except OSError as exc:
        raise write_error(out_dir, exc) from exc
    try:
        try:
            yield staging
        except WriteError as exc:  # named by where it was going, not by the staging folder
            raise WriteError(str(exc).replace(str(staging), str(out_dir))) from exc
        files = sorted(p for p in staging.rglob("*") if p.is_file())
        files.sort(key=lambda p: p.relative_to(staging).as_posix() in last)
        with signals_deferred():
            for file in files:
                target = out_dir / file.relative_to(staging)
                try:
                    target.parent.mkdir(parents=True, exist_ok=True)
                    os.replace(file, target)
                except OSError as exc:
                    raise write_error(target, exc) from exc
    finally:
        shutil.rmtree(staging, ignore_errors=True)


def format_table(headers: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    """A Markdown table: ``headers`` and ``rows`` of cell texts, columns padded to width."""
    widths = [len(h) for h in headers]
    for row in rows:
        if len(row) != len(headers):
            raise ValueError(f"row {list(row)} has {len(row)} cells, expected {len(headers)}")
        widths = [max(w, len(cell)) for w, cell in zip(widths, row, strict=True)]

    def line(cells: Sequence[str]) -> str:
        return "| " + " | ".join(c.ljust(w) for c, w in zip(cells, widths, strict=True)) + " |"

    rule = "|" + "|".join("-" * (w + 2) for w in widths) + "|"
    return "\n".join([line(headers), rule, *(line(row) for row in rows)])
