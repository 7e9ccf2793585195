"""An experiment's request, resolved once: :func:`resolve_request` turns what a caller
gives (an env id, observer and controller names, seeds, options) into one validated
:class:`Request` that ``compare`` and ``sweep`` pass down, so nothing below re-reads the
env id or looks a name up again.

:func:`check_pair` and :func:`check_controller` are the library's checks of one observer
and controller by name; the command line checks a controller with this one (its other
up-front checks are :mod:`observer_gym.train.core.checks`).

Each observer becomes an :class:`~observer_gym.train.core.observer_env.ObserverEntry`
(its env mode, the package's pipeline options or an outside entry, its options, the env
options it needs) and each controller a :class:`ControllerEntry` (the package's design, a
trained agent, a stable-baselines3 zip or an outside entry). Both are strings and dicts:
they travel to workers and Ray tasks inside each episode's
:class:`~observer_gym.train.experiments.episode.EpisodeSpec` with the
:class:`~observer_gym.envs.System` record, and no process looks their names up again (a
worker imports the entries' modules, nothing more).
"""

from __future__ import annotations

import importlib.util
from collections.abc import Mapping, Sequence
from typing import Any, NamedTuple

from observer_gym.controllers import ControllerDesign, check_controller_fits, controllers_of
from observer_gym.envs import System, system_for_id
from observer_gym.train.core import entries
from observer_gym.train.core.checks import (
    AGENT_FORMS,
    BACKENDS,
    OUTSIDE_FORMS,
    RAY_INSTALL_HINT,
    check_seeds,
    frames_message,
)
from observer_gym.train.core.controller_entries import check_policy_file, is_policy_file
from observer_gym.train.core.entries import (
    Plugin,
    check_options,
    find_plugin,
    load_factory,
)
from observer_gym.train.core.observer_env import (
    ObserverEntry,
    require_observer_modules,
    resolve_observer,
)
from observer_gym.train.core.tasks import Task, task_of
from observer_gym.train.experiments.camera_scale import (
    camera_scale,
    is_pixel_valued,
    options_in_entry_pixels,
)
from observer_gym.train.rl.run_dir import check_agent, expand_agent, parse_agent_spec, trained_with


class ControllerEntry(NamedTuple):
    """One controller of a request."""

    name: str
    kind: str  # "design" (the package's), "agent" (ALGO:DIR), "policy" (ALGO:PATH.zip), "outside"
    plugin: Plugin | None  # an outside controller's entry
    options: dict[str, Any]  # its factory's keyword arguments (outside controllers only)
    # a trained agent's env options (its config's env_kwargs: image size, reward shaping),
    # under the request's own for its pairs' episodes; empty for any other controller
    env_options: dict[str, Any] = {}  # noqa: RUF012 (a NamedTuple default, never mutated)


class Request(NamedTuple):
    """A checked request of ``compare`` or ``sweep``."""

    system: System
    task: Task  # observer_gym.train.core.tasks.<system>
    observers: tuple[ObserverEntry, ...]
    controllers: tuple[ControllerEntry, ...]  # a multi-seed agent stands for its seeds' agents
    named_controllers: tuple[str, ...]  # the controllers as given
    seed_groups: dict[str, list[str]]  # each multi-seed name: its seeds' agents
    seeds: tuple[int, ...]
    env_kwargs: dict[str, Any]
    observer_options: dict[str, Any]  # as given, for every outside observer
    controller_options: dict[str, Any]  # as given, for every outside controller
    steps: int | None
    workers: int
    backend: str
    address: str | None

    @property
    def env_id(self) -> str:
        return self.system.env_id

    def observer(self, name: str) -> ObserverEntry:
        return next(entry for entry in self.observers if entry.name == name)

    def controller(self, name: str) -> ControllerEntry:
        return next(entry for entry in self.controllers if entry.name == name)

    def env_kwargs_for(
        self, controller: ControllerEntry, point: Mapping[str, Any] | None = None
    ) -> dict[str, Any]:
        """The ``gym.make`` options of ``controller``'s episodes: a trained agent's own
        env options, and the request's (and a sweep cell's ``point``) over them, each
        pixel-valued one in the agent camera's pixels (times :meth:`camera_scale`), so
        that every entry meets the same angles (camera_scale.py)."""
        given = {**self.env_kwargs, **(point or {})}
        scale = self.camera_scale(controller, given)
        return {**controller.env_options, **options_in_entry_pixels(given, scale)}

    def camera_scale(self, controller: ControllerEntry, options: Mapping[str, Any]) -> float:
        """The scale of ``controller``'s own camera (a trained agent's env options) if
        ``options`` hold a pixel-valued option to translate to it, else 1."""
        if not controller.env_options or not any(map(is_pixel_valued, options)):
            return 1.0
        return camera_scale(self.env_id, controller.env_options)

    @property
    def agent_env_options(self) -> dict[str, dict[str, Any]]:
        """Each trained agent's own env options, for the agents that have some (what
        results record beside ``env_kwargs``)."""
        return {c.name: c.env_options for c in self.controllers if c.env_options}

    @property
    def observer_env_options(self) -> dict[str, dict[str, Any]]:
        """The env options each observer needs and gets wherever it runs
        (observer_env.make_env), for the observers that need some (what results record
        beside ``env_kwargs``)."""
        return {o.name: dict(o.env_options) for o in self.observers if o.env_options}

    def agent_camera_scales(self, varied: Sequence[str] = ()) -> dict[str, float]:
        """Each agent whose pixel-valued options (the request's, or the ``varied`` keys of
        a sweep) are scaled to its camera: that scale (what results record)."""
        names = {*self.env_kwargs, *varied}
        scales = {c.name: self.camera_scale(c, dict.fromkeys(names)) for c in self.controllers}
        return {name: scale for name, scale in scales.items() if scale != 1.0}

    @property
    def observer_names(self) -> list[str]:
        return [entry.name for entry in self.observers]

    @property
    def controller_names(self) -> list[str]:
        return [entry.name for entry in self.controllers]


