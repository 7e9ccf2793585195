"""A benchmark run's level files, ``levels/<level>.json``: what a finished level records,
and whether a level file found in the output folder is the plan's level, unchanged,
before a resumed run reuses it (as ``sweep`` does with its cells,
:mod:`observer_gym.train.experiments.sweep_cells`).

A level file records the run's digest (:func:`plan_digest`: suite version, env, level
options, observer, controller, episodes), the level's name, its seeds, each episode's
headline value, and the sha256 of these. :func:`level_problem` says what makes a file
not the plan's level as written (another run, other seeds, a value changed without the
hash, a file cut short); such a level runs again, with a warning.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping, Sequence
from typing import Any

from observer_gym.train.reports.outputs import OneLineWarning

LEVELS_DIR = "levels"
LEVEL_FORMAT = 1
HASHED = ("run", "level", "seeds", "values")


class BenchmarkWarning(OneLineWarning):
    """Something about a benchmark's output folder worth knowing (a level run again)."""


def canonical_sha256(data: Any) -> str:
    """The sha256 of ``data`` as canonical JSON (sorted keys, no spaces)."""
    text = json.dumps(data, sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hashlib.sha256(text.encode()).hexdigest()


def plan_digest(identity: Mapping[str, Any]) -> str:
    """The digest of what decides a run's numbers (``identity``: JSON types)."""
    return canonical_sha256(identity)[:16]


def level_file(
    digest: str,
    level: str,
    seeds: Sequence[int],
    values: Sequence[float],
    episode_s: Sequence[float],
    wall_s: float | None = None,
) -> dict[str, Any]:
    """What ``levels/<level>.json`` holds for a finished level; ``timing`` (outside the
    hash): each episode's time and the level's wall time ``wall_s`` (the levels run in one
    batch: the time from the batch's start, or the previous level's end, to its end, so
    the levels of a batch sum to the batch's wall time)."""
    data: dict[str, Any] = {
        "format": LEVEL_FORMAT,
        "run": digest,
        "level": level,
        "seeds": list(seeds),
        "values": [float(v) for v in values],
    }
    data["sha256"] = canonical_sha256({key: data[key] for key in HASHED})
    data["timing"] = {"episode_s": [float(t) for t in episode_s]}
    if wall_s is not None:
        data["timing"]["wall_s"] = float(wall_s)
    return data


def level_wall_s(data: Mapping[str, Any]) -> float:
    """A finished level file's wall time: its ``timing.wall_s``, or for a file written
    before levels recorded it, the sum of its episodes' times (one worker's wall time)."""
    timing = data.get("timing")
    timing = timing if isinstance(timing, dict) else {}
    wall_s = timing.get("wall_s")
    if isinstance(wall_s, int | float) and not isinstance(wall_s, bool):
        return float(wall_s)
    episode_s = timing.get("episode_s")
    if isinstance(episode_s, list):
        return float(sum(t for t in episode_s if isinstance(t, int | float)))
    return 0.0


def level_problem(data: Any, digest: str, level: str, seeds: Sequence[int]) -> str | None:
    """What makes the level file ``data`` (as read) not ``level`` of the run ``digest``
    on ``seeds`` as it was written, in words; None if nothing does."""
    if not isinstance(data, dict):
        return "it is not a JSON object"
    if data.get("format") != LEVEL_FORMAT:
        return f"it is in format {data.get('format')!r}, not {LEVEL_FORMAT}"
    if data.get("run") != digest:
        return f"it belongs to another run ({data.get('run')!r}, not {digest})"
    if data.get("level") != level:
        return f"it is level {data.get('level')!r}'s"
    if data.get("seeds") != list(seeds):
        return "its seeds are not the level's"
    values = data.get("values")
    if not isinstance(values, list) or len(values) != len(seeds):
        return (
            f"it holds {len(values) if isinstance(values, list) else 'no'} values, not {len(seeds)}"
        )
    if not all(isinstance(v, int | float) and not isinstance(v, bool) for v in values):
        return "a value is not a number"
    if data.get("sha256") != canonical_sha256({key: data.get(key) for key in HASHED}):
        return "its sha256 is not that of its values (edited, or cut short)"
    return None
