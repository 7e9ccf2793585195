"""A benchmark run's outputs, derived from its per-episode records and the suite alone:
``episodes.csv``, ``scores.json``, ``table.md`` and ``scores.png`` (written together,
:func:`~observer_gym.train.reports.outputs.output_set`), and ``timing.json``.

:func:`scores_document` is what ``scores.json`` holds, and what ``benchmark --check``
derives again from ``episodes.csv`` to compare: the suite version, the entry, the seeds
of every level, the package versions, per level the headline metric's mean, the
reference values, the normalised score with its 95 % interval, the aggregate (IQM over
levels) with its interval, whether the run is official, and the sha256 of
``episodes.csv``. Wall-clock times go to ``timing.json`` only.
"""

from __future__ import annotations

import hashlib
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from observer_gym.train.experiments.benchmark.records import EPISODES_CSV, EpisodeRecord, csv_text
from observer_gym.train.experiments.benchmark.request import BenchmarkRequest, command_line
from observer_gym.train.experiments.benchmark.score import METHOD, Scores, score_levels
from observer_gym.train.experiments.benchmark.suite import SystemSuite
from observer_gym.train.reports.outputs import (
    VERSIONED_PACKAGES,
    format_table,
    output_set,
    package_versions,
    write_json_atomic,
)

BENCHMARK_JSON = "benchmark.json"
SCORES_JSON = "scores.json"
TABLE_MD = "table.md"
SCORES_PNG = "scores.png"
TIMING_JSON = "timing.json"
# rliable is no longer among them: its statistics are computed here, to the same bits
# (observer_gym.train.reports.bootstrap); folders that recorded its version still check
PACKAGES = (*VERSIONED_PACKAGES, "scipy")


def versions() -> dict[str, str]:
    """The versions of the packages that decide a benchmark's numbers."""
    return package_versions(PACKAGES)


def values_by_level(suite: SystemSuite, records: Sequence[EpisodeRecord]) -> dict[str, list[float]]:
    """Each level's headline values in episode order, the levels in the suite's order."""
    return {
        level.name: [
            r.value for r in sorted(records, key=lambda r: r.episode) if r.level == level.name
        ]
        for level in suite.levels
    }


def scores_document(
    suite: SystemSuite,
    entry: Mapping[str, Any],
    records: Sequence[EpisodeRecord],
    package_versions: Mapping[str, str],
) -> tuple[dict[str, Any], Scores]:
    """What ``scores.json`` holds (JSON types) and the :class:`Scores` it shows.
    ``entry``: ``observer``, ``controller``, ``observer_options``, ``controller_options``,
    ``episodes`` (per level), and ``agent_env_options`` if the controller is an agent
    trained with env options (recorded only when there are some), ``camera_scale`` if
    they change the camera's size (recorded only then: the levels' pixel-valued options
    ran times it, the metric is in the default camera's pixels; camera_scale.py), and
    ``observer_env_options`` if the observer needs env options (recorded only then),
    ``entries`` where an outside observer or controller came from (recorded only for one:
    :func:`~observer_gym.train.experiments.episode.entry_identities`); the
    command is derived from them (:func:`command_line`)."""
    scores = score_levels(values_by_level(suite, records), suite.references, suite.metric.better)
    episodes = entry["episodes"]
    document = {
        "suite": suite.version,
        "env": suite.env_id,
        "observer": entry["observer"],
        "controller": entry["controller"],
        "observer_options": dict(entry["observer_options"]),
        "controller_options": dict(entry["controller_options"]),
        **(
            {"agent_env_options": dict(entry["agent_env_options"])}
            if entry.get("agent_env_options")
            else {}
        ),
        **(
            {"camera_scale": float(entry["camera_scale"])}
            if entry.get("camera_scale", 1.0) != 1.0
            else {}
        ),
        **(
            {"observer_env_options": dict(entry["observer_env_options"])}
            if entry.get("observer_env_options")
            else {}
        ),
        # where an outside observer or controller came from (recorded only for one)
        **({"entries": dict(entry["entries"])} if entry.get("entries") else {}),
        "command": command_line(
            suite,
            entry["observer"],
            entry["controller"],
            episodes,
            entry["observer_options"],
            entry["controller_options"],
        ),
        "official": episodes == suite.episodes,
        "episodes_per_level": episodes,
        "metric": suite.metric._asdict(),
        "levels": [
            {
                "level": level.name,
                "env_options": level.env_options,
                "seeds": level.seeds(episodes),
                "metric_mean": score.metric_mean,
                "oracle": score.oracle_value,
                "floor": score.floor,
                "floor_value": score.floor_value,
                "score": score.score.value,
                "score_low": score.score.low,
                "score_high": score.score.high,
            }
            for level, score in zip(suite.levels, scores.levels, strict=True)
        ],
        "aggregate": {
            "iqm": scores.aggregate.value,
            "low": scores.aggregate.low,
            "high": scores.aggregate.high,
            "method": METHOD,
        },
        "references_command": suite.references_command,
        "packages": dict(package_versions),
        "episodes_csv_sha256": hashlib.sha256(
            csv_text(records, suite.metric.name).encode()
        ).hexdigest(),
    }
    return document, scores


