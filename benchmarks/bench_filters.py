"""Kalman-filter step time on one core: ours, filterpy's, and the steady-state path.

The model is BallTable's rolling ball (RollingBallModel: 6 states, 2 measurements, 20 ms),
with the gravity input. One step = predict + update. Each filter runs in blocks of
``--block`` steps, the filters taking turns for ``--rounds`` rounds so that clock and cache
drift hit them alike; the table gives the median step time. Targets: ours <= 0.7 x
filterpy (with Joseph form, symmetrisation and the positive-definiteness check that
filterpy does not do); steady-state path <= 5 us.

    python benchmarks/bench_filters.py [--rounds 40] [--block 500]
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Callable

import filterpy
import numpy as np
from filterpy.kalman import KalmanFilter as FilterpyKalmanFilter

from observer_gym.envs.ball_table.geometry import up_in_table
from observer_gym.estimation.ball_table.models import RollingBallModel
from observer_gym.estimation.filters import KalmanFilter
from observer_gym.estimation.steady_state import SteadyStateKalmanFilter

DT_S = 0.02
RATIO_TARGET = 0.7
STEADY_STATE_TARGET_US = 5.0


def _workload(steps: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Inputs (steps, 2) for a wobbling table and noisy position measurements (steps, 2)."""
    rng = np.random.default_rng(seed)
    t = DT_S * np.arange(steps)
    us = np.array(
        [
            RollingBallModel.gravity_acceleration(up_in_table(0.05 * np.sin(tk), 0.05 * np.cos(tk)))
            for tk in t
        ]
    )
    ys = rng.normal(scale=0.05, size=(steps, 2))
    return us, ys


def _steppers(model: RollingBallModel) -> dict[str, Callable[[np.ndarray, np.ndarray], None]]:
    Phi, Gamma, Q = model.matrices(DT_S)
    C, R = model.C, model.R
    x0, P0 = np.zeros(6), np.diag([1e-4, 1e-4, 1e-2, 1e-2, 1.0, 1.0])

    ours = KalmanFilter(x0, P0)

    def ours_step(u: np.ndarray, y: np.ndarray) -> None:
        ours.predict(Phi, Q, Gamma, u)
        ours.update(y, C, R)

    fp = FilterpyKalmanFilter(dim_x=6, dim_z=2, dim_u=2)
    fp.x, fp.P = x0.reshape(6, 1).copy(), P0.copy()
    fp.F, fp.B, fp.Q, fp.H, fp.R = (np.array(a) for a in (Phi, Gamma, Q, C, R))

    def filterpy_step(u: np.ndarray, y: np.ndarray) -> None:
        fp.predict(u.reshape(2, 1))
        fp.update(y)

    ss = SteadyStateKalmanFilter.from_model(x0, Phi, C, Q, R)

    def steady_step(u: np.ndarray, y: np.ndarray) -> None:
        ss.predict(Phi, Gamma, u)
        ss.update(y)

    return {"ours": ours_step, "filterpy": filterpy_step, "steady": steady_step}


def measure(rounds: int, block: int) -> dict[str, float]:
    """Median predict + update time per filter, microseconds."""
    steppers = _steppers(RollingBallModel())
    us, ys = _workload(block)
    clock = time.perf_counter
    samples: dict[str, list[float]] = {name: [] for name in steppers}
    for _ in range(rounds):
        for name, step in steppers.items():
            times = samples[name]
            for u, y in zip(us, ys, strict=True):
                start = clock()
                step(u, y)
                times.append(clock() - start)
    return {name: 1e6 * float(np.median(times)) for name, times in samples.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=40, help="turns each filter takes")
    parser.add_argument("--block", type=int, default=500, help="steps per turn")
    args = parser.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})  # one core

    t = measure(args.rounds, args.block)
    ratio = t["ours"] / t["filterpy"]
    print(
        f"Rolling-ball model: 6 states, 2 measurements; median of "
        f"{args.rounds * args.block} predict + update steps, one core; "
        f"numpy {np.__version__}, filterpy {filterpy.__version__}"
    )
    rows = [
        ("observer_gym KalmanFilter (Joseph, symmetrised, PD check)", t["ours"], ""),
        ("filterpy.kalman.KalmanFilter (Joseph)", t["filterpy"], ""),
        (
            "ratio ours / filterpy",
            ratio,
            f"target <= {RATIO_TARGET}: {'met' if ratio <= RATIO_TARGET else 'MISSED'}",
        ),
        (
            "observer_gym SteadyStateKalmanFilter",
            t["steady"],
            f"target <= {STEADY_STATE_TARGET_US} us: "
            f"{'met' if t['steady'] <= STEADY_STATE_TARGET_US else 'MISSED'}",
        ),
    ]
    print(f"{'filter':58s} {'us/step':>8s}  check")
    for name, value, check in rows:
        unit = f"{value:8.3f}" if name.startswith("ratio") else f"{value:8.2f}"
        print(f"{name:58s} {unit}  {check}")


if __name__ == "__main__":
    main()
