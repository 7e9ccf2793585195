"""``observer-gym run``: closed-loop episodes of a controller on the oracle state or on an
observer's estimate, with metrics, a summary, plots and ``results.json``.

What is measured and drawn depends on the env: its task module in
:mod:`observer_gym.train.core.tasks` supplies the observers, metrics, summary rows and plots.
The episodes themselves are :mod:`observer_gym.train.experiments.episode`'s.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from observer_gym.envs import system_for_id
from observer_gym.train.core import entries
from observer_gym.train.core.tasks import task_of
from observer_gym.train.experiments.episode import EpisodeSpec, check_entries, run_episodes
from observer_gym.train.experiments.request import Request, check_pair_of, resolve_request
from observer_gym.train.experiments.videos import (
    RerunPlan,
    VideoPlan,
    plan_rerun,
    plan_videos_for,
    with_rerun,
    with_videos,
)
from observer_gym.train.reports.consistency import (
    NEES_COLUMN,
    consistency_text,
    episode_consistency,
    nees_flag,
)
from observer_gym.train.reports.outputs import (
    check_folder_kind,
    format_table,
    json_text,
    output_folder,
    output_set,
    package_versions,
    to_jsonable,
    write_json_atomic,
)


def run_experiment(
    env_id: str,
    observer: str,
    controller: str,
    episodes: int,
    seed: int,
    out_dir: str | Path,
    steps: int | None = None,
    workers: int = 1,
    progress: bool = True,
    env_kwargs: Mapping[str, Any] | None = None,
    reset_options: Mapping[str, Any] | None = None,
    cli_args: Mapping[str, Any] | None = None,
    observer_options: Mapping[str, Any] | None = None,
    controller_options: Mapping[str, Any] | None = None,
    video_dir: str | Path | None = None,
    video_episodes: Sequence[int] | None = None,
    rerun_file: str | Path | None = None,
    rerun_episode: int | None = None,
) -> dict[str, Any]:
    """Run ``episodes`` closed-loop episodes; write results and plots.

    Episode i resets with ``seed + i`` (and ``reset_options``, e.g. a fixed start) and
    runs to the env's end (termination or its time limit) or ``steps`` steps. With
    ``workers`` > 1 the episodes run in that many spawned processes, with results
    identical to ``workers=1``.

    Writes into ``out_dir`` (created and locked, one command at a time; see
    :func:`~observer_gym.train.reports.outputs.output_folder` for what is removed and
    reported there before, and the folder removed again if the run fails before writing
    anything) the task's plots (BallTable: ``path.png``, ``error.png``, ``estimate.png`` for
    the observers) and, last, ``results.json``:
    ``config``, ``seed``, ``versions``, ``episodes`` (per-episode metrics of the task's
    ``episode_metrics``), ``summary``, ``files``; as a set
    (:func:`~observer_gym.train.reports.outputs.output_set`): all of them or, if one fails, none.

    Args:
        env_id: a registered id, with or without ``observer_gym/`` ("BallTable-v0").
        observer: one of the task's ``OBSERVERS`` (BallTable: oracle, kf, kf-latency, ekf,
            raw, oracle-visible, each but oracle also as NAME-measurements, and pixels), or
            an outside observer (:mod:`observer_gym.train.core.entries`).
        controller: one of the env's ``observer_gym.controllers.controllers_for(env_id)``,
            a trained agent ``ALGO:DIR`` (``ppo:runs/ppo-balltable``), a stable-baselines3
            zip ``ALGO:PATH.zip`` or an outside controller.
        episodes: number of episodes (>= 1).
        seed: seed of episode 0.
        out_dir: the output folder.
        steps: cap on each episode's steps (None: the env's time limit).
        workers: processes to run episodes in (>= 1).
        progress: show a tqdm bar over episodes.
        env_kwargs: extra ``gym.make`` options (the observer sets ``obs_mode``).
        reset_options: options for every ``env.reset``.
        cli_args: the command line's arguments, recorded in the config.
        observer_options, controller_options: keyword arguments of the observer's pipeline
            and of the controller's factory (or design), recorded in the config.
        video_dir: write a video of the episodes ``video_episodes`` (indices, default the
            first) into this folder (:mod:`observer_gym.train.experiments.videos`); the
            results are the same with and without.
        rerun_file: write a recording of episode ``rerun_episode`` (an index, default 0)
            into this ``.rrd`` file for the rerun viewer
            (:mod:`observer_gym.train.reports.rerun_recording`); the results are the same
            with and without.

    Returns:
        What ``results.json`` holds (JSON types).

    Raises:
        ValueError: an unknown env, observer or controller, a count < 1 or a negative seed.
    """
    system = system_for_id(env_id)  # resolved once: the request and its episodes carry it
    check_pair_of(system, observer, controller)  # the command's messages first
    for name, value in (("episodes", episodes), ("workers", workers), ("steps", steps)):
        if value is not None and (int(value) != value or value < 1):
            raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
    if int(seed) != seed or seed < 0:
        raise ValueError(f"seed must be an integer >= 0, got {seed!r}")
    env_kwargs = dict(env_kwargs or {})
    if "obs_mode" in env_kwargs:
        raise ValueError("env_kwargs must not set obs_mode: the observer decides it")
    request = resolve_request(
        system, [observer], [controller], range(seed, seed + episodes), workers, "local", None,
        steps, env_kwargs, observer_options, controller_options,
    )  # fmt: skip
    observer_entry, controller_entry = request.observers[0], request.controllers[0]
    videos = plan_videos_for(video_dir, video_episodes, episodes, [observer_entry])
    rerun = plan_rerun(rerun_file, rerun_episode, episodes)
    check_entries(system, observer_entry, controller_entry, env_kwargs, seed)
    out_dir = Path(out_dir)
    check_folder_kind(out_dir, "run")
    # and again once the folder is this run's alone (another command may have written it)
    with output_folder(out_dir, "run", check=lambda folder: check_folder_kind(folder, "run")):
        return _run_into(
            out_dir, request, reset_options, cli_args, progress, videos, rerun,
        )  # fmt: skip


def _run_into(
    out_dir: Path,
    request: Request,
    reset_options: Mapping[str, Any] | None,
    cli_args: Mapping[str, Any] | None,
    progress: bool,
    videos: VideoPlan | None = None,
    rerun: RerunPlan | None = None,
) -> dict[str, Any]:
    """:func:`run_experiment`'s episodes and outputs, its request checked."""
    observer, controller = request.observers[0], request.controllers[0]
    task, env_kwargs, seeds = request.task, request.env_kwargs_for(controller), request.seeds
    specs = [
        EpisodeSpec.of_entries(
            request.system,
            observer,
            controller,
            seed,
            max_steps=request.steps,
            env_kwargs=env_kwargs,
            reset_options=reset_options,
        )
        for seed in seeds
    ]
    specs = with_rerun(with_videos(specs, videos, len(seeds)), rerun)
    tic_s = time.perf_counter()
    records = run_episodes(specs, request.workers, progress)
    wall_time_s = time.perf_counter() - tic_s

    per_episode = [
        {
            "episode": i,
            "seed": spec.seed,
            **task.episode_metrics(record),
            **episode_consistency(record),
        }
        for i, (spec, record) in enumerate(zip(specs, records, strict=True))
    ]
    summary = task.summarize(per_episode)
    consistency = nees_flag(per_episode)._asdict()
    observed = observer.record()

    results = to_jsonable(
        {
            "config": {
                "env_id": request.env_id,
                "env_kwargs": {"obs_mode": observed["obs_mode"], **env_kwargs},
                **{k: v for k, v in observed.items() if k != "obs_mode"},
                "controller_options": controller.options,
                "env_config": records[0]["env_config"],
                "observer": observer.name,
                "controller": controller.name,
                "controller_config": records[0]["controller"],
                "episodes": len(seeds),
                "seed": seeds[0],
                "steps": request.steps,
                "workers": request.workers,
                "reset_options": reset_options,
                **task.CONFIG,
                "out_dir": str(out_dir),
                "cli_args": cli_args,
            },
            "seed": seeds[0],
            "versions": package_versions(),
            "wall_time_s": wall_time_s,
            "episodes": per_episode,
            "summary": summary,
            "consistency": consistency,
        }
    )
    try:
        json_text(results)
    except ValueError as exc:
        raise ValueError(f"results.json cannot be written: {exc}") from None
    with output_set(out_dir) as staging:  # the plots and results.json, all or none
        results["files"] = [*task.plot(records, observer.name, staging), "results.json"]
        write_json_atomic(staging / "results.json", results)
    return results