def table_markdown(suite: SystemSuite, document: Mapping[str, Any]) -> str:
    """The run's table: per level the metric's mean, the references and the score with
    its 95 % interval; the aggregate last."""
    from observer_gym.train.core.systems import system_entry

    label, unit, scale, digits, better = system_entry(suite.system).task.COMPARE_METRICS[
        suite.metric.name
    ]
    shown = f"{label} ({unit}, {better} is better)" if unit else f"{label} ({better} is better)"

    def metric(value: float) -> str:
        return f"{value * scale:.{digits}f}"

    rows = [
        [
            row["level"],
            str(len(row["seeds"])),
            metric(row["metric_mean"]),
            metric(row["oracle"]),
            f"{metric(row['floor_value'])} ({row['floor']})",
            f"{row['score']:.3f} [{row['score_low']:.3f}, {row['score_high']:.3f}]",
        ]
        for row in document["levels"]
    ]
    agg = document["aggregate"]
    rows.append(
        [
            "IQM over levels",
            "",
            "",
            "",
            "",
            f"{agg['iqm']:.3f} [{agg['low']:.3f}, {agg['high']:.3f}]",
        ]
    )
    status = "official" if document["official"] else "UNOFFICIAL (fewer episodes than the suite's)"
    head = (
        f"Benchmark {suite.version}, {suite.system.short_id}: observer {document['observer']}, "
        f"controller {document['controller']} ({status})\n\n"
        f"Metric: {shown}. Score: 1 = the oracle observer with {suite.controller}, "
        "0 = the floor (the worse of the raw camera baseline and doing nothing); 95 % "
        "intervals.\n\n"
    )
    if document.get("camera_scale", 1.0) != 1.0:
        head += (
            f"The agent's own camera is the default scaled by {document['camera_scale']:.6g}: "
            "the levels' pixel-valued options ran times that factor, and a metric in pixels "
            "is in the default camera's pixels.\n\n"
        )
    table = format_table(["level", "episodes", "metric", "oracle", "floor", "score [95 %]"], rows)
    return head + table + f"\n\nCommand: {document['command']}\n"


def plot_scores(document: Mapping[str, Any], path: Path) -> None:
    """Interval estimates of the level scores and the aggregate, drawn as rliable's
    interval-estimate plots draw them (matplotlib alone)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = [row["level"] for row in document["levels"]] + ["IQM"]
    points = [row["score"] for row in document["levels"]] + [document["aggregate"]["iqm"]]
    lows = [row["score_low"] for row in document["levels"]] + [document["aggregate"]["low"]]
    highs = [row["score_high"] for row in document["levels"]] + [document["aggregate"]["high"]]
    fig, ax = plt.subplots(figsize=(6.0, 0.5 + 0.5 * len(names)))
    ys = list(range(len(names)))[::-1]
    for y, p, lo, hi in zip(ys, points, lows, highs, strict=True):
        ax.barh(y, hi - lo, left=lo, height=0.6, alpha=0.5, color="C0")
        ax.plot([p, p], [y - 0.3, y + 0.3], color="k")
    ax.axvline(0.0, color="grey", lw=0.8, ls=":")
    ax.axvline(1.0, color="grey", lw=0.8, ls="--")
    ax.set_yticks(ys, names)
    ax.set_xlabel("normalised score (1: oracle, 0: floor), 95 % interval")
    status = "" if document["official"] else " (unofficial)"
    ax.set_title(
        f"{document['env'].split('/')[-1]}: {document['observer']} + "
        f"{document['controller']}{status}",
        fontsize=9,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def write_outputs(
    out_dir: Path,
    request: BenchmarkRequest,
    records: Sequence[EpisodeRecord],
    wall_s: float,
    reused_s: Mapping[str, float] | None = None,
) -> tuple[Scores, str]:
    """Write the run's outputs into ``out_dir``; its scores and table text. ``wall_s``:
    this call's wall time; ``reused_s``: the recorded wall times of the levels it reused
    (:func:`timing_document`)."""
    suite = request.suite
    entry = {
        "observer": request.observer,
        "controller": request.controller,
        "observer_options": request.observer_options,
        "controller_options": request.controller_options,
        "agent_env_options": request.agent_env_options,
        "camera_scale": request.camera_scale,
        "observer_env_options": request.observer_env_options,
        "entries": request.entries,
        "episodes": request.episodes,
    }
    document, scores = scores_document(suite, entry, records, versions())
    text = table_markdown(suite, document)
    with output_set(out_dir, last=(SCORES_JSON,)) as staging:
        (staging / EPISODES_CSV).write_text(csv_text(records, suite.metric.name), encoding="utf-8")
        (staging / TABLE_MD).write_text(text, encoding="utf-8")
        plot_scores(document, staging / SCORES_PNG)
        write_json_atomic(staging / SCORES_JSON, document)
    write_json_atomic(out_dir / TIMING_JSON, timing_document(request, wall_s, reused_s or {}))
    return scores, text


def timing_document(
    request: BenchmarkRequest, this_run_s: float, reused_s: Mapping[str, float]
) -> dict[str, Any]:
    """What ``timing.json`` holds: ``wall_s``, the run's wall time: this call's
    (``this_run_s``) plus the recorded wall times of the levels it reused from the folder
    (``reused_s``, by level: each level's own, as its file records it), so a resumed run
    reports the time its levels took, not only the resume's; ``this_run_s`` and
    ``reused_levels_s`` apart; the workers and the backend (of this call)."""
    return {
        "wall_s": this_run_s + sum(reused_s.values()),
        "this_run_s": this_run_s,
        "reused_levels_s": {name: float(s) for name, s in reused_s.items()},
        "workers": request.workers,
        "backend": request.backend,
    }
