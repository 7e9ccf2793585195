"""``observer-gym train --seeds``: one agent per seed, trained in parallel, and their
aggregate.

A multi-seed run's folder ``OUT`` holds ``seeds.json`` (what is trained: the seeds and
the options, :class:`SeedsConfig`) and one ordinary run folder per seed,
``OUT/seed_<s>/`` (:mod:`observer_gym.train.rl.training`), so everything that reads a run
reads each seed's. When every seed has finished, :func:`aggregate_seeds` reads each seed's
config and :func:`observer_gym.train.reports.aggregate.aggregate_runs` writes
``learning_curves.png``, ``aggregate.json`` and ``aggregate.md`` into ``OUT``.

Every seed's config.json is written before any training starts; then the seeds train in
``workers`` spawned processes (``backend="local"``) or as Ray tasks (``"ray"``), each
calling :func:`~observer_gym.train.rl.training.continue_run` on its folder. A seed's result
depends only on its config (SB3 seeded with the seed, ``torch_threads`` PyTorch threads,
its own env seeds), so the weights equal a single-seed ``train`` run's with that seed,
whatever runs beside it.

Interruptions: each worker runs in its own process group, so Ctrl-C (SIGINT) or SIGTERM
reaches only this process, which passes a SIGTERM to every worker, starts no more seeds
and waits: each worker ends its run as a single run does (``state.json`` "interrupted",
its last checkpoint kept). :func:`resume_seeds` then trains every unfinished seed on, from
its checkpoint, or from its start if it saved none.
"""

from __future__ import annotations

import dataclasses
import multiprocessing
import os
import signal
import time
import traceback
import warnings
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from multiprocessing.connection import Connection, wait
from pathlib import Path
from typing import Any

from tqdm import tqdm

from observer_gym.envs.json_file import read_json
from observer_gym.train.core.checks import check_backend, check_seeds
from observer_gym.train.reports.aggregate import (
    CURVE_REPS,
    FINAL_REPS,
    Aggregate,
    aggregate_runs,
    statistics_text,
)
from observer_gym.train.reports.folder_lock import check_not_busy, folder_lock
from observer_gym.train.reports.outputs import (
    OutputFolderWarning,
    output_folder,
    package_versions,
    to_jsonable,
    write_json_atomic,
)
from observer_gym.train.reports.parent_watch import end_with_parent
from observer_gym.train.reports.ray_tasks import local_cpus, run_tasks_ray
from observer_gym.train.rl.checks import check_seeds_folder
from observer_gym.train.rl.run_dir import (
    SEED_PREFIX,
    SEEDS_FILE,
    check_new_seeds_folder,
    latest_checkpoint,
    read_config,
    read_state,
    seed_run_dirs,
)
from observer_gym.train.rl.training import continue_run, run_config, write_run_config

POLL_S = 1.0  # how often the progress bar reads the seeds' checkpoints


@dataclasses.dataclass(frozen=True)
class SeedsConfig:
    """``seeds.json``: what a multi-seed run trains (each seed's full settings are in its
    own config.json)."""

    env_id: str
    algo: str
    obs: str
    observer: str
    seeds: tuple[int, ...]
    target_timesteps: int
    cli_args: Mapping[str, Any] | None = None

    def as_dict(self) -> dict[str, Any]:
        return to_jsonable(
            {**dataclasses.asdict(self), "versions": package_versions(("observer-gym",))}
        )

    @classmethod
    def read(cls, out_dir: str | Path) -> SeedsConfig:
        """The ``seeds.json`` of ``out_dir``; ValueError if it has none."""
        path = Path(out_dir) / SEEDS_FILE
        if not path.is_file():
            raise ValueError(
                f"{out_dir} is not a multi-seed training run (no {SEEDS_FILE}); make one with "
                "'observer-gym train --seeds'"
            )
        data = read_json(path)  # JSONFileError (a ValueError) naming it
        if not isinstance(data, dict):
            raise ValueError(f"{path} is not a multi-seed run's record (a JSON object)")
        fields = {f.name for f in dataclasses.fields(cls)}
        # the file's JSON values, of the types the fields say (as_dict wrote them)
        values: dict[str, Any] = {k: v for k, v in data.items() if k in fields}
        if "seeds" in values:
            values["seeds"] = tuple(values["seeds"])
        return cls(**values)


