"""``observer-gym sweep``: every observer x controller at every point of a grid of env
options, on the same seeds, resumable.

The cells and their episodes come from
:func:`~observer_gym.train.experiments.sweep_plan.check_sweep`
(episode i resets with seed S + i in every cell, so cells are paired episode by episode,
across observers and controllers as in ``observer-gym compare`` and across grid points as
far as the varied option leaves the world's random draws alone: docs/sweep.md). The
episodes run as compare's do (locally by
:func:`~observer_gym.train.experiments.episode.iter_episodes`, or
as Ray tasks by :func:`~observer_gym.train.experiments.ray_backend.iter_episodes_ray`), measured
with
the task's metrics (:func:`~observer_gym.train.reports.compare_stats.episode_values`) and
summarised with compare's intervals and paired differences.

Resuming: ``sweep.json`` in the output folder records the arguments that decide the numbers;
each finished cell is written at once, atomically, to ``cells/<id>.json``
(:mod:`observer_gym.train.experiments.sweep_cells`). A run into a folder with the same
``sweep.json`` skips the cells found there that are the plan's cells as written (their grid
point, observer, controller, seeds, the sha256 of their records and their summary checked;
any other runs again, with a :class:`SweepWarning`); a run with other arguments is refused
before anything is written. A sweep holds its folder's lock while it runs
(:func:`~observer_gym.train.reports.outputs.output_folder`): a second command into it is
refused (:class:`~observer_gym.train.reports.folder_lock.FolderBusyError`), and the folder's
arguments are checked again under the lock before ``sweep.json`` is written. The outputs are
assembled from the cell files alone (:func:`assemble_results`, then
:mod:`observer_gym.train.reports.sweep_report`), so a resumed sweep writes the bytes of an
uninterrupted one; wall-clock times go to ``timing.json`` only.
"""

from __future__ import annotations

import dataclasses
import json
import time
import warnings
from collections.abc import Callable, Generator, Mapping, Sequence
from contextlib import closing
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from observer_gym.envs.json_file import read_json
from observer_gym.train.core.args import point_text, value_text
from observer_gym.train.core.tasks import task_of
from observer_gym.train.experiments.episode import EpisodeSpec, iter_episodes, run_episode
from observer_gym.train.experiments.sweep_cells import SweepWarning, cell_file, finished_cells
from observer_gym.train.experiments.sweep_grid import VaryInput, world_draw_notes
from observer_gym.train.experiments.sweep_plan import (
    ARGUMENTS_FILE,
    CELLS_DIR,
    Cell,
    SweepPlan,
    check_out_dir,
    check_sweep,
)
from observer_gym.train.experiments.videos import (
    RerunFolderPlan,
    VideoPlan,
    plan_reruns,
    plan_videos_for,
    with_reruns,
    with_videos,
)
from observer_gym.train.reports.compare_report import safe_name
from observer_gym.train.reports.compare_stats import (
    CONFIDENCE,
    compare_metrics,
    episode_values,
    metrics_statistics,
    paired_difference,
)
from observer_gym.train.reports.consistency import nees_flag
from observer_gym.train.reports.outputs import (
    VERSIONED_PACKAGES,
    output_folder,
    package_versions,
    to_jsonable,
    write_json_atomic,
)
from observer_gym.train.reports.progress import progress_bar
from observer_gym.train.reports.sweep_report import write_outputs

TIMING_FILE = "timing.json"


@dataclass(frozen=True)
class SweepResult:
    """What :func:`run_sweep` did."""

    out_dir: Path
    results: dict[str, Any]  # what results.json holds
    cells_run: int  # cells computed by this call
    cells_reused: int  # cells found finished in the output folder
    wall_time_s: float  # the whole call
    episode_time_s: float  # the sum of the times of the episodes this call ran
    files: list[str]  # written into out_dir, besides cells/, sweep.json and timing.json