def check_controller(controller: str, system: System, observer: ObserverEntry) -> None:
    """Raise ``ValueError`` unless ``controller`` can act on ``observer``'s output in
    ``system``'s env: one of the system's controllers (``controllers_of(system)``; another
    system's is refused naming those that fit), a trained agent ``ALGO:DIR`` whose
    folder holds a run of the system's env with a model to load
    (:func:`observer_gym.train.rl.run_dir.check_agent`), a stable-baselines3 zip
    ``ALGO:PATH.zip``, or an outside controller (an import path or an entry point's name,
    :mod:`observer_gym.train.core.entries`; its factory is imported). Controllers, outside
    ones and agents trained on the state or an estimate read the state layout (any
    observer but "pixels" and "detections"); an agent trained on rgb reads only
    "pixels", one trained on measurements only "detections"."""
    entry = resolve_controller(system, controller)
    check_controller_reads(system, entry, observer)


def check_controller_reads(
    system: System, controller: ControllerEntry, observer: ObserverEntry
) -> None:
    """ValueError unless the resolved ``controller`` reads what ``observer`` gives in
    ``system``'s env (see :func:`check_controller`); looks no name up."""
    if controller.kind == "agent":
        check_agent(controller.name, system.env_id, observer.reads_pixels, observer.name)
    elif observer.reads_pixels:
        raise ValueError(frames_message(controller.name, observer.name))


def check_pair(env_id: str, observer: str, controller: str) -> str:
    """The registered id of ``env_id`` after checking that ``observer`` is one of its
    task's ``OBSERVERS`` or an outside observer whose factory imports, and ``controller``
    acts on it (:func:`check_controller`); ValueError naming what is allowed otherwise.
    Builds no env."""
    system = system_for_id(env_id)
    check_pair_of(system, observer, controller)
    return system.env_id


def check_pair_of(system: System, observer: str, controller: str) -> None:
    """:func:`check_pair` for a resolved ``system``."""
    entry = resolve_observer(system, observer)
    if entry.plugin is not None:
        entries.load_factory(entry.plugin)
    check_controller(controller, system, entry)


def names_of(kind: str, names: Sequence[str] | str, allowed: str) -> list[str]:
    """``names`` (a list, or text split at commas) as a list; ValueError for an empty list,
    an empty name or a name given twice (``kind`` and ``allowed`` in the message)."""
    if isinstance(names, str):
        names = [name.strip() for name in names.split(",")]
    names = list(names)
    if not names:
        raise ValueError(f"{kind} must name at least one; allowed: {allowed}")
    if "" in names:
        raise ValueError(f"{kind} has an empty name in {names}; allowed: {allowed}")
    duplicates = sorted({name for name in names if names.count(name) > 1})
    if duplicates:
        raise ValueError(f"{kind} lists {', '.join(map(repr, duplicates))} more than once")
    return names


def _observer_entry(system: System, task: Task, name: str, options: dict) -> ObserverEntry:
    entry = resolve_observer(system, name, task=task)
    if entry.plugin is None:
        require_observer_modules(system, entry)  # the learned ones: PyTorch
        return entry
    load_factory(entry.plugin)  # ValueError naming the entry if it does not import
    return entry.with_options(options)


