"""``observer-gym compare``: every (observer, controller) pair of one env on the same seeds.

Episode i of every pair resets with the same seed, so every pair starts from the same
state and, as far as the env draws its disturbances from the reset seed, meets the same
disturbances: differences between pairs are paired, episode by episode. Each pair's
per-episode metrics come from the env's task module (:mod:`observer_gym.train.core.tasks`),
whose ``COMPARE_METRICS`` decides which go into the table (the first is the primary
metric, the one of the "oracle vs observer" column).

:func:`run_comparison` checks the inputs (:func:`check_comparison`), runs all episodes in
one batch (:func:`run_pairs`: locally in worker processes or as Ray tasks, the same
results), analyses them (:mod:`observer_gym.train.reports.compare_stats`) and writes the outputs
(:mod:`observer_gym.train.reports.compare_report`).
"""

from __future__ import annotations

import ast
import shlex
import time
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, NamedTuple

from observer_gym.train.core.observer_env import make_env, resolve_observer
from observer_gym.train.experiments.episode import (
    EpisodeSpec,
    build_controller,
    check_entries,
    run_episodes,
)
from observer_gym.train.experiments.request import Request, resolve_request
from observer_gym.train.experiments.videos import (
    RerunFolderPlan,
    VideoPlan,
    plan_reruns,
    plan_videos_for,
    with_reruns,
    with_videos,
)
from observer_gym.train.reports.aggregate import across_seeds
from observer_gym.train.reports.compare_report import format_seeds, pair_folders, write_comparison
from observer_gym.train.reports.compare_stats import (
    CONFIDENCE,
    ORACLE,
    analyse_pairs,
    compare_counts,
    compare_metrics,
)
from observer_gym.train.reports.outputs import (
    VERSIONED_PACKAGES,
    check_folder_kind,
    output_folder,
    package_versions,
)
from observer_gym.train.rl.run_dir import SEED_PREFIX