# --- one episode, one cell -------------------------------------------------------------------
def sweep_episode(spec: EpisodeSpec) -> dict[str, Any]:
    """One episode (:func:`~observer_gym.train.experiments.episode.run_episode`) reduced to what a
    cell
    keeps: its metrics (the task's, JSON types), the state it started from, the
    controller's description and the seconds it took (measured where it ran)."""
    tic_s = time.perf_counter()
    record = run_episode(spec)
    values = episode_values(task_of(spec.system), record)  # once per episode spec
    return {
        "metrics": to_jsonable(values),
        "start": to_jsonable(record["state"][0]),
        "controller": to_jsonable(record["controller"]),
        "time_s": time.perf_counter() - tic_s,
    }


# --- running -------------------------------------------------------------------------------
def _episodes(
    plan: SweepPlan, specs: Sequence[EpisodeSpec]
) -> Generator[tuple[int, Any], None, None]:
    """(index, :func:`sweep_episode` of specs[index]) as they finish, on the plan's backend."""
    if plan.backend == "ray":
        from observer_gym.train.experiments.ray_backend import (
            iter_episodes_ray,  # deferred: imports Ray
        )

        return iter_episodes_ray(specs, plan.address, sweep_episode)
    return iter_episodes(specs, plan.workers, sweep_episode)


def cell_line(cell: Cell, done: int, total: int, episodes: int, elapsed_s: float) -> str:
    """The line that reports a finished cell (``on_cell``): ``cell 2/6 finished:
    latency_s=0.05, kf-measurements + lqr, 10 episodes (12.3 s since the start)``."""
    return (
        f"cell {done}/{total} finished: {point_text(cell.point)}, {cell.observer} + "
        f"{cell.controller}, {episodes} episode{'s' if episodes != 1 else ''} "
        f"({elapsed_s:.1f} s since the start)"
    )


def run_cells(
    out_dir: Path,
    plan: SweepPlan,
    cells: Sequence[Cell],
    progress: bool = True,
    on_cell: Callable[[str], None] | None = None,
    videos: VideoPlan | None = None,
    reruns: RerunFolderPlan | None = None,
) -> dict[str, dict]:
    """Run every episode of ``cells`` in one batch; write each cell to
    ``out_dir/cells/<id>.json`` (atomically) as soon as its last episode is in, then call
    ``on_cell`` with one line saying so (:func:`cell_line`), if given. Returns the cell
    files' contents by id. An error or Ctrl-C stops it; the cells written stay. With
    ``videos`` and ``reruns``, the chosen episodes of each cell write their videos and
    rerun recordings (file names begin with the cell's grid point)."""
    specs, owner = [], []
    for k, cell in enumerate(cells):
        point = "".join(f"{safe_name(f'{key}-{value_text(v)}')}__" for key, v in cell.point.items())
        cell_specs = with_videos(plan.specs(cell), videos, len(plan.seeds), prefix=point)
        cell_specs = with_reruns(cell_specs, reruns, len(plan.seeds), prefix=point)
        for i, spec in enumerate(cell_specs):
            specs.append(spec)
            owner.append((k, i))
    if not specs:
        return {}
    (out_dir / CELLS_DIR).mkdir(exist_ok=True)
    results: list[list[Any]] = [[None] * len(plan.seeds) for _ in cells]
    per_cell = len(plan.seeds)
    missing = [per_cell] * len(cells)
    written: dict[str, dict] = {}
    bar = progress_bar(total=len(specs), unit="episode", desc="sweep", disable=not progress)
    tic_s = time.perf_counter()
    # closing: an error here, or Ctrl-C, stops the workers at once (their pending episodes
    # are dropped) rather than when the generator is collected
    with bar, closing(_episodes(plan, specs)) as episodes:
        bar.set_postfix_str(f"cells 0/{len(cells)}")
        for index, episode in episodes:
            k, i = owner[index]
            results[k][i] = episode
            missing[k] -= 1
            if missing[k] == 0:
                # as read back from the file: the outputs are the same from either
                data = cell_file(plan, cells[k], results[k])
                write_json_atomic(out_dir / CELLS_DIR / f"{cells[k].id}.json", data)
                written[cells[k].id] = data
                bar.set_postfix_str(f"cells {len(written)}/{len(cells)}")
                if on_cell is not None:
                    elapsed_s = time.perf_counter() - tic_s
                    on_cell(cell_line(cells[k], len(written), len(cells), per_cell, elapsed_s))
            bar.update(1)
    return written


