"""``observer-gym evaluate``: a trained agent's closed-loop episodes, scored exactly as
``observer-gym run`` scores a baseline controller (same metrics, same results.json); for
a multi-seed run (``train --seeds``), every seed's agent on the same episodes and the
primary metric across seeds (:func:`evaluate_seeds`)."""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from observer_gym.envs import system_for_id
from observer_gym.train.core.tasks import task_of
from observer_gym.train.experiments.run import run_experiment
from observer_gym.train.reports.aggregate import METHOD, SeedStatistics, across_seeds
from observer_gym.train.reports.compare_stats import MetricSpec, compare_metrics
from observer_gym.train.reports.outputs import (
    OutputFolderWarning,
    format_table,
    output_folder,
    output_set,
    write_json_atomic,
)
from observer_gym.train.rl.run_dir import (
    SEED_PREFIX,
    is_multi_seed,
    killed_text,
    model_files,
    read_config,
    read_state,
    seed_run_dirs,
)

ACROSS_SEEDS_JSON = "across_seeds.json"
ACROSS_SEEDS_MD = "across_seeds.md"


def evaluate_agent(
    run_dir: str | Path,
    episodes: int,
    out_dir: str | Path,
    seed: int = 0,
    observer: str | None = None,
    steps: int | None = None,
    workers: int = 1,
    progress: bool = True,
    cli_args: Mapping[str, Any] | None = None,
    video_dir: str | Path | None = None,
    video_episodes: Sequence[int] | None = None,
    rerun_file: str | Path | None = None,
    rerun_episode: int | None = None,
) -> dict[str, Any]:
    """Run ``episodes`` episodes (seeds ``seed``, ``seed + 1``, ...) of the agent trained
    in ``run_dir`` on its env with its training env options, reading ``observer``'s output
    (default: the observer it was trained on; an agent trained on the state or an
    estimate also runs on any other observer of the state layout). Writes and returns
    ``run_experiment``'s results; the agent is the final model, or the latest checkpoint
    of a run that has not finished. A run that was killed
    (:func:`~observer_gym.train.rl.run_dir.read_state`) is reported with an
    :class:`~observer_gym.train.reports.outputs.OutputFolderWarning` naming the checkpoint used.
    ``video_dir``, ``video_episodes``: videos of episodes, and ``rerun_file``,
    ``rerun_episode``: a rerun recording of one, as :func:`run_experiment`'s."""
    config = read_config(run_dir)
    _, _, trained_steps = model_files(run_dir)  # a clear error now if there is nothing to load
    state = read_state(run_dir)
    if state is not None and state["status"] == "killed":
        warnings.warn(
            f"{killed_text(run_dir, state)}; evaluating its latest checkpoint "
            f"({trained_steps} steps)",
            OutputFolderWarning,
            stacklevel=2,
        )
    return run_experiment(
        env_id=config["env_id"],
        observer=observer or config["observer"],
        controller=f"{config['algo']}:{run_dir}",
        episodes=episodes,
        seed=seed,
        out_dir=out_dir,
        steps=steps,
        workers=workers,
        progress=progress,
        env_kwargs=config["env_kwargs"],
        cli_args=cli_args,
        video_dir=video_dir,
        video_episodes=video_episodes,
        rerun_file=rerun_file,
        rerun_episode=rerun_episode,
    )


# --- a multi-seed run: every seed's agent on the same episodes ------------------------------------
@dataclasses.dataclass(frozen=True)
class SeedsEvaluation:
    """What :func:`evaluate_seeds` found: each seed's agent's mean of the task's primary
    metric over the same episodes, and those means across seeds."""

    out_dir: Path
    env_id: str
    metric: str  # the task's primary metric (the first of its COMPARE_METRICS)
    spec: MetricSpec  # its label, unit, scale from the stored SI value, digits, better
    per_seed: dict[int, float | None]  # None: no episode of that seed had a value
    statistics: SeedStatistics | None  # None: no seed had a value
    results: dict[int, dict[str, Any]]  # each seed's results.json

    def as_dict(self) -> dict[str, Any]:
        label, unit, scale, digits, better = self.spec
        return {
            "env_id": self.env_id,
            "metric": self.metric,
            "label": label,
            "unit": unit,
            "scale": scale,
            "digits": digits,
            "better": better,
            "per_seed": {str(k): v for k, v in self.per_seed.items()},
            "statistics": None if self.statistics is None else self.statistics.as_dict(),
            "folders": {str(seed): f"{SEED_PREFIX}{seed}" for seed in self.results},
            "episodes": len(next(iter(self.results.values()))["episodes"]),
        }


def metric_mean(task: Any, episodes: Sequence[Mapping[str, Any]], metric: str) -> float | None:
    """The mean of ``metric`` over ``episodes`` (results.json's per-episode metrics, with
    the task's ``compare_extras`` added as compare adds them) where it has a value; a
    flag's mean is its rate. None if no episode has a value."""
    extras = getattr(task, "compare_extras", None)
    values = []
    for episode in episodes:
        value = {**episode, **(extras(episode) if extras else {})}.get(metric)
        if value is not None:
            values.append(float(value))
    return float(np.mean(values)) if values else None


def seeds_statistics(
    per_seed: Mapping[int, float | None], reps: int | None = None
) -> SeedStatistics | None:
    """:func:`~observer_gym.train.reports.aggregate.across_seeds` of the seeds with a value."""
    scores = {seed: value for seed, value in per_seed.items() if value is not None}
    if not scores:
        return None
    return across_seeds(scores) if reps is None else across_seeds(scores, reps)


