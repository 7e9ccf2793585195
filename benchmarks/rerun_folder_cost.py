"""What ``compare --rerun DIR`` costs: steps per second of a comparison's episodes without
and with a recording of every pair's episode.

    .venv/bin/python benchmarks/rerun_folder_cost.py                 # defaults below
    .venv/bin/python benchmarks/rerun_folder_cost.py --steps 300 --repeats 5

BallTable-v0, the pairs kf x lqr and raw x lqr (rgb frames at 50 Hz), one seed, run by
:func:`~observer_gym.train.experiments.compare.run_pairs` (what ``observer-gym compare``
runs before its tables and plots) in this process (``--workers 1``), without and with a
:func:`~observer_gym.train.experiments.videos.plan_reruns` folder (one ``.rrd`` per
pair's episode, in a temporary folder). ``--repeats`` rounds, the two alternated so that
a change of the machine's load touches both; for each, steps per wall-clock second and
per CPU second of this process (rerun's writer threads included), the load average
(``os.getloadavg``) at its start, and the recordings' size. Then the medians.
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path

from observer_gym.train.experiments.compare import check_comparison, run_pairs
from observer_gym.train.experiments.videos import plan_reruns


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=200, help="steps per episode")
    parser.add_argument("--repeats", type=int, default=3, help="rounds of each")
    args = parser.parse_args()
    request = check_comparison(
        "BallTable-v0", ["kf", "raw"], ["lqr"], [0], workers=1, steps=args.steps
    )
    rates: dict[str, list[tuple[float, float]]] = {"compare": [], "compare --rerun DIR": []}
    for _ in range(args.repeats):
        for kind in rates:
            with tempfile.TemporaryDirectory() as tmp:
                folder = Path(tmp) / "rrd"
                plan = plan_reruns(folder, None, 1) if kind != "compare" else None
                load = os.getloadavg()[0]
                tic, cpu = time.perf_counter(), time.process_time()
                runs = run_pairs(request, progress=False, reruns=plan)
                wall_s, cpu_s = time.perf_counter() - tic, time.process_time() - cpu
                steps = sum(len(record["actions"]) for record in runs.records)
                size_mb = sum(p.stat().st_size for p in folder.glob("*.rrd")) / 1e6
            rates[kind].append((steps / wall_s, steps / cpu_s))
            print(
                f"{kind:20s} {steps} steps: {steps / wall_s:6.1f} steps/s, "
                f"{steps / cpu_s:6.1f} steps per CPU second, load {load:.1f}, "
                f".rrd {size_mb:.2f} MB",
                flush=True,
            )
    print(f"\nmedian of {args.repeats}, load now {os.getloadavg()[0]:.1f}:")
    for kind, found in rates.items():
        wall = statistics.median(r[0] for r in found)
        per_cpu = [r[1] for r in found]
        print(
            f"{kind:20s} {wall:6.1f} steps/s, {statistics.median(per_cpu):6.1f} steps per CPU "
            f"second ({min(per_cpu):.1f}-{max(per_cpu):.1f})"
        )


if __name__ == "__main__":
    main()
