"""Observers and controllers from outside the package: by import path or entry point.

Wherever ``run``, ``compare``, ``sweep`` or ``evaluate`` take an observer or a controller
name, they also take

- an import path ``package.module:factory`` (the module importable from the Python path
  of the command and of its workers), or
- the name of an entry point that an installed package declares in the group
  ``observer_gym.observers`` or ``observer_gym.controllers``, e.g. in its pyproject.toml::

      [project.entry-points."observer_gym.observers"]
      alpha-beta = "mylab.filters:make_observer"

An observer factory is called as ``factory(env, **options)`` with the unwrapped env and
returns a pipeline with ``reset()`` and ``observe(obs, info, action) -> Estimate``
(:mod:`observer_gym.estimation.observer`). It reads the camera frames (``obs_mode="rgb"``)
or, with the suffix ``-measurements`` on the entry (``mylab.filters:make_observer-measurements``,
``alpha-beta-measurements``), the perfect detector's measurements, as the built-in
observers' names do. A controller factory is called as ``factory(env, **options)`` with
the env it acts on (whose observation is the state or an estimate of it) and returns an
object with stable-baselines3's ``predict(obs, state, episode_start, deterministic)``;
its ``reset()``, if it has one, is called before every episode.

From Python (:mod:`observer_gym.train.experiments.api`), an entry can also be the factory itself or
an object with the protocol (a pipeline, a controller; each episode gets a deep copy). A
module-level factory is named by its import path; anything else gets the name
``python:<module>:<qualname>@<identity>`` (:func:`object_identity`: a hash of its
content, so two closures of one qualname are two entries) and travels to the workers
inside each episode's spec (:func:`as_name`), so it must pickle when episodes run in
other processes.

A factory may declare the systems it is made for as an attribute ``systems``, a sequence
of env ids (``make_controller.systems = ("BallTable-v0",)``, or a class attribute): an
experiment on another system refuses it in one line before any episode, and
``observer-gym list`` shows those systems (for an entry that declares none, the systems a
trial build on each succeeds on).

Names of the package's own observers and controllers win over an entry point of the same
name. This module imports nothing but the standard library, so the command line checks an
entry before it loads any layer.
"""

from __future__ import annotations

import contextlib
import copy
import functools
import hashlib
import importlib
import math
import pickle
import reprlib
import sys
import types
import warnings
from collections.abc import Callable, Iterator, Mapping
from importlib import metadata
from typing import Any, NamedTuple

from observer_gym.train.core.messages import OneLineWarning

OBSERVER_GROUP = "observer_gym.observers"
CONTROLLER_GROUP = "observer_gym.controllers"
GROUPS = {"observer": OBSERVER_GROUP, "controller": CONTROLLER_GROUP}
MEASUREMENTS_SUFFIX = "-measurements"
NOT_INSTALLED = "not installed"
OBJECT_PREFIX = "python:"
# The entries given as Python objects in this process, by (kind, name): set while an
# experiment runs (:func:`objects_in_use`), from the specs in a worker.
_OBJECTS: dict[tuple[str, str], Any] = {}


class Plugin(NamedTuple):
    """An observer or controller from outside the package, as a request names it."""

    kind: str  # "observer" or "controller"
    name: str  # as given: "mylab.filters:make_observer-measurements", "alpha-beta"
    target: str  # the factory's import path: "mylab.filters:make_observer"
    obs_mode: str | None  # an observer's env mode ("rgb" or "measurements"); None for a controller
    source: str  # "import path" or "entry point of <distribution>"
    package: str  # the distribution that provides it, else the module's top-level package
    version: str  # the distribution's version, or "not installed"

    def describe(self, options: Mapping[str, Any] | None = None) -> dict[str, Any]:
        """What results record of the entry: its import path, source, package, version
        and ``options``."""
        return {
            "name": self.name,
            "import_path": self.target,
            "source": self.source,
            "package": self.package,
            "version": self.version,
            "options": dict(options or {}),
        }


def is_import_path(text: str) -> bool:
    """Whether ``text`` reads ``dotted.module:dotted.attribute`` (an optional
    ``-measurements`` suffix aside)."""
    module, sep, attribute = text.removesuffix(MEASUREMENTS_SUFFIX).partition(":")
    return bool(sep) and all(
        part.isidentifier() for part in module.split(".") + attribute.split(".")
    )


