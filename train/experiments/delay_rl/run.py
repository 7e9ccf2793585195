"""Running a random-delay study into its folder, resumably.

The folder of one system's study::

    study.json                      the plan (StudyPlan.as_dict)
    delivery.json                   each level's frames: out-of-order fraction, ages
    train/<level>/<input>/          one multi-seed training run (train --seeds' layout)
    eval/<level>/<input>/at_<L>.json   its agents evaluated at level L, per seed
    reference/<input>/at_<L>.json   the classical controller on that input's belief at L
    table.json, table.md, curves_<level>.png   derived from the records above

Every step writes its record once, whole (staged and renamed), and is skipped when its
record is there, so running the same command again continues a study where it stopped:
trainings resume from their last checkpoint (:func:`~observer_gym.train.rl.seeds.
train_runs`), evaluations not yet recorded run again from their start. A command that
names more inputs than the folder's study (the same levels, seeds and budget) adds them:
``study.json`` records the larger plan and only the added inputs train and evaluate.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from observer_gym.envs import system_for_id
from observer_gym.envs.json_file import read_json
from observer_gym.train.core.observer_env import resolve_observer
from observer_gym.train.core.tasks import task_of
from observer_gym.train.experiments.delay_rl.delivery import measure_delivery
from observer_gym.train.experiments.delay_rl.layout import (
    DELIVERY_FILE,
    PLAN_FILE,
    TIMING_FILE,
    cell_dir,
    eval_path,
    reference_path,
)
from observer_gym.train.experiments.delay_rl.plan import (
    LEVELS,
    REFERENCE_CONTROLLERS,
    StudyPlan,
)
from observer_gym.train.experiments.delay_rl.table import StudyTable, derive_table, write_table
from observer_gym.train.experiments.episode import EpisodeSpec, run_episodes
from observer_gym.train.experiments.request import resolve_controller
from observer_gym.train.reports.folder_lock import LOCK_FILE, folder_lock
from observer_gym.train.reports.outputs import package_versions, write_json_atomic
from observer_gym.train.reports.ray_tasks import local_cpus
from observer_gym.train.rl.run_dir import SEEDS_FILE, read_config, read_state, seed_run_dirs
from observer_gym.train.rl.seeds import prepare_seeds, seed_dir, seeds_configs, train_runs

DELIVERY_FRAMES = 3000  # frames counted per level (an out-of-order fraction to ~1 %)
COMMAND = "study delay-rl"


@dataclasses.dataclass(frozen=True)
class StudyResult:
    """What :func:`run_study` did and the table it derived."""

    out_dir: Path
    plan: StudyPlan
    table: StudyTable
    wall_time_s: float
    trained_runs: int  # seed runs trained (on) in this call
    evaluations: int  # evaluation records written in this call


def run_study(
    plan: StudyPlan,
    out_dir: str | Path,
    workers: int | None = None,
    backend: str = "local",
    address: str | None = None,
    progress: bool = True,
    lines: Callable[[str], None] | None = None,
    cli_args: Mapping[str, Any] | None = None,
) -> StudyResult:
    """Run (or continue) the study ``plan`` in ``out_dir`` (module docstring).

    Args:
        plan: what to train and evaluate; a folder that holds a study must hold this plan.
        out_dir: the study's folder.
        workers, backend, address: where the seeds train and the episodes run (as
            ``train --seeds``: local processes, default one per CPU, or Ray tasks).
        progress: progress bars; ``lines``: called with one line per finished part.
        cli_args: the command line, recorded in each run's config.json.

    Raises:
        ValueError: ``out_dir`` holds another study, or something else.
        FolderBusyError: another command holds ``out_dir``.
        RuntimeError: a seed's training failed (the others trained on first).
    """
    out_dir = Path(out_dir)
    say = lines or (lambda line: None)
    tic_s = time.perf_counter()
    check_study_folder(out_dir, plan)
    out_dir.mkdir(parents=True, exist_ok=True)
    with folder_lock(out_dir, COMMAND):
        if not (out_dir / PLAN_FILE).exists():
            write_json_atomic(
                out_dir / PLAN_FILE, {**plan.as_dict(), "versions": package_versions()}
            )
        else:
            _add_inputs(out_dir, plan, say)
        if not (out_dir / DELIVERY_FILE).exists():
            write_json_atomic(out_dir / DELIVERY_FILE, _delivery(plan))
            say("measured how each level's frames arrive")
        trained = _train(plan, out_dir, workers, backend, address, progress, cli_args, say)
        episode_workers = 1 if backend == "ray" else (workers or local_cpus())
        evaluations = _evaluate(plan, out_dir, episode_workers, progress, say)
        evaluations += _references(plan, out_dir, episode_workers, progress, say)
        _log_time(out_dir, time.perf_counter() - tic_s, trained, evaluations)
        table = derive_table(out_dir)
        write_table(out_dir, table)
    return StudyResult(out_dir, plan, table, time.perf_counter() - tic_s, trained, evaluations)


def _add_inputs(out_dir: Path, plan: StudyPlan, say: Callable[[str], None]) -> None:
    """Record ``plan`` in the folder if it adds inputs to the study held there (its
    records stay; only the added inputs train and evaluate), keeping the versions the
    study began with and listing each addition with the versions that made it."""
    data = read_json(out_dir / PLAN_FILE)
    held = StudyPlan.from_dict(data)
    if held == plan:
        return
    check_study_folder(out_dir, plan)  # the folder may have changed since the first check
    added = [name for name in plan.inputs if name not in held.inputs]
    additions = [*data.get("inputs_added", []), {"inputs": added, "versions": package_versions()}]
    write_json_atomic(
        out_dir / PLAN_FILE,
        {**plan.as_dict(), "versions": data.get("versions"), "inputs_added": additions},
    )
    say(f"added input(s) {', '.join(added)} to the study")


def _log_time(out_dir: Path, wall_time_s: float, trained: int, evaluations: int) -> None:
    """Append this invocation's wall time to the folder's timing record (only an
    invocation that reached the end: an interrupted one's work is counted by the next)."""
    path = out_dir / TIMING_FILE
    timing = read_json(path) if path.exists() else {"invocations": []}
    timing["invocations"].append(
        {
            "wall_time_s": wall_time_s,
            "seed_runs_trained": trained,
            "evaluations": evaluations,
            "cpus": local_cpus(),
        }
    )
    write_json_atomic(path, timing)


def check_study_folder(out_dir: Path, plan: StudyPlan) -> None:
    """ValueError if ``out_dir`` holds something but this plan's study or a study this
    plan extends with more inputs (:meth:`StudyPlan.extends`)."""
    recorded = out_dir / PLAN_FILE
    if recorded.exists():
        held = StudyPlan.from_dict(read_json(recorded))
        if held != plan and not plan.extends(held):
            raise ValueError(
                f"{out_dir} holds another study ({held.env_id}, levels {','.join(held.levels)}, "
                f"inputs {','.join(held.inputs)}, seeds {len(held.seeds)}, {held.timesteps} "
                "steps); continue it with the same options (more inputs may be added) or "
                "choose a new folder"
            )
    elif out_dir.exists() and any(p.name != LOCK_FILE for p in out_dir.iterdir()):
        raise ValueError(f"{out_dir} is not empty and holds no study; choose a new folder")


def _delivery(plan: StudyPlan) -> dict[str, Any]:
    return {
        level.name: {
            **level._asdict(),
            **measure_delivery(
                plan.env_id, level.env_kwargs(), DELIVERY_FRAMES, plan.eval_seed
            )._asdict(),
        }
        for level in plan.level_records.values()
    }


def _train(
    plan: StudyPlan,
    out_dir: Path,
    workers: int | None,
    backend: str,
    address: str | None,
    progress: bool,
    cli_args: Mapping[str, Any] | None,
    say: Callable[[str], None],
) -> int:
    """Set out every training cell not yet set out, train every unfinished seed, and
    aggregate each cell; returns how many seed runs trained."""
    from observer_gym.train.rl.seeds import aggregate_seeds

    inputs = plan.input_records
    for level, name in plan.train_cells():
        folder = cell_dir(out_dir, level, name)
        if (folder / SEEDS_FILE).exists():
            continue
        agent_input = inputs[name]
        record, configs = seeds_configs(
            plan.env_id,
            plan.algo,
            agent_input.obs,
            folder,
            plan.seeds,
            cli_args,
            timesteps=plan.timesteps,
            observer=agent_input.observer,
            hyperparams={**agent_input.hyperparams, **plan.curve_hyperparams},
            env_kwargs=LEVELS[level].env_kwargs(),
            # each seed's envs in its own process: the seeds are what runs in parallel
            vec_env="dummy",
        )
        prepare_seeds(folder, record, configs)
    todo = [
        path
        for level, name in plan.train_cells()
        for path in seed_run_dirs(cell_dir(out_dir, level, name)).values()
        if (read_state(path) or {}).get("status") != "finished"
    ]
    if todo:
        say(f"training {len(todo)} seed runs")
        errors = train_runs(todo, workers, backend, address, progress)
        if errors:
            details = "; ".join(
                f"{path}: {error.strip().splitlines()[-1]}" for path, error in errors.items()
            )
            raise RuntimeError(f"training failed for {len(errors)} run(s): {details}")
        unfinished = [p for p in todo if (read_state(p) or {}).get("status") != "finished"]
        if unfinished:  # stopped by a signal: every run keeps its last checkpoint
            raise KeyboardInterrupt
    for level, name in plan.train_cells():
        folder = cell_dir(out_dir, level, name)
        if not (folder / "aggregate.json").exists():
            aggregate_seeds(folder)
    return len(todo)


def _evaluate(
    plan: StudyPlan, out_dir: Path, workers: int, progress: bool, say: Callable[[str], None]
) -> int:
    """Evaluate every seed's agent of every evaluation cell not yet recorded."""
    system = system_for_id(plan.env_id)  # resolved once; each agent and observer per seed
    written = 0
    for trained_at, name, at in plan.eval_cells():
        path = eval_path(out_dir, trained_at, name, at)
        if path.exists():
            continue
        folder = cell_dir(out_dir, trained_at, name)
        specs, owners = [], []
        for seed in plan.seeds:
            run_dir = seed_dir(folder, seed)
            config = read_config(run_dir)
            env_kwargs = {**config["env_kwargs"], **LEVELS[at].env_kwargs()}
            observer = resolve_observer(system, config["observer"])
            agent = resolve_controller(system, f"{plan.algo}:{run_dir}")
            for episode in range(plan.eval_episodes):
                specs.append(
                    EpisodeSpec.of_entries(
                        system, observer, agent, plan.eval_seed + episode, env_kwargs=env_kwargs
                    )
                )
                owners.append(seed)
        records = run_episodes(specs, workers, progress, desc=f"eval {name} at {at}")
        per_seed = _scores(plan, owners, records)
        path.parent.mkdir(parents=True, exist_ok=True)
        write_json_atomic(
            path,
            {"trained_at": trained_at, "input": name, "at": at, "per_seed": per_seed},
        )
        written += 1
        say(f"evaluated {name} trained at {trained_at} at {at}")
    return written


def _references(
    plan: StudyPlan, out_dir: Path, workers: int, progress: bool, say: Callable[[str], None]
) -> int:
    """The classical controller on each input's belief at each level, not yet recorded."""
    system = system_for_id(plan.env_id)
    controller = REFERENCE_CONTROLLERS[system.name]
    design = resolve_controller(system, controller)
    yaml_kwargs = _yaml_env_kwargs(plan)
    written = 0
    for name, agent_input in plan.input_records.items():
        if agent_input.reference_observer is None:
            continue
        for at in plan.levels:
            path = reference_path(out_dir, name, at)
            if path.exists():
                continue
            env_kwargs = {**yaml_kwargs, **LEVELS[at].env_kwargs()}
            observer = resolve_observer(system, agent_input.reference_observer)
            specs = [
                EpisodeSpec.of_entries(
                    system, observer, design, plan.eval_seed + episode, env_kwargs=env_kwargs
                )
                for episode in range(plan.eval_episodes)
            ]
            records = run_episodes(specs, workers, progress, desc=f"{controller} on {name}")
            scores = _scores(plan, [0] * len(records), records)["0"]
            path.parent.mkdir(parents=True, exist_ok=True)
            write_json_atomic(
                path,
                {
                    "input": name,
                    "at": at,
                    "controller": controller,
                    "observer": agent_input.reference_observer,
                    **scores,
                },
            )
            written += 1
            say(f"reference {controller} on {name} at {at}")
    return written


def _yaml_env_kwargs(plan: StudyPlan) -> dict[str, Any]:
    """The env options of the system's tuned recipe (e.g. BallCatcher's reward shaping),
    which the agents train with and the reference lines run with."""
    from observer_gym.train.rl.hyperparams import resolve_hyperparams

    return dict(resolve_hyperparams(plan.env_id, plan.algo, "state")["env_kwargs"])


def _scores(
    plan: StudyPlan, owners: list[int], records: list[dict[str, Any]]
) -> dict[str, dict[str, Any]]:
    """Per seed: the mean of the task's primary metric and of the return over its
    episodes, and each episode's values."""
    task = task_of(system_for_id(plan.env_id))
    metric = next(iter(task.COMPARE_METRICS))
    by_seed: dict[str, dict[str, Any]] = {}
    for seed, record in zip(owners, records, strict=True):
        metrics = task.episode_metrics(record)
        entry = by_seed.setdefault(str(seed), {"metric": [], "return": []})
        entry["metric"].append(float(metrics[metric]))
        entry["return"].append(float(metrics["return"]))
    return {
        seed: {
            "metric_mean": float(np.mean(entry["metric"])),
            "return_mean": float(np.mean(entry["return"])),
            "metric": entry["metric"],
            "return": entry["return"],
        }
        for seed, entry in by_seed.items()
    }
