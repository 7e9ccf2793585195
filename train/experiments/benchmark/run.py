"""``observer-gym benchmark``: one entry (observer + controller) on every level of its
system's suite, scored, resumable.

:func:`check_benchmark` resolves the request once (the entries by name, import path or
entry point, as ``compare`` and ``sweep`` take them:
:func:`~observer_gym.train.experiments.request.resolve_request`) against the suite
(:func:`~observer_gym.train.experiments.benchmark.suite.load_suite`). :func:`run_benchmark`
runs every level's episodes (episode i of a level resets with its i-th fixed seed), in
worker processes or as Ray tasks, under the output folder's lock
(:func:`~observer_gym.train.reports.outputs.output_folder`), writes each finished level
at once to ``levels/<level>.json`` (:mod:`~observer_gym.train.experiments.benchmark.levels`),
and assembles the outputs from the level files alone
(:mod:`~observer_gym.train.experiments.benchmark.report`): a resumed run writes the
numbers of an uninterrupted one. ``--episodes N`` below the suite's count runs the first
N seeds of each level and is marked unofficial.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
import warnings
from collections.abc import Callable, Generator, Mapping, Sequence
from contextlib import closing
from pathlib import Path
from typing import Any, NamedTuple

from observer_gym.envs.json_file import read_json
from observer_gym.train.experiments.benchmark.levels import (
    LEVELS_DIR,
    BenchmarkWarning,
    level_file,
    level_problem,
    level_wall_s,
)
from observer_gym.train.experiments.benchmark.records import EpisodeRecord, metric_value
from observer_gym.train.experiments.benchmark.report import BENCHMARK_JSON, write_outputs
from observer_gym.train.experiments.benchmark.request import BenchmarkRequest
from observer_gym.train.experiments.benchmark.score import Scores
from observer_gym.train.experiments.benchmark.suite import (
    DEFAULT_VERSION,
    Level,
    SystemSuite,
    load_suite,
)
from observer_gym.train.experiments.camera_scale import (
    CAMERA_GEOMETRY_OPTIONS,
    camera_scale,
    is_pixel_valued,
)
from observer_gym.train.experiments.episode import EpisodeSpec, iter_episodes
from observer_gym.train.experiments.request import resolve_request
from observer_gym.train.experiments.sweep import sweep_episode
from observer_gym.train.experiments.videos import (
    RerunFolderPlan,
    VideoPlan,
    plan_reruns,
    plan_videos,
    with_reruns,
    with_videos,
)
from observer_gym.train.reports.compare_report import safe_name
from observer_gym.train.reports.outputs import (
    OutputFolderError,
    check_folder_kind,
    output_folder,
    write_json_atomic,
)
from observer_gym.train.reports.progress import progress_bar
from observer_gym.train.rl.run_dir import TrainedWith, parse_agent_spec, trained_with


class BenchmarkResult(NamedTuple):
    """What :func:`run_benchmark` did."""

    out_dir: Path
    scores: Scores
    official: bool
    reused: tuple[str, ...]  # the levels reused from the folder
    text: str  # the table


def check_benchmark(
    env_id: str,
    observer: str,
    controller: str,
    episodes: int | None = None,
    workers: int = 1,
    backend: str = "local",
    address: str | None = None,
    version: str = DEFAULT_VERSION,
    observer_options: Mapping[str, Any] | None = None,
    controller_options: Mapping[str, Any] | None = None,
) -> BenchmarkRequest:
    """The checked request; ValueError naming what is wrong and what is allowed (the
    suite, the entries, ``episodes`` from 1 to the suite's count, workers, backend)."""
    suite = load_suite(env_id, version)
    if episodes is None:
        episodes = suite.episodes
    if (
        isinstance(episodes, bool)
        or not isinstance(episodes, int)
        or not (1 <= episodes <= suite.episodes)
    ):
        raise ValueError(
            f"episodes must be an integer from 1 to the suite's {suite.episodes} per level "
            f"(fewer: an unofficial run), got {episodes!r}"
        )
    request = resolve_request(
        suite.env_id,
        [observer],
        [controller],
        suite.levels[0].seeds(episodes),
        workers=workers,
        backend=backend,
        address=address,
        observer_options=observer_options,
        controller_options=controller_options,
    )
    if request.seed_groups:
        raise ValueError(
            f"controller {controller!r} is a multi-seed agent folder; benchmark one seed's "
            f"agent at a time: {', '.join(request.seed_groups[controller])}"
        )
    agent_options = request.controller(controller).env_options
    scale = camera_scale(suite.env_id, agent_options)
    check_agent_task(suite, controller, agent_options, scale)
    return BenchmarkRequest(
        suite,
        observer,
        controller,
        episodes,
        workers,
        backend,
        address,
        request.observer(observer).options,
        request.controller(controller).options,
        agent_options,
        scale,
    )


# A trained agent's env options that change only how it sees and is rewarded, and so
# travel with it to every level: its camera's geometry and the reward's weights.
AGENT_VIEW_OPTIONS = CAMERA_GEOMETRY_OPTIONS | {"shaping_weight", "effort_weight"}


def check_agent_task(
    suite: SystemSuite, controller: str, agent_options: Mapping[str, Any], scale: float
) -> None:
    """ValueError, one line, if the agent ``controller`` was trained with env options
    that change the task its levels set: only :data:`AGENT_VIEW_OPTIONS` travel, and a
    pixel-valued option (camera_scale.py) equal to its default in the agent's camera's
    pixels (its default times ``scale``: the same task, seen by a smaller camera). An
    agent trained with a larger hole or no aim spread would bring them to every level."""
    config_class = suite.system.env_class().config_class
    defaults = {
        field.name: field.default
        for field in dataclasses.fields(config_class)
        if field.default is not dataclasses.MISSING
    }
    changed = []
    for key, value in agent_options.items():
        if key in AGENT_VIEW_OPTIONS:
            continue
        default = defaults.get(key)
        if (
            is_pixel_valued(key)
            and isinstance(value, (int, float))
            and isinstance(default, (int, float))
            and math.isclose(value, default * scale, rel_tol=1e-6)
        ):
            continue  # the default task in the agent's pixels
        changed.append(f"{key}={value!r}")
    if changed:
        raise ValueError(
            f"controller {controller!r} was trained with env options that change the task: "
            f"{', '.join(changed)}; the suite's levels set the task, and only options that "
            "change how an agent sees or is rewarded travel "
            f"({', '.join(sorted(AGENT_VIEW_OPTIONS))}, and pixel-valued options at their "
            "default in the agent's pixels)"
        )


def agent_entry(policy: str) -> TrainedWith:
    """The observer and env options an agent ``ALGO:DIR`` (or a shipped ``ALGO:NAME``)
    was trained with, from its config.json (checked against its recorded hash).

    Raises:
        ValueError: ``policy`` is not ``ALGO:DIR`` or names no training run.
    """
    spec = parse_agent_spec(policy)
    if spec is None:
        raise ValueError(
            f"policy {policy!r} is not a trained agent; expected ALGO:DIR (one seed's run) "
            "or ALGO:NAME of a shipped agent (observer-gym list)"
        )
    algo, run_dir = spec
    return trained_with(run_dir, algo)


def check_out_dir(out_dir: Path, request: BenchmarkRequest) -> None:
    """OutputFolderError unless ``out_dir`` is new, empty, or holds this same run."""
    check_folder_kind(out_dir, "benchmark")
    path = out_dir / BENCHMARK_JSON
    if not path.exists():
        return
    try:
        recorded = read_json(path).get("identity")
    except (OSError, ValueError, AttributeError):
        recorded = None
    if recorded != json.loads(json.dumps(request.identity())):
        raise OutputFolderError(
            f"{out_dir} holds another benchmark run (its {BENCHMARK_JSON} differs); use "
            "another output folder, or the same arguments to resume it"
        )


def _finished_levels(out_dir: Path, request: BenchmarkRequest) -> dict[str, dict[str, Any]]:
    """The level files in ``out_dir`` that are this run's levels as written; a
    :class:`BenchmarkWarning` for each other one (it runs again)."""
    finished = {}
    for level in request.suite.levels:
        path = out_dir / LEVELS_DIR / f"{level.name}.json"
        if not path.exists():
            continue
        problem: str | None
        try:  # NaN, a key twice, deep nesting: refused by the reader, so it runs again
            data = read_json(path)
        except (OSError, ValueError) as exc:
            problem = f"it cannot be read ({' '.join(str(exc).split())})"
        else:
            problem = level_problem(
                data, request.digest(), level.name, level.seeds(request.episodes)
            )
        if problem is None:
            finished[level.name] = data
        else:
            warnings.warn(
                BenchmarkWarning(f"level {level.name!r} in {path} runs again: {problem}"),
                stacklevel=2,
            )
    return finished


def _episodes(
    request: BenchmarkRequest, specs: Sequence[EpisodeSpec]
) -> Generator[tuple[int, Any], None, None]:
    if request.backend == "ray":
        from observer_gym.train.experiments.ray_backend import iter_episodes_ray  # imports Ray

        return iter_episodes_ray(specs, request.address, sweep_episode)
    return iter_episodes(specs, request.workers, sweep_episode)


def level_line(
    level: str, done: int, total: int, episodes: int, metric: str, mean: float, wall_s: float
) -> str:
    """The line that reports a finished level (``on_level``): ``level 'lab' finished
    (2/3): 460 episodes, caught mean 0.6543, 134.2 s``."""
    return (
        f"level {level!r} finished ({done}/{total}): {episodes} episode"
        f"{'s' if episodes != 1 else ''}, {metric} mean {mean:.4g}, {wall_s:.1f} s"
    )


def _run_levels(
    out_dir: Path,
    request: BenchmarkRequest,
    levels: Sequence[Level],
    progress: bool,
    on_level: Callable[[str], None] | None = None,
    videos: VideoPlan | None = None,
    reruns: RerunFolderPlan | None = None,
) -> dict[str, dict[str, Any]]:
    """Run every episode of ``levels`` in one batch; write each level's file as soon as
    its last episode is in (with its wall time: :func:`~observer_gym.train.experiments.
    benchmark.levels.level_file`) and call ``on_level`` with a line saying so
    (:func:`level_line`); the level files' contents by name. With ``videos`` and
    ``reruns``, the chosen episodes of each level write their videos and rerun recordings
    (file names begin with the level's name)."""
    specs, owner = [], []
    for k, level in enumerate(levels):
        prefix = f"{safe_name(level.name)}__"
        level_specs = with_videos(request.specs(level), videos, request.episodes, prefix)
        level_specs = with_reruns(level_specs, reruns, request.episodes, prefix)
        for i, spec in enumerate(level_specs):
            specs.append(spec)
            owner.append((k, i))
    if not specs:
        return {}
    (out_dir / LEVELS_DIR).mkdir(exist_ok=True)
    n = request.episodes
    values: list[list[float]] = [[0.0] * n for _ in levels]
    times: list[list[float]] = [[0.0] * n for _ in levels]
    missing = [n] * len(levels)
    metric = request.suite.metric.name
    written = {}
    bar = progress_bar(total=len(specs), unit="episode", desc="benchmark", disable=not progress)
    last_s = time.perf_counter()  # the batch's start, then the last level's end
    with bar, closing(_episodes(request, specs)) as episodes:
        bar.set_postfix_str(f"levels 0/{len(levels)}")
        for index, episode in episodes:
            k, i = owner[index]
            where = f"level {levels[k].name!r}, episode {i} (seed {specs[index].seed})"
            values[k][i] = metric_value(episode["metrics"].get(metric), metric, where)
            times[k][i] = episode["time_s"]
            missing[k] -= 1
            if missing[k] == 0:
                level = levels[k]
                now_s = time.perf_counter()
                wall_s, last_s = now_s - last_s, now_s
                data = level_file(
                    request.digest(), level.name, level.seeds(n), values[k], times[k], wall_s
                )
                write_json_atomic(out_dir / LEVELS_DIR / f"{level.name}.json", data)
                written[level.name] = data
                bar.set_postfix_str(f"levels {len(written)}/{len(levels)}")
                if on_level is not None:
                    mean = sum(values[k]) / n
                    on_level(
                        level_line(level.name, len(written), len(levels), n, metric, mean, wall_s)
                    )
            bar.update(1)
    return written


def run_benchmark(
    request: BenchmarkRequest,
    out_dir: str | Path,
    progress: bool = True,
    cli_args: Mapping[str, Any] | None = None,
    on_level: Callable[[str], None] | None = None,
    video_dir: str | Path | None = None,
    video_episodes: Sequence[int] | None = None,
    rerun_dir: str | Path | None = None,
    rerun_episodes: Sequence[int] | None = None,
) -> BenchmarkResult:
    """Run (or resume) ``request`` into ``out_dir``; see the module docstring.

    ``video_dir``: videos of the episodes ``video_episodes`` (indices, default the first)
    of each level run now, if the observer reads camera images
    (:mod:`observer_gym.train.experiments.videos`; levels reused are not run again).
    ``rerun_dir``: a rerun recording of the episodes ``rerun_episodes`` (default the
    first) of each level run now, one ``.rrd`` each named as the videos are.

    ``progress`` draws a bar over the episodes; ``on_level`` is called with one line for
    each level as it finishes (:func:`level_line`; the command prints it on stderr when
    no bar can be drawn). ``timing.json``'s ``wall_s`` is this call's wall time plus the
    recorded wall times of the levels it reused from the folder (after a resume: the
    whole run's time, not the resume's alone;
    :func:`~observer_gym.train.experiments.benchmark.report.timing_document`).

    Raises:
        OutputFolderError: ``out_dir`` holds other results.
        FolderBusyError: another command holds ``out_dir``.
        ValueError: an episode failed (naming it and its seed), or had no headline value.
    """
    out_dir = Path(out_dir)
    videos = plan_videos(
        video_dir, video_episodes, request.episodes, request.suite.env_id, [request.observer]
    )
    reruns = plan_reruns(rerun_dir, rerun_episodes, request.episodes)
    tic_s = time.perf_counter()
    with output_folder(out_dir, "benchmark", check=lambda p: check_out_dir(p, request)):
        write_json_atomic(
            out_dir / BENCHMARK_JSON,
            {
                "identity": request.identity(),
                "command": request.command(),
                "arguments": dict(cli_args or {}),
            },
        )
        finished = _finished_levels(out_dir, request)
        todo = [level for level in request.suite.levels if level.name not in finished]
        levels = {
            **finished,
            **_run_levels(out_dir, request, todo, progress, on_level, videos, reruns),
        }
        records = [
            EpisodeRecord(level.name, i, seed, value)
            for level in request.suite.levels
            for i, (seed, value) in enumerate(
                zip(levels[level.name]["seeds"], levels[level.name]["values"], strict=True)
            )
        ]
        reused_s = {name: level_wall_s(finished[name]) for name in finished}
        scores, text = write_outputs(
            out_dir, request, records, time.perf_counter() - tic_s, reused_s
        )
    return BenchmarkResult(out_dir, scores, request.official, tuple(finished), text)
