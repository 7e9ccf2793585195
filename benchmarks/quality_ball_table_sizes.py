"""BallTable's classical detector against the frame size: each size's detection rate and
the errors of the detector and of an observer's estimate, in closed loop.

Per size, ``VisionObserver(gym.make("observer_gym/BallTable-v0", obs_mode="rgb",
image_width_px=W, image_height_px=H), observer=...)`` under the LQR on the estimate
(``make_controller("lqr", env)``), seeds 0, 1, ... for ``--steps`` steps each: the share
of new frames whose table and ball the detector found, the RMSE of the detected ball
position on the table (not for ``ekf``, which takes the image stage's pixels), and the
RMSE of the estimate's ball position and tilt against ``info["state"]`` over every step
(tests/estimation/test_ball_table_small_frames.py bounds the rows up to 160 x 120).

    python benchmarks/quality_ball_table_sizes.py [--sizes 84x84 120x90 160x120 240x180 320x240]
        [--seeds 2] [--steps 150] [--observer kf]
"""

from __future__ import annotations

import argparse

import gymnasium as gym
import numpy as np

import observer_gym.envs  # noqa: F401  (registers the envs)
from observer_gym.controllers import make_controller
from observer_gym.estimation import VisionObserver
from observer_gym.estimation.ball_table.features import BallTableFeatures

SIZES = ("84x84", "120x90", "160x120", "240x180", "320x240")


def measure(
    width_px: int, height_px: int, seeds: int = 2, steps: int = 150, observer: str = "kf"
) -> dict[str, float]:
    """The size's figures (see the module docstring): ``frames`` (new frames),
    ``table_rate`` and ``ball_rate`` (their shares found), ``detected_ball_rmse_m``,
    ``ball_rmse_m`` and ``tilt_rmse_rad`` (the estimate's, over every step)."""
    ball_errors, tilt_errors, detected_errors = [], [], []
    frames = tables = balls = 0
    for seed in range(seeds):
        env = VisionObserver(
            gym.make(
                "observer_gym/BallTable-v0",
                obs_mode="rgb",
                image_width_px=width_px,
                image_height_px=height_px,
            ),
            observer=observer,
        )
        try:
            controller = make_controller("lqr", env)
            obs, info = env.reset(seed=seed)
            for _ in range(steps):
                action, _ = controller.predict(obs, deterministic=True)
                obs, _, terminated, truncated, info = env.step(action)
                mean, state = info["estimate"]["mean"], info["state"]
                ball_errors.append(mean[0:2] - state[0:2])
                tilt_errors.append(mean[4:6] - state[4:6])
                detection = info["estimate"]["measurement"]
                if isinstance(detection, BallTableFeatures):  # ekf: the image stage's pixels
                    frames += 1
                    tables += detection.corners_px is not None
                    balls += detection.ball_px is not None
                elif detection is not None:
                    frames += 1
                    tables += detection.table_found
                    balls += detection.ball_found
                    if detection.ball_found:
                        detected_errors.append(detection.ball_pos_table_m - state[0:2])
                if terminated or truncated:
                    break
        finally:
            env.close()
    ball, tilt = np.array(ball_errors), np.array(tilt_errors)
    detected = np.array(detected_errors).reshape(-1, 2)
    return {
        "frames": frames,
        "table_rate": tables / max(frames, 1),
        "ball_rate": balls / max(frames, 1),
        "detected_ball_rmse_m": float(np.sqrt(np.mean(np.sum(detected**2, axis=1))))
        if len(detected)
        else float("nan"),
        "ball_rmse_m": float(np.sqrt(np.mean(np.sum(ball**2, axis=1)))),
        "tilt_rmse_rad": float(np.sqrt(np.mean(tilt**2))),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", nargs="+", default=list(SIZES), help="WxH, e.g. 84x84")
    parser.add_argument("--seeds", type=int, default=2)
    parser.add_argument("--steps", type=int, default=150)
    parser.add_argument("--observer", default="kf")
    args = parser.parse_args()
    print(
        f"BallTable-v0, rgb, {args.observer} + lqr, seeds 0-{args.seeds - 1} x {args.steps} steps"
    )
    print(
        "| frame (px) | frames | table found | ball found | detected ball RMSE (mm) "
        "| estimate: ball RMSE (mm) | tilt RMSE (mrad) |"
    )
    print("|---|---|---|---|---|---|---|")
    for size in args.sizes:
        width_px, height_px = (int(n) for n in size.lower().split("x"))
        row = measure(width_px, height_px, args.seeds, args.steps, args.observer)
        detected_mm = 1e3 * row["detected_ball_rmse_m"]
        print(
            f"| {width_px} x {height_px} | {row['frames']} | {row['table_rate']:.1%} "
            f"| {row['ball_rate']:.1%} | {'-' if np.isnan(detected_mm) else f'{detected_mm:.2f}'} "
            f"| {1e3 * row['ball_rmse_m']:.2f} | {1e3 * row['tilt_rmse_rad']:.2f} |"
        )


if __name__ == "__main__":
    main()