@functools.cache
def entry_points(kind: str) -> dict[str, metadata.EntryPoint]:
    """The installed entry points of ``kind`` ("observer" or "controller"), by name,
    without those refused with a warning naming them (:func:`entry_point_problem`)."""
    found = {}
    for ep in metadata.entry_points(group=GROUPS[kind]):
        problem = entry_point_problem(kind, ep.name)
        if problem is None:
            found[ep.name] = ep
            continue
        distribution = ep.dist.name if ep.dist is not None else "an unknown distribution"
        warnings.warn(
            f"the {kind} entry point '{printable(ep.name)}' of {distribution} is ignored: "
            f"{problem}",
            OneLineWarning,
            stacklevel=2,
        )
    return found


def entry_point_problem(kind: str, name: str) -> str | None:
    """Why an installed entry point's ``name`` cannot name an entry, or None: an
    observer's name ending in ``-measurements`` (that suffix picks the env mode of the
    name before it), or a name of characters other than printable ones."""
    if not name or not all(character.isprintable() for character in name):
        return "its name must be printable characters"
    if kind == "observer" and name.endswith(MEASUREMENTS_SUFFIX):
        return (
            f"an observer's name may not end in {MEASUREMENTS_SUFFIX!r}: that suffix on a "
            "name asks for the measurements of the observer named before it"
        )
    return None


def printable(text: str) -> str:
    """``text`` with every character that is not printable (a terminal's escape codes,
    newlines) written as its Python escape, for names shown on a terminal or a page."""
    return "".join(c if c.isprintable() else c.encode("unicode_escape").decode() for c in text)


def refresh() -> None:
    """Read the installed packages and their entry points again (after an install in
    this process)."""
    entry_points.cache_clear()
    _distributions.cache_clear()


@functools.cache
def _distributions() -> Mapping[str, list[str]]:
    return metadata.packages_distributions()


def _version_of(module: str) -> tuple[str, str]:
    """(distribution, version) of the installed distribution that provides ``module``'s
    top-level package, else (that package, "not installed")."""
    top = module.split(".")[0]
    for distribution in _distributions().get(top, []):
        try:
            return distribution, metadata.version(distribution)
        except metadata.PackageNotFoundError:  # pragma: no cover - a broken install
            continue
    return top, NOT_INSTALLED


def find_plugin(kind: str, name: str) -> Plugin | None:
    """The plugin ``name`` stands for (an import path, an installed entry point's name or
    a Python object given in this process, each with an optional ``-measurements`` suffix
    for an observer), None for any other name. Imports nothing."""
    if kind not in GROUPS:
        raise ValueError(f"kind must be one of {', '.join(GROUPS)}, got {kind!r}")
    obs_mode = None
    stem = name
    if kind == "observer":
        measurements = name.endswith(MEASUREMENTS_SUFFIX)
        stem = name.removesuffix(MEASUREMENTS_SUFFIX) if measurements else name
        obs_mode = "measurements" if measurements else "rgb"
    if (kind, stem) in _OBJECTS:
        target = stem.removeprefix(OBJECT_PREFIX)
        package, version = _version_of(target.partition(":")[0])
        return Plugin(kind, name, stem, obs_mode, "python object", package, version)
    if is_import_path(stem):
        package, version = _version_of(stem.partition(":")[0])
        return Plugin(kind, name, stem, obs_mode, "import path", package, version)
    entry_point = entry_points(kind).get(stem)
    if entry_point is None:
        return None
    distribution = entry_point.dist.name if entry_point.dist is not None else stem
    try:
        version = metadata.version(distribution)
    except metadata.PackageNotFoundError:  # pragma: no cover - an entry point without a dist
        version = NOT_INSTALLED
    return Plugin(
        kind,
        name,
        entry_point.value,
        obs_mode,
        f"entry point of {distribution}",
        distribution,
        version,
    )