# --- the results ---------------------------------------------------------------------------
def assemble_results(
    plan: SweepPlan, cells: Mapping[str, Mapping[str, Any]], versions: Mapping[str, str]
) -> dict[str, Any]:
    """What ``results.json`` holds (without ``files``), from the plan and its cell files:
    ``config`` (the arguments, the command, the metrics), ``versions``, ``starts_match``
    (episode i of every cell of a grid point starts from the same state),
    ``starts_match_across_grid`` (and at every grid point), ``cells`` (per cell: its
    point, observer, controller, the statistics of every compared metric and
    ``vs_reference``, the paired difference of the primary metric from the cell with the
    same observer and controller at the first grid point) and ``episodes`` (one row per
    episode: cell id, the point's values, observer, controller, episode, seed, metrics)."""
    task = plan.request.task
    metrics = compare_metrics(task)
    primary = plan.primary_metric
    first = plan.grid.first()
    reference = {
        (c.observer, c.controller): cells[c.id] for c in plan.cells if dict(c.point) == first
    }
    summaries, rows = [], []
    for cell in plan.cells:
        data = cells[cell.id]
        episodes = data["episodes"]
        base = reference[cell.observer, cell.controller]
        summaries.append(
            {
                "id": cell.id,
                "point": dict(cell.point),
                "observer": cell.observer,
                "controller": cell.controller,
                **plan.request.observer(cell.observer).record(),
                "controller_config": data["controller_config"],
                "statistics": metrics_statistics(episodes, metrics),
                "consistency": nees_flag(episodes)._asdict(),
                "vs_reference": None
                if base is data
                else paired_difference(
                    [e.get(primary) for e in episodes], [e.get(primary) for e in base["episodes"]]
                ),
            }
        )
        for episode in episodes:
            rows.append(
                {
                    "cell": cell.id,
                    **cell.point,
                    "observer": cell.observer,
                    "controller": cell.controller,
                    **episode,
                }
            )
    starts = [
        (json.dumps(cell.point, sort_keys=True), cells[cell.id]["starts"]) for cell in plan.cells
    ]
    by_point: dict[str, list] = {}
    for point, start in starts:
        by_point.setdefault(point, []).append(start)
    base_config = _base_config(plan)
    return to_jsonable(
        {
            "config": {
                **plan.arguments(),
                "keys": list(plan.grid.keys),
                "seeds": list(plan.seeds),
                "grid_points": len(plan.grid.points()),
                "cells": len(plan.cells),
                "env_config": {
                    k: v for k, v in dataclasses.asdict(base_config).items() if k != "obs_mode"
                },
                "env_config_class": type(base_config).__name__,
                "confidence": CONFIDENCE,
                "primary_metric": primary,
                "second_metric": plan.second_metric,
                "metrics": {
                    key: dict(
                        zip(("label", "unit", "scale", "digits", "better"), spec, strict=True)
                    )
                    for key, spec in metrics.items()
                },
                "reference": first,
                "plots": "one per varied key: the other keys at their first value",
                **task.CONFIG,
                "command": plan.command(),
            },
            "versions": dict(versions),
            "starts_match": all(all(s == group[0] for s in group) for group in by_point.values()),
            "starts_match_across_grid": all(s == starts[0][1] for _, s in starts),
            "cells": summaries,
            "episodes": rows,
        }
    )


