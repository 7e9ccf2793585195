"""The outputs of ``observer-gym compare``: ``table.md``, ``table.csv``, ``bar_<metric>.png``,
the task's plots of every pair under ``pairs/<observer>__<controller>/`` and, last,
``results.json``; and the text the command prints.
"""

from __future__ import annotations

import csv
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from observer_gym.train.core.entries import entry_line
from observer_gym.train.core.plots import new_figure, save_figure
from observer_gym.train.reports.aggregate import METHOD
from observer_gym.train.reports.compare_stats import (
    ORACLE,
    PERCENT,
    MetricSpec,
    compare_counts,
    compare_metrics,
)
from observer_gym.train.reports.consistency import NEES_COLUMN, NEES_KEY_TEXT, consistency_text
from observer_gym.train.reports.outputs import (
    format_table,
    json_text,
    output_set,
    to_jsonable,
    write_json_atomic,
)


# --- names -------------------------------------------------------------------------------
def safe_name(name: str) -> str:
    """``name`` as a folder name: runs of characters other than letters, digits, ``.``,
    ``_`` and ``-`` become ``-`` (``ppo:runs/x`` -> ``ppo-runs-x``)."""
    return re.sub(r"[^A-Za-z0-9._-]+", "-", name).strip(".-") or "unnamed"


def pair_folders(pairs: Sequence[tuple[str, str]]) -> list[str]:
    """One distinct folder name ``<observer>__<controller>`` per (observer, controller)
    pair (a suffix ``-2``, ``-3``... where two pairs' safe names collide)."""
    folders: list[str] = []
    for observer, controller in pairs:
        base = f"{safe_name(observer)}__{safe_name(controller)}"
        folder, k = base, 1
        while folder in folders:
            k += 1
            folder = f"{base}-{k}"
        folders.append(folder)
    return folders


def format_seeds(seeds: Sequence[int]) -> str:
    """Seeds as ``--seeds`` text: runs of consecutive seeds as ranges (``0-2,5,7-8``)."""
    parts: list[str] = []
    k = 0
    while k < len(seeds):
        j = k
        while j + 1 < len(seeds) and seeds[j + 1] == seeds[j] + 1:
            j += 1
        parts.append(str(seeds[k]) if j == k else f"{seeds[k]}-{seeds[j]}")
        k = j + 1
    return ",".join(parts)


# --- tables and plots ----------------------------------------------------------------------
def _number(value: float, digits: int) -> str:
    return f"{value:.{digits}f}"


def format_statistic(stat: Mapping[str, Any], scale: float, digits: int, episodes: int) -> str:
    """A table cell: "mean ± half-width", a rate as "rate [low, high]", "n/a" without a
    value, and "(n=k)" when fewer than all ``episodes`` have a value."""
    if stat["n"] == 0 or stat["mean"] is None:
        return "n/a"
    mean = _number(stat["mean"] * scale, digits)
    if stat["method"] == "wilson":
        low, high = (_number(stat[k] * scale, digits) for k in ("low", "high"))
        text = f"{mean} [{low}, {high}]"
    elif stat["half_width"] is None:
        text = mean
    else:
        text = f"{mean} ± {_number(stat['half_width'] * scale, digits)}"
    if stat["n"] < episodes:
        text += f" (n={stat['n']})"
    return text


def format_difference(diff: Mapping[str, Any], scale: float, digits: int, episodes: int) -> str:
    """The "vs oracle" cell: "+mean ± half-width (×ratio)", "(n=k)" if fewer episodes."""
    if diff["n"] == 0 or diff["mean"] is None:
        return "n/a"
    text = f"{diff['mean'] * scale:+.{digits}f}"
    if diff["half_width"] is not None:
        text += f" ± {_number(diff['half_width'] * scale, digits)}"
    if diff["ratio"] is not None:
        text += f" (×{diff['ratio']:.2f})"
    if diff["n"] < episodes:
        text += f" (n={diff['n']})"
    return text


def _header(label: str, unit: str, better: str | None = None) -> str:
    text = f"{label} ({unit})" if unit else label
    return f"{text} {'↓' if better == 'lower' else '↑'}" if better else text


def difference_unit(unit: str) -> str:
    """The unit of a difference: percentage points for a percentage."""
    return "pp" if unit == "%" else unit


def format_counts(counts: Mapping[str, int]) -> str:
    """A counted cell: "value count" for every value that some episode had, in order
    ("rim_touch 44, bounced_off 27"), or "none"."""
    return ", ".join(f"{value} {count}" for value, count in counts.items() if count) or "none"


