"""What ``observer-gym sweep``'s machinery costs: one sweep of BallTable-v0 (3 values of
``measurement_noise_px`` x oracle, kf-measurements x lqr, pid = 12 cells), its running
phase's wall time against the sum of its episodes' own times measured inside the same run
(``timing.json``; target: the machinery adds <= 5 %), what a cell costs, the checks and
the report (table, CSV, plots, results.json), and a second run that finds every cell done
(resume). The load average is printed before and after: on a busy machine the episodes
and the wall clock slow alike, the ratio is what to read.

    python benchmarks/bench_sweep.py [--episodes 3] [--steps 200] [--workers 1]

With ``--workers W`` > 1 the running phase is compared as wall x W against the sum (the
workers' start-up then counts as overhead).

Then what an outside observer and controller cost (docs/your_method.md): a sweep of
kf-measurements and lqr against the same two named by import path
(benchmarks/outside_entries.py passes them through, so every cell does the same work),
in one run: each cell's median episode time against the built-in cell's (target: <= 1.05),
and the checks before running (the outside entries are tried once on a built world).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

from observer_gym.train.experiments.sweep import run_sweep
from observer_gym.train.reports.outputs import format_table, write_json_atomic

sys.path.insert(0, str(Path(__file__).parent))  # outside_entries, as a user's package
OUTSIDE_TARGET = 1.05  # an outside cell's median episode time over the built-in cell's
KF, LQR = "kf-measurements", "lqr"
OUTSIDE_KF, OUTSIDE_LQR = "outside_entries:kf_delegate-measurements", "outside_entries:lqr_delegate"

TARGET = 0.05  # the machinery's share of the running phase
SWEEP = {
    "env_id": "BallTable-v0",
    "vary": {"measurement_noise_px": [0.0, 1.0, 2.0]},
    "observers": ["oracle", "kf-measurements"],
    "controllers": ["lqr", "pid"],
    "seed": 0,
    "env_kwargs": {"push_rate_hz": 1.0},
    "progress": False,
}


def _load() -> str:
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


def _cell_write_ms(out_dir: Path, repeats: int = 50) -> float:
    """Milliseconds to write one cell file atomically (temp + rename), as the sweep does."""
    path = next((out_dir / "cells").glob("*.json"))
    data = json.loads(path.read_text())
    tic = time.perf_counter()
    for _ in range(repeats):
        write_json_atomic(path, data)
    return 1e3 * (time.perf_counter() - tic) / repeats


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--episodes", type=int, default=3, help="episodes per cell (default: 3)")
    parser.add_argument("--steps", type=int, default=200, help="steps per episode (default: 200)")
    parser.add_argument("--workers", type=int, default=1, help="local workers (default: 1)")
    args = parser.parse_args()

    load_start = _load()
    with tempfile.TemporaryDirectory() as tmp, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out_dir = Path(tmp) / "sweep"
        options = {**SWEEP, "episodes": args.episodes, "steps": args.steps}
        first = run_sweep(**options, out_dir=out_dir, workers=args.workers)
        timing = json.loads((out_dir / "timing.json").read_text())
        write_ms = _cell_write_ms(out_dir)
        again = run_sweep(**options, out_dir=out_dir, workers=args.workers)
    load_end = _load()

    cells, episodes = timing["cells_run"], timing["episodes_run"]
    run_s, sum_s = timing["run_s"], timing["episode_time_s_sum"]
    overhead = run_s * args.workers / sum_s - 1.0
    per_cell_machinery_ms = 1e3 * (run_s * args.workers - sum_s) / cells
    rows = [
        ["cells x episodes (steps each)", f"{cells} x {args.episodes} ({args.steps})"],
        ["workers", str(args.workers)],
        ["running phase, wall (s)", f"{run_s:.2f}"],
        ["sum of the episodes' own times (s)", f"{sum_s:.2f}"],
        [
            "machinery's share of the running phase",
            f"{100 * overhead:+.1f} % ({'within' if overhead <= TARGET else 'over'} the "
            f"{100 * TARGET:.0f} % target)",
        ],
        ["a cell: its episodes (s)", f"{sum_s / cells:.3f}"],
        ["a cell: the machinery around them (ms)", f"{per_cell_machinery_ms:.1f}"],
        ["a cell file's atomic write (ms)", f"{write_ms:.2f}"],
        ["an episode, mean (s)", f"{sum_s / episodes:.3f}"],
        ["checks before running (s)", f"{timing['check_s']:.2f}"],
        ["report: table, CSV, 1 plot, results.json (s)", f"{timing['report_s']:.2f}"],
        ["whole sweep, wall (s)", f"{first.wall_time_s:.2f}"],
        [
            "whole sweep vs the episodes' sum",
            f"{100 * (first.wall_time_s * args.workers / sum_s - 1):+.1f} %",
        ],
        [
            f"re-run, all {again.cells_reused} cells found done (s)",
            f"{again.wall_time_s:.2f}",
        ],
        ["load average (1, 5, 15 min) before", load_start],
        ["load average (1, 5, 15 min) after", load_end],
    ]
    print(f"observer-gym sweep machinery, {os.cpu_count()} CPU(s)")
    print(format_table(["measure", "value"], rows))
    print()
    print(outside_table(args.episodes, args.steps))


def outside_table(episodes: int, steps: int) -> str:
    """The built-in and outside cells of one sweep, their median episode times and ratios."""
    load_start = _load()
    with tempfile.TemporaryDirectory() as tmp, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        common = {**SWEEP, "episodes": episodes, "steps": steps, "vary": {"latency_s": [0.0]}}
        builtin = run_sweep(
            **{**common, "observers": [KF], "controllers": [LQR]}, out_dir=Path(tmp) / "builtin"
        )
        mixed = run_sweep(
            **{**common, "observers": [KF, OUTSIDE_KF], "controllers": [LQR, OUTSIDE_LQR]},
            out_dir=Path(tmp) / "mixed",
        )
        timing = json.loads((Path(tmp) / "mixed" / "timing.json").read_text())
        checks = [
            json.loads((Path(tmp) / name / "timing.json").read_text())["check_s"]
            for name in ("builtin", "mixed")
        ]
    medians = {
        (cell["observer"], cell["controller"]): float(
            np.median(timing["cells"][cell["id"]]["episode_s"])
        )
        for cell in mixed.results["cells"]
    }
    reference = medians[KF, LQR]
    rows = [
        [
            observer,
            controller,
            f"{1e3 * median:.1f}",
            f"{median / reference:.3f}"
            + (
                ""
                if (observer, controller) == (KF, LQR)
                else (" (within)" if median / reference <= OUTSIDE_TARGET else " (over)")
            ),
        ]
        for (observer, controller), median in medians.items()
    ]
    del builtin
    rows.append(["checks before running, built-ins only (s)", "", f"{checks[0]:.2f}", ""])
    rows.append(["checks before running, with the outside entries (s)", "", f"{checks[1]:.2f}", ""])
    rows.append(["load average before / after", "", load_start, _load()])
    return (
        f"outside entries against built-ins ({episodes} episodes x {steps} steps per cell, "
        f"target <= {OUTSIDE_TARGET})\n"
        + format_table(["observer", "controller", "median episode (ms)", "x built-in"], rows)
    )


if __name__ == "__main__":
    main()
