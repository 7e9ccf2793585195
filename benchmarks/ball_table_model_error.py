"""The rolling-ball model's acceleration error on BallTable-v0, which sets the noise rule's
MODEL_ACCEL_STD_MPS2 (estimation/ball_table/noise.py):

    python benchmarks/ball_table_model_error.py [--seeds 10] [--steps 500]

The LQR on the true state, no pushes, ``seeds`` episodes of up to ``steps`` steps. Over each
20 ms step the ball's true acceleration in the table frame, (v(k+1) - v(k)) / dt, against
what ``kf``'s rolling model predicts given the true tilt: (5/7) g sin(tilt) at the
interval's mean tilt, and (``with rotation``) the table's angular acceleration h theta''
with the tilt rate from the arm's lag model, g (u - theta), at both ends
(RollingBallModel.rotation_increment). Prints the RMS and 99th percentile of |error| per
axis, with and without the rotation term.
"""

from __future__ import annotations

import argparse

import gymnasium as gym
import numpy as np

import observer_gym.envs  # noqa: F401  (registers the envs)
from observer_gym.controllers import make_controller
from observer_gym.envs.ball_table.geometry import up_in_table
from observer_gym.estimation.ball_table.models import RollingBallModel, TiltLagModel

ENV_ID = "observer_gym/BallTable-v0"


def model_errors(seeds: int, steps: int) -> tuple[np.ndarray, np.ndarray]:
    """(error without the rotation term, with it), each (n, 2) in m/s^2."""
    env = gym.make(ENV_ID, obs_mode="state")
    cfg = env.unwrapped.config
    lag = TiltLagModel.from_arm(cfg.arm_position_gain, cfg.physics_dt_s, 0.0)
    controller = make_controller("lqr", env)
    dt_s = cfg.dt_s
    plain, rotated = [], []
    for seed in range(seeds):
        _, info = env.reset(seed=seed)
        x, command = info["state"], np.zeros(2)
        for _ in range(steps):
            action, _ = controller.predict(np.asarray(x, np.float32))
            _, _, terminated, truncated, info = env.step(action)
            x_next, applied = info["state"], np.asarray(info["applied_action"], float)
            tilt0, tilt1 = x[4:6], x_next[4:6]
            gravity = RollingBallModel.gravity_acceleration(up_in_table(*(0.5 * (tilt0 + tilt1))))
            error = (x_next[2:4] - x[2:4]) / dt_s - gravity
            turned = RollingBallModel.rotation_increment(
                lag.rate(tilt0, command), lag.rate(tilt1, applied), tilt1 - tilt0, dt_s
            )
            plain.append(error)
            rotated.append(error - turned[2:4] / dt_s)
            x, command = x_next, applied
            if terminated or truncated:
                break
    env.close()
    return np.array(plain), np.array(rotated)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--steps", type=int, default=500)
    args = parser.parse_args()
    plain, rotated = model_errors(args.seeds, args.steps)
    print(f"{ENV_ID}: rolling model's acceleration error over {len(plain)} steps (m/s^2)")
    print("| model | RMS x | RMS y | 99th pct x | 99th pct y | lag-one corr x | y |")
    print("|---|---|---|---|---|---|---|")
    for name, err in (("5/7 g sin(tilt)", plain), ("with rotation", rotated)):
        rms = np.sqrt(np.mean(err**2, axis=0))
        p99 = np.percentile(np.abs(err), 99, axis=0)
        lag1 = [np.corrcoef(err[:-1, i], err[1:, i])[0, 1] for i in (0, 1)]
        print(
            f"| {name} | {rms[0]:.3f} | {rms[1]:.3f} | {p99[0]:.3f} | {p99[1]:.3f} "
            f"| {lag1[0]:.2f} | {lag1[1]:.2f} |"
        )


if __name__ == "__main__":
    main()
