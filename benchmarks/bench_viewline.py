"""Viewline Kalman filter cost per frame on one core (docs/spec/catcher.md; the paper's
detection took < 4 ms per image, so the filter is a small share of the observer's cost).

Workload: throws seen by the two rig cameras of
observer_gym.estimation.ball_catcher.synthetic_throws (656 x 480, alternating every 20 ms,
0.5 px noise), the filter gated (p = 3.5). Cases:

- add_frame: one frame, exact Phi, Gamma, R1 to its capture time, two viewline rows.
- add_frames_at_tick, 2 frames: the paper's stacked form, four rows with offsets (26).
- late frame, 1 later frame redone: camera 2's frames arrive after camera 1's next one,
  so each costs a roll-back, its own update and the re-filter of one later frame.
- predicted(t): the estimate at a control tick, the filter unchanged.

The cases take turns for ``--rounds`` rounds of ``--throws`` throws x 24 frames; the table
gives the median time per call.

    python benchmarks/bench_viewline.py [--rounds 20] [--throws 10]
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Callable

import numpy as np

from observer_gym.estimation.ball_catcher import synthetic_throws as st
from observer_gym.estimation.ball_catcher.filters import ViewlineKalmanFilter
from observer_gym.estimation.viewline import CameraFrame

PAPER_DETECTION_MS = 4.0  # the paper: image processing < 4 ms per image


def _new_filter() -> ViewlineKalmanFilter:
    return ViewlineKalmanFilter(st.PAPER_X0, st.PAPER_P0, accel_noise_std=0.05)


def _frames(throws: int) -> list[list[st.SyntheticFrame]]:
    rng = np.random.default_rng(0)
    out = []
    for _ in range(throws):
        frames = st.alternating_frames(st.random_throw(rng), 24, rng)
        out.append([f for f in frames if f.uv_px is not None])
    return out


def _case_add_frame(frames, times: list[float]) -> None:
    kf, clock = _new_filter(), time.perf_counter
    for f in frames:
        start = clock()
        kf.add_frame(f.capture_time_s, f.K, f.T_world_cam, f.uv_px)
        times.append(clock() - start)


def _case_tick(frames, times: list[float]) -> None:
    kf, clock = _new_filter(), time.perf_counter
    pairs = [frames[i : i + 2] for i in range(0, len(frames) - 1, 2)]
    for pair in pairs:
        tick_s = pair[-1].capture_time_s + 0.005
        stack = [CameraFrame(f.capture_time_s, f.K, f.T_world_cam, f.uv_px) for f in pair]
        start = clock()
        kf.add_frames_at_tick(tick_s, stack)
        times.append(clock() - start)


def _case_late(frames, times: list[float]) -> None:
    kf, clock = _new_filter(), time.perf_counter
    # Deliver each even frame after the next odd one: the even one is late by one frame.
    order = []
    for i in range(0, len(frames) - 1, 2):
        order += [frames[i + 1], frames[i]]
    for j, f in enumerate(order):
        start = clock()
        kf.add_frame(f.capture_time_s, f.K, f.T_world_cam, f.uv_px)
        elapsed = clock() - start
        if j % 2 == 1:  # the late one
            times.append(elapsed)


def _case_predicted(frames, times: list[float]) -> None:
    kf, clock = _new_filter(), time.perf_counter
    for f in frames:
        kf.add_frame(f.capture_time_s, f.K, f.T_world_cam, f.uv_px)
        start = clock()
        kf.predicted(f.capture_time_s + 0.01)
        times.append(clock() - start)


CASES: dict[str, Callable] = {
    "add_frame (1 frame, exact Phi/Gamma/R1, 2 rows)": _case_add_frame,
    "add_frames_at_tick (2 frames, 4 offset rows) per tick": _case_tick,
    "late frame (roll back, update, redo 1 later frame)": _case_late,
    "predicted(t) (estimate at a tick, filter unchanged)": _case_predicted,
}


def measure(rounds: int, throws: int) -> dict[str, float]:
    """Median time per call of each case, microseconds."""
    workload = _frames(throws)
    samples: dict[str, list[float]] = {name: [] for name in CASES}
    for _ in range(rounds):
        for name, case in CASES.items():
            for frames in workload:
                case(frames, samples[name])
    return {name: 1e6 * float(np.median(t)) for name, t in samples.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=20, help="turns each case takes")
    parser.add_argument("--throws", type=int, default=10, help="throws (24 frames) per turn")
    args = parser.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})  # one core

    t = measure(args.rounds, args.throws)
    print(
        f"Viewline Kalman filter, two rig cameras, gated; median over {args.rounds} rounds x "
        f"{args.throws} throws x 24 frames, one core; numpy {np.__version__}"
    )
    print(f"{'case':56s} {'us/call':>8s}  {'share of 4 ms':>13s}")
    for name, us in t.items():
        print(f"{name:56s} {us:8.1f}  {100.0 * us / (1e3 * PAPER_DETECTION_MS):12.1f}%")
    print(f"(the paper's detection: < {PAPER_DETECTION_MS:.0f} ms per image)")


if __name__ == "__main__":
    main()
