"""``observer-gym benchmark --check DIR``: whether a benchmark folder's scores are what
its per-episode records and the suite's definition give.

:func:`check_folder` reads ``scores.json`` and ``episodes.csv``, checks the suite version
(a shipped one), the levels, their env options and seeds (the suite's, first to last),
the episode count (the suite's for an official run), the package versions recorded (this
installation's), that every level has every episode, and then derives ``scores.json``
and ``table.md`` again from ``episodes.csv`` and the suite
(:func:`~observer_gym.train.experiments.benchmark.report.scores_document`; an agent's
camera scale derived from its recorded env options). The first
difference raises :class:`FolderCheckError` with one line naming it. It finds an edited
value, seed or score, a missing episode or file; it is no signature (whoever edits the
records and writes every derived number again is not caught).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from observer_gym.controllers.registry import controllers_of
from observer_gym.envs import system_for_id
from observer_gym.envs.json_file import JSONFileError, read_bytes_limited, read_json
from observer_gym.estimation.observer import modules_needed
from observer_gym.train.core.observer_env import observer_env_options
from observer_gym.train.core.tasks import task_of
from observer_gym.train.experiments.benchmark.records import EPISODES_CSV, MAX_CSV_BYTES, read_csv
from observer_gym.train.experiments.benchmark.report import (
    SCORES_JSON,
    TABLE_MD,
    scores_document,
    table_markdown,
    versions,
)
from observer_gym.train.experiments.benchmark.suite import load_suite
from observer_gym.train.experiments.camera_scale import camera_scale
from observer_gym.train.reports.outputs import NOT_INSTALLED


class FolderCheckError(ValueError):
    """A benchmark folder that is not what its records and the suite give: one line."""


def _first_difference(recorded: Any, derived: Any, where: str) -> str | None:
    """Where ``recorded`` and ``derived`` (JSON values) first differ, with both values;
    None if they agree (numbers exactly)."""
    if isinstance(recorded, bool) or isinstance(derived, bool):
        same = recorded is derived
    elif isinstance(recorded, int | float) and isinstance(derived, int | float):
        same = float(recorded) == float(derived)
    elif isinstance(recorded, dict) and isinstance(derived, dict):
        for key in dict.fromkeys([*derived, *recorded]):
            if key not in recorded or key not in derived:
                side = "missing" if key not in recorded else "not expected"
                return f"{where}.{key} is {side}"
            found = _first_difference(recorded[key], derived[key], f"{where}.{key}")
            if found:
                return found
        return None
    elif isinstance(recorded, list) and isinstance(derived, list):
        if len(recorded) != len(derived):
            return f"{where} has {len(recorded)} entries, the re-derived {len(derived)}"
        for i, (a, b) in enumerate(zip(recorded, derived, strict=True)):
            found = _first_difference(a, b, f"{where}[{i}]")
            if found:
                return found
        return None
    else:
        same = recorded == derived
    return None if same else f"{where} is {_short(recorded)}, re-derived {_short(derived)}"


def _short(value: Any) -> str:
    text = json.dumps(value)
    return text if len(text) <= 120 else text[:117] + "..."


def _agent_options_problem(controller: str, recorded: dict[str, Any]) -> str | None:
    """Where the recorded agent env options differ from the agent's own config, if the
    agent (``ALGO:DIR`` or a shipped ``ALGO:NAME``) is on this machine; None otherwise."""
    from observer_gym.train.experiments.benchmark.run import agent_entry

    try:
        trained = agent_entry(controller).env_options
    except ValueError:  # not an agent, or not here: nothing to compare with
        return None
    if trained != recorded:
        return (
            f"agent_env_options is {_short(recorded)}, but agent {controller} was trained "
            f"with {_short(trained)}"
        )
    return None


# The [rl] extra's packages: absent from a core install (observer_gym.extras)
RL_PACKAGES = ("stable-baselines3", "torch")


def _needs_rl(env_id: str, observer: Any, controller: Any) -> bool:
    """Whether an entry may depend on the ``[rl]`` extra: a learned observer, an agent or
    an outside entry (whose imports are unknown); False only for a built-in observer that
    needs no more than the core install and a built-in controller."""
    if not isinstance(observer, str) or not isinstance(controller, str):
        return True
    setup = task_of(system_for_id(env_id)).OBSERVERS.get(observer)
    if setup is None:
        return True
    pipeline = None if setup[1] is None else setup[1].get("observer")
    system = system_for_id(env_id)
    return bool(modules_needed(system, pipeline)) or controller not in controllers_of(system)


def _check_same_packages(
    path: Path, recorded: dict[str, Any], env_id: str, doc: dict[str, Any]
) -> None:
    """FolderCheckError naming the first package whose recorded version differs from this
    installation's. A core install (no ``[rl]`` extra) checks a folder of a built-in
    classical entry made on a full install: torch and stable-baselines3 decide none of its
    numbers, so their absence here is no difference."""
    classical = not _needs_rl(env_id, doc.get("observer"), doc.get("controller"))
    for name, version_here in versions().items():
        if name in RL_PACKAGES and classical and version_here == NOT_INSTALLED:
            continue
        if recorded.get(name) != version_here:
            raise FolderCheckError(
                f"{path}: package {name} is {recorded.get(name)!r} in the folder, "
                f"{version_here!r} here"
            )


def check_folder(folder: str | Path, *, same_packages: bool = True) -> str:
    """A one-line confirmation if ``folder`` checks out (see the module docstring).

    ``same_packages=False`` skips the comparison of the recorded package versions with
    this installation's (the leaderboard, whose rows span releases, shows them instead);
    the scores are still derived with the recorded versions.

    Raises:
        FolderCheckError: one line naming the first thing that differs.
    """
    folder = Path(folder)
    path = folder / SCORES_JSON
    if not path.is_file():
        raise FolderCheckError(f"{folder} has no {SCORES_JSON}: not a finished benchmark folder")
    try:
        doc = read_json(path)
        version, env, episodes = doc["suite"], doc["env"], doc["episodes_per_level"]
        levels = doc["levels"]
    except JSONFileError as exc:  # a key twice, too deep, too large, not JSON: named
        raise FolderCheckError(f"{exc}; not a benchmark's scores") from None
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise FolderCheckError(f"{path} cannot be read as a benchmark's scores: {exc!r}") from None
    try:
        suite = load_suite(str(env), str(version))
    except ValueError as exc:
        raise FolderCheckError(f"{path}: {exc}") from None
    if (
        isinstance(episodes, bool)
        or not isinstance(episodes, int)
        or not (1 <= episodes <= suite.episodes)
    ):
        raise FolderCheckError(
            f"{path}: episodes_per_level is {episodes!r}; suite {version} allows 1 to "
            f"{suite.episodes}"
        )
    names = [row.get("level") if isinstance(row, dict) else None for row in levels]
    if names != [level.name for level in suite.levels]:
        raise FolderCheckError(
            f"{path}: its levels are {names}, suite {version}'s are "
            f"{[level.name for level in suite.levels]}"
        )
    for row, level in zip(levels, suite.levels, strict=True):
        if row.get("seeds") != level.seeds(episodes):
            raise FolderCheckError(
                f"{path}: level {level.name!r}'s seeds are not suite {version}'s "
                f"{level.seed_start} to {level.seed_start + episodes - 1}"
            )
    recorded_packages = doc.get("packages")
    if not isinstance(recorded_packages, dict):
        raise FolderCheckError(f"{path}: no package versions recorded")
    if same_packages:
        _check_same_packages(path, recorded_packages, suite.env_id, doc)
    try:
        records = read_csv(folder / EPISODES_CSV, suite.metric.name)
    except ValueError as exc:
        raise FolderCheckError(str(exc)) from None
    for level in suite.levels:
        rows = [r for r in records if r.level == level.name]
        if len(rows) != episodes:
            raise FolderCheckError(
                f"{folder / EPISODES_CSV}: level {level.name!r} has {len(rows)} episodes, "
                f"not {episodes}"
            )
        for i, (row, seed) in enumerate(zip(rows, level.seeds(episodes), strict=True)):
            if row.episode != i or row.seed != seed:
                raise FolderCheckError(
                    f"{folder / EPISODES_CSV}: level {level.name!r}'s row {i} is episode "
                    f"{row.episode}, seed {row.seed}; the suite's episode {i} has seed {seed}"
                )
    extra = sorted({r.level for r in records} - {level.name for level in suite.levels})
    if extra:
        raise FolderCheckError(f"{folder / EPISODES_CSV}: level {extra[0]!r} is not in the suite")
    entry = {key: doc.get(key) for key in ("observer", "controller")}
    for key in ("observer_options", "controller_options"):
        options = doc.get(key)
        if not isinstance(options, dict):
            raise FolderCheckError(f"{path}: {key} is {_short(options)}, not a table of options")
        entry[key] = options
    if "agent_env_options" in doc:
        options = doc["agent_env_options"]
        if not isinstance(options, dict) or not options:
            raise FolderCheckError(
                f"{path}: agent_env_options is {_short(options)}, not a table of options"
            )
        entry["agent_env_options"] = options
        try:  # derived from the options: a recorded scale that differs is a difference
            entry["camera_scale"] = camera_scale(suite.env_id, options)
        except ValueError as exc:
            raise FolderCheckError(f"{path}: {exc}") from None
    if "entries" in doc:  # where outside entries came from, as recorded (not re-derived)
        if not isinstance(doc["entries"], dict):
            raise FolderCheckError(f"{path}: entries is {_short(doc['entries'])}, not a table")
        entry["entries"] = doc["entries"]
    if not all(isinstance(entry[key], str) for key in ("observer", "controller")):
        raise FolderCheckError(f"{path}: observer and controller must be names")
    # derived from the observer's name: a recorded table that differs is a difference
    entry["observer_env_options"] = observer_env_options(
        system_for_id(suite.env_id), entry["observer"]
    )
    problem = _agent_options_problem(entry["controller"], entry.get("agent_env_options", {}))
    if problem:
        raise FolderCheckError(f"{path}: {problem}")
    derived, _ = scores_document(suite, {**entry, "episodes": episodes}, records, recorded_packages)
    difference = _first_difference(doc, derived, "scores.json")
    if difference:
        raise FolderCheckError(f"{folder}: {difference}")
    table = folder / TABLE_MD
    try:
        table_text = read_bytes_limited(table, MAX_CSV_BYTES).decode("utf-8", errors="replace")
    except (OSError, ValueError):
        table_text = None
    if table_text != table_markdown(suite, derived):
        raise FolderCheckError(f"{table} is missing or not the table of {SCORES_JSON}")
    status = "official" if derived["official"] else "unofficial"
    return (
        f"{folder}: OK, suite {version} {suite.system.short_id}, {derived['observer']} + "
        f"{derived['controller']}, {len(suite.levels)} levels x {episodes} episodes "
        f"({status}), IQM {derived['aggregate']['iqm']:.3f} "
        f"[{derived['aggregate']['low']:.3f}, {derived['aggregate']['high']:.3f}] re-derived"
    )