def evaluate_seeds(
    seeds_dir: str | Path,
    episodes: int,
    out_dir: str | Path,
    seed: int = 0,
    observer: str | None = None,
    steps: int | None = None,
    workers: int = 1,
    progress: bool = True,
    cli_args: Mapping[str, Any] | None = None,
    reps: int | None = None,
    video_dir: str | Path | None = None,
    video_episodes: Sequence[int] | None = None,
) -> SeedsEvaluation:
    """Score the agent of every seed of the multi-seed run in ``seeds_dir`` on the same
    ``episodes`` episodes (seeds ``seed``, ``seed + 1``, ...): :func:`evaluate_agent` of
    each into ``out_dir/seed_<s>/`` (its results.json and plots), then across seeds the
    mean and the IQM with its 95 % interval (rliable's method) of each agent's mean of the task's
    primary metric, written to ``out_dir/across_seeds.json`` and ``across_seeds.md``.
    With ``video_dir``, each seed's videos go to ``video_dir/seed_<s>/``.

    Raises:
        ValueError: no multi-seed run in ``seeds_dir``, or a seed's run that cannot be
            evaluated (as :func:`evaluate_agent`).
    """
    runs = seed_run_dirs(seeds_dir)
    if not is_multi_seed(seeds_dir):
        raise ValueError(f"{seeds_dir} is not a multi-seed training run (no seed_<s>/ runs)")
    configs = {s: read_config(path) for s, path in runs.items()}
    env_ids = {config["env_id"] for config in configs.values()}
    if len(env_ids) > 1:
        raise ValueError(f"the seeds of {seeds_dir} were trained on different envs: {env_ids}")
    for path in runs.values():
        model_files(path)
    env_id = env_ids.pop()
    task = task_of(system_for_id(env_id))
    metric, spec = next(iter(compare_metrics(task).items()))
    out_dir = Path(out_dir)
    with output_folder(out_dir, "evaluate"):
        results = {}
        for s, path in runs.items():
            results[s] = evaluate_agent(
                path,
                episodes,
                out_dir / f"{SEED_PREFIX}{s}",
                seed=seed,
                observer=observer,
                steps=steps,
                workers=workers,
                progress=progress,
                cli_args=cli_args,
                video_dir=None if video_dir is None else Path(video_dir) / f"{SEED_PREFIX}{s}",
                video_episodes=video_episodes,
            )
        per_seed = {s: metric_mean(task, r["episodes"], metric) for s, r in results.items()}
        evaluation = SeedsEvaluation(
            out_dir, env_id, metric, spec, per_seed, seeds_statistics(per_seed, reps), results
        )
        with output_set(out_dir, last=(ACROSS_SEEDS_JSON,)) as staging:  # both or neither
            (staging / ACROSS_SEEDS_MD).write_text(seeds_markdown(evaluation), encoding="utf-8")
            write_json_atomic(staging / ACROSS_SEEDS_JSON, evaluation.as_dict())
    return evaluation


def seeds_table(evaluation: SeedsEvaluation) -> str:
    """A Markdown table: each seed's mean of the primary metric, then the mean and the IQM
    with its interval across seeds, in the metric's unit."""
    label, unit, scale, digits, better = evaluation.spec

    def number(value: float | None) -> str:
        return "n/a" if value is None else f"{value * scale:.{digits}f}"

    rows = [[f"seed {s}", number(v)] for s, v in evaluation.per_seed.items()]
    stats = evaluation.statistics
    if stats is not None:
        rows += [
            ["mean across seeds", number(stats.mean)],
            [
                f"IQM [{stats.confidence * 100:g} % interval]",
                f"{number(stats.iqm)} [{number(stats.iqm_low)}, {number(stats.iqm_high)}]",
            ],
        ]
    header = f"{label} ({unit})" if unit else label
    return format_table(["agent", f"{header} {'↓' if better == 'lower' else '↑'}"], rows)


def seeds_markdown(evaluation: SeedsEvaluation) -> str:
    """``across_seeds.md``: what ran, the table of :func:`seeds_table` and how it was
    computed."""
    first = next(iter(evaluation.results.values()))["config"]
    n = first["episodes"]
    stats = evaluation.statistics
    reps = "" if stats is None else f", {stats.reps} replications"
    return "\n".join(
        [
            f"{evaluation.env_id}, observer {first['observer']}: the agent of each seed on "
            f"the same {n} episode(s), seeds {first['seed']}..{first['seed'] + n - 1}.",
            "",
            seeds_table(evaluation),
            "",
            f"Each seed: its mean over the episodes. Across seeds: {METHOD}{reps}. "
            "Each seed's full results: seed_<s>/results.json.",
            "",
        ]
    )


def seeds_evaluation_text(evaluation: SeedsEvaluation) -> str:
    """What ``observer-gym evaluate`` prints of a multi-seed run."""
    first = next(iter(evaluation.results.values()))["config"]
    wall_time_s = sum(r["wall_time_s"] for r in evaluation.results.values())
    return "\n".join(
        [
            f"observer-gym evaluate: {evaluation.env_id}, observer {first['observer']}, "
            f"{len(evaluation.results)} seed(s) x {first['episodes']} episode(s), "
            f"{wall_time_s:.1f} s",
            seeds_table(evaluation),
            f"output: {evaluation.out_dir}",
        ]
    )
