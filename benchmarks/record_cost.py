"""What ``observer-gym record`` costs: steps per second of a run without and with
``--video``, with ``--rerun`` and of a recording, and the peak memory of a recording
against a run as the episode grows.

    .venv/bin/python benchmarks/record_cost.py                  # defaults below
    .venv/bin/python benchmarks/record_cost.py --steps 300 --repeats 5 --long 100,500,1000

BallTable-v0, observer kf (rgb frames, 50 Hz: what a recording stores as observations),
controller lqr. A run is one episode through
:func:`~observer_gym.train.experiments.episode.run_episode` (what ``observer-gym run``
runs), with ``--video`` into a temporary folder or ``--rerun`` into a temporary
``.rrd`` file (skipped without rerun-sdk); a recording is
:func:`~observer_gym.train.experiments.record.record_experiment` with one episode (what
``observer-gym record`` runs: the dataset written, staged and renamed, included).

- **Speed**: ``--repeats`` rounds of each, alternated so that a change of the
  machine's load touches all; the median steps per wall-clock second of each and its ratio
  to the plain run. The load average (``os.getloadavg``) is printed before and after.
- **Memory**: for each episode length of ``--long``, a fresh process runs one episode
  (plain run or recording) and reports its peak resident size (``getrusage``'s
  ``ru_maxrss``) and the peak of the Python heap (``tracemalloc``, NumPy's arrays
  included). Minari's ``DataCollector`` keeps the episode's steps in memory until the
  episode ends (then writes it out), so a recording's peak grows with the episode's
  length; the table shows by how much.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

from observer_gym.extras import missing_modules
from observer_gym.train.experiments.episode import EpisodeSpec, run_episode
from observer_gym.train.reports.rerun_recording import RerunRequest
from observer_gym.train.reports.video import VideoRequest

ENV = "observer_gym/BallTable-v0"
ENV_ID = "BallTable-v0"


def env_kwargs(steps: int) -> dict:
    # the env's own time limit lifted so that a long episode is as long as asked
    return {"max_episode_steps": steps + 1}


def run_plain(steps: int, video: Path | None = None, rerun: Path | None = None) -> None:
    request = None if video is None else VideoRequest(str(video), "v")
    recording = None if rerun is None else RerunRequest(str(rerun), "r")
    spec = EpisodeSpec.of(
        ENV, "kf", "lqr", seed=0, max_steps=steps, env_kwargs=env_kwargs(steps), video=request,
        rerun=recording,
    )  # fmt: skip
    run_episode(spec)


def run_record(steps: int, out: Path) -> None:
    from observer_gym.train.experiments.record import record_experiment

    record_experiment(
        ENV_ID, "kf", "lqr", 1, 0, out, steps=steps, progress=False, env_kwargs=env_kwargs(steps)
    )


def timed(kind: str, steps: int, folder: Path, i: int) -> tuple[float, float]:
    """Steps per wall-clock second and per CPU second of this process (its threads
    included: rerun's writer; not ffmpeg's process)."""
    tic, cpu = time.perf_counter(), time.process_time()
    if kind == "run":
        run_plain(steps)
    elif kind == "run --video":
        run_plain(steps, folder)  # the existing folder; v.mp4 replaced each round
    elif kind == "run --rerun":
        run_plain(steps, rerun=folder / "r.rrd")  # replaced each round
    else:
        run_record(steps, folder / f"record{i}")
    return steps / (time.perf_counter() - tic), steps / (time.process_time() - cpu)


def child(kind: str, steps: int) -> None:
    """One episode in this fresh process; prints its peaks as JSON."""
    with tempfile.TemporaryDirectory() as folder:
        tracemalloc.start()
        if kind == "run":
            run_plain(steps)
        else:
            run_record(steps, Path(folder) / "r")
        heap_peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
    rss_kib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # KiB on Linux
    print(json.dumps({"rss_mib": rss_kib / 1024, "heap_mib": heap_peak / 2**20}))


def peaks(kind: str, steps: int) -> dict:
    out = subprocess.run(
        [sys.executable, __file__, "--child", kind, str(steps)],
        capture_output=True, text=True, check=True,
    )  # fmt: skip
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--long", default="100,500,1000")
    parser.add_argument("--child", nargs=2, metavar=("KIND", "STEPS"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child(args.child[0], int(args.child[1]))
        return
    print(f"load average before: {os.getloadavg()}")
    kinds: tuple[str, ...] = ("run", "run --video", "run --rerun", "record")
    if missing_modules(["rerun"]):
        kinds = tuple(k for k in kinds if k != "run --rerun")
    rates: dict[str, list[float]] = {k: [] for k in kinds}
    cpu_rates: dict[str, list[float]] = {k: [] for k in kinds}
    with tempfile.TemporaryDirectory() as folder:
        run_plain(20)  # warm-up: imports, PyBullet
        for i in range(args.repeats):
            for kind in kinds:
                wall, cpu = timed(kind, args.steps, Path(folder), i)
                rates[kind].append(wall)
                cpu_rates[kind].append(cpu)
    plain = statistics.median(rates["run"])
    print(f"\nspeed: {args.steps}-step episodes, median of {args.repeats}")
    plain_cpu = statistics.median(cpu_rates["run"])
    print(f"{'':<14}{'steps/s':>9}{'ratio':>8}{'steps/CPU s':>13}{'ratio':>8}")
    for kind in kinds:
        median, cpu = statistics.median(rates[kind]), statistics.median(cpu_rates[kind])
        print(f"{kind:<14}{median:>9.1f}{median / plain:>8.2f}{cpu:>13.1f}{cpu / plain_cpu:>8.2f}")
    print("\nmemory: one episode in a fresh process (MiB)")
    print(f"{'steps':>6}{'run RSS':>10}{'record RSS':>12}{'run heap':>10}{'record heap':>13}")
    for steps in (int(s) for s in args.long.split(",") if s.strip()):
        run, rec = peaks("run", steps), peaks("record", steps)
        print(
            f"{steps:>6}{run['rss_mib']:>10.1f}{rec['rss_mib']:>12.1f}"
            f"{run['heap_mib']:>10.1f}{rec['heap_mib']:>13.1f}"
        )
    print(f"\nload average after: {os.getloadavg()}")


if __name__ == "__main__":
    main()
