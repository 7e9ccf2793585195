"""What ``observer-gym list`` shows: every system, observer, controller and shipped agent,
with one line each, and the outside observers and controllers installed packages add
through entry points (:mod:`observer_gym.train.core.entries`).
"""

from __future__ import annotations

from typing import NamedTuple

from observer_gym.controllers import controllers_of
from observer_gym.envs import SYSTEMS
from observer_gym.envs.json_file import read_json
from observer_gym.estimation.observer import OBSERVER_ROLES, modules_needed
from observer_gym.train.core import entries
from observer_gym.train.core.systems import SystemEntry, system_entries
from observer_gym.train.rl.shipped import README_FILE, shipped_names, shipped_path

# the observers of a task that are no pipeline
TASK_OBSERVERS = {
    "oracle": "the true state (no camera)",
    "pixels": "the camera frames themselves, for agents trained with --obs rgb",
    "detections": "the newest frame's detections, unfiltered, for agents trained with "
    "--obs measurements",
}
MEASUREMENTS = "-measurements"


class Listed(NamedTuple):
    """One line of the catalogue."""

    kind: str  # "system", "observer", "controller" or "agent"
    name: str  # what a command takes
    systems: tuple[str, ...]  # the env ids it fits (an outside entry: entry_systems)
    summary: str  # one line
    source: str  # "observer-gym", or "entry point of <distribution>"
    # needs the [rl] extra (PyTorch, stable-baselines3: observer_gym.extras): the
    # learned observers and the agents
    needs_rl: bool = False


def observer_summary(name: str) -> str:
    """One line for a task observer's ``name``."""
    if name in TASK_OBSERVERS:
        return TASK_OBSERVERS[name]
    role = name.removesuffix(MEASUREMENTS)
    summary = OBSERVER_ROLES.get(role, role)
    return summary + (
        ", from the perfect detector's measurements (no rendering)"
        if name.endswith(MEASUREMENTS)
        else ", from rendered frames"
    )


def _agent_summary(name: str) -> tuple[str, str]:
    """(env id, one line) of the shipped agent ``name``: from its config and README title."""
    folder = shipped_path(name)
    assert folder is not None  # one of shipped_names()
    config = read_json(folder / "config.json")
    readme = folder / README_FILE
    title = ""
    if readme.is_file():
        first = readme.read_text(encoding="utf-8").splitlines()[:1]
        title = first[0].lstrip("# ").strip() if first else ""
    return config["env_id"], title or f"{config['algo']} on --obs {config['obs']}"


def _observer_needs_rl(entry: SystemEntry, name: str) -> bool:
    """Whether the task observer ``name`` of ``entry`` runs a pipeline that needs the
    ``[rl]`` extra (:func:`~observer_gym.estimation.observer.modules_needed`)."""
    setup = entry.task.OBSERVERS.get(name)
    if setup is None or setup[1] is None:
        return False
    return bool(modules_needed(entry.system, setup[1].get("observer")))


def catalogue() -> list[Listed]:
    """Every system, observer, controller and shipped agent of the package, then the
    installed entry points' observers and controllers."""
    items: list[Listed] = []
    system_list = system_entries()
    for entry in system_list:
        env_class = entry.system.env_class()
        doc = (env_class.__doc__ or "").strip().splitlines()
        items.append(
            Listed(
                "system",
                entry.system.short_id,
                (entry.env_id,),
                doc[0] if doc else "",
                "observer-gym",
            )
        )
    for kind, field in (("observer", "observers"), ("controller", "controllers")):
        names: dict[str, list[str]] = {}
        needs_rl: set[str] = set()
        for entry in system_list:
            for name in getattr(entry, field):
                names.setdefault(name, []).append(entry.env_id)
                if kind == "observer" and _observer_needs_rl(entry, name):
                    needs_rl.add(name)
        for name, env_ids in names.items():
            if kind == "observer":
                summary = observer_summary(name)
            else:
                first = next(e for e in system_list if name in e.controllers)
                summary = controllers_of(first.system)[name].summary
            items.append(
                Listed(kind, name, tuple(env_ids), summary, "observer-gym", name in needs_rl)
            )
    for name in shipped_names():
        env_id, summary = _agent_summary(name)
        folder = shipped_path(name)
        assert folder is not None  # one of shipped_names()
        algo = read_json(folder / "config.json")["algo"]
        items.append(
            Listed("agent", f"{algo}:{name}", (env_id,), summary, "observer-gym", needs_rl=True)
        )
    for kind in ("observer", "controller"):
        for name, entry_point in entries.entry_points(kind).items():
            plugin = entries.find_plugin(kind, name)
            assert plugin is not None  # an installed entry point
            items.append(
                Listed(
                    kind,
                    name,
                    entry_systems(plugin),
                    f"{entry_point.value} ({plugin.version})",
                    plugin.source,
                )
            )
    return items


def entry_systems(plugin: entries.Plugin) -> tuple[str, ...]:
    """The env ids an outside entry fits: those its factory declares
    (:func:`~observer_gym.train.core.entries.declared_systems`), else those a trial
    build succeeds on (:func:`~observer_gym.train.experiments.episode.check_entries` with the
    system's first controller, or on the true state for a controller; an observer on
    measurements, then on frames). An entry that cannot even be imported fits none."""
    try:
        declared = entries.declared_systems(entries.load_factory(plugin))
    except ValueError:
        return ()
    if declared is not None:
        ids = {**{s.env_id: s.env_id for s in SYSTEMS}, **{s.short_id: s.env_id for s in SYSTEMS}}
        return tuple(dict.fromkeys(ids[d] for d in declared if d in ids))
    return tuple(system.env_id for system in SYSTEMS if _trial(plugin, system.env_id))


def _trial(plugin: entries.Plugin, env_id: str) -> bool:
    """Whether ``plugin`` builds and acts once on ``env_id`` (warnings silenced)."""
    import warnings

    from observer_gym.controllers import controllers_of
    from observer_gym.envs import system_for_id
    from observer_gym.train.core.observer_env import resolve_observer
    from observer_gym.train.experiments.episode import check_entries
    from observer_gym.train.experiments.request import resolve_controller

    system = system_for_id(env_id)

    if plugin.kind == "controller":
        pairs = [("oracle", plugin.name)]
    else:
        first = next(iter(controllers_of(system)))
        pairs = [(f"{plugin.name}{MEASUREMENTS}", first), (plugin.name, first)]
    for observer, controller in pairs:
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                check_entries(
                    system,
                    resolve_observer(system, observer),
                    resolve_controller(system, controller),
                )
        except Exception:  # any failure: it does not fit (run names the cause)
            continue
        return True
    return False
