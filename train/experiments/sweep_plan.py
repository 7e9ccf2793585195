"""What ``observer-gym sweep`` runs: its cells and the arguments that decide its numbers,
checked before anything runs.

A cell is one grid point (:mod:`observer_gym.train.experiments.sweep_grid`) x observer x controller,
named by a stable id (its file ``cells/<id>.json``). :func:`check_sweep` checks a request,
as ``observer-gym compare`` checks its own plus the grid and the output folder, and
returns its :class:`SweepPlan`: the cells, each cell's episodes
(:class:`~observer_gym.train.experiments.episode.EpisodeSpec`; episode i resets with seed S + i in
every
cell), the arguments recorded in ``sweep.json`` and the command line that repeats them.
"""

from __future__ import annotations

import hashlib
import json
import shlex
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from observer_gym.envs.json_file import read_json
from observer_gym.train.core.args import value_text
from observer_gym.train.core.entries import entry_identity
from observer_gym.train.experiments.compare import check_designs, check_pairs_once, option_text
from observer_gym.train.experiments.episode import EpisodeSpec
from observer_gym.train.experiments.request import Request, resolve_request
from observer_gym.train.experiments.sweep_grid import Grid, VaryInput, check_grid
from observer_gym.train.reports.compare_report import safe_name
from observer_gym.train.reports.compare_stats import compare_metrics
from observer_gym.train.reports.outputs import OutputFolderError, check_folder_kind, to_jsonable
from observer_gym.train.reports.sweep_report import ROW_COLUMNS

# The output folder: the arguments (written once), a file per finished cell.
ARGUMENTS_FILE = "sweep.json"
CELLS_DIR = "cells"


# --- the plan ----------------------------------------------------------------------------
@dataclass(frozen=True)
class Cell:
    """One grid point x observer x controller."""

    point: Mapping[str, Any]
    observer: str
    controller: str

    @property
    def id(self) -> str:
        """A stable file name: the cell readable (``latency_s-0.02__oracle__lqr``, cut to
        100 characters) and 10 hex digits of a hash of its exact values."""
        exact = json.dumps([dict(self.point), self.observer, self.controller], sort_keys=True)
        digest = hashlib.sha256(exact.encode()).hexdigest()[:10]
        parts = [f"{key}-{value_text(value)}" for key, value in self.point.items()]
        readable = "__".join(safe_name(p) for p in [*parts, self.observer, self.controller])
        return f"{readable[:100]}-{digest}"


