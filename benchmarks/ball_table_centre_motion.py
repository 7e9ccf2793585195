"""How far the arm lets BallTable-v0's table centre move from its home, which sets the
pixel EKF's table-translation noise (estimation/ball_table/pixel_ekf.py,
TABLE_CENTRE_STEP_STD_M and TABLE_CENTRE_HOLD_STD_M):

    python benchmarks/ball_table_centre_motion.py [--seeds 10] [--steps 500] [--push-rate-hz 0.5]

The LQR on the true state with pushes on the ball, ``seeds`` episodes of up to ``steps``
steps. The arm is commanded to tilt the table about a fixed centre
(envs/ball_table/scene.py), but its joints lag, so the true centre (the simulator's table
pose) wanders. Prints, per world axis, the RMS and largest offset of the centre from
TABLE_CENTRE_HOME_WORLD and the RMS and 99th percentile of its change over one env step
(the random walk's per-step std), and the offset's lag-one correlation.
"""

from __future__ import annotations

import argparse

import gymnasium as gym
import numpy as np

import observer_gym.envs  # noqa: F401  (registers the envs)
from observer_gym.controllers import make_controller
from observer_gym.envs.ball_table.geometry import TABLE_CENTRE_HOME_WORLD

ENV_ID = "observer_gym/BallTable-v0"


def centre_offsets(seeds: int, steps: int, push_rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """(the centre's offsets from home after each step, their changes over the step), each
    (n, 3) in m, world frame."""
    env = gym.make(ENV_ID, obs_mode="state", push_rate_hz=push_rate_hz)
    scene = env.unwrapped.scene
    controller = make_controller("lqr", env)
    offsets, changes = [], []
    for seed in range(seeds):
        _, info = env.reset(seed=seed)
        before = scene.table_pose()[:3, 3] - TABLE_CENTRE_HOME_WORLD
        for _ in range(steps):
            action, _ = controller.predict(np.asarray(info["state"], np.float32))
            _, _, terminated, truncated, info = env.step(action)
            offset = scene.table_pose()[:3, 3] - TABLE_CENTRE_HOME_WORLD
            offsets.append(offset)
            changes.append(offset - before)
            before = offset
            if terminated or truncated:
                break
    env.close()
    return np.array(offsets), np.array(changes)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--steps", type=int, default=500)
    parser.add_argument("--push-rate-hz", type=float, default=0.5)
    args = parser.parse_args()
    offsets, changes = centre_offsets(args.seeds, args.steps, args.push_rate_hz)
    print(
        f"{ENV_ID}: the table centre's offset from home over {len(offsets)} steps "
        f"(pushes at {args.push_rate_hz} Hz; mm)"
    )
    print(
        "| axis | offset RMS | offset max | step change RMS | step change 99th pct | lag-one corr |"
    )
    print("|---|---|---|---|---|---|")
    for i, axis in enumerate("xyz"):
        o, c = offsets[:, i] * 1e3, changes[:, i] * 1e3
        print(
            f"| {axis} | {np.sqrt(np.mean(o**2)):.4f} | {np.max(np.abs(o)):.3f} "
            f"| {np.sqrt(np.mean(c**2)):.4f} | {np.percentile(np.abs(c), 99):.4f} "
            f"| {np.corrcoef(o[:-1], o[1:])[0, 1]:.2f} |"
        )


if __name__ == "__main__":
    main()