def comparison_table(
    pairs: Sequence[Mapping[str, Any]],
    metrics: Mapping[str, MetricSpec],
    episodes: int,
    counts: Mapping[str, str] | None = None,
) -> str:
    """The Markdown table: one row per pair, a column per metric, right after the primary
    metric's a column per counted key of ``counts`` (key -> label: the pair's ``counts``,
    :func:`format_counts`), when some pair has a ``vs_oracle`` the column of the primary
    metric's paired difference from the oracle, and when some pair has an estimate the
    NEES/dof column with its band (⚠ outside)."""
    primary = next(iter(metrics))
    label, unit, scale, digits, _ = metrics[primary]
    counts = counts or {}
    with_oracle = any(p["vs_oracle"] is not None for p in pairs)
    with_nees = any((p.get("consistency") or {}).get("nees_ratio") is not None for p in pairs)
    headers = ["observer", "controller"]
    headers += [_header(lab, u, better) for lab, u, _, _, better in metrics.values()]
    headers[3:3] = list(counts.values())
    if with_oracle:
        headers.append(_header(f"Δ {label} vs oracle", difference_unit(unit)))
    if with_nees:
        headers.append(NEES_COLUMN)
    rows = []
    for pair in pairs:
        row = [pair["observer"], pair["controller"]]
        for key, (_, _, sc, dg, _) in metrics.items():
            row.append(format_statistic(pair["statistics"][key], sc, dg, episodes))
        row[3:3] = [format_counts(pair["counts"][key]) for key in counts]
        if with_oracle:
            diff = pair["vs_oracle"]
            row.append(
                "reference"
                if pair["observer"] == ORACLE
                else "n/a"
                if diff is None
                else format_difference(diff, scale, digits, episodes)
            )
        if with_nees:
            row.append(consistency_text(pair.get("consistency")))
        rows.append(row)
    return format_table(headers, rows)


def across_seeds_table(entries: Sequence[Mapping[str, Any]], spec: MetricSpec) -> str:
    """The Markdown table of the multi-seed agents: per (observer, agent) each seed's mean
    of the primary metric (``spec``), their mean and their IQM with its interval."""
    label, unit, scale, digits, better = spec

    def number(value: float | None) -> str:
        return "n/a" if value is None else _number(value * scale, digits)

    rows = []
    for entry in entries:
        stats = entry["statistics"]
        per_seed = ", ".join(f"{seed}: {number(v)}" for seed, v in entry["per_seed"].items())
        if stats is None:
            mean = iqm = "n/a"
        else:
            mean = number(stats["mean"])
            iqm = (
                f"{number(stats['iqm'])} [{number(stats['iqm_low'])}, {number(stats['iqm_high'])}]"
            )
        rows.append([entry["observer"], entry["controller"], per_seed, mean, iqm])
    headers = [
        "observer",
        "agent (multi-seed)",
        f"per seed: {_header(label, unit, better)}",
        "mean",
        f"IQM [{PERCENT} interval]",
    ]
    return format_table(headers, rows)


def write_markdown(
    path: Path,
    table: str,
    metrics: Mapping[str, MetricSpec],
    env_id: str,
    seeds: Sequence[int],
    steps: int | None,
    command: str,
    cli_args: Mapping[str, Any] | None,
    seeds_table: str | None = None,
    outside: Sequence[str] = (),
    counts: Mapping[str, str] | None = None,
) -> None:
    """``table.md``: the command line (when run from it), what was run (with the
    ``outside`` entries' lines, :func:`outside_entries`), the table, a key (naming the
    counted columns, ``counts``: key -> label) and, with multi-seed agents, their table
    across seeds (``seeds_table``)."""
    primary_label = next(iter(metrics.values()))[0]
    counted = ", ".join(counts.values()) if counts else ""
    lines = [f"`{command}`", ""] if cli_args is not None else []
    lines += [
        f"{env_id}: {len(seeds)} episode(s) per pair, seeds {format_seeds(seeds)} "
        f"(episode i of every pair has the same seed), "
        + (f"at most {steps} steps each." if steps else "each to the env's end."),
        "",
        *[f"- {line}" for line in outside],
        *([""] if outside else []),
        table,
        "",
        f"Cells: mean ± {PERCENT} half-width (Student t) over the episodes with a "
        f"value, (n=k) when fewer than all; rates: rate [{PERCENT} Wilson interval]. "
        "↓ lower is better, ↑ higher is better. "
        f"Δ vs oracle: observer − oracle of {primary_label}, episode by episode on the same "
        f"seeds, mean ± {PERCENT} half-width (Student t), and (×) the ratio of the "
        f"means. {NEES_KEY_TEXT}"
        + (
            f" Counted ({counted}): how many of the pair's episodes had each value "
            "(values no episode had left out)."
            if counted
            else ""
        ),
        "",
    ]
    if seeds_table is not None:
        lines += [
            "Multi-seed agents: each seed's agent is a row above; across seeds:",
            "",
            seeds_table,
            "",
            f"Per seed: its mean of {primary_label} over the episodes; across seeds: {METHOD}.",
            "",
        ]
    path.write_text("\n".join(lines), encoding="utf-8")


