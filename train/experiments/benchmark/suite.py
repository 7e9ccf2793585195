"""A benchmark suite: its data files, read and checked.

A suite version (``v1``) is a folder ``suites/<version>/`` inside the package with one
JSON file per system (``<system>.json``, the system's ``name``: ``ball_table.json``).
Each file holds the system's sensor levels (the ``gym.make`` options of each, its fixed
evaluation seeds), the headline metric, the reference controller, and per level the
reference values that fix the normalised score (the oracle's, the raw floor's and the
idle floor's mean of the metric, with the command that measured them).
docs/benchmark.md gives every number's reason.

:func:`load_suite` reads one file and checks it: the version and env match where the
file sits, every option is a field of the env's config and in its range (the config's
own checks, which build no world), the seeds are fixed (a first seed and a count),
unique within the suite and disjoint from the seeds 0-99 the docs use, the metric is one
the task measures. Any fault raises ValueError naming the file, the key and what is
allowed. A level never changes within a suite version: a new level or a changed number
is a new version.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from importlib import resources
from pathlib import Path
from typing import Any, NamedTuple

from observer_gym.envs import System, system_for_id
from observer_gym.envs.json_file import read_json

SUITES_PACKAGE = "observer_gym.train.experiments.benchmark"
DEFAULT_VERSION = "v1"
DOC_SEEDS = range(0, 100)  # the seeds docs/ and examples use: never an evaluation seed
BETTER = ("lower", "higher")
REFERENCES = ("oracle", "raw", "idle")


class Metric(NamedTuple):
    """A system's headline metric: a key of the task's episode metrics."""

    name: str  # e.g. "mean_distance_m"
    better: str  # "lower" or "higher", as the task's COMPARE_METRICS says


class References(NamedTuple):
    """A level's reference values of the metric (each the mean over the level's seeds)."""

    oracle: float  # the oracle observer with the reference controller: score 1
    raw: float  # the camera's detections, no filter, the reference controller
    idle: float  # the zero action (doing nothing)
    episodes: int  # how many of the level's seeds they were measured on

    def floor(self, better: str) -> tuple[str, float]:
        """The floor (score 0): the worse of ``raw`` and ``idle``, with its name."""
        worse = max if better == "lower" else min
        value = worse(self.raw, self.idle)
        return ("raw" if value == self.raw else "idle"), value


class Level(NamedTuple):
    """One sensor level of a system's suite."""

    name: str  # "ideal", "lab", "field"
    env_options: dict[str, Any]  # gym.make keyword arguments
    seed_start: int  # episode i resets with seed_start + i

    def seeds(self, episodes: int) -> list[int]:
        return list(range(self.seed_start, self.seed_start + episodes))


class SystemSuite(NamedTuple):
    """One system's part of a suite version, as checked by :func:`load_suite`."""

    version: str
    system: System
    metric: Metric
    controller: str  # the reference controller
    floor_observer: str  # the raw baseline's observer (the camera, no filter)
    episodes: int  # per level, official
    levels: tuple[Level, ...]
    references: dict[str, References]  # by level name
    references_command: str  # what measured the references
    path: str  # the file read, for messages

    @property
    def env_id(self) -> str:
        return self.system.env_id

    def level(self, name: str) -> Level:
        for level in self.levels:
            if level.name == name:
                return level
        allowed = ", ".join(level.name for level in self.levels)
        raise ValueError(f"suite {self.version} has no level {name!r}; allowed: {allowed}")


def suite_path(version: str, system: System) -> Path:
    """The file of ``system``'s part of suite ``version`` (it may not exist)."""
    root = resources.files(SUITES_PACKAGE).joinpath("suites")
    return Path(str(root)) / version / f"{system.name}.json"


def suite_versions() -> list[str]:
    """The suite versions shipped in the package, sorted."""
    root = Path(str(resources.files(SUITES_PACKAGE).joinpath("suites")))
    return sorted(p.name for p in root.iterdir() if p.is_dir() and not p.name.startswith("_"))


def load_suite(
    env_id: str, version: str = DEFAULT_VERSION, path: Path | None = None
) -> SystemSuite:
    """``env_id``'s part of suite ``version`` (from ``path`` if given, else the package's
    file), checked (see the module docstring).

    Raises:
        ValueError: naming the file, the key and what is allowed.
    """
    system = system_for_id(env_id)
    if path is None:
        if version not in suite_versions():
            raise ValueError(
                f"unknown suite version {version!r}; allowed: {', '.join(suite_versions())}"
            )
        path = suite_path(version, system)
    try:
        data = read_json(path)
    except (OSError, ValueError) as exc:
        raise ValueError(f"suite file {path}: cannot be read as JSON: {exc}") from None
    return parse_suite(data, system, version, str(path))


class _Reader:
    """Typed reads of one suite file's keys; ValueError naming the file and key."""

    def __init__(self, path: str) -> None:
        self.path = path

    def fail(self, key: str, message: str) -> ValueError:
        return ValueError(f"suite file {self.path}: {key}: {message}")

    def get(self, data: Mapping[str, Any], key: str, where: str, kind: type | tuple) -> Any:
        name = f"{where}.{key}" if where else key
        if not isinstance(data, Mapping) or key not in data:
            raise self.fail(name, "missing")
        value = data[key]
        if isinstance(value, bool) and bool not in (kind if isinstance(kind, tuple) else (kind,)):
            raise self.fail(name, f"must be {_kind_name(kind)}, got {value!r}")
        if not isinstance(value, kind):
            raise self.fail(name, f"must be {_kind_name(kind)}, got {value!r}")
        return value

    def number(self, data: Mapping[str, Any], key: str, where: str) -> float:
        value = float(self.get(data, key, where, (int, float)))
        if not math.isfinite(value):
            raise self.fail(f"{where}.{key}", f"must be finite, got {value!r}")
        return value

    def only(self, data: Mapping[str, Any], keys: tuple[str, ...], where: str) -> None:
        extra = sorted(set(data) - set(keys))
        if extra:
            raise self.fail(
                where or "top level", f"unknown key {extra[0]!r}; allowed: {', '.join(keys)}"
            )


