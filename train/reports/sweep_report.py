"""The outputs of ``observer-gym sweep``, from its results (what
:func:`observer_gym.train.experiments.sweep.assemble_results` returns): ``table.md``,
``episodes.csv``,
one plot per varied key (``<key>.png``) and, last and atomically, ``results.json``; and
the text the command prints.

Nothing here depends on the wall clock, so a resumed sweep writes the same table, CSV and
results as an uninterrupted one.
"""

from __future__ import annotations

import csv
import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from observer_gym.train.core.args import point_text, value_text
from observer_gym.train.core.plots import new_figure, save_figure
from observer_gym.train.reports.compare_report import (
    difference_unit,
    format_difference,
    format_seeds,
    format_statistic,
    outside_entries,
)
from observer_gym.train.reports.compare_stats import PERCENT, MetricSpec
from observer_gym.train.reports.consistency import NEES_COLUMN, NEES_KEY_TEXT, consistency_text
from observer_gym.train.reports.outputs import (
    format_table,
    json_text,
    output_set,
    write_text_atomic,
)

ROW_COLUMNS = ("observer", "controller", "episode", "seed")


def _metrics(config: Mapping[str, Any]) -> dict[str, MetricSpec]:
    """The compared metrics of results' ``config`` as MetricSpec tuples."""
    fields = ("label", "unit", "scale", "digits", "better")
    return {key: tuple(spec[f] for f in fields) for key, spec in config["metrics"].items()}


def _shown_metrics(config: Mapping[str, Any]) -> list[str]:
    """The primary metric and, if another, the second."""
    return list(dict.fromkeys([config["primary_metric"], config["second_metric"]]))


def _header(spec: MetricSpec) -> str:
    label, unit, _, _, better = spec
    text = f"{label} ({unit})" if unit else label
    return f"{text} {'↓' if better == 'lower' else '↑'}"


# --- table.md ------------------------------------------------------------------------------
def sweep_table(results: Mapping[str, Any]) -> str:
    """The Markdown table: one row per cell (the varied keys' values, observer,
    controller), the primary and the second metric (mean ± 95 % half-width, rates with
    their Wilson interval) and the paired difference of the primary metric from the
    reference cell (same observer and controller at the first grid point)."""
    config = results["config"]
    metrics = _metrics(config)
    shown = _shown_metrics(config)
    label, unit, scale, digits, _ = metrics[config["primary_metric"]]
    n = config["episodes"]
    headers = [*config["keys"], "observer", "controller"]
    headers += [_header(metrics[key]) for key in shown]
    headers.append(f"Δ {label} vs reference" + (f" ({difference_unit(unit)})" if unit else ""))
    cells = results["cells"]
    with_nees = any((c.get("consistency") or {}).get("nees_ratio") is not None for c in cells)
    if with_nees:
        headers.append(NEES_COLUMN)
    rows = []
    for cell in cells:
        row = [value_text(cell["point"][key]) for key in config["keys"]]
        row += [cell["observer"], cell["controller"]]
        for key in shown:
            _, _, sc, dg, _ = metrics[key]
            row.append(format_statistic(cell["statistics"][key], sc, dg, n))
        diff = cell["vs_reference"]
        row.append("reference" if diff is None else format_difference(diff, scale, digits, n))
        if with_nees:
            row.append(consistency_text(cell.get("consistency")))
        rows.append(row)
    return format_table(headers, rows)


def write_markdown(path: Path, results: Mapping[str, Any]) -> None:
    """``table.md``: the command line, what ran, the table and how to read it."""
    config = results["config"]
    n, steps = config["episodes"], config["steps"]
    fixed = config["env_kwargs"]
    primary_label = config["metrics"][config["primary_metric"]]["label"]
    lines = [
        f"`{config['command']}`",
        "",
        f"{config['env_id']}: {config['grid_points']} grid point(s) x "
        f"{len(config['observers'])} observer(s) x {len(config['controllers'])} "
        f"controller(s) = {config['cells']} cells, {n} episode(s) each, seeds "
        f"{format_seeds(config['seeds'])} (episode i of every cell has the same seed), "
        + (f"at most {steps} steps each." if steps else "each to the env's end.")
        + (f" Fixed env options: {point_text(fixed)}." if fixed else ""),
        "",
        *[f"- {line}" for line in outside_entries(results["cells"])],
        *([""] if outside_entries(results["cells"]) else []),
        sweep_table(results),
        "",
        f"Cells: mean ± {PERCENT} half-width (Student t) over the episodes with a value, "
        f"(n=k) when fewer than all; rates: rate [{PERCENT} Wilson interval]. ↓ lower is "
        f"better, ↑ higher is better. Δ vs reference: {primary_label} of the cell minus "
        "that of the cell with the same observer and controller at the first grid point "
        f"({point_text(config['reference'])}), episode by episode on the same seeds, mean ± "
        f"{PERCENT} half-width (Student t), and (×) the ratio of the means. Per-episode "
        f"values: episodes.csv; every metric's interval: results.json. {NEES_KEY_TEXT}",
        "",
    ]
    path.write_text("\n".join(lines), encoding="utf-8")


# --- episodes.csv ------------------------------------------------------------------------------
def _csv_value(value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, list | dict):
        return json.dumps(value, separators=(",", ":"))
    return str(value)


