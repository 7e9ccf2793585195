"""Reading a JSON file the package did not just write, strictly: one reader for every
such file (a run's config.json and checkpoint records, a results folder's scores.json, a
sweep's cells, learned weights' reports, ...).

:func:`read_json` refuses, with a :class:`JSONFileError` (a ValueError) naming the file:

- a path that is no regular file (a folder, or a link to ``/dev/zero`` or a FIFO, which
  would be read forever), and a file larger than ``max_bytes``;
- text that is not UTF-8 JSON;
- an object with a key twice (``{"aggregate": 1, "aggregate": 2}``): Python's ``json``
  keeps the last one, another reader may show the first, so such a file means different
  things to different readers;
- ``NaN`` and ``Infinity`` (no JSON; the package never writes them) unless
  ``allow_nan``;
- nesting deeper than ``max_depth`` (Python's parser would stop with a RecursionError).

It lives in ``envs/``, the lowest layer, so that ``estimation/`` and ``train/`` share it.
The standard library parses; what it does not check (duplicate keys, depth, the size and
kind of file) is checked here.
"""

from __future__ import annotations

import json
import os
import stat
from collections.abc import Iterable
from pathlib import Path
from typing import Any

MAX_JSON_BYTES = 256 * 1024 * 1024  # a sweep's results.json of many cells stays far below
MAX_JSON_DEPTH = 64  # the package's files nest at most about 8 levels


class JSONFileError(ValueError):
    """A JSON file that cannot be read as the package's: its path and why."""


def read_bytes_limited(path: str | os.PathLike, max_bytes: int) -> bytes:
    """The bytes of the regular file ``path`` (a link is followed), at most ``max_bytes``.

    Raises:
        JSONFileError: no regular file there (a folder, a device such as ``/dev/zero``, a
            FIFO), or one larger than ``max_bytes``.
        OSError: it cannot be opened or read (no such file, no permission).
    """
    path = Path(path)
    # O_NONBLOCK: opening a FIFO does not wait for a writer; it is refused below
    fd = os.open(path, os.O_RDONLY | os.O_CLOEXEC | os.O_NONBLOCK)
    with os.fdopen(fd, "rb") as f:
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):
            raise JSONFileError(f"{path} is not a regular file (a device, FIFO or folder)")
        data = f.read(max_bytes + 1)
    if len(data) > max_bytes:
        raise JSONFileError(f"{path} is larger than {max_bytes} bytes, the most read here")
    return data


def _object_without_duplicates(pairs: Iterable[tuple[str, Any]]) -> dict[str, Any]:
    result: dict[str, Any] = {}
    for key, value in pairs:
        if key in result:
            raise ValueError(f"the key {key!r} appears twice in one object")
        result[key] = value
    return result


def _no_constant(name: str) -> Any:
    raise ValueError(f"{name} is not JSON")


def _depth(value: Any, max_depth: int) -> int | None:
    """The nesting depth of ``value`` if it exceeds ``max_depth``, else None (iterative:
    no recursion on a deep value)."""
    stack = [(value, 1)]
    while stack:
        item, depth = stack.pop()
        if isinstance(item, dict | list):
            if depth > max_depth:
                return depth
            children = item.values() if isinstance(item, dict) else item
            stack.extend((child, depth + 1) for child in children)
    return None


def parse_json(
    text: str | bytes,
    source: str,
    *,
    allow_nan: bool = False,
    max_depth: int = MAX_JSON_DEPTH,
) -> Any:
    """``text`` parsed as :func:`read_json` parses a file; ``source`` names it in errors.

    Raises:
        JSONFileError: see :func:`read_json`.
    """
    try:
        if isinstance(text, bytes):
            text = text.decode("utf-8")
        data = json.loads(
            text,
            object_pairs_hook=_object_without_duplicates,
            parse_constant=None if allow_nan else _no_constant,
        )
    except RecursionError:
        raise JSONFileError(
            f"{source} is nested deeper than Python's parser goes; at most {max_depth} "
            "levels are read"
        ) from None
    except (ValueError, UnicodeDecodeError) as exc:
        raise JSONFileError(f"{source} is not valid JSON: {exc}") from None
    if _depth(data, max_depth) is not None:
        raise JSONFileError(f"{source} is nested deeper than {max_depth} levels, the most read")
    return data


def read_json(
    path: str | os.PathLike,
    *,
    allow_nan: bool = False,
    max_bytes: int = MAX_JSON_BYTES,
    max_depth: int = MAX_JSON_DEPTH,
) -> Any:
    """The JSON in the file ``path``, read strictly (see the module docstring).

    Raises:
        JSONFileError: (a ValueError) no regular file, too large, not UTF-8 JSON, a key
            twice in one object, NaN or infinity (unless ``allow_nan``), nested deeper
            than ``max_depth``; naming ``path``.
        OSError: it cannot be opened or read (no such file, no permission).
    """
    data = read_bytes_limited(path, max_bytes)
    return parse_json(data, str(path), allow_nan=allow_nan, max_depth=max_depth)