def resolve_controller(
    system: System,
    name: str,
    options: Mapping[str, Any] | None = None,
    designs: Mapping[str, ControllerDesign] | None = None,
) -> ControllerEntry:
    """The :class:`ControllerEntry` of controller ``name`` for ``system`` (whose
    controllers are ``designs``, looked up if not given) with ``options``: a trained agent
    ``ALGO:DIR`` (its env options read from its run, if it is one), a stable-baselines3
    zip (checked), one of ``designs``, or an outside controller (its factory imported).
    ValueError naming what fits for any other name (another system's controller, an
    unknown one)."""
    options = dict(options or {})
    spec = parse_agent_spec(name)
    if spec is not None:
        if is_policy_file(spec[1]):
            check_policy_file(name, spec[1])
            return ControllerEntry(name, "policy", None, options)
        try:
            env_options = trained_with(spec[1], spec[0]).env_options
        except ValueError:  # not a run: check_controller_reads names what is wrong
            env_options = {}
        return ControllerEntry(name, "agent", None, options, env_options)
    if name in (controllers_of(system) if designs is None else designs):
        return ControllerEntry(name, "design", None, options)
    plugin = find_plugin("controller", name)
    if plugin is None:
        # refuses the name (no design of the system) naming those that fit
        check_controller_fits(name, system, others=f", {AGENT_FORMS}, {OUTSIDE_FORMS}")
        return ControllerEntry(name, "design", None, options)
    load_factory(plugin)  # ValueError naming the entry if it does not import
    return ControllerEntry(name, "outside", plugin, options)


def _check_options(kind: str, given: dict, entries: Sequence[Any]) -> None:
    check_options(kind, given)
    if given and not any(entry.plugin is not None for entry in entries):
        names = ", ".join(entry.name for entry in entries)
        raise ValueError(
            f"{kind} options {given} apply to outside {kind}s (an import path or an entry "
            f"point) only; none is among {names}"
        )


def resolve_request(
    env: str | System,
    observers: Sequence[str] | str,
    controllers: Sequence[str] | str,
    seeds: Sequence[int],
    workers: int = 1,
    backend: str = "local",
    address: str | None = None,
    steps: int | None = None,
    env_kwargs: Mapping[str, Any] | None = None,
    observer_options: Mapping[str, Any] | None = None,
    controller_options: Mapping[str, Any] | None = None,
) -> Request:
    """The :class:`Request` of these inputs, after the checks that build no env: the env
    (an id, resolved once, or its :class:`~observer_gym.envs.System`),
    the observers (the task's ``OBSERVERS`` or outside entries that import), the
    controllers (:func:`check_controller` for every pair; a
    multi-seed agent stands for its seeds' agents), non-empty lists
    without duplicates, seeds, ``workers``, ``steps``, ``backend``, ``address``, no
    ``obs_mode`` in ``env_kwargs``, and options only where an outside entry takes them.

    Raises:
        ValueError: naming the bad value and what is allowed.
    """
    system = env if isinstance(env, System) else system_for_id(env)
    task = task_of(system)
    observer_options, controller_options = (
        dict(observer_options or {}),
        dict(controller_options or {}),
    )
    observer_names = names_of("observers", observers, ", ".join(task.OBSERVERS))
    observer_entries = tuple(
        _observer_entry(system, task, name, observer_options) for name in observer_names
    )
    named = names_of("controllers", controllers, "a controller name or ALGO:DIR")
    seed_groups = {name: expand_agent(name) for name in named if expand_agent(name) != [name]}
    expanded = [agent for name in named for agent in seed_groups.get(name, [name])]
    duplicates = sorted({c for c in expanded if expanded.count(c) > 1})
    if duplicates:
        raise ValueError(f"controllers name {', '.join(map(repr, duplicates))} more than once")
    designs = controllers_of(system)
    controller_entries = tuple(resolve_controller(system, name, None, designs) for name in expanded)
    controller_entries = tuple(
        entry._replace(options=dict(controller_options)) if entry.plugin else entry
        for entry in controller_entries
    )
    for controller_entry in controller_entries:
        for observer_entry in observer_entries:
            check_controller_reads(system, controller_entry, observer_entry)
    _check_options("observer", observer_options, observer_entries)
    _check_options("controller", controller_options, controller_entries)
    seeds = tuple(check_seeds(seeds))
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ValueError(f"workers must be an integer >= 1, got {workers!r}")
    if steps is not None and (isinstance(steps, bool) or not isinstance(steps, int) or steps < 1):
        raise ValueError(f"steps must be an integer >= 1 or None, got {steps!r}")
    if backend not in BACKENDS:
        raise ValueError(f"unknown backend {backend!r}; allowed: {', '.join(BACKENDS)}")
    if address is not None and backend != "ray":
        raise ValueError(
            f"address {address!r} is a Ray cluster's address: it needs backend 'ray', "
            f"got {backend!r}"
        )
    if backend == "ray":
        if workers != 1:
            raise ValueError(
                f"workers={workers} applies to the local backend only; with backend 'ray' "
                "the cluster's CPUs decide how many episodes run at once"
            )
        if importlib.util.find_spec("ray") is None:
            raise ValueError(f"backend 'ray' needs Ray, which is not installed: {RAY_INSTALL_HINT}")
    env_kwargs = dict(env_kwargs or {})
    if "obs_mode" in env_kwargs:
        raise ValueError("env_kwargs must not set obs_mode: each observer decides it")
    return Request(
        system, task, observer_entries, controller_entries, tuple(named), seed_groups, seeds,
        env_kwargs, observer_options, controller_options, steps, workers, backend, address,
    )  # fmt: skip
