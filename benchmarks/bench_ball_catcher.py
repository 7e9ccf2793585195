"""BallCatcher-v1 throughput and observer cost on one core.

- Env steps per second (10 ms steps, two cameras at 50 Hz, the box held still, episodes
  reset as they end) in each obs_mode, and the simulated time each wall second buys.
- The observer pipeline's cost per delivered frame (rgb: detector + viewline filter;
  measurements: the filter alone), timed around ``pipeline.observe`` only, beside the
  paper's "detection < 4 ms per image" (docs/spec/catcher.md).

    python benchmarks/bench_ball_catcher.py [--episodes 20]
"""

from __future__ import annotations

import argparse
import os
import time

import gymnasium as gym
import numpy as np

import observer_gym.envs  # noqa: F401  (registers the envs)
from observer_gym.estimation import VisionObserver
from observer_gym.train.reports.outputs import format_table

PAPER_DETECTION_MS = 4.0


def env_rate(obs_mode: str, episodes: int) -> tuple[float, float]:
    """(env steps per second, simulated seconds per wall second)."""
    env = gym.make("observer_gym/BallCatcher-v1", obs_mode=obs_mode)
    steps = 0
    zero = np.zeros(3, np.float32)
    start = time.perf_counter()
    for seed in range(episodes):
        env.reset(seed=seed)
        done = False
        while not done:
            _, _, terminated, truncated, _ = env.step(zero)
            steps += 1
            done = terminated or truncated
    wall_s = time.perf_counter() - start
    env.close()
    return steps / wall_s, steps * 0.01 / wall_s


def observer_cost_us(obs_mode: str, episodes: int) -> tuple[float, float, int]:
    """(median and 90th percentile per frame, us; frames timed): each step's observe()
    time divided by the frames it processed, over the steps that delivered frames."""
    env = VisionObserver(gym.make("observer_gym/BallCatcher-v1", obs_mode=obs_mode))
    pipeline = env.pipeline
    per_frame_us, frames = [], 0
    original = pipeline.observe

    def timed(obs, info, action):
        start = time.perf_counter()
        estimate = original(obs, info, action)
        elapsed = time.perf_counter() - start
        if info["frames"]:
            per_frame_us.append(1e6 * elapsed / len(info["frames"]))
        return estimate

    pipeline.observe = timed
    zero = np.zeros(3, np.float32)
    for seed in range(episodes):
        env.reset(seed=seed)
        done = False
        while not done:
            _, _, terminated, truncated, info = env.step(zero)
            frames += len(info["frames"])
            done = terminated or truncated
    env.close()
    return float(np.median(per_frame_us)), float(np.percentile(per_frame_us, 90)), frames


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=20)
    args = parser.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})  # one core

    rates = {mode: env_rate(mode, args.episodes) for mode in ("state", "measurements", "rgb")}
    base = rates["state"][0]
    print(f"BallCatcher-v1 env steps, {args.episodes} episodes per mode, one core\n")
    print(
        format_table(
            ["obs_mode", "steps/s", "simulated s per wall s", "vs state"],
            [
                [mode, f"{r:.0f}", f"{sim:.2f}", f"{r / base:.2f}x"]
                for mode, (r, sim) in rates.items()
            ],
        )
    )
    print("\nObserver pipeline per delivered frame (pipeline.observe only)\n")
    rows = []
    for mode in ("measurements", "rgb"):
        median, p90, frames = observer_cost_us(mode, args.episodes)
        rows.append(
            [
                mode,
                f"{median:.0f}",
                f"{p90:.0f}",
                str(frames),
                f"{median / 1e3 / PAPER_DETECTION_MS:.3f}",
            ]
        )
    print(
        format_table(["obs_mode", "median us", "p90 us", "frames", "median / paper's 4 ms"], rows)
    )


if __name__ == "__main__":
    main()
