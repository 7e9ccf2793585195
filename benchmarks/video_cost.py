"""What ``--video`` costs: steps per second with and without it, and the memory of a long
episode with it against without.

    .venv/bin/python benchmarks/video_cost.py                 # defaults below
    .venv/bin/python benchmarks/video_cost.py --steps 300 --repeats 5 --long 500,2000

One process, one run. BallTable-v0, observer kf (rgb frames, 50 Hz), controller lqr,
episodes through :func:`~observer_gym.train.experiments.episode.run_episode` (what
``observer-gym run`` runs), the video written into a temporary folder.

- **Speed**: ``--repeats`` pairs of one ``--steps``-step episode without and one with
  ``--video``, alternated so that a change of the machine's load touches both; the median
  steps per second of each, by the wall clock and by CPU time (this process's and its
  finished children's, ffmpeg's: less moved by the other programs on the machine). The
  load average (``os.getloadavg``) is printed before and after.
- **Memory**: for each episode length of ``--long``, the peak of the Python heap
  (``tracemalloc``: NumPy's arrays included) during the episode, without and with video.
  The episode's own record grows with its length either way (it keeps every step's
  info); the video's share, with minus without, stays the same however long the
  episode: the frames go to ffmpeg as they are drawn, none is kept. ffmpeg runs in a
  process of its own: its largest resident size (``getrusage(RUSAGE_CHILDREN)``) is
  printed too.
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import tempfile
import time
import tracemalloc
from pathlib import Path

from observer_gym.train.experiments.episode import EpisodeSpec, run_episode
from observer_gym.train.reports.video import VideoRequest

ENV = "observer_gym/BallTable-v0"


def spec(steps: int, folder: Path | None, name: str = "v") -> EpisodeSpec:
    video = None if folder is None else VideoRequest(str(folder), name)
    # the env's own time limit lifted so that a long episode is as long as asked
    return EpisodeSpec.of(
        ENV, "kf", "lqr", seed=0, max_steps=steps,
        env_kwargs={"max_episode_steps": steps + 1}, video=video,
    )  # fmt: skip


def cpu_s() -> float:
    """CPU seconds of this process and of its finished children (ffmpeg)."""
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + children.ru_utime + children.ru_stime


def steps_per_s(steps: int, folder: Path | None) -> tuple[float, float]:
    """Steps per wall-clock second and per CPU second (this process and ffmpeg's)."""
    tic, tic_cpu = time.perf_counter(), cpu_s()
    record = run_episode(spec(steps, folder))
    count = len(record["actions"])
    return count / (time.perf_counter() - tic), count / (cpu_s() - tic_cpu)


def peak_mib(steps: int, folder: Path | None) -> float:
    tracemalloc.start()
    try:
        run_episode(spec(steps, folder, f"long{steps}"))
        return tracemalloc.get_traced_memory()[1] / 2**20
    finally:
        tracemalloc.stop()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=300, help="steps of a speed episode")
    parser.add_argument("--repeats", type=int, default=3, help="speed pairs to take medians of")
    parser.add_argument(
        "--long",
        default="500,2000",
        help="episode lengths (steps) of the memory rows ('' for none)",
    )
    args = parser.parse_args()
    print(f"load average at the start: {os.getloadavg()}")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        steps_per_s(20, folder)  # warm up: imports, the renderer, ffmpeg's first start
        plain, filmed = [], []
        for _ in range(args.repeats):
            plain.append(steps_per_s(args.steps, None))
            filmed.append(steps_per_s(args.steps, folder))
        print(f"\nBallTable-v0, kf + lqr, {args.steps}-step episodes, median of {args.repeats}:")
        print("| run | steps/s (median) | each | steps per CPU s (median) | each |")
        print("|---|---|---|---|---|")
        medians = {}
        for name, runs in (("without --video", plain), ("with --video", filmed)):
            wall, cpu = [r[0] for r in runs], [r[1] for r in runs]
            medians[name] = (statistics.median(wall), statistics.median(cpu))
            print(
                f"| {name} | {medians[name][0]:.1f} | {', '.join(f'{x:.1f}' for x in wall)} "
                f"| {medians[name][1]:.1f} | {', '.join(f'{x:.1f}' for x in cpu)} |"
            )
        (a, a_cpu), (b, b_cpu) = medians["without --video"], medians["with --video"]
        print(f"with/without: {b / a:.2f} (wall clock), {b_cpu / a_cpu:.2f} (CPU)")

        print("\nPeak Python heap (tracemalloc) of one episode:")
        print("| steps | without (MiB) | with --video (MiB) | video's share (MiB) | MP4 (MB) |")
        print("|---|---|---|---|---|")
        for steps in (int(s) for s in args.long.split(",") if s.strip()):
            without = peak_mib(steps, None)
            with_video = peak_mib(steps, folder)
            size_mb = (folder / f"long{steps}.mp4").stat().st_size / 1e6
            print(
                f"| {steps} | {without:.1f} | {with_video:.1f} | {with_video - without:+.1f} "
                f"| {size_mb:.2f} |"
            )
    children_mib = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    print(f"\nffmpeg's largest resident size (children's max RSS): {children_mib:.0f} MiB")
    print(f"load average at the end: {os.getloadavg()}")


if __name__ == "__main__":
    main()
