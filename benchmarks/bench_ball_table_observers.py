"""Per-frame cost of each BallTable observer (estimation/ball_table: kf, kf-latency, ekf,
raw, oracle-visible) on one core, from rendered frames and from measurements.

Records episodes first (the ball circling under a PD law on the true state, the camera's
latency as given), then times only ``pipeline.observe`` frame by frame in episode order:
the median and the 90th percentile per frame of each observer, each on the same recorded
steps. From rgb the image stage (~0.4 ms, benchmarks/bench_detector.py) is in every
observer's time; ``kf-latency`` with latency rewinds and replays its filter every frame;
``kf`` under a declared calibration error (``--calib-rotation-deg``) re-linearises the
calibration's offset whenever a pixel moved by more than 0.5 px (estimation/ball_table/
noise.py, ``CALIBRATION_REUSE_PX``), for its tilt filter's offset states.

    python benchmarks/bench_ball_table_observers.py [--frames 400] [--latency-s 0.05] \
        [--calib-rotation-deg 0.5]
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import cv2
import gymnasium as gym
import numpy as np

import observer_gym.envs  # noqa: F401  (registers the envs)
from observer_gym.estimation import default_pipeline
from observer_gym.estimation.ball_table import OBSERVERS

EPISODE_FRAMES = 200


def circle_action(time_s: float, state: np.ndarray) -> np.ndarray:
    """A PD tilt law on the true state: the ball follows a 5 cm circle."""
    angle = 0.8 * time_s
    ref = 0.05 * np.array([np.cos(angle), np.sin(angle)])
    accel = 4.0 * (ref - state[0:2]) - 3.0 * state[2:4]
    gain = 5.0 / 7.0 * 9.81
    return np.clip([-accel[1] / gain, accel[0] / gain], -0.1, 0.1).astype(np.float32)


def record(obs_mode: str, frames: int, **options):
    """Episodes of (obs, info, action) steps, ``frames`` in all, and their env's config."""
    episodes, seed, total = [], 0, 0
    env = gym.make("observer_gym/BallTable-v0", obs_mode=obs_mode, **options)
    while total < frames:
        obs, info = env.reset(seed=seed)
        steps = [(obs, info, None)]
        for k in range(min(EPISODE_FRAMES, frames - total) - 1):
            obs, _, terminated, _, info = env.step(circle_action(k * 0.02, info["state"]))
            steps.append((obs, info, info["applied_action"]))
            if terminated:
                break
        episodes.append(steps)
        total += len(steps)
        seed += 1
    return episodes, env


def time_observer(name: str, env, episodes, repeats: int) -> np.ndarray:
    pipeline = default_pipeline(env, name)
    times = []
    for repeat in range(repeats + 1):  # the first pass warms the caches up
        for steps in episodes:
            pipeline.reset()
            for obs, info, action in steps:
                start = time.perf_counter()
                pipeline.observe(obs, info, action)
                if repeat:
                    times.append(time.perf_counter() - start)
    return np.array(times) * 1e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=400)
    parser.add_argument("--repeats", type=int, default=2, help="timed passes over the frames")
    parser.add_argument("--latency-s", type=float, default=0.05, help="for a second kf-latency row")
    parser.add_argument("--calib-rotation-deg", type=float, default=0.5, help="for a second kf row")
    args = parser.parse_args()
    os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
    cv2.setNumThreads(1)
    print(f"BallTable observers, {args.frames} frames per mode, one core ({platform.machine()})")
    print(f"{'mode':13s} {'observer':36s} {'median us':>10s} {'p90 us':>8s}")
    cases = [(mode, {}, name) for mode in ("measurements", "rgb") for name in OBSERVERS]
    latency = {"latency_s": args.latency_s}
    cases += [(mode, latency, "kf-latency") for mode in ("measurements", "rgb")]
    calibration = {"calib_rotation_error_deg": args.calib_rotation_deg}
    cases += [(mode, calibration, "kf") for mode in ("measurements", "rgb")]
    recorded: dict = {}
    for mode, options, name in cases:
        key = (mode, tuple(options.items()))
        if key not in recorded:
            recorded[key] = record(mode, args.frames, **options)
        episodes, env = recorded[key]
        times = time_observer(name, env.unwrapped, episodes, args.repeats)
        label = name + "".join(f" ({k} {v})" for k, v in options.items())
        print(f"{mode:13s} {label:36s} {np.median(times):10.1f} {np.percentile(times, 90):8.1f}")
    for _, env in recorded.values():
        env.close()


if __name__ == "__main__":
    main()