@dataclasses.dataclass(frozen=True)
class SeedRun:
    """How one seed's run ended."""

    seed: int
    run_dir: Path
    status: str  # finished, interrupted, failed (or, not started, its state.json's status)
    timesteps: int | None
    train_steps_per_s: float | None
    error: str | None = None  # a failed run's traceback


@dataclasses.dataclass(frozen=True)
class SeedsResult:
    """What :func:`train_seeds` and :func:`resume_seeds` did."""

    out_dir: Path
    runs: tuple[SeedRun, ...]  # every seed of the folder, as it stands now
    wall_time_s: float
    steps_trained: int  # env steps all seeds trained in this call
    aggregate: Aggregate | None  # written when every seed has finished

    @property
    def status(self) -> str:
        """finished (every seed) or interrupted."""
        return "finished" if all(run.status == "finished" for run in self.runs) else "interrupted"

    @property
    def env_steps_per_s(self) -> float:
        """Env steps all seeds trained in this call per second of wall time."""
        return self.steps_trained / max(self.wall_time_s, 1e-9)


def seed_dir(out_dir: str | Path, seed: int) -> Path:
    """The run folder of ``seed`` in the multi-seed folder ``out_dir``."""
    return Path(out_dir) / f"{SEED_PREFIX}{seed}"


def train_seeds(
    env_id: str,
    algo: str,
    obs: str,
    out_dir: str | Path,
    seeds: Sequence[int],
    workers: int | None = None,
    backend: str = "local",
    address: str | None = None,
    progress: bool = True,
    cli_args: Mapping[str, Any] | None = None,
    reps: int | None = None,
    **options: Any,
) -> SeedsResult:
    """Train one agent per seed of ``seeds`` into ``out_dir/seed_<s>/`` and aggregate them.

    Args:
        env_id, algo, obs: as :func:`~observer_gym.train.rl.training.train_agent`.
        out_dir: the multi-seed folder; it must hold no run yet.
        seeds: distinct seeds >= 0; each seed's run is what ``train_agent(..., seed=s)``
            would train.
        workers: processes for the local backend (default: one per seed, at most the CPUs
            this process may use); each seed also runs its own ``n_envs`` envs.
        backend: "local" (spawned processes) or "ray" (one Ray task per seed).
        address: the Ray cluster (backend "ray"; None: a local Ray instance). Every node
            must see ``out_dir`` at the same path (a shared file system).
        progress: show a progress bar over the seeds' env steps (their checkpoints').
        cli_args: the command line, recorded in seeds.json and each config.json.
        reps: bootstrap replications of the final scores' interval (None:
            :data:`~observer_gym.train.reports.aggregate.FINAL_REPS`).
        options: the other keywords of ``train_agent`` (timesteps, estimate_from,
            observer, n_envs, vec_env, hyperparams, env_kwargs, tensorboard).

    Holds ``out_dir``'s lock (:mod:`observer_gym.train.reports.folder_lock`) from before
    it writes seeds.json until the aggregate is written; each seed's training holds its
    own folder's.

    Raises:
        ValueError: a bad argument or hyperparameter, or a run already in ``out_dir``
            (also one written there by another command since the first check), before
            anything is written.
        FolderBusyError: another command holds ``out_dir``; nothing was written.
        RuntimeError: a seed's training raised (the others run to their end first).
    """
    check_backend(backend, workers, address)
    out_dir = Path(out_dir)
    record, configs = seeds_configs(env_id, algo, obs, out_dir, seeds, cli_args, **options)
    # the folder is this run's alone from before seeds.json is written until the aggregate
    # is; whether it holds a run is checked again under the lock
    with output_folder(out_dir, "train", marker=False, check=check_new_seeds_folder):
        _write_seeds(out_dir, record, configs)
        return _train(out_dir, record.seeds, None, workers, backend, address, progress, reps)


