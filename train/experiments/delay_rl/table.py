"""The random-delay study's table, derived from its folder's per-seed records alone.

For every agent the score is its seed's mean of the task's primary metric over the
evaluation episodes (BallTable: the ball's mean distance from the centre; BallCatcher: the
catch rate); across seeds, the IQM with its 95 % stratified-bootstrap interval
(:func:`~observer_gym.train.reports.aggregate.across_seeds`, rliable's method). Three
tables: each input trained and evaluated at each level; the agents trained at the shift
level evaluated at every level, with what each loses against its own level; how each
level's frames arrive. The classical controller on each belief is the reference line.
``--check`` derives the table again and compares it with ``table.json``.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

from observer_gym.envs import system_for_id
from observer_gym.envs.json_file import read_json
from observer_gym.train.core.tasks import task_of
from observer_gym.train.experiments.delay_rl.layout import (
    DELIVERY_FILE,
    PLAN_FILE,
    TIMING_FILE,
    cell_dir,
    eval_path,
    reference_path,
)
from observer_gym.train.experiments.delay_rl.plan import SHIFT_FROM, StudyPlan
from observer_gym.train.reports.aggregate import across_seeds
from observer_gym.train.reports.outputs import (
    format_table,
    json_text,
    write_json_atomic,
    write_text_atomic,
)
from observer_gym.train.rl.run_dir import read_state, seed_run_dirs

TABLE_JSON = "table.json"
TABLE_MD = "table.md"
REPS = 10_000  # bootstrap replications of each interval


@dataclasses.dataclass(frozen=True)
class StudyTable:
    """What ``table.json`` holds."""

    plan: dict[str, Any]
    metric: dict[str, Any]  # key, label, unit, scale, digits, better
    cells: list[dict[str, Any]]  # trained_at, input, at, statistics (IQM, interval, scores)
    references: list[dict[str, Any]]  # input, at, controller, observer, metric_mean
    delivery: dict[str, Any]
    budget: dict[str, Any]

    def as_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


def derive_table(out_dir: str | Path) -> StudyTable:
    """The table of the study in ``out_dir`` from its records (module docstring).

    Raises:
        ValueError: the folder holds no study, or a record is missing (the study has not
            finished: run it again to continue).
    """
    out_dir = Path(out_dir)
    if not (out_dir / PLAN_FILE).is_file():
        raise ValueError(f"{out_dir} holds no delay-rl study (no {PLAN_FILE})")
    plan = StudyPlan.from_dict(read_json(out_dir / PLAN_FILE))
    task = task_of(system_for_id(plan.env_id))
    key = next(iter(task.COMPARE_METRICS))
    label, unit, scale, digits, better = task.COMPARE_METRICS[key]
    cells = []
    for trained_at, name, at in plan.eval_cells():
        record = _read(eval_path(out_dir, trained_at, name, at))
        scores = {int(seed): entry["metric_mean"] for seed, entry in record["per_seed"].items()}
        returns = {int(seed): entry["return_mean"] for seed, entry in record["per_seed"].items()}
        cells.append(
            {
                "trained_at": trained_at,
                "input": name,
                "at": at,
                "metric": across_seeds(scores, REPS).as_dict(),
                "return": across_seeds(returns, REPS).as_dict(),
            }
        )
    references = []
    for name, agent_input in plan.input_records.items():
        if agent_input.reference_observer is None:
            continue
        for at in plan.levels:
            record = _read(reference_path(out_dir, name, at))
            references.append(
                {k: record[k] for k in ("input", "at", "controller", "observer", "metric_mean")}
            )
    runs = [
        path
        for level, name in plan.train_cells()
        for path in seed_run_dirs(cell_dir(out_dir, level, name)).values()
    ]
    # each run trains in one process on one core: its wall time is its CPU time (of its
    # last segment: a run resumed after a stop counts from the resume)
    wall_s = [float((read_state(path) or {}).get("segment_wall_time_s") or 0.0) for path in runs]
    timing = _read(out_dir / TIMING_FILE)
    budget = {
        "timesteps_per_seed": plan.timesteps,
        "seed_runs": len(runs),
        "env_steps": plan.timesteps * len(runs),
        "training_cpu_hours": sum(wall_s) / 3600.0,
        "wall_time_hours": sum(t["wall_time_s"] for t in timing["invocations"]) / 3600.0,
        "invocations": len(timing["invocations"]),
        "cpus": sorted({t["cpus"] for t in timing["invocations"]}),
    }
    return StudyTable(
        plan=plan.as_dict(),
        metric={
            "key": key,
            "label": label,
            "unit": unit,
            "scale": scale,
            "digits": digits,
            "better": better,
        },
        cells=cells,
        references=references,
        delivery=_read(out_dir / DELIVERY_FILE),
        budget=budget,
    )


def _read(path: Path) -> Any:
    if not path.is_file():
        raise ValueError(
            f"{path} is missing: the study has not finished; run the same command again "
            "to continue it"
        )
    return read_json(path)


def write_table(out_dir: str | Path, table: StudyTable) -> None:
    """``table.md``, the curves, and last ``table.json`` into ``out_dir``."""
    out_dir = Path(out_dir)
    write_text_atomic(out_dir / TABLE_MD, table_markdown(table))
    plot_curves(out_dir, table)
    write_json_atomic(out_dir / TABLE_JSON, table.as_dict())


def check_table(out_dir: str | Path) -> list[str]:
    """The differences between the folder's ``table.json`` and the table derived again
    from its records (empty: it checks out)."""
    out_dir = Path(out_dir)
    path = out_dir / TABLE_JSON
    if not path.is_file():
        return [f"{path} is missing"]
    derived = json.loads(json_text(derive_table(out_dir).as_dict()))
    stored = read_json(path)
    return [
        f"{key} differs: table.json has {stored.get(key)!r:.200}, the records give "
        f"{derived.get(key)!r:.200}"
        for key in derived
        if stored.get(key) != derived[key]
    ]


def _number(value: float, table: StudyTable) -> str:
    metric = table.metric
    return f"{value * metric['scale']:.{metric['digits']}f}"


def _interval(stats: dict[str, Any], table: StudyTable) -> str:
    return (
        f"{_number(stats['iqm'], table)} [{_number(stats['iqm_low'], table)}, "
        f"{_number(stats['iqm_high'], table)}]"
    )


def table_markdown(table: StudyTable) -> str:
    """The three tables and the budget as Markdown."""
    plan = StudyPlan.from_dict(table.plan)
    metric = table.metric
    unit = f" ({metric['unit']})" if metric["unit"] else ""
    cell = {(c["trained_at"], c["input"], c["at"]): c for c in table.cells}
    lines = [
        f"# Random-delay study: {plan.env_id}",
        "",
        f"{metric['label']}{unit}, {metric['better']} is better: IQM across "
        f"{len(plan.seeds)} seeds [95 % stratified-bootstrap interval]; each seed's score "
        f"is its mean over {plan.eval_episodes} evaluation episodes. PPO, "
        f"{plan.timesteps:,} env steps per seed.",
        "",
        "## Trained and evaluated at each level",
        "",
    ]
    rows = []
    for name, agent_input in plan.input_records.items():
        row = [f"{name}: {agent_input.summary}"]
        for level in plan.levels:
            trained_at = plan.trained_at(level, name)
            if trained_at is None:
                row.append(f"not trained ({agent_input.trained_only_at} only)")
                continue
            found = cell.get((trained_at, name, level))
            row.append("" if found is None else _interval(found["metric"], table))
        rows.append(row)
    references = {(r["input"], r["at"]): r for r in table.references}
    for name, agent_input in plan.input_records.items():
        if agent_input.reference_observer is None:
            continue
        controller = next(r["controller"] for r in table.references if r["input"] == name)
        row = [f"{controller} on {agent_input.reference_observer} (reference)"]
        for level in plan.levels:
            row.append(_number(references[(name, level)]["metric_mean"], table))
        rows.append(row)
    lines += [format_table(["input", *plan.levels], rows), ""]
    if SHIFT_FROM in plan.levels and len(plan.levels) > 1:
        lines += [
            f"## Shift: trained at {SHIFT_FROM}, evaluated at every level",
            "",
            f"Each cell: the IQM, and in brackets the change against the same agents at "
            f"{SHIFT_FROM}, then against agents trained at that level.",
            "",
        ]
        rows = []
        for name, agent_input in plan.input_records.items():
            own = cell.get((plan.trained_at(SHIFT_FROM, name), name, SHIFT_FROM))
            if own is None:
                continue
            row = [name]
            for level in plan.levels:
                shifted = cell.get((plan.trained_at(SHIFT_FROM, name), name, level))
                native = cell.get((plan.trained_at(level, name), name, level))
                if shifted is None:
                    row.append("")
                    continue
                text = _number(shifted["metric"]["iqm"], table)
                if level != SHIFT_FROM:
                    change = shifted["metric"]["iqm"] - own["metric"]["iqm"]
                    against = ""
                    if native is not None and not agent_input.delay_free:
                        gap = shifted["metric"]["iqm"] - native["metric"]["iqm"]
                        against = f", {_signed(gap, table)}"
                    elif plan.trained_at(level, name) is None:
                        against = ", not trained there"
                    text += f" ({_signed(change, table)}{against})"
                row.append(text)
            rows.append(row)
        lines += [format_table(["input", *plan.levels], rows), ""]
    lines += ["## How the frames arrive", ""]
    rows = []
    for level in plan.levels:
        d = table.delivery[level]
        rows.append(
            [
                level,
                f"{d['latency_s']:g}",
                f"{d['latency_jitter_s']:g}",
                f"{d['frame_drop_prob']:g}",
                f"{d['out_of_order_fraction'] * 100:.1f} %",
                f"{d['newest_age_mean_s'] * 1e3:.0f}",
                str(d["frames_delivered"]),
            ]
        )
    lines += [
        format_table(
            [
                "level",
                "latency (s)",
                "jitter (s)",
                "drop prob.",
                "out of order",
                "newest age, mean (ms)",
                "frames counted",
            ],
            rows,
        ),
        "",
        "## Budget",
        "",
        f"{table.budget['seed_runs']} seed runs x {table.budget['timesteps_per_seed']:,} env "
        f"steps = {table.budget['env_steps']:,} env steps; training "
        f"{table.budget['training_cpu_hours']:.2f} CPU hours (one core per run); the study "
        f"took {table.budget['wall_time_hours']:.2f} h of wall time in "
        f"{table.budget['invocations']} invocation(s) on "
        f"{'/'.join(str(c) for c in table.budget['cpus'])} CPUs.",
        "",
    ]
    return "\n".join(lines)


def _signed(value: float, table: StudyTable) -> str:
    text = _number(value, table)
    return text if text.startswith("-") else f"+{text}"


def plot_curves(out_dir: Path, table: StudyTable) -> None:
    """``curves_<level>.png``: each input's mean evaluation return during training (its
    cell's aggregate.json band) at that level."""
    from observer_gym.train.core.plots import new_figure, save_figure  # deferred

    plan = StudyPlan.from_dict(table.plan)
    for level in plan.levels:
        trained = [
            (name, trained_at)
            for name in plan.inputs
            if (trained_at := plan.trained_at(level, name)) is not None
        ]
        if not trained:  # e.g. a folder of an input trained at another level only
            continue
        fig = new_figure((7.5, 4.5))
        ax = fig.subplots()
        for name, trained_at in trained:
            folder = cell_dir(out_dir, trained_at, name)
            band = read_json(folder / "aggregate.json")["curve"]
            if not band["timesteps"]:
                continue
            (line,) = ax.plot(band["timesteps"], band["mean"], lw=2, label=name)
            ax.fill_between(
                band["timesteps"], band["low"], band["high"], color=line.get_color(), alpha=0.2
            )
        ax.set(
            xlabel="env steps",
            ylabel="evaluation return (deterministic policy)",
            title=f"{plan.env_id}, delay {level}: mean across seeds, 95 % interval",
        )
        ax.grid(True, alpha=0.3)
        ax.legend(loc="lower right", fontsize=8)
        save_figure(fig, out_dir / f"curves_{level}.png")