@dataclass(frozen=True)
class SweepPlan:
    """A checked sweep: what :func:`check_sweep` returns and
    :func:`observer_gym.train.experiments.sweep.run_sweep` runs."""

    request: Request  # the env, observers, controllers, seeds, options: resolved once
    grid: Grid
    primary_metric: str
    second_metric: str

    @property
    def env_id(self) -> str:
        return self.request.env_id

    @property
    def observers(self) -> tuple[str, ...]:
        return tuple(self.request.observer_names)

    @property
    def controllers(self) -> tuple[str, ...]:
        return tuple(self.request.controller_names)

    @property
    def seeds(self) -> tuple[int, ...]:
        return self.request.seeds

    @property
    def steps(self) -> int | None:
        return self.request.steps

    @property
    def env_kwargs(self) -> Mapping[str, Any]:
        return self.request.env_kwargs

    @property
    def workers(self) -> int:
        return self.request.workers

    @property
    def backend(self) -> str:
        return self.request.backend

    @property
    def address(self) -> str | None:
        return self.request.address

    @property
    def observer_options(self) -> Mapping[str, Any]:
        return self.request.observer_options

    @property
    def controller_options(self) -> Mapping[str, Any]:
        return self.request.controller_options

    @property
    def cells(self) -> list[Cell]:
        """Every cell: grid points outermost (the first key slowest), then controllers,
        then observers."""
        return [
            Cell(point, observer, controller)
            for point in self.grid.points()
            for controller in self.controllers
            for observer in self.observers
        ]

    def arguments(self) -> dict[str, Any]:
        """What decides the numbers (JSON types): a folder's ``sweep.json`` must hold
        these for a run to reuse its cells. Workers, backend and the report's options
        are not among them."""
        return json.loads(
            json.dumps(
                to_jsonable(
                    {
                        "env_id": self.env_id,
                        "vary": self.grid.as_dict(),
                        "observers": list(self.observers),
                        "controllers": list(self.controllers),
                        "episodes": len(self.seeds),
                        "seed": self.seeds[0],
                        "steps": self.steps,
                        "env_kwargs": dict(self.env_kwargs),
                        # only when given: the folders of sweeps without them stay valid
                        **(
                            {"observer_options": dict(self.observer_options)}
                            if self.observer_options
                            else {}
                        ),
                        **(
                            {"agent_env_options": self.request.agent_env_options}
                            if self.request.agent_env_options
                            else {}
                        ),
                        **(
                            {"observer_env_options": self.request.observer_env_options}
                            if self.request.observer_env_options
                            else {}
                        ),
                        **(
                            {"agent_camera_scale": scales}
                            if (scales := self.request.agent_camera_scales(self.grid.keys))
                            else {}
                        ),
                        **(
                            {"controller_options": dict(self.controller_options)}
                            if self.controller_options
                            else {}
                        ),
                        # where outside entries come from (entry_identity): an upgraded
                        # package's entry, or another object, does not reuse the cells
                        **({"entries": found} if (found := self.entry_identities()) else {}),
                    }
                )
            )
        )

    def entry_identities(self) -> dict[str, dict[str, Any]]:
        """:func:`~observer_gym.train.core.entries.entry_identity` of every
        outside observer and controller, by ``"<kind> <name>"``."""
        plugins = [entry.plugin for entry in self.request.observers]
        plugins += [entry.plugin for entry in self.request.controllers]
        return {
            f"{plugin.kind} {plugin.name}": entry_identity(plugin)
            for plugin in plugins
            if plugin is not None
        }

    def digest(self) -> str:
        """A hash of :meth:`arguments`, recorded in every cell file."""
        text = json.dumps(self.arguments(), sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:16]

    def specs(self, cell: Cell) -> list[EpisodeSpec]:
        """The cell's episodes: episode i resets with ``seeds[i]``."""
        observer = self.request.observer(cell.observer)
        controller = self.request.controller(cell.controller)
        # an agent's own env options, under the sweep's fixed ones and the cell's point
        # (pixel-valued ones in the agent camera's pixels: Request.env_kwargs_for)
        env_kwargs = self.request.env_kwargs_for(controller, cell.point)
        return [
            EpisodeSpec.of_entries(
                self.request.system,
                observer,
                controller,
                seed,
                max_steps=self.steps,
                env_kwargs=env_kwargs,
            )
            for seed in self.seeds
        ]

    def command(self) -> str:
        """The ``observer-gym sweep`` command line that computes these numbers again (add
        ``--out DIR``; workers and backend do not change them)."""
        words = ["observer-gym", "sweep", "--env", self.env_id.split("/", 1)[-1]]
        for key, values in self.grid.as_dict().items():
            words += ["--vary", f"{key}={','.join(value_text(v) for v in values)}"]
        words += ["--observers", ",".join(self.observers)]
        words += ["--controllers", ",".join(self.controllers)]
        words += ["--episodes", str(len(self.seeds)), "--seed", str(self.seeds[0])]
        if self.steps is not None:
            words += ["--steps", str(self.steps)]
        for flag, options in (
            ("--env-option", self.env_kwargs),
            ("--observer-option", self.observer_options),
            ("--controller-option", self.controller_options),
        ):
            for key, value in options.items():
                words += [flag, option_text(key, value)]
        words += ["--second-metric", self.second_metric]
        return shlex.join(words)


