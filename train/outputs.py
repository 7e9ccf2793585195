"""What the commands leave behind: JSON written atomically, package versions, text tables."""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Iterable, Mapping, Sequence
from datetime import datetime
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np

# The distributions that decide what an experiment computes.
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
    """``observer-gym-out/<command>-YYYYmmdd-HHMMSS`` under the current directory."""
    return Path.cwd() / "observer-gym-out" / f"{command}-{datetime.now():%Y%m%d-%H%M%S}"


def package_versions(names: Iterable[str] = VERSIONED_PACKAGES) -> dict[str, str]:
    """Installed version of each distribution in ``names`` ("not installed" if missing)."""
    versions = {}
    for name in names:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = "not installed"
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


def write_json_atomic(path: str | os.PathLike, data: Any) -> None:
    """Write ``data`` as JSON to a temp file beside ``path``, then rename it into place.

    A reader sees the old file or the whole new one, never half of it. NumPy values are
    converted (:func:`to_jsonable`); NaN and infinity raise ``ValueError`` (they are not
    JSON), so undefined numbers must be given as None. No temp file is left behind.
    """
    path = Path(path)
    text = json.dumps(to_jsonable(data), indent=2, allow_nan=False) + "\n"
    fd, tmp_name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as f:
            f.write(text)
        os.chmod(tmp_name, 0o644)  # mkstemp makes it owner-only
        os.replace(tmp_name, path)
    except BaseException:
        Path(tmp_name).unlink(missing_ok=True)
        raise


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
