"""MPC solve time per step (OSQP), at horizons 20 and 50, on one core.

Runs BallTable-v0 closed loop with the true state (obs_mode="state") and the MPC
controller from the env's random starts, and records OSQP's own solve time
(``result.info.solve_time``: the warm-started solve, setup excluded) and the wall time of
the controller's whole ``predict`` call, per step. Prints median and 99th percentile per
horizon, beside the LQR's predict time and the 20 ms frame period. Target: median solve
<= 1 ms at horizon 20.

    python benchmarks/bench_mpc.py [--episodes 4] [--steps 250]
"""

from __future__ import annotations

import argparse
import os
import time

import gymnasium as gym
import numpy as np

import observer_gym.envs  # noqa: F401  (registers the envs)
from observer_gym.controllers import make_controller

ENV_ID = "observer_gym/BallTable-v0"
HORIZONS = (20, 50)
TARGET_MEDIAN_MS = 1.0


def rollout_times(controller, env, episodes: int, steps: int):
    """(solver seconds, predict seconds, failures) per step over the episodes."""
    solve_s, predict_s = [], []
    for episode in range(episodes):
        obs, _ = env.reset(seed=episode)
        controller.reset()
        for _ in range(steps):
            start = time.perf_counter()
            action, _ = controller.predict(obs)
            predict_s.append(time.perf_counter() - start)
            solve_s.append(getattr(controller, "last_solve_time_s", np.nan))
            obs, _, terminated, truncated, _ = env.step(action)
            if terminated or truncated:
                break
    return np.array(solve_s), np.array(predict_s), getattr(controller, "failures", 0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=4)
    parser.add_argument("--steps", type=int, default=250)
    args = parser.parse_args()
    os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})

    env = gym.make(ENV_ID, obs_mode="state")
    frame_ms = env.unwrapped.config.dt_s * 1e3
    rows = []
    lqr = make_controller("lqr", env)
    _, lqr_predict, _ = rollout_times(lqr, env, args.episodes, args.steps)
    rows.append(("lqr", np.nan, np.nan, np.median(lqr_predict), 0))
    medians = {}
    for horizon in HORIZONS:
        mpc = make_controller("mpc", env, horizon=horizon)
        solve, predict, failures = rollout_times(mpc, env, args.episodes, args.steps)
        medians[horizon] = np.median(solve) * 1e3
        rows.append(
            (
                f"mpc N={horizon}",
                np.median(solve),
                np.percentile(solve, 99),
                np.median(predict),
                failures,
            )
        )
    env.close()

    print(f"BallTable-v0 controllers, {args.episodes} episodes x {args.steps} steps, one core")
    header = ("controller", "solve med ms", "solve p99 ms", "predict med ms", "failures")
    print(f"{header[0]:12s} {header[1]:>13s} {header[2]:>13s} {header[3]:>15s} {header[4]:>9s}")
    for name, med, p99, pred, failures in rows:
        solve = (
            f"{med * 1e3:13.3f} {p99 * 1e3:13.3f}" if np.isfinite(med) else f"{'-':>13s} {'-':>13s}"
        )
        print(f"{name:12s} {solve} {pred * 1e3:15.3f} {failures:9d}")
    print(
        f"frame period {frame_ms:.0f} ms; horizon 20 median solve {medians[20]:.3f} ms "
        f"(target <= {TARGET_MEDIAN_MS} ms), {frame_ms / medians[20]:.0f}x inside the frame"
    )
    print(f"horizon 50 / horizon 20 median solve: {medians[50] / medians[20]:.2f}")


if __name__ == "__main__":
    main()