def load_factory(plugin: Plugin) -> Callable[..., Any]:
    """The factory ``plugin`` names, imported; ValueError naming the entry and what is
    wrong (the module cannot be imported, has no such attribute, or it is not callable)."""
    if (plugin.kind, plugin.target) in _OBJECTS:
        return _OBJECTS[plugin.kind, plugin.target]
    module_name, _, attribute = plugin.target.partition(":")
    where = f"{plugin.kind} {plugin.name!r}"
    try:
        target: Any = importlib.import_module(module_name)
    except (Exception, SystemExit) as exc:  # ImportError, anything raised on import, sys.exit
        raise ValueError(
            f"{where}: cannot import {module_name!r}: {type(exc).__name__}: {exc}"
        ) from None
    for part in attribute.split("."):
        try:
            target = getattr(target, part)
        except AttributeError:
            raise ValueError(
                f"{where}: module {module_name!r} has no attribute {attribute!r}"
            ) from None
    if not callable(target):
        raise ValueError(
            f"{where}: {plugin.target} is a {type(target).__name__}, not a factory "
            "(a callable taking the env and the options)"
        )
    return target


def declared_systems(factory: Any) -> tuple[str, ...] | None:
    """The env ids a factory declares it is made for (its attribute ``systems``: a text or
    a sequence of texts), None if it declares none. ValueError for a declaration of
    anything else."""
    declared = getattr(factory, "systems", None)
    if declared is None:
        return None
    if isinstance(declared, str):
        declared = (declared,)
    try:
        listed = tuple(declared)
    except TypeError:
        listed = ()
    if not listed or not all(isinstance(env_id, str) for env_id in listed):
        raise ValueError(
            f"{getattr(factory, '__qualname__', factory)!r} declares systems={declared!r}; "
            "expected env ids, e.g. ('BallTable-v0',)"
        )
    return listed


def check_declared(plugin: Plugin, env_id: str, short_id: str) -> None:
    """ValueError, one line naming ``plugin``, if its factory declares systems
    (:func:`declared_systems`) and ``env_id`` (``observer_gym/X``, short ``X``) is not one."""
    declared = declared_systems(load_factory(plugin))
    if declared is None:
        return
    if env_id in declared or short_id in declared:
        return
    raise ValueError(
        f"{plugin.kind} {plugin.name!r} does not fit {short_id}: it declares it is made for "
        f"{', '.join(declared)} (its factory's systems)"
    )


def build(plugin: Plugin, env: Any, options: Mapping[str, Any] | None = None) -> Any:
    """``factory(env, **options)`` of ``plugin``, checked: ValueError naming the entry when
    the factory raises, or returns an object without the protocol's methods (an observer
    pipeline's ``reset`` and ``observe``, a controller's ``predict``)."""
    factory = load_factory(plugin)
    where = f"{plugin.kind} {plugin.name!r}"
    try:
        made = factory(env, **dict(options or {}))
    except (Exception, SystemExit) as exc:  # sys.exit in a factory ends only the entry
        raise ValueError(
            f"{where}: {plugin.target}(env, **{dict(options or {})}) raised "
            f"{type(exc).__name__}: {exc}"
        ) from None
    needed = ("reset", "observe") if plugin.kind == "observer" else ("predict",)
    missing = [method for method in needed if not callable(getattr(made, method, None))]
    if missing:
        raise ValueError(
            f"{where}: {plugin.target} returned a {type(made).__name__} without "
            f"{', '.join(m + '()' for m in missing)}; an {plugin.kind} must have "
            f"{', '.join(m + '()' for m in needed)}"
        )
    return made


def _import_path_of(obj: Any) -> str | None:
    """``module:qualname`` of a module-level function or class that imports back as
    itself (not from ``__main__``), else None."""
    module, qualname = getattr(obj, "__module__", None), getattr(obj, "__qualname__", None)
    if not module or not qualname or module == "__main__" or "<" in qualname:
        return None
    try:
        found: Any = importlib.import_module(module)
        for part in qualname.split("."):
            found = getattr(found, part)
    except (ImportError, AttributeError):
        return None
    return f"{module}:{qualname}" if found is obj else None


class _Copies:
    """A factory that gives each episode a deep copy of a given pipeline or controller."""

    def __init__(self, prototype: Any) -> None:
        self.prototype = prototype

    def __call__(self, env: Any, **options: Any) -> Any:
        if options:
            raise TypeError(f"an object given as an entry takes no options, got {options}")
        return copy.deepcopy(self.prototype)