def seeds_configs(
    env_id: str,
    algo: str,
    obs: str,
    out_dir: str | Path,
    seeds: Sequence[int],
    cli_args: Mapping[str, Any] | None = None,
    **options: Any,
) -> tuple[SeedsConfig, dict[int, dict[str, Any]]]:
    """The ``seeds.json`` and each seed's ``config.json`` of a new multi-seed run in
    ``out_dir`` (the arguments of :func:`train_seeds`), checked; nothing is written.

    Raises:
        ValueError: a bad argument or hyperparameter, or a run already in ``out_dir``.
    """
    seeds = check_seeds(seeds)
    out_dir = Path(out_dir)
    check_seeds_folder(out_dir)
    configs = {
        seed: run_config(
            env_id, algo, obs, seed_dir(out_dir, seed), seed=seed, cli_args=cli_args, **options
        )
        for seed in seeds
    }
    first = configs[seeds[0]]
    record = SeedsConfig(
        env_id=first["env_id"],
        algo=algo,
        obs=obs,
        observer=first["observer"],
        seeds=seeds,
        target_timesteps=int(first["hyperparams"]["n_timesteps"]),
        cli_args=cli_args,
    )
    return record, configs


def prepare_seeds(
    out_dir: str | Path, record: SeedsConfig, configs: Mapping[int, Mapping[str, Any]]
) -> None:
    """Write the multi-seed run :func:`seeds_configs` made into the new folder ``out_dir``
    (seeds.json and every seed's config.json) without training it: a study sets out every
    run before it trains any, and :func:`train_runs` trains them.

    Raises:
        ValueError: a run already in ``out_dir``.
        FolderBusyError: another command holds ``out_dir``; nothing was written.
    """
    out_dir = Path(out_dir)
    with output_folder(out_dir, "train", marker=False, check=check_new_seeds_folder):
        _write_seeds(out_dir, record, configs)


def _write_seeds(
    out_dir: Path, record: SeedsConfig, configs: Mapping[int, Mapping[str, Any]]
) -> None:
    write_json_atomic(out_dir / SEEDS_FILE, record.as_dict())
    for seed, config in configs.items():
        write_run_config(seed_dir(out_dir, seed), config)


def train_runs(
    run_dirs: Sequence[str | Path],
    workers: int | None = None,
    backend: str = "local",
    address: str | None = None,
    progress: bool = True,
) -> dict[Path, str]:
    """Train every run folder of ``run_dirs`` on to its configured timesteps
    (:func:`~observer_gym.train.rl.training.continue_run`: from its latest checkpoint, from
    its start if it saved none; a finished one is left as it is), in ``workers`` spawned
    processes or as Ray tasks, as :func:`train_seeds` trains its seeds; the folders may
    belong to different multi-seed runs. Returns the traceback of each run that raised,
    by its resolved folder. Signals stop it as they stop :func:`train_seeds`."""
    check_backend(backend, workers, address)
    paths = [Path(path).resolve() for path in run_dirs]
    if not paths:
        return {}
    if backend == "ray":
        return _train_ray(paths, None, address, progress)
    count = workers if workers is not None else min(len(paths), local_cpus())
    return _train_local(paths, None, count, progress)