def check_comparison(
    env_id: str,
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
    """Check a comparison's inputs; return its
    :class:`~observer_gym.train.experiments.request.Request`.
    A trained agent naming a multi-seed run (``ALGO:DIR`` with ``DIR/seed_<s>/``) stands
    for one agent per seed (the request's ``controllers``; ``named_controllers`` are the
    names as given and ``seed_groups`` each multi-seed name's agents; scores across seeds
    are rliable's IQM and interval).

    The cheap checks come first and build no env
    (:func:`~observer_gym.train.experiments.request.resolve_request`); then each baseline controller
    is designed once on the env's state version with ``env_kwargs``
    (:func:`check_designs`: a BallCatcher controller on BallTable, or a bad env option,
    fails here rather than in every episode), and each pair with an outside observer or
    controller is tried once (:func:`observer_gym.train.experiments.episode.check_entries`).
    ``observer_options`` and ``controller_options`` go to every outside observer's and
    controller's factory.

    Raises:
        ValueError: naming the bad value and what is allowed.
    """
    request = resolve_request(
        env_id, observers, controllers, seeds, workers, backend, address, steps, env_kwargs,
        observer_options, controller_options,
    )  # fmt: skip
    check_designs(request, request.env_kwargs)
    check_pairs_once(request, request.env_kwargs)
    return request


def check_pairs_once(request: Request, env_kwargs: Mapping[str, Any]) -> None:
    """Try every pair with an outside observer or controller once with ``env_kwargs``
    (:func:`observer_gym.train.experiments.episode.check_entries`)."""
    for controller in request.controllers:
        for observer in request.observers:
            check_entries(request.system, observer, controller, env_kwargs, request.seeds[0])


def check_designs(request: Request, env_kwargs: Mapping[str, Any]) -> None:
    """Design every baseline controller of the package once on the state env with
    ``env_kwargs`` (trained agents were checked against the env by check_controller,
    outside ones are tried by :func:`check_pairs_once`); ValueError if the env or a
    design fails."""
    env_id = request.env_id
    baselines = [c for c in request.controllers if c.kind == "design"]
    if not baselines:
        return
    oracle = resolve_observer(request.system, ORACLE, task=request.task)
    try:
        env = make_env(request.system, oracle, env_kwargs)
    except (TypeError, ValueError) as exc:
        raise ValueError(
            f"cannot make {env_id} with env options {dict(env_kwargs)}: {exc}"
        ) from exc
    try:
        for controller in baselines:
            try:
                build_controller(controller, env, request.system)
            except ValueError as exc:
                raise ValueError(
                    f"controller {controller.name!r} does not fit {env_id}: {exc}"
                ) from exc
    finally:
        env.close()


# --- the command line that repeats a comparison ---------------------------------------
def option_text(key: str, value: Any) -> str:
    """``KEY=VALUE`` that ``observer_gym.train.cli.env_option`` reads back as ``value``."""
    if isinstance(value, str):
        try:
            same = ast.literal_eval(value) == value
        except (ValueError, SyntaxError):
            same = True  # read back as text
        return f"{key}={value if same else repr(value)}"
    return f"{key}={value!r}"


def command_line(
    env_id: str,
    observers: Sequence[str],
    controllers: Sequence[str],
    seeds: Sequence[int],
    steps: int | None = None,
    workers: int = 1,
    backend: str = "local",
    address: str | None = None,
    env_kwargs: Mapping[str, Any] | None = None,
    observer_options: Mapping[str, Any] | None = None,
    controller_options: Mapping[str, Any] | None = None,
) -> str:
    """The ``observer-gym compare`` command line that runs this comparison again (without
    ``--out``: it writes a new folder)."""
    words = [
        "observer-gym",
        "compare",
        "--env",
        env_id.split("/", 1)[-1],
        "--observers",
        ",".join(observers),
        "--controllers",
        ",".join(controllers),
        "--seeds",
        format_seeds(seeds),
    ]
    if steps is not None:
        words += ["--steps", str(steps)]
    if workers != 1:
        words += ["--workers", str(workers)]
    if backend != "local":
        words += ["--backend", backend]
    if address is not None:
        words += ["--address", address]
    for flag, options in (
        ("--env-option", env_kwargs),
        ("--observer-option", observer_options),
        ("--controller-option", controller_options),
    ):
        for key, value in (options or {}).items():
            words += [flag, option_text(key, value)]
    return shlex.join(words)


# --- multi-seed agents ----------------------------------------------------------------------
def across_seed_groups(
    pairs: Sequence[Mapping[str, Any]], seed_groups: Mapping[str, Sequence[str]], metric: str
) -> list[dict[str, Any]]:
    """For each multi-seed agent of ``seed_groups`` (name -> its seeds' agents) and each
    observer: each seed's agent's mean of ``metric`` over the episodes (its statistics'
    mean), and across seeds their mean and IQM with its 95 % interval
    (:func:`~observer_gym.train.reports.aggregate.across_seeds`, None if no seed has a value)."""
    lookup = {(p["observer"], p["controller"]): p for p in pairs}
    observers = list(dict.fromkeys(p["observer"] for p in pairs))
    entries = []
    for name, agents in seed_groups.items():
        for observer in observers:
            per_seed = {
                _seed_of(agent): lookup[observer, agent]["statistics"][metric]["mean"]
                for agent in agents
            }
            scores = {seed: value for seed, value in per_seed.items() if value is not None}
            entries.append(
                {
                    "observer": observer,
                    "controller": name,
                    "agents": list(agents),
                    "metric": metric,
                    "per_seed": {str(seed): value for seed, value in per_seed.items()},
                    "statistics": across_seeds(scores).as_dict() if scores else None,
                }
            )
    return entries


def _seed_of(agent: str) -> int:
    """The seed of ``ALGO:DIR/seed_<s>``."""
    return int(Path(agent.partition(":")[2]).name.removeprefix(SEED_PREFIX))


# --- running and the whole comparison ------------------------------------------------------
class PairRuns(NamedTuple):
    """The episodes of every pair, as :func:`run_pairs` ran them."""

    pairs: list[tuple[str, str]]  # (observer, controller), controllers outermost
    records: list[dict[str, Any]]  # the episodes of pairs[0] on every seed, then pairs[1]...
    wall_time_s: float

    def by_pair(self, episodes: int) -> dict[tuple[str, str], list[dict[str, Any]]]:
        """The records of each pair (``episodes`` per pair)."""
        n = episodes
        return {pair: self.records[k * n : (k + 1) * n] for k, pair in enumerate(self.pairs)}


def run_pairs(
    request: Request,
    progress: bool = True,
    videos: VideoPlan | None = None,
    reruns: RerunFolderPlan | None = None,
) -> PairRuns:
    """Run episode i of every (observer, controller) pair of ``request`` with
    ``seeds[i]``, all in one batch: locally in ``workers`` processes or as Ray tasks (the
    same records); with ``videos`` and ``reruns``, the chosen episodes write their videos
    and rerun recordings."""
    pairs = [(o, c) for c in request.controllers for o in request.observers]
    specs = [
        EpisodeSpec.of_entries(
            request.system,
            observer,
            controller,
            seed,
            max_steps=request.steps,
            env_kwargs=request.env_kwargs_for(controller),
        )
        for observer, controller in pairs
        for seed in request.seeds
    ]
    specs = with_reruns(with_videos(specs, videos, len(request.seeds)), reruns, len(request.seeds))
    tic_s = time.perf_counter()
    if request.backend == "ray":
        from observer_gym.train.experiments.ray_backend import (
            run_episodes_ray,  # deferred: imports Ray
        )

        records = run_episodes_ray(specs, address=request.address, progress=progress)
    else:
        records = run_episodes(specs, request.workers, progress, desc="compare")
    names = [(o.name, c.name) for o, c in pairs]
    return PairRuns(names, records, time.perf_counter() - tic_s)


def run_comparison(
    env_id: str,
    observers: Sequence[str] | str,
    controllers: Sequence[str] | str,
    seeds: Sequence[int],
    out_dir: str | Path,
    workers: int = 1,
    backend: str = "local",
    address: str | None = None,
    steps: int | None = None,
    env_kwargs: Mapping[str, Any] | None = None,
    progress: bool = True,
    cli_args: Mapping[str, Any] | None = None,
    observer_options: Mapping[str, Any] | None = None,
    controller_options: Mapping[str, Any] | None = None,
    video_dir: str | Path | None = None,
    video_episodes: Sequence[int] | None = None,
    rerun_dir: str | Path | None = None,
    rerun_episodes: Sequence[int] | None = None,
) -> dict[str, Any]:
    """Run every (observer, controller) pair on ``seeds``; write tables, plots, results.

    Episode i of every pair resets with ``seeds[i]``. Every input is checked first
    (:func:`check_comparison`); then all episodes run in one batch.

    Writes into ``out_dir`` (created and locked, one command at a time; removed again if the
    comparison fails before writing anything:
    :func:`~observer_gym.train.reports.outputs.output_folder`): ``table.md``
    (one row per pair: mean ± 95 % half-width of each of the task's
    ``COMPARE_METRICS``, rates with their Wilson interval, the task's ``COMPARE_COUNTS``
    counted, and, with "oracle" among the observers, the paired difference of the primary
    metric observer − oracle),
    ``table.csv`` (observer, controller, metric, n,
    mean, half_width, low, high, interval; values in the metric's stored SI unit, rates
    0-1), ``bar_<metric>.png`` per metric, the task's plots of each pair in
    ``pairs/<observer>__<controller>/`` and, last and atomically, ``results.json``
    (:func:`observer_gym.train.reports.compare_report.write_comparison`). Warns when the pairs'
    episodes do not all start from the same state for the same seed.

    Args:
        env_id: a registered id, with or without ``observer_gym/``.
        observers: names of the task's ``OBSERVERS`` (a string is split at commas).
        controllers: controller names or trained agents ``ALGO:DIR``.
        seeds: distinct reset seeds >= 0, the same for every pair.
        out_dir: the output folder.
        workers: processes for the local backend (>= 1); results do not depend on it.
        backend: "local" or "ray" (Ray tasks; the same results).
        address: the Ray cluster to connect to (backend "ray" only; None: start a local
            Ray instance).
        steps: cap on each episode's steps (None: the env's time limit).
        env_kwargs: extra ``gym.make`` options for every pair (the observer sets obs_mode).
        progress: show a progress bar over episodes.
        cli_args: the command line's arguments, recorded in results.json; when given,
            table.md starts with the command line that regenerates it.
        video_dir: write videos of the episodes ``video_episodes`` (indices, default the
            first) of every pair whose observer reads camera images into this folder
            (:mod:`observer_gym.train.experiments.videos`); the results are the same.
        rerun_dir: write a rerun recording of the episodes ``rerun_episodes`` (indices,
            default the first) of every pair into this folder, one ``.rrd`` each named as
            the videos are (:func:`~observer_gym.train.experiments.videos.with_reruns`);
            the results are the same.

    Returns:
        What ``results.json`` holds (JSON types): ``config``, ``versions``,
        ``wall_time_s``, ``pairs`` (per pair: ``observer``, ``controller``, ``folder``,
        ``episodes`` with each episode's metrics, the task's ``summary``, ``statistics``
        per compared metric, ``counts`` per counted key if the task has
        ``COMPARE_COUNTS``, ``vs_oracle``, ``files``), ``starts_match`` and ``files``.

    Raises:
        ValueError: a bad input (see :func:`check_comparison`).
    """
    request = check_comparison(
        env_id, observers, controllers, seeds, workers, backend, address, steps, env_kwargs,
        observer_options, controller_options,
    )  # fmt: skip
    task, seeds = request.task, list(request.seeds)
    videos = plan_videos_for(video_dir, video_episodes, len(seeds), request.observers)
    reruns = plan_reruns(rerun_dir, rerun_episodes, len(seeds))
    metrics = compare_metrics(task)
    out_dir = Path(out_dir)
    check_folder_kind(out_dir, "compare")
    # and again once the folder is this comparison's alone
    with output_folder(
        out_dir, "compare", check=lambda folder: check_folder_kind(folder, "compare")
    ):
        runs = run_pairs(request, progress, videos, reruns)
        observed = {entry.name: entry.record() for entry in request.observers}
        analysis = analyse_pairs(
            task, runs.pairs, pair_folders(runs.pairs), seeds, runs.records, observed
        )
        across = across_seed_groups(analysis.pairs, request.seed_groups, next(iter(metrics)))
        if not analysis.starts_match:
            warnings.warn(
                "observer-gym compare: the pairs' episodes do not all start from the same state "
                "for the same seed; the paired differences are not paired",
                stacklevel=2,
            )

        env_config = dict(runs.records[0]["env_config"])
        env_config.pop("obs_mode", None)  # each pair's is its observer's (pairs[].obs_mode)
        ray = ("ray",) if request.backend == "ray" else ()
        versions = (*VERSIONED_PACKAGES, "scipy", *ray)
        results = {
            "config": {
                "env_id": request.env_id,
                "observers": request.observer_names,
                "controllers": request.controller_names,
                "seed_groups": request.seed_groups,
                "seeds": seeds,
                "episodes": len(seeds),
                "steps": request.steps,
                "env_kwargs": request.env_kwargs,
                # only when an agent has some: other folders keep their bytes
                **(
                    {"agent_env_options": request.agent_env_options}
                    if request.agent_env_options
                    else {}
                ),
                **(
                    {"observer_env_options": request.observer_env_options}
                    if request.observer_env_options
                    else {}
                ),
                # an agent with its own camera: the scale of its pixel-valued options
                **(
                    {"agent_camera_scale": scales}
                    if (scales := request.agent_camera_scales())
                    else {}
                ),
                "env_config": env_config,
                "workers": request.workers,
                "backend": request.backend,
                "address": request.address,
                "confidence": CONFIDENCE,
                "primary_metric": next(iter(metrics)),
                "metrics": {
                    key: dict(
                        zip(("label", "unit", "scale", "digits", "better"), spec, strict=True)
                    )
                    for key, spec in metrics.items()
                },
                # only for a task with counted columns: other folders keep their bytes
                **(
                    {
                        "counts": {
                            key: {"label": label, "values": list(values)}
                            for key, (label, values) in counted.items()
                        }
                    }
                    if (counted := compare_counts(task))
                    else {}
                ),
                **task.CONFIG,
                "command": command_line(
                    request.env_id,
                    request.observer_names,
                    request.named_controllers,
                    seeds,
                    request.steps,
                    request.workers,
                    request.backend,
                    request.address,
                    request.env_kwargs,
                    request.observer_options,
                    request.controller_options,
                ),
                "observer_options": request.observer_options,
                "controller_options": request.controller_options,
                "out_dir": str(out_dir),
                "cli_args": cli_args,
            },
            "versions": package_versions(versions),
            "wall_time_s": runs.wall_time_s,
            "starts_match": analysis.starts_match,
            "pairs": analysis.pairs,
            "across_seeds": across,
        }
        return write_comparison(out_dir, task, results, runs.by_pair(len(seeds)))