def _kind_name(kind: type | tuple) -> str:
    kinds = kind if isinstance(kind, tuple) else (kind,)
    names = {int: "an integer", float: "a number", str: "a string", dict: "a table", list: "a list"}
    return " or ".join(names.get(k, k.__name__) for k in kinds)


_TOP = (
    "suite",
    "env",
    "metric",
    "controller",
    "floor_observer",
    "episodes",
    "levels",
    "references_command",
)
_LEVEL = ("env_options", "seed_start", "references")
_REFS = ("oracle", "raw", "idle", "episodes")


def parse_suite(data: Any, system: System, version: str, path: str) -> SystemSuite:
    """The :class:`SystemSuite` of ``data`` (a suite file's JSON), checked; ValueError
    naming ``path``, the key and what is allowed."""
    from observer_gym.train.core.systems import system_entry  # imports every layer

    read = _Reader(path)
    if not isinstance(data, Mapping):
        raise read.fail("top level", "must be a JSON object")
    read.only(data, _TOP, "")
    if read.get(data, "suite", "", str) != version:
        raise read.fail("suite", f"is {data['suite']!r}; this file is suite {version!r}")
    if read.get(data, "env", "", str) != system.short_id:
        raise read.fail("env", f"is {data['env']!r}; this file is {system.short_id!r}'s")
    entry = system_entry(system)
    metric_data = read.get(data, "metric", "", dict)
    read.only(metric_data, ("name", "better"), "metric")
    metric = Metric(
        read.get(metric_data, "name", "metric", str), read.get(metric_data, "better", "metric", str)
    )
    if metric.better not in BETTER:
        raise read.fail("metric.better", f"is {metric.better!r}; allowed: {', '.join(BETTER)}")
    if metric.name not in entry.task.COMPARE_METRICS:
        allowed = ", ".join(entry.task.COMPARE_METRICS)
        raise read.fail("metric.name", f"is {metric.name!r}; allowed: {allowed}")
    task_better = entry.task.COMPARE_METRICS[metric.name][4]
    if metric.better != task_better:
        raise read.fail("metric.better", f"is {metric.better!r}; the task's is {task_better!r}")
    controller = read.get(data, "controller", "", str)
    if controller not in entry.controllers:
        raise read.fail("controller", f"is {controller!r}; allowed: {', '.join(entry.controllers)}")
    floor_observer = read.get(data, "floor_observer", "", str)
    if floor_observer not in entry.observers:
        raise read.fail(
            "floor_observer", f"is {floor_observer!r}; allowed: {', '.join(entry.observers)}"
        )
    episodes = read.get(data, "episodes", "", int)
    if episodes < 1:
        raise read.fail("episodes", f"is {episodes}; allowed: an integer >= 1")
    levels_data = read.get(data, "levels", "", dict)
    if not levels_data:
        raise read.fail("levels", "must name at least one level")
    config_class = system.env_class().config_class
    levels: list[Level] = []
    references: dict[str, References] = {}
    taken: dict[str, range] = {}
    for name, level_data in levels_data.items():
        where = f"levels.{name}"
        read.get(levels_data, name, "levels", dict)
        read.only(level_data, _LEVEL, where)
        options = dict(read.get(level_data, "env_options", where, dict))
        if "obs_mode" in options:
            raise read.fail(f"{where}.env_options.obs_mode", "must not be set: the entry decides")
        try:
            config_class.from_kwargs(**options)
        except (TypeError, ValueError) as exc:
            raise read.fail(f"{where}.env_options", str(exc)) from None
        start = read.get(level_data, "seed_start", where, int)
        seeds = range(start, start + episodes)
        if start < DOC_SEEDS.stop:
            raise read.fail(
                f"{where}.seed_start",
                f"is {start}; allowed: an integer >= {DOC_SEEDS.stop} (seeds "
                f"{DOC_SEEDS.start}-{DOC_SEEDS.stop - 1} are the docs')",
            )
        for other, other_seeds in taken.items():
            if seeds.start < other_seeds.stop and other_seeds.start < seeds.stop:
                raise read.fail(
                    f"{where}.seed_start",
                    f"its seeds {seeds.start}-{seeds.stop - 1} overlap level {other!r}'s "
                    f"{other_seeds.start}-{other_seeds.stop - 1}; every level's seeds are its own",
                )
        taken[name] = seeds
        refs_data = read.get(level_data, "references", where, dict)
        read.only(refs_data, _REFS, f"{where}.references")
        oracle, raw, idle = (read.number(refs_data, k, f"{where}.references") for k in REFERENCES)
        refs = References(
            oracle, raw, idle, read.get(refs_data, "episodes", f"{where}.references", int)
        )
        if refs.episodes != episodes:
            raise read.fail(
                f"{where}.references.episodes",
                f"is {refs.episodes}; the references are measured on the level's {episodes} seeds",
            )
        floor_value = refs.floor(metric.better)[1]
        if refs.oracle == floor_value:
            raise read.fail(
                f"{where}.references",
                f"the oracle's {refs.oracle} equals the floor's: no score can be normalised",
            )
        levels.append(Level(name, options, start))
        references[name] = refs
    command = read.get(data, "references_command", "", str)
    return SystemSuite(
        version,
        system,
        metric,
        controller,
        floor_observer,
        episodes,
        tuple(levels),
        references,
        command,
        path,
    )
