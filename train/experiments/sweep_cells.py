"""A sweep's cell files, ``cells/<id>.json``: what a finished cell records, and whether a
cell file found in the output folder is the plan's cell, unchanged, before a resumed
sweep reuses it.

A cell file (:func:`cell_file`) records the cell's identity (the sweep's digest, the
cell's id, grid point, observer and controller), its episode records (per episode: index,
seed and the task's metrics), their start states and the controller's design, the
sha256 of all these (:func:`records_sha256`), the statistics of every compared metric
over the records (``summary``) and the episodes' times. :func:`finished_cells` reuses a
cell file only if it is the plan's cell as written: the identity and the seeds those
of the plan's cell, the sha256 that of what it holds, the statistics those re-derived
from its records. Any other file is reported with a :class:`SweepWarning` naming the cell
and what differed, and the cell runs again. This finds a cell file copied over another
cell's, edited seeds or metrics and a file cut short; it is no signature (whoever
rewrites the records, the hash and the statistics together is not caught).
"""

from __future__ import annotations

import hashlib
import json
import math
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from observer_gym.envs.json_file import read_json
from observer_gym.train.experiments.sweep_plan import CELLS_DIR, Cell, SweepPlan
from observer_gym.train.reports.compare_stats import compare_metrics, metrics_statistics
from observer_gym.train.reports.outputs import OneLineWarning, json_text

# 2: the records' sha256 and their summary (format 1 had neither, and is run again)
CELL_FORMAT = 2
# What the sha256 covers: everything but the times, the hash and the summary.
HASHED = ("sweep", "id", "point", "observer", "controller", "controller_config", "episodes",
          "starts")  # fmt: skip
_REL_TOL = 1e-9  # re-derived statistics: the same numbers up to the last bits


class SweepWarning(OneLineWarning):
    """Something about a sweep's pairing or its output folder worth knowing."""


def records_sha256(data: Mapping[str, Any]) -> str:
    """The sha256 of the :data:`HASHED` fields of the cell file ``data`` as canonical
    JSON (sorted keys, no spaces)."""
    body = {key: data[key] for key in HASHED}
    text = json.dumps(body, sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hashlib.sha256(text.encode()).hexdigest()


def _summary(plan: SweepPlan, episodes: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    statistics = metrics_statistics(episodes, compare_metrics(plan.request.task))
    return json.loads(json.dumps(statistics))  # JSON types, as read back from the file


def cell_file(plan: SweepPlan, cell: Cell, episodes: Sequence[Mapping[str, Any]]) -> dict:
    """What ``cells/<id>.json`` holds for the finished ``cell`` (``episodes``: the
    :func:`~observer_gym.train.experiments.sweep.sweep_episode` of each seed, in order), in
    JSON types as read back from the file.

    Raises:
        ValueError: a value JSON cannot hold (NaN, infinity), naming where it is.
    """
    data = json.loads(
        json_text(
            {
                "format": CELL_FORMAT,
                "sweep": plan.digest(),
                "id": cell.id,
                "point": dict(cell.point),
                "observer": cell.observer,
                "controller": cell.controller,
                "controller_config": episodes[0]["controller"],
                "episodes": [
                    {"episode": i, "seed": seed, **episode["metrics"]}
                    for i, (seed, episode) in enumerate(zip(plan.seeds, episodes, strict=True))
                ],
                "starts": [episode["start"] for episode in episodes],
                "timing": {"episode_s": [episode["time_s"] for episode in episodes]},
            }
        )
    )
    data["records_sha256"] = records_sha256(data)
    data["summary"] = _summary(plan, data["episodes"])
    return data


def _shown(value: Any) -> str:
    text = json.dumps(value, separators=(",", ":"))
    return text if len(text) <= 60 else text[:57] + "..."


def _close(a: Any, b: Any) -> bool:
    """``a`` equals ``b`` (JSON values), numbers up to :data:`_REL_TOL`."""
    if isinstance(a, bool) or isinstance(b, bool):
        return a is b
    if isinstance(a, int | float) and isinstance(b, int | float):
        return math.isclose(a, b, rel_tol=_REL_TOL, abs_tol=1e-300)
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_close(a[k], b[k]) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_close(x, y) for x, y in zip(a, b, strict=True))
    return a == b


def cell_problem(data: Any, plan: SweepPlan, cell: Cell) -> str | None:
    """What makes the cell file ``data`` (as read) not ``cell`` of ``plan`` as it was
    written, in words; None if nothing does."""
    if not isinstance(data, dict):
        return "it is not a JSON object"
    if data.get("format") != CELL_FORMAT:
        return (
            f"it is in cell format {_shown(data.get('format'))}, not {CELL_FORMAT} (the "
            "format that records the sha256 of its episode records)"
        )
    if data.get("sweep") != plan.digest():
        return f"it belongs to another sweep ({_shown(data.get('sweep'))}, not {plan.digest()})"
    here = {"id": cell.id, "point": dict(cell.point), "observer": cell.observer,
            "controller": cell.controller}  # fmt: skip
    for key, value in here.items():
        if data.get(key) != value:
            return f"its {key} is {_shown(data.get(key))}, not {_shown(value)}"
    episodes, starts = data.get("episodes"), data.get("starts")
    if not isinstance(episodes, list) or not all(isinstance(e, dict) for e in episodes):
        return "its episodes are not a list of records"
    seeds = [e.get("seed") for e in episodes]
    if seeds != list(plan.seeds):
        return f"its seeds are {_shown(seeds)}, not {_shown(list(plan.seeds))}"
    if [e.get("episode") for e in episodes] != list(range(len(plan.seeds))):
        return "its episodes are not numbered 0, 1, ... in order"
    if not isinstance(starts, list) or len(starts) != len(plan.seeds):
        return f"it has not one start state per episode ({len(plan.seeds)})"
    try:
        digest = records_sha256(data)
    except (KeyError, ValueError, TypeError) as exc:
        return f"its records cannot be hashed ({exc})"
    if data.get("records_sha256") != digest:
        return (
            "its records do not match the sha256 recorded with them (changed after it was written)"
        )
    try:
        summary = _summary(plan, episodes)
    except (ValueError, TypeError) as exc:
        return f"its episode records cannot be summarised ({exc})"
    stored = data.get("summary")
    if not isinstance(stored, dict) or stored.keys() != summary.keys():
        return "its summary does not list the compared metrics"
    for key, value in summary.items():
        if not _close(stored[key], value):
            return f"its summary of {key} is not that of its episode records"
    return None


def finished_cells(out_dir: Path, plan: SweepPlan) -> dict[str, dict]:
    """The plan's cells already in ``out_dir/cells`` (by id) that :func:`cell_problem`
    finds nothing wrong with; each other cell file found there is left out with a
    :class:`SweepWarning` naming it and what differed (that cell runs again)."""
    found: dict[str, dict] = {}
    for cell in plan.cells:
        path = out_dir / CELLS_DIR / f"{cell.id}.json"
        if not path.exists():
            continue
        problem: str | None
        try:
            data = read_json(path)
        except (OSError, ValueError) as exc:
            problem = f"it is not readable as JSON ({' '.join(str(exc).split())})"
        else:
            problem = cell_problem(data, plan, cell)
        if problem is not None:
            warnings.warn(
                f"{path} is not this sweep's finished cell {cell.id}: {problem}; it runs again",
                SweepWarning,
                stacklevel=3,
            )
            continue
        found[cell.id] = data
    return found