CSV_COLUMNS = ("observer", "controller", "metric", "n", "mean", "half_width", "low", "high")


def write_csv(
    path: Path,
    pairs: Sequence[Mapping[str, Any]],
    metrics: Mapping[str, MetricSpec],
) -> None:
    """``table.csv``: one row per pair and metric (stored SI values, rates 0-1), and one
    per pair with an oracle difference (metric ``<primary>_minus_oracle``); empty cells
    for undefined numbers; ``interval`` says how the interval was computed."""
    primary = next(iter(metrics))
    with path.open("w", newline="", encoding="utf-8") as f:
        writer = csv.writer(f)
        writer.writerow([*CSV_COLUMNS, "interval"])

        def row(pair: Mapping[str, Any], metric: str, stat: Mapping[str, Any]) -> None:
            numbers = ["" if stat[k] is None else repr(float(stat[k])) for k in CSV_COLUMNS[4:]]
            writer.writerow(
                [pair["observer"], pair["controller"], metric, stat["n"], *numbers, stat["method"]]
            )

        for pair in pairs:
            for key in metrics:
                row(pair, key, pair["statistics"][key])
            if pair["vs_oracle"] is not None:
                row(pair, f"{primary}_minus_oracle", pair["vs_oracle"])


def plot_bars(
    pairs: Sequence[Mapping[str, Any]],
    observers: Sequence[str],
    controllers: Sequence[str],
    key: str,
    spec: MetricSpec,
    episodes: int,
    path: Path,
) -> None:
    """A grouped bar chart of one metric: controllers on the x axis, one bar per observer,
    error bars the 95 % interval (t or Wilson); a bar with fewer episodes than all is
    labelled n=k, a pair without a value n/a."""
    label, unit, scale, _, better = spec
    lookup = {(p["observer"], p["controller"]): p["statistics"][key] for p in pairs}
    fig = new_figure((max(5.0, 1.2 + 0.6 * len(controllers) * len(observers)), 4.0))
    ax = fig.add_subplot()
    x = np.arange(len(controllers))
    width = 0.8 / len(observers)
    for j, observer in enumerate(observers):
        heights, below, above, counts = [], [], [], []
        for controller in controllers:
            stat = lookup[observer, controller]
            mean = np.nan if stat["mean"] is None else stat["mean"] * scale
            heights.append(mean)
            counts.append("" if stat["n"] == episodes else f"n={stat['n']}")
            if stat["low"] is None:
                below.append(0.0)
                above.append(0.0)
            else:
                below.append(mean - stat["low"] * scale)
                above.append(stat["high"] * scale - mean)
        positions = x + (j - (len(observers) - 1) / 2) * width
        bars = ax.bar(
            positions,
            heights,
            width,
            yerr=[below, above],
            capsize=3,
            color=f"C{j % 10}",
            label=short_label(observer),
        )
        ax.bar_label(bars, labels=counts, label_type="center", fontsize=7)
        for position, height in zip(positions, heights, strict=True):
            if np.isnan(height):
                ax.text(position, 0.0, "n/a", ha="center", va="bottom", fontsize=7)
    ax.set_xticks(x, [short_label(c) for c in controllers])
    ax.set_xlim(-0.5, len(controllers) - 0.5)
    ax.set_xlabel("controller")
    ax.set_ylabel(f"{label} ({unit})" if unit else label)
    ax.set_title(
        f"{label} ({better} is better)\nmean and {PERCENT} interval, {episodes} episode(s)",
        fontsize=9,
    )
    ax.grid(True, axis="y", alpha=0.3)
    ax.legend(title="observer", fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    save_figure(fig, path)


# --- the whole output ------------------------------------------------------------------------
def write_comparison(
    out_dir: Path,
    task: Any,
    results: Mapping[str, Any],
    records: Mapping[tuple[str, str], Sequence[Mapping[str, Any]]],
) -> dict[str, Any]:
    """Write a comparison's outputs into ``out_dir``: the task's plots of every pair (from
    its episodes' ``records``; their names go into the pair's ``files``), a bar chart per
    metric, ``table.md``, ``table.csv`` and, last, ``results.json``: ``results``
    (``config``, ``versions``, ``wall_time_s``, ``starts_match``, ``pairs``) with the list
    of ``files``. They are written as a set
    (:func:`~observer_gym.train.reports.outputs.output_set`): all of them or, if one fails, none.
    Returns what ``results.json`` holds (JSON types).

    Raises:
        ValueError: ``results`` holds a value JSON cannot hold (NaN), found before
            anything is written.
        WriteError: a file could not be written (a full disk).
    """
    config, pairs = results["config"], results["pairs"]
    metrics = compare_metrics(task)
    counts = {key: label for key, (label, _) in compare_counts(task).items()}
    n = config["episodes"]
    try:
        json_text(results)
    except ValueError as exc:
        raise ValueError(f"results.json cannot be written: {exc}") from None
    files = []
    with output_set(out_dir) as staging:
        for pair in pairs:
            pair_dir = staging / "pairs" / pair["folder"]
            pair_dir.mkdir(parents=True, exist_ok=True)
            names = task.plot(
                records[pair["observer"], pair["controller"]], pair["observer"], pair_dir
            )
            pair["files"] = [f"pairs/{pair['folder']}/{name}" for name in names]
            files += pair["files"]
        for key, spec in metrics.items():
            name = f"bar_{key}.png"
            plot_bars(
                pairs, config["observers"], config["controllers"], key, spec, n, staging / name
            )
            files.append(name)

        table = comparison_table(pairs, metrics, n, counts)
        across = results.get("across_seeds") or []
        seeds_table = across_seeds_table(across, next(iter(metrics.values()))) if across else None
        write_markdown(
            staging / "table.md",
            table,
            metrics,
            config["env_id"],
            config["seeds"],
            config["steps"],
            config["command"],
            config["cli_args"],
            seeds_table,
            outside_entries(pairs),
            counts,
        )
        write_csv(staging / "table.csv", pairs, metrics)
        files += ["table.md", "table.csv", "results.json"]
        written = to_jsonable({**results, "files": files})
        write_json_atomic(staging / "results.json", written)
    return written


def short_label(name: str, width: int = 32) -> str:
    """``name`` for a plot's tick or legend: a long one (a path, an import path) keeps its
    start and end around an ellipsis."""
    if len(name) <= width:
        return name
    keep = (width - 1) // 2
    return f"{name[:keep]}…{name[-keep:]}"


def outside_entries(rows: Sequence[Mapping[str, Any]]) -> list[str]:
    """One line per outside observer and controller among ``rows`` (pairs or sweep
    cells, each once): its import path, package, version and options."""
    lines = []
    for row in rows:
        for kind, entry in (
            ("observer", row.get("entry")),
            ("controller", (row.get("controller_config") or {}).get("entry")),
        ):
            if entry:
                lines.append(entry_line(kind, entry))
    return list(dict.fromkeys(lines))


def comparison_text(results: Mapping[str, Any]) -> str:
    """What ``observer-gym compare`` prints: what ran, the table and the output folder."""
    config = results["config"]
    metrics = {
        key: (spec["label"], spec["unit"], spec["scale"], spec["digits"], spec["better"])
        for key, spec in config["metrics"].items()
    }
    counts = {key: spec["label"] for key, spec in config.get("counts", {}).items()}
    n = config["episodes"]
    return "\n".join(
        [
            f"observer-gym compare: {config['env_id']}, {len(config['observers'])} observer(s) "
            f"x {len(config['controllers'])} controller(s), {n} episode(s) each (seeds "
            f"{format_seeds(config['seeds'])}), {config['backend']} backend, "
            f"{results['wall_time_s']:.1f} s",
            *outside_entries(results["pairs"]),
            *(
                [
                    f"{name}'s own camera is the default scaled by {scale:.6g}: its episodes' "
                    "pixel-valued options are times that (the same angles as every entry)"
                    for name, scale in config.get("agent_camera_scale", {}).items()
                ]
            ),
            comparison_table(results["pairs"], metrics, n, counts),
            *(
                ["across seeds:", across_seeds_table(across, next(iter(metrics.values())))]
                if (across := results.get("across_seeds"))
                else []
            ),
            f"output: {config['out_dir']}",
        ]
    )
