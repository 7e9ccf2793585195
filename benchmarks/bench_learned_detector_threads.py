"""One frame through each learned detector on torch's default threads against one thread
(estimation/learned/network.py ``one_torch_thread``, what ``detect`` uses), idle and with
busy processes beside it:

    python benchmarks/bench_learned_detector_threads.py [--frames 40] [--busy 2]

Per system and load, the median time of one frame's network call (ms) on the default
thread count and on one thread, and their ratio, measured in this one run. ``--busy N``
starts N processes, each in a session of its own as another job would be, that spin
while the second half is measured (on a two-core machine, 2 stand for two other jobs),
and stops them after.
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import time
from collections.abc import Iterator
from contextlib import contextmanager

import gymnasium as gym
import numpy as np
import torch

import observer_gym.envs  # noqa: F401  (registers the envs)
from observer_gym.estimation.ball_catcher import learned_detector as ball_catcher
from observer_gym.estimation.ball_table import learned_detector as ball_table
from observer_gym.estimation.learned.frame_detector import LearnedDetector
from observer_gym.estimation.learned.heatmap_detector import LearnedPointDetector
from observer_gym.estimation.target_follower import learned_detector as target_follower

SYSTEMS = {  # env id -> (detector class, weights, the rgb observation's frame key or None)
    "observer_gym/BallTable-v0": (LearnedDetector, ball_table.WEIGHTS, None),
    "observer_gym/TargetFollower-v0": (LearnedDetector, target_follower.WEIGHTS, None),
    "observer_gym/BallCatcher-v1": (LearnedPointDetector, ball_catcher.WEIGHTS, "camera_0"),
}


def _spin() -> None:
    os.setsid()  # a session of its own, as another job's: the kernel's autogroups then
    # share the cores between it and this process as between two jobs
    while True:
        pass


@contextmanager
def busy(processes: int) -> Iterator[None]:
    """``processes`` spinning processes for the block's duration."""
    spinners = [multiprocessing.Process(target=_spin, daemon=True) for _ in range(processes)]
    for p in spinners:
        p.start()
    try:
        time.sleep(0.5)
        yield
    finally:
        for p in spinners:
            p.terminate()
            p.join()


def median_ms(detector, frame: np.ndarray, frames: int) -> float:
    """The median wall time of ``detector.detect(frame)`` over ``frames`` calls (ms)."""
    detector.detect(frame)  # warm-up
    times = []
    for _ in range(frames):
        tic = time.perf_counter()
        detector.detect(frame)
        times.append(time.perf_counter() - tic)
    return 1e3 * float(np.median(times))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=40)
    parser.add_argument("--busy", type=int, default=2)
    args = parser.parse_args()
    cases = []
    for env_id, (cls, weights, key) in SYSTEMS.items():
        detector = cls(weights)
        env = gym.make(env_id, obs_mode="rgb")
        obs, _ = env.reset(seed=0)
        env.close()
        frame = obs if key is None else obs[key]
        cases.append((env_id.split("/")[-1], detector, frame))
    print(f"torch {torch.__version__}, default threads {torch.get_num_threads()}")
    print("| system | load | default threads (ms) | one thread (ms) | ratio |")
    print("|---|---|---|---|---|")
    for load, processes in (("idle", 0), (f"{args.busy} busy", args.busy)):
        with busy(processes):
            for name, detector, frame in cases:
                one = median_ms(detector, frame, args.frames)
                # the same call with detect's one-thread context lifted
                detector.outputs = lambda x, d=detector: d.net(x)  # type: ignore[method-assign]
                with torch.no_grad():
                    default = median_ms(detector, frame, args.frames)
                del detector.outputs
                print(f"| {name} | {load} | {default:.2f} | {one:.2f} | {default / one:.1f}x |")


if __name__ == "__main__":
    main()
