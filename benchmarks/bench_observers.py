"""Cost per step of every observer of every system, on recorded frames, on one core.

    python benchmarks/bench_observers.py [--steps 300] [--rounds 5] [--obs-mode measurements]

For each system, one episode of ``--steps`` steps with uniform random actions (seed 0) is
recorded once in ``--obs-mode`` (measurements: the perfect detector's pixels; rgb: the
frames, so the cost includes the image stage), with the env's default sensor options
and ``--latency-s`` of latency. Then every observer of the system (the ``OBSERVERS`` of
``observer_gym.estimation.<system>``) replays the same recording: ``reset`` and one
``observe(obs, info, action)`` per step, timed with ``time.process_time`` around the
whole replay (the env is not in the time). Observers take turns every round; the table
gives the median over ``--rounds`` rounds of the time per step and its ratio to the
system's default observer measured in the same round (median of the rounds' ratios).
A step delivers at most one frame per camera (BallCatcher: two cameras at 50 Hz, 100 Hz
steps: one frame per step on average), so the time per step is the time per frame.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import gymnasium as gym
import numpy as np

import observer_gym.envs  # noqa: F401  (registers the envs)
from observer_gym.envs import SYSTEMS
from observer_gym.estimation import observers_of_system


def record(env_id: str, obs_mode: str, steps: int, latency_s: float) -> list[tuple]:
    """(obs, info, applied action or None) of a reset and ``steps`` random steps."""
    env = gym.make(env_id, obs_mode=obs_mode, latency_s=latency_s)
    try:
        env.action_space.seed(0)
        obs, info = env.reset(seed=0)
        samples = [(obs, info, None)]
        for _ in range(steps):
            obs, _, terminated, truncated, info = env.step(env.action_space.sample())
            samples.append((obs, info, np.asarray(info["applied_action"], dtype=float)))
            if terminated or truncated:
                break
        return samples
    finally:
        env.close()


def replay_s(pipeline, samples: list[tuple]) -> float:
    """CPU seconds of one reset + observe over ``samples``."""
    tic = time.process_time()
    pipeline.reset()
    for obs, info, action in samples:
        pipeline.observe(obs, info, action)
    return time.process_time() - tic


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--obs-mode", choices=("measurements", "rgb"), default="measurements")
    parser.add_argument("--latency-s", type=float, default=0.0)
    parser.add_argument("--cpu", type=int, default=0, help="the core to pin to")
    args = parser.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {args.cpu})
    load_start = os.getloadavg()
    print(
        f"obs_mode {args.obs_mode}, latency {args.latency_s * 1e3:.0f} ms, {args.steps} "
        f"steps, {args.rounds} rounds, one core [{args.cpu}]; CPU time per step (median of "
        "rounds) and its ratio to the default observer (median of the rounds' ratios)\n"
    )
    print("| env | observer | us per step | x default | steps |")
    print("|---|---|---|---|---|")
    for system in SYSTEMS:
        samples = record(system.env_id, args.obs_mode, args.steps, args.latency_s)
        env = gym.make(system.env_id, obs_mode=args.obs_mode, latency_s=args.latency_s)
        try:
            factories = observers_of_system(system)
            pipelines = {name: make(env.unwrapped) for name, make in factories.items()}
            default = next(iter(pipelines))
            for pipeline in pipelines.values():  # warm-up: caches, lazy imports
                replay_s(pipeline, samples[:20])
            times = {name: [] for name in pipelines}
            ratios = {name: [] for name in pipelines}
            for r in range(args.rounds):
                order = list(pipelines) if r % 2 == 0 else list(reversed(pipelines))
                this_round = {name: replay_s(pipelines[name], samples) for name in order}
                for name, t in this_round.items():
                    times[name].append(t / len(samples))
                    ratios[name].append(t / this_round[default])
            for name in pipelines:
                print(
                    f"| {system.short_id} | {name} | {statistics.median(times[name]) * 1e6:.0f} "
                    f"| {statistics.median(ratios[name]):.2f} | {len(samples)} |"
                )
        finally:
            env.close()
    print(f"\nload average (1, 5, 15 min): start {load_start}, end {os.getloadavg()}")


if __name__ == "__main__":
    main()