def as_name(kind: str, entry: Any, obs_mode: str = "rgb") -> tuple[str, dict[tuple[str, str], Any]]:
    """``(name, objects)`` for an entry given from Python: a name or import path (text)
    as it is, with no objects; a module-level factory by its import path; any other
    factory, or an object with the protocol (an observer pipeline's ``reset`` and
    ``observe``, a controller's ``predict``; each episode gets a deep copy), as
    ``python:<module>:<qualname>@<identity>`` (:func:`object_identity`) with ``objects``
    mapping (kind, that name) to the factory.
    An observer's name gets the ``-measurements`` suffix for ``obs_mode`` "measurements".
    ValueError for anything else."""
    suffix = MEASUREMENTS_SUFFIX if kind == "observer" and obs_mode == "measurements" else ""
    if isinstance(entry, str):
        return entry, {}
    needed = ("reset", "observe") if kind == "observer" else ("predict",)
    has_protocol = all(callable(getattr(entry, m, None)) for m in needed)
    if isinstance(entry, type) or (callable(entry) and not has_protocol):  # a factory
        path = _import_path_of(entry)
        if path is not None:
            return path + suffix, {}
        factory = entry
    elif has_protocol:
        factory = _Copies(entry)
        entry = type(entry)
    else:
        raise ValueError(
            f"{kind} {entry!r}: expected a name, an import path package.module:factory, a "
            f"factory (env, **options) or an object with {', '.join(m + '()' for m in needed)}"
        )
    module = printable(str(getattr(entry, "__module__", "object")))
    qualname = printable(str(getattr(entry, "__qualname__", type(entry).__name__)))
    name = f"{OBJECT_PREFIX}{module}:{qualname}@{object_identity(factory)}"
    return name + suffix, {(kind, name): factory}


def object_identity(obj: Any) -> str:
    """What tells an entry given as an object from another of the same qualname: the
    sha256 (12 hex digits) of its content (its pickle; for a closure, its code, defaults
    and captured values), the same in every process for the same content; else, for an
    object whose content does not hash, ``local-<id>``, this object in this process
    only (a resumed sweep then runs its cells again)."""
    content = _content(obj)
    if content is None:
        return f"local-{id(obj):x}"
    return hashlib.sha256(content).hexdigest()[:12]


def _code_bytes(code: types.CodeType) -> bytes:
    """A code object's bytecode, names and constants (nested code objects likewise), as
    bytes: not ``marshal.dumps``, whose output depends on reference counts."""
    consts = tuple(
        _code_bytes(const) if isinstance(const, types.CodeType) else repr(const)
        for const in code.co_consts
    )
    fields = (code.co_name, code.co_code, consts, code.co_names, code.co_varnames,
              code.co_freevars, code.co_cellvars)  # fmt: skip
    return repr(fields).encode()


def _content(obj: Any, depth: int = 0) -> bytes | None:
    """Bytes that stand for ``obj``'s content, or None. Hand-written: pickle refuses
    closures, and no standard-library function hashes a function's code and captures."""
    try:
        return pickle.dumps(obj, protocol=4)
    except Exception:  # pickle raises several types (PicklingError, AttributeError, TypeError)
        pass
    if depth > 8:
        return None
    if isinstance(obj, _Copies):
        return _content(obj.prototype, depth + 1)
    if isinstance(obj, types.FunctionType):
        parts = [_code_bytes(obj.__code__)]
        try:
            captured = [cell.cell_contents for cell in obj.__closure__ or ()]
        except ValueError:  # an empty cell
            return None
        for item in (obj.__defaults__, obj.__kwdefaults__, *captured):
            part = _content(item, depth + 1)
            if part is None:
                return None
            parts.append(part)
        return b"\0".join(hashlib.sha256(part).digest() for part in parts)
    return None


def entry_identity(plugin: Plugin) -> dict[str, Any]:
    """Where an outside entry comes from, as results record it and as sweeps and
    benchmarks key their cells and levels by: its import path, source, distribution and
    version (:meth:`Plugin.describe` without options), and ``code_sha256``: the sha256
    (16 hex digits) of the source file of the module that defines its factory, or, for an
    entry given as an object, its :func:`object_identity`. An upgrade of the package that
    changes the factory's module, or another object of the same qualname, is another
    entry. ValueError as :func:`load_factory`."""
    factory = load_factory(plugin)
    record = plugin.describe()
    del record["options"]
    if (plugin.kind, plugin.target) in _OBJECTS:
        record["code_sha256"] = object_identity(factory)
        return record
    module = sys.modules.get(getattr(factory, "__module__", "") or "")
    path = getattr(module, "__file__", None)
    try:
        with open(path, "rb") as source:  # type: ignore[arg-type]  # None: TypeError
            record["code_sha256"] = hashlib.sha256(source.read()).hexdigest()[:16]
    except (OSError, TypeError):  # a module without a source file (built in, frozen)
        record["code_sha256"] = object_identity(factory)
    return record