def write_episodes_csv(path: Path, results: Mapping[str, Any]) -> None:
    """``episodes.csv``: one row per episode, columns the varied keys, observer,
    controller, episode, seed and every metric of the task (stored SI values, rates as
    True/False; empty for an undefined value; a list as JSON)."""
    keys = results["config"]["keys"]
    taken = {"cell", *keys, *ROW_COLUMNS}
    metric_names = list(
        dict.fromkeys(name for row in results["episodes"] for name in row if name not in taken)
    )
    columns = [*keys, *ROW_COLUMNS, *metric_names]
    with path.open("w", newline="", encoding="utf-8") as f:
        writer = csv.writer(f)
        writer.writerow(columns)
        for row in results["episodes"]:
            writer.writerow([_csv_value(row.get(column)) for column in columns])


# --- <key>.png -----------------------------------------------------------------------------
def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _column(stats: Sequence[Mapping[str, Any]], name: str, scale: float) -> np.ndarray:
    """Field ``name`` of each statistic, scaled; NaN where undefined (a gap in the line)."""
    return np.array([np.nan if s[name] is None else s[name] * scale for s in stats], dtype=float)


def plot_key(path: Path, results: Mapping[str, Any], key: str) -> None:
    """The primary and the second metric against ``key``'s values, the other keys at
    their first value: one line per observer x controller, the band its 95 % interval
    (Student t, rates Wilson); numbers on a numeric axis, other values as categories."""
    config = results["config"]
    metrics = _metrics(config)
    shown = _shown_metrics(config)
    values = config["vary"][key]
    others = {k: v for k, v in config["reference"].items() if k != key}
    numeric = all(map(_is_number, values))
    x = np.array(values, dtype=float) if numeric else np.arange(len(values), dtype=float)
    order = np.argsort(x, kind="stable")  # numbers given out of order are drawn in order
    lines: dict[tuple[str, str], dict[Any, Mapping[str, Any]]] = {}
    for cell in results["cells"]:
        point = cell["point"]
        if all(point[k] == v for k, v in others.items()):
            lines.setdefault((cell["observer"], cell["controller"]), {})[json.dumps(point[key])] = (
                cell["statistics"]
            )
    fig = new_figure((5.0 * len(shown) + 1.5, 4.0))
    axes = fig.subplots(1, len(shown), squeeze=False)[0]
    for ax, metric in zip(axes, shown, strict=True):
        label, unit, scale, _, better = metrics[metric]
        for j, ((observer, controller), stats_by_value) in enumerate(lines.items()):
            stats = [stats_by_value[json.dumps(values[k])][metric] for k in order]
            mean, low, high = (_column(stats, name, scale) for name in ("mean", "low", "high"))
            color = f"C{j % 10}"
            ax.plot(x[order], mean, "o-", color=color, label=f"{observer} / {controller}")
            ax.fill_between(x[order], low, high, color=color, alpha=0.2, lw=0)
        if not numeric:
            ax.set_xticks(x, [value_text(v) for v in values])
        ax.set_xlabel(key)
        ax.set_ylabel(f"{label} ({unit})" if unit else label)
        ax.set_title(f"{label} ({better} is better)", fontsize=9)
        ax.grid(True, alpha=0.3)
    axes[-1].legend(
        title="observer / controller", fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0)
    )
    held = "the only varied key"
    if others:
        held = f"other keys at their first value: {point_text(others)}"
    fig.suptitle(
        f"{config['env_id'].split('/')[-1]} vs {key}; mean and {PERCENT} interval over "
        f"{config['episodes']} episode(s) per point; {held}",
        fontsize=9,
    )
    save_figure(fig, path)


# --- all of them -------------------------------------------------------------------------------
def write_outputs(out_dir: Path, results: Mapping[str, Any]) -> dict[str, Any]:
    """Write ``table.md``, ``episodes.csv``, ``<key>.png`` per varied key and, last,
    ``results.json`` (``results`` with the list of ``files``) into ``out_dir``, as a set
    (:func:`~observer_gym.train.reports.outputs.output_set`): all of them or, if one fails, none,
    the folder's earlier outputs kept. Returns what results.json holds.

    Raises:
        ValueError: ``results`` holds a value JSON cannot hold (NaN: a cell file with a
            number that is not finite), found before anything is written.
        WriteError: a file could not be written (a full disk).
    """
    plots = [f"{key}.png" for key in results["config"]["keys"]]
    written = {**results, "files": ["table.md", "episodes.csv", *plots, "results.json"]}
    try:
        text = json_text(written)
    except ValueError as exc:
        raise ValueError(f"results.json cannot be written: {exc}") from None
    with output_set(out_dir) as staging:
        for key, name in zip(results["config"]["keys"], plots, strict=True):
            plot_key(staging / name, results, key)
        write_markdown(staging / "table.md", results)
        write_episodes_csv(staging / "episodes.csv", results)
        write_text_atomic(staging / "results.json", text)
    return json.loads(text)


def sweep_text(
    results: Mapping[str, Any], out_dir: Path, ran: int, reused: int, seconds: float
) -> str:
    """What ``observer-gym sweep`` prints: what ran, the table and where the outputs are."""
    config = results["config"]
    return "\n".join(
        [
            f"observer-gym sweep: {config['env_id']}, {config['cells']} cells "
            f"({config['grid_points']} grid point(s) x {len(config['observers'])} observer(s) "
            f"x {len(config['controllers'])} controller(s)), {config['episodes']} episode(s) "
            f"each; {ran} cell(s) run, {reused} reused from the folder; {seconds:.1f} s",
            *outside_entries(results["cells"]),
            sweep_table(results),
            f"table: {out_dir / 'table.md'}",
            "plots: " + ", ".join(str(out_dir / f) for f in results["files"] if f.endswith(".png")),
            f"output: {out_dir}",
        ]
    )