def resume_seeds(
    out_dir: str | Path,
    timesteps: int | None = None,
    workers: int | None = None,
    backend: str = "local",
    address: str | None = None,
    progress: bool = True,
    reps: int | None = None,
) -> SeedsResult:
    """Train every unfinished seed of the multi-seed run in ``out_dir`` on (from its
    latest checkpoint, or from its start if it saved none), up to its configured
    timesteps or the new total ``timesteps`` (which also extends finished seeds), then
    aggregate. A seed found killed is reported with an
    :class:`~observer_gym.train.reports.outputs.OutputFolderWarning`.

    Holds ``out_dir``'s lock (:mod:`observer_gym.train.reports.folder_lock`) while it
    checks, trains and aggregates; each seed's training holds its own folder's.

    Raises:
        ValueError: no multi-seed run there, a seed still running, or a bad argument.
        FolderBusyError: another command holds ``out_dir`` or a seed's folder.
    """
    check_backend(backend, workers, address)
    if timesteps is not None and (int(timesteps) != timesteps or timesteps < 1):
        raise ValueError(f"timesteps must be an integer >= 1, got {timesteps!r}")
    out_dir = Path(out_dir)
    SeedsConfig.read(out_dir)  # no multi-seed run there: said before the lock
    with folder_lock(out_dir, "train --resume"):
        return _resume(out_dir, timesteps, workers, backend, address, progress, reps)


def _resume(
    out_dir: Path,
    timesteps: int | None,
    workers: int | None,
    backend: str,
    address: str | None,
    progress: bool,
    reps: int | None,
) -> SeedsResult:
    """:func:`resume_seeds`'s work, under the folder's lock."""
    record = SeedsConfig.read(out_dir)
    todo = []
    for seed in record.seeds:
        run_dir = seed_dir(out_dir, seed)
        check_not_busy(run_dir)  # a seed training there now: FolderBusyError
        read_config(run_dir)
        state = read_state(run_dir)
        status = None if state is None else state["status"]
        if state is not None and status == "running":
            raise ValueError(
                f"seed {seed} of {out_dir} is still running (pid "
                f"{(state.get('writer') or {}).get('pid', '?')}); stop it before resuming"
            )
        if status == "killed":
            warnings.warn(
                f"seed {seed}'s run in {run_dir} was killed; resuming it",
                OutputFolderWarning,
                stacklevel=2,
            )
        if status != "finished" or timesteps is not None:
            todo.append(seed)
    return _train(out_dir, tuple(todo), timesteps, workers, backend, address, progress, reps)


def _train(
    out_dir: Path,
    seeds: tuple[int, ...],
    timesteps: int | None,
    workers: int | None,
    backend: str,
    address: str | None,
    progress: bool,
    reps: int | None,
) -> SeedsResult:
    """Train ``seeds``'s runs on (:func:`continue_run`), then report every seed of the
    folder and aggregate them if all have finished."""
    run_dirs = [seed_dir(out_dir, seed).resolve() for seed in seeds]
    before = {path: _start_steps(path) for path in run_dirs}
    tic_s = time.perf_counter()
    if not run_dirs:
        errors: dict[Path, str] = {}
    elif backend == "ray":
        errors = _train_ray(run_dirs, timesteps, address, progress)
    else:
        count = workers if workers is not None else min(len(run_dirs), local_cpus())
        errors = _train_local(run_dirs, timesteps, count, progress)
    wall_time_s = time.perf_counter() - tic_s
    runs = []
    for seed, path in seed_run_dirs(out_dir).items():
        state = read_state(path) or {}
        error = errors.get(path.resolve())
        runs.append(
            SeedRun(
                seed=seed,
                run_dir=path,
                status="failed" if error else state.get("status", "not started"),
                timesteps=state.get("timesteps"),
                train_steps_per_s=state.get("train_steps_per_s"),
                error=error,
            )
        )
    steps = sum(max(_timesteps(p) - before[p], 0) for p in run_dirs)
    failed = [(run.seed, run.error) for run in runs if run.error]
    if failed:
        details = "; ".join(
            f"seed {seed}: {error.strip().splitlines()[-1]}" for seed, error in failed
        )
        raise RuntimeError(f"training failed for {len(failed)} seed(s) of {out_dir}: {details}")
    aggregate = None
    if runs and all(run.status == "finished" for run in runs):
        kwargs = {} if reps is None else {"reps": reps}
        aggregate = aggregate_seeds(out_dir, **kwargs)
    return SeedsResult(out_dir, tuple(runs), wall_time_s, steps, aggregate)