def check_picklable(objects: Mapping[tuple[str, str], Any]) -> None:
    """ValueError, one line, for an entry given as an object that does not pickle (it
    cannot reach a worker process or a Ray task)."""
    for (kind, name), factory in objects.items():
        try:
            pickle.dumps(factory)
        except (
            Exception
        ) as exc:  # pickle raises several types (PicklingError, AttributeError, TypeError)
            raise ValueError(
                f"{kind} {name!r} cannot run in workers: it does not pickle ({type(exc).__name__}: "
                f"{exc}); define it at module level, name it by import path, or use workers=1"
            ) from None


@contextlib.contextmanager
def objects_in_use(objects: Mapping[tuple[str, str], Any]) -> Iterator[None]:
    """Make the entries given as objects findable by name (:func:`find_plugin`) inside."""
    added = {key: value for key, value in objects.items() if key not in _OBJECTS}
    _OBJECTS.update(added)
    try:
        yield
    finally:
        for key in added:
            _OBJECTS.pop(key, None)


def objects_for(observer: str, controller: str) -> dict[tuple[str, str], Any]:
    """The entries given as objects among ``observer`` and ``controller`` (for an
    episode's spec)."""
    wanted = {("observer", observer.removesuffix(MEASUREMENTS_SUFFIX)), ("controller", controller)}
    return {key: value for key, value in _OBJECTS.items() if key in wanted}


def check_options(kind: str, options: Mapping[str, Any]) -> None:
    """ValueError, one line naming the option, unless every value of an outside
    ``kind``'s ``options`` is one results record as it was given: JSON's types (text,
    bool, None, int, a finite float, and lists and text-keyed mappings of these). Checked
    before the first episode, so a run does not end at "results.json cannot be written"."""
    for key, value in options.items():
        problem = _unrecordable(value)
        if problem is not None:
            raise ValueError(
                f"{kind} option {key!r} = {reprlib.repr(value)} cannot be recorded in the "
                f"results: {problem}; allowed: text, true/false, null, integers, finite "
                "numbers, and lists and mappings of these"
            )


def _unrecordable(value: Any, depth: int = 0) -> str | None:
    """Why ``value`` is not recorded in JSON as it is, or None."""
    if depth > 32:
        return "it is nested more than 32 levels deep"
    if value is None or isinstance(value, (str, bool, int)):
        return None
    if isinstance(value, float):
        return None if math.isfinite(value) else f"{value!r} is not a finite number"
    if isinstance(value, (list, tuple)):
        for item in value:
            problem = _unrecordable(item, depth + 1)
            if problem is not None:
                return problem
        return None
    if isinstance(value, Mapping):
        for key, item in value.items():
            if not isinstance(key, str):
                return f"the key {key!r} is not text"
            problem = _unrecordable(item, depth + 1)
            if problem is not None:
                return problem
        return None
    return f"a {type(value).__name__} is not one of JSON's types"


def entry_line(kind: str, entry: Mapping[str, Any]) -> str:
    """One line for a table's header from a :meth:`Plugin.describe` record: "observer
    NAME = IMPORT_PATH (PACKAGE VERSION; options {...})"."""
    where = "" if entry["name"] == entry["import_path"] else f" = {entry['import_path']}"
    options = f"; options {entry['options']}" if entry["options"] else ""
    return f"{kind} {entry['name']}{where} ({entry['package']} {entry['version']}{options})"


def unknown_message(kind: str, name: str, env_id: str, builtins: list[str]) -> str:
    """The one line for a name that is neither built in nor an entry: what is allowed."""
    installed = sorted(entry_points(kind))
    return (
        f"unknown {kind} {name!r} for {env_id}; allowed: {', '.join(builtins)}, "
        f"an import path package.module:factory"
        + (f", or an installed entry point: {', '.join(installed)}" if installed else "")
    )
