"""What one benchmark entry costs from the rendered frames against the perfect detector's
measurements, per system and level, in one process.

    .venv/bin/python benchmarks/benchmark_entry_cost.py --episodes 4

For each system it runs the first ``--episodes`` official seeds of every level of the
suite with the reference controller, through ``kf-measurements`` (no rendering) and
through ``kf`` (the camera renders every frame and the detector reads it), one episode
after another in this process (``time.process_time``: CPU seconds, so other jobs on the
machine slow the wall clock, not the figure), and prints the CPU seconds per episode,
the ratio rgb / measurements measured in this run, and the projection to an official
run (the level's mean times the suite's episode count, summed over the levels).
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from observer_gym.train.experiments.benchmark.run import check_benchmark
from observer_gym.train.experiments.benchmark.suite import load_suite
from observer_gym.train.experiments.sweep import sweep_episode

SYSTEMS = ("BallTable-v0", "BallCatcher-v1", "TargetFollower-v0")
OBSERVERS = ("kf-measurements", "kf")


def episode_cpu_s(env_id: str, observer: str, level_name: str, episodes: int) -> list[float]:
    """CPU seconds of each of the level's first ``episodes`` episodes."""
    suite = load_suite(env_id)
    request = check_benchmark(env_id, observer, suite.controller, episodes=episodes)
    times = []
    for spec in request.specs(suite.level(level_name)):
        tic = time.process_time()
        sweep_episode(spec)
        times.append(time.process_time() - tic)
    return times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--episodes", type=int, default=4, help="seeds per level (default 4)")
    parser.add_argument("--env", action="append", choices=SYSTEMS, help="default: all three")
    args = parser.parse_args()
    print(f"load average at start: {os.getloadavg()[0]:.1f}", flush=True)
    print(
        "| system | level | kf-measurements (CPU s / episode) | kf from frames | ratio |",
        flush=True,
    )
    print("|---|---|---|---|---|", flush=True)
    projected: dict[str, dict[str, float]] = {}
    for env_id in args.env or SYSTEMS:
        suite = load_suite(env_id)
        projected[env_id] = dict.fromkeys(OBSERVERS, 0.0)
        for level in suite.levels:
            means = {}
            for observer in OBSERVERS:
                means[observer] = float(np.mean(episode_cpu_s(env_id, observer, level.name,
                                                              args.episodes)))  # fmt: skip
                projected[env_id][observer] += means[observer] * suite.episodes
            print(
                f"| {env_id} | {level.name} | {means['kf-measurements']:.3f} | "
                f"{means['kf']:.3f} | {means['kf'] / means['kf-measurements']:.1f} |",
                flush=True,
            )
    print()
    print("| system | official suite, kf-measurements (CPU min) | kf from frames (CPU min) |")
    print("|---|---|---|")
    for env_id, cost in projected.items():
        print(f"| {env_id} | {cost['kf-measurements'] / 60:.1f} | {cost['kf'] / 60:.1f} |")
    print(f"load average at end: {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