def aggregate_seeds(
    out_dir: str | Path, reps: int = FINAL_REPS, curve_reps: int = CURVE_REPS
) -> Aggregate:
    """Aggregate the ``seed_<s>/`` runs of the multi-seed folder ``out_dir``
    (:func:`~observer_gym.train.reports.aggregate.aggregate_runs`, with each run's config
    read here; ``reps`` and ``curve_reps`` its bootstrap replications).

    Raises:
        ValueError: as ``aggregate_runs`` (no seed runs, runs that differ, a run not
            evaluated yet) or a seed's ``config.json`` that cannot be read.
    """
    runs = seed_run_dirs(out_dir)
    configs = {seed: read_config(path) for seed, path in runs.items()}
    return aggregate_runs(out_dir, runs, configs, reps, curve_reps)


def _timesteps(run_dir: Path) -> int:
    """A run's env steps by its state.json (0 without one)."""
    return int((read_state(run_dir) or {}).get("timesteps") or 0)


def _start_steps(run_dir: Path) -> int:
    """Where training a run on starts: its latest checkpoint's env steps, else 0."""
    checkpoint = latest_checkpoint(run_dir / "checkpoints")
    return 0 if checkpoint is None else int(checkpoint["timesteps"])


# --- the local backend: one spawned process per running seed ------------------------------------
def _worker(run_dir: str, timesteps: int | None, connection: Connection) -> None:
    """A worker process: its own process group (a terminal's Ctrl-C reaches only the
    parent, which passes a SIGTERM on) and a SIGTERM of its own when the parent ends
    (:func:`~observer_gym.train.reports.parent_watch.end_with_parent`: a killed command
    leaves no seed training), then :func:`continue_run`; sends ``None`` or the traceback
    of what it raised."""
    os.setpgrp()
    end_with_parent()
    try:
        continue_run(run_dir, timesteps)
    except BaseException as exc:  # reported by the parent, with the seed
        connection.send("".join(traceback.format_exception(exc)))
    else:
        connection.send(None)
    finally:
        connection.close()


@contextmanager
def _signals_recorded(received: list[int]) -> Iterator[None]:
    """SIGINT and SIGTERM append their number to ``received`` instead of stopping this
    process (outside the main thread: signals are left alone)."""

    def handler(signum: int, frame: Any) -> None:
        received.append(signum)

    try:
        previous = {s: signal.signal(s, handler) for s in (signal.SIGINT, signal.SIGTERM)}
    except ValueError:  # not the main thread
        yield
        return
    try:
        yield
    finally:
        for signum, old in previous.items():
            signal.signal(signum, old)


def _train_local(
    run_dirs: Sequence[Path], timesteps: int | None, workers: int, progress: bool
) -> dict[Path, str]:
    """Train ``run_dirs`` in at most ``workers`` spawned processes at a time; returns the
    traceback of each run that raised. A signal (SIGINT, SIGTERM) stops the start of
    further runs and is passed to the running ones as SIGTERM."""
    context = multiprocessing.get_context("spawn")
    waiting = list(run_dirs)
    running: dict[Path, tuple[Any, Connection]] = {}
    errors: dict[Path, str] = {}
    received: list[int] = []
    forwarded = False
    total = sum(_target(path, timesteps) for path in run_dirs)
    with tqdm(total=total, unit="step", desc="train seeds", disable=not progress) as bar:
        with _signals_recorded(received):
            while waiting or running:
                while waiting and len(running) < workers and not received:
                    path = waiting.pop(0)
                    receiver, sender = context.Pipe(duplex=False)
                    process = context.Process(
                        target=_worker, args=(str(path), timesteps, sender), name=path.name
                    )
                    process.start()
                    sender.close()
                    running[path] = (process, receiver)
                if received and not forwarded:
                    waiting.clear()
                    for process, _ in running.values():
                        _terminate(process)
                    forwarded = True
                if not running:
                    break
                sentinels = {process.sentinel: path for path, (process, _) in running.items()}
                for sentinel in wait(list(sentinels), timeout=POLL_S):
                    path = sentinels[sentinel]
                    process, receiver = running.pop(path)
                    message = receiver.recv() if receiver.poll() else None
                    process.join()
                    stopped = forwarded and process.exitcode == -signal.SIGTERM
                    if message is None and process.exitcode not in (0, None) and not stopped:
                        message = f"its process exited with code {process.exitcode}"
                    if message is not None:
                        errors[path] = message
                bar.n = sum(_progress_steps(path) for path in run_dirs)
                bar.refresh()
    return errors