def _base_config(plan: SweepPlan) -> Any:
    """The env's configuration with the sweep's fixed options (the keys at their defaults)."""
    config_class = plan.request.system.env_class().config_class
    return config_class.from_kwargs(**plan.env_kwargs)


def _versions(plan: SweepPlan) -> dict[str, str]:
    names = VERSIONED_PACKAGES + ("scipy",) + (("ray",) if plan.backend == "ray" else ())
    return package_versions(names)


# --- the whole sweep -------------------------------------------------------------------------
def run_sweep(
    env_id: str,
    vary: VaryInput,
    observers: Sequence[str] | str,
    controllers: Sequence[str] | str,
    out_dir: str | Path,
    episodes: int = 10,
    seed: int = 0,
    workers: int = 1,
    backend: str = "local",
    address: str | None = None,
    steps: int | None = None,
    env_kwargs: Mapping[str, Any] | None = None,
    second_metric: str | None = None,
    progress: bool = True,
    cli_args: Mapping[str, Any] | None = None,
    observer_options: Mapping[str, Any] | None = None,
    controller_options: Mapping[str, Any] | None = None,
    on_cell: Callable[[str], None] | None = None,
    video_dir: str | Path | None = None,
    video_episodes: Sequence[int] | None = None,
    rerun_dir: str | Path | None = None,
    rerun_episodes: Sequence[int] | None = None,
) -> SweepResult:
    """Run every cell (grid point x observer x controller) of a sweep on the same seeds,
    resuming from the cells ``out_dir`` already holds; write its outputs.

    Every input is checked first (:func:`check_sweep`; nothing is written for a bad one).
    Then, holding ``out_dir``'s lock, in ``out_dir``: ``sweep.json`` (the arguments,
    written once), ``cells/<id>.json`` for each cell as it finishes (the cells found there
    from an earlier run with the same arguments are not run again if each is the plan's
    cell as written: :func:`~observer_gym.train.experiments.sweep_cells.finished_cells`),
    and from the cell files ``table.md``, ``episodes.csv``, ``<key>.png`` per varied key
    and, last and atomically, ``results.json``
    (:func:`assemble_results`; the same bytes whether or not the sweep was resumed);
    ``timing.json`` gets this call's wall-clock times, the episodes' times, the backend
    and ``cli_args``.

    Warns (:class:`SweepWarning`) when a varied key may change the world's random draws
    (:func:`~observer_gym.train.experiments.sweep_grid.world_draw_notes`), when episode i of a grid
    point's cells does not start from one state, and when the cells found were computed
    with other package versions.

    Args:
        env_id: a registered id, with or without ``observer_gym/``.
        vary: {key: values} or [(key, values), ...]; values as the key's type or as text.
        observers, controllers: names of the task's ``OBSERVERS`` and of controllers (or
            trained agents ``ALGO:DIR``), lists or comma-separated text.
        out_dir: the output folder; a new one, or one to resume.
        episodes: episodes per cell (>= 1); episode i resets with ``seed + i``.
        seed: the first seed (>= 0).
        workers: processes for the local backend (>= 1); the numbers do not depend on it.
        backend: "local" or "ray"; address: the Ray cluster (None: a local instance).
        steps: cap on each episode's steps (None: the env's time limit).
        env_kwargs: fixed ``gym.make`` options for every cell (not a varied key).
        second_metric: the metric shown beside the primary one in the table and plots.
        observer_options, controller_options: keyword arguments of every outside observer's
            and controller's factory.
        progress: a progress bar over the episodes to run.
        cli_args: the command line's arguments, recorded in timing.json.
        on_cell: called with one line for each cell as it finishes (:func:`cell_line`;
            the command prints it when no bar can be drawn).
        video_dir: write videos of the episodes ``video_episodes`` (indices, default the
            first) of every cell run now whose observer reads camera images into this
            folder (:mod:`observer_gym.train.experiments.videos`; cells reused from an
            earlier run are not run again, so they get none).
        rerun_dir: write a rerun recording of the episodes ``rerun_episodes`` (indices,
            default the first) of every cell run now into this folder, one ``.rrd`` each
            named as the videos are (cells reused get none).

    Raises:
        ValueError: a bad input, or an ``out_dir`` holding another sweep
            (:func:`check_out_dir`: an
            :class:`~observer_gym.train.reports.outputs.OutputFolderError`), before
            anything runs; cells that cannot be summarised (a value that is not a finite
            number), before any output is written.
        FolderBusyError: another command holds ``out_dir``
            (:mod:`observer_gym.train.reports.folder_lock`); nothing was written.
        WriteError: an output could not be written (the earlier outputs are kept).
        KeyboardInterrupt: Ctrl-C; the cells written stay, each whole.
    """
    tic_s = time.perf_counter()
    plan = check_sweep(
        env_id, vary, observers, controllers, episodes, seed, out_dir, workers, backend,
        address, steps, env_kwargs, second_metric, observer_options, controller_options,
    )  # fmt: skip
    videos = plan_videos_for(video_dir, video_episodes, episodes, plan.request.observers)
    reruns = plan_reruns(rerun_dir, rerun_episodes, episodes)
    for note in world_draw_notes(plan.request.system, plan.grid):
        warnings.warn(note, SweepWarning, stacklevel=2)
    out_dir = Path(out_dir)
    versions = _versions(plan)
    checked_s = time.perf_counter()
    # the folder checked again once it is this sweep's alone: another sweep may have
    # written its sweep.json since check_sweep read the folder
    with output_folder(out_dir, "sweep", check=lambda folder: check_out_dir(folder, plan)):
        arguments_path = out_dir / ARGUMENTS_FILE
        if arguments_path.exists():
            stored = read_json(arguments_path).get("versions")
            if stored != versions:
                warnings.warn(
                    f"the cells in {out_dir} were computed with other package versions "
                    f"({stored}); the cells run now use {versions}",
                    SweepWarning,
                    stacklevel=2,
                )
        else:
            write_json_atomic(arguments_path, {"arguments": plan.arguments(), "versions": versions})
        cells = finished_cells(out_dir, plan)
        reused = len(cells)
        todo = [cell for cell in plan.cells if cell.id not in cells]
        ran = run_cells(out_dir, plan, todo, progress, on_cell, videos, reruns)
        cells.update(ran)
        ran_s = time.perf_counter()

        try:
            results = assemble_results(plan, cells, versions)
        except (ValueError, TypeError) as exc:  # a cell file holding a value of no number
            raise ValueError(
                f"the cells in {out_dir / CELLS_DIR} cannot be summarised: {exc}"
            ) from None
        if not results["starts_match"]:
            warnings.warn(
                "episode i of the cells of a grid point does not always start from the same "
                "state: those cells are not paired",
                SweepWarning,
                stacklevel=2,
            )
        written = write_outputs(out_dir, results)
        done_s = time.perf_counter()
        episode_s = [t for data in ran.values() for t in data["timing"]["episode_s"]]
        write_json_atomic(
            out_dir / TIMING_FILE,
            {
                "wall_time_s": done_s - tic_s,
                "check_s": checked_s - tic_s,
                "run_s": ran_s - checked_s,
                "report_s": done_s - ran_s,
                "cells_run": len(ran),
                "cells_reused": reused,
                "episodes_run": len(episode_s),
                "episode_time_s_sum": sum(episode_s),
                "workers": plan.workers,
                "backend": plan.backend,
                "address": plan.address,
                "out_dir": str(out_dir),
                "cli_args": cli_args,
                "cells": {cell_id: data["timing"] for cell_id, data in ran.items()},
            },
        )
    return SweepResult(
        out_dir, written, len(ran), reused, done_s - tic_s, sum(episode_s), written["files"]
    )