def results_text(results: Mapping[str, Any], command: str = "run") -> str:
    """What ``observer-gym run`` (and ``evaluate``, ``command="evaluate"``) print of
    :func:`run_experiment`'s results: what ran, the task's summary table and the output
    folder."""
    config = results["config"]
    first, episodes = config["seed"], config["episodes"]
    last = first + episodes - 1
    lines = [
        f"observer-gym {command}: {config['env_id']}, observer {config['observer']}, controller "
        f"{config['controller']}, {episodes} episode(s), seeds {first}..{last}, "
        f"{results['wall_time_s']:.1f} s",
        *entry_lines(config.get("entry"), config["controller_config"].get("entry")),
        summary_table(results["summary"], task_of(system_for_id(config["env_id"])).SUMMARY_ROWS),
    ]
    consistency = results.get("consistency")
    if consistency and consistency.get("nees_ratio") is not None:
        lines.append(f"{NEES_COLUMN}: {consistency_text(consistency)}")
    return "\n".join([*lines, f"output: {config['out_dir']}"])


def entry_lines(observer: Mapping | None, controller: Mapping | None) -> list[str]:
    """The header lines naming an outside observer's and controller's entries."""
    pairs = (("observer", observer), ("controller", controller))
    return [entries.entry_line(kind, entry) for kind, entry in pairs if entry]


def summary_table(
    summary: Mapping[str, Any], rows: Mapping[str, tuple[str, str, float, int]]
) -> str:
    """A Markdown table with one row per entry of ``rows`` (a task's ``SUMMARY_ROWS``:
    key -> label, unit, scale from the stored SI value, digits), in readable units."""
    lines = []
    for key, (label, unit, scale, digits) in rows.items():
        value = summary[key]
        text = "-" if value is None else f"{value * scale:.{digits}f}"
        lines.append([label, text, unit])
    return format_table(["metric", "value", "unit"], lines)