def _terminate(process: Any) -> None:
    try:
        os.kill(process.pid, signal.SIGTERM)
    except ProcessLookupError:
        pass


def _target(run_dir: Path, timesteps: int | None) -> int:
    if timesteps is not None:
        return int(timesteps)
    return int(read_config(run_dir)["hyperparams"]["n_timesteps"])


def _progress_steps(run_dir: Path) -> int:
    """A run's env steps as far as its files tell: the latest checkpoint's, or a
    finished run's count."""
    state = read_state(run_dir) or {}
    if state.get("status") in ("finished", "interrupted"):
        return int(state.get("timesteps", 0))
    checkpoint = latest_checkpoint(run_dir / "checkpoints")
    return 0 if checkpoint is None else int(checkpoint["timesteps"])


# --- the ray backend ---------------------------------------------------------------------------
def _train_ray(
    run_dirs: Sequence[Path], timesteps: int | None, address: str | None, progress: bool
) -> dict[Path, str]:
    """Train ``run_dirs`` as Ray tasks
    (:func:`~observer_gym.train.reports.ray_tasks.run_tasks_ray`); returns the traceback
    of each run that raised."""

    try:
        outcomes = run_tasks_ray(
            _ray_task,
            [(str(path), timesteps) for path in run_dirs],
            address=address,
            progress=progress,
            desc="train seeds",
            unit="seed",
        )
    except KeyboardInterrupt:  # the tasks were cancelled: each run's state.json tells
        return {}
    return {path: error for path, error in zip(run_dirs, outcomes, strict=True) if error}


def _ray_task(run_dir: str, timesteps: int | None) -> str | None:
    """One seed as a Ray task: :func:`continue_run`; None or the traceback it raised."""
    try:
        continue_run(run_dir, timesteps)
    except Exception as exc:
        return "".join(traceback.format_exception(exc))
    return None


# --- what the command prints ----------------------------------------------------------------------
def seeds_text(result: SeedsResult) -> str:
    """What ``observer-gym train --seeds`` prints: each seed's end, the throughput, the
    aggregate (or how to resume) and the output folder."""
    lines = []
    for run in result.runs:
        speed = (
            "" if run.train_steps_per_s is None else f", {run.train_steps_per_s:.0f} env steps/s"
        )
        lines.append(f"seed {run.seed}: {run.status} at {run.timesteps} steps{speed}")
    lines.append(
        f"{result.steps_trained} env steps in {result.wall_time_s:.1f} s wall time "
        f"({result.env_steps_per_s:.0f} env steps/s over all seeds)"
    )
    if result.aggregate is not None:
        lines.append(
            "final evaluation return across seeds: "
            + statistics_text(result.aggregate.final_return, digits=2)
        )
    else:
        lines.append(f"continue with 'observer-gym train --resume {result.out_dir}'")
    lines.append(f"output: {result.out_dir}")
    return "\n".join(
        f"observer-gym train: {line}" if k == 0 else line for k, line in enumerate(lines)
    )