# --- checks --------------------------------------------------------------------------------
def _count(name: str, value: Any, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return value


def check_sweep(
    env_id: str,
    vary: VaryInput,
    observers: Sequence[str] | str,
    controllers: Sequence[str] | str,
    episodes: int = 10,
    seed: int = 0,
    out_dir: str | Path | None = None,
    workers: int = 1,
    backend: str = "local",
    address: str | None = None,
    steps: int | None = None,
    env_kwargs: Mapping[str, Any] | None = None,
    second_metric: str | None = None,
    observer_options: Mapping[str, Any] | None = None,
    controller_options: Mapping[str, Any] | None = None,
) -> SweepPlan:
    """Check a sweep's inputs before anything runs; return its :class:`SweepPlan`.

    In order: ``episodes`` >= 1 and ``seed`` >= 0; the env, observers, controllers,
    ``workers``, ``backend``, ``address``, ``steps`` and ``env_kwargs`` as compare checks
    them (:func:`~observer_gym.train.experiments.request.resolve_request`); the grid
    (:func:`~observer_gym.train.experiments.sweep_grid.check_grid`: every key an option of the env,
    every value of its type and range, the configuration of every grid point valid with
    every observer's obs_mode); ``second_metric`` one of the task's ``COMPARE_METRICS``
    (default: its second); every baseline controller designed once at the first grid
    point, and each pair with an outside observer or controller tried once there with its
    options (:func:`~observer_gym.train.experiments.episode.check_entries`); and, with ``out_dir``,
    that
    the folder holds no other sweep (:func:`check_out_dir`).

    Raises:
        ValueError: one line naming the bad value and what is allowed.
    """
    episodes = _count("episodes", episodes, 1)
    seed = _count("seed", seed, 0)
    request = resolve_request(
        env_id, observers, controllers, list(range(seed, seed + episodes)), workers, backend,
        address, steps, env_kwargs, observer_options, controller_options,
    )  # fmt: skip
    env_id, env_kwargs, task = request.env_id, request.env_kwargs, request.task
    modes = [entry.obs_mode for entry in request.observers]
    grid = check_grid(request.system, vary, env_kwargs, modes)
    metrics = list(compare_metrics(task))
    if second_metric is None:
        second_metric = metrics[1] if len(metrics) > 1 else metrics[0]
    if second_metric not in metrics:
        raise ValueError(
            f"unknown metric {second_metric!r} for {env_id}; allowed: {', '.join(metrics)}"
        )
    taken = sorted(set(grid.keys) & {"cell", *ROW_COLUMNS, *metrics})
    if taken:
        raise ValueError(f"vary: {', '.join(taken)} would name a column of the results twice")
    first_point = {**env_kwargs, **grid.first()}
    check_designs(request, first_point)
    check_pairs_once(request, first_point)
    plan = SweepPlan(request, grid, metrics[0], second_metric)
    if out_dir is not None:
        check_out_dir(out_dir, plan)
    return plan


def _shown(value: Any) -> str:
    text = json.dumps(value, separators=(",", ":"))
    return text if len(text) <= 80 else text[:77] + "..."


def check_out_dir(out_dir: str | Path, plan: SweepPlan) -> None:
    """:class:`~observer_gym.train.reports.outputs.OutputFolderError` (a ValueError)
    unless ``out_dir`` is new, or holds a sweep with the plan's arguments (``sweep.json``;
    the message names every argument that differs), or holds neither a ``results.json``
    nor ``cells/`` of something else. :func:`check_sweep` runs it before anything runs,
    and :func:`~observer_gym.train.experiments.sweep.run_sweep` again once it holds the
    folder's lock, before it writes there."""
    out_dir = Path(out_dir)
    path = out_dir / ARGUMENTS_FILE
    if path.exists():
        try:
            stored = read_json(path)["arguments"]
            if not isinstance(stored, dict):
                raise TypeError
        except (OSError, ValueError, KeyError, TypeError):
            raise OutputFolderError(
                f"{path} is not readable as a sweep's arguments; use another output folder"
            ) from None
        here = plan.arguments()
        differs = [k for k in dict.fromkeys([*stored, *here]) if stored.get(k) != here.get(k)]
        if differs:
            shown = "; ".join(
                f"{k} {_shown(stored.get(k))} there, {_shown(here.get(k))} here" for k in differs
            )
            raise OutputFolderError(
                f"{out_dir} holds a sweep with other arguments ({shown}); run with the same "
                "arguments to resume it, or use another output folder"
            )
    elif (out_dir / "results.json").exists() or (out_dir / CELLS_DIR).exists():
        raise OutputFolderError(
            f"{out_dir} holds results but no {ARGUMENTS_FILE}: not a sweep's folder; use "
            "another output folder"
        )
    else:  # a training run's, a benchmark's, a demo's folder: as run and compare refuse it
        check_folder_kind(out_dir, "sweep")
