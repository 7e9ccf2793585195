"""BallTable-v0 plant figures: the rolling ball against 5/7 g sin(theta), and the arm's
response to a tilt step (what tests/envs/test_ball_table_physics.py bounds).

    python benchmarks/quality_ball_table.py
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np

import observer_gym.envs  # noqa: F401  (registers the envs)
from observer_gym.envs.ball_table import StateIndex
from observer_gym.envs.sim import GRAVITY_MPS2

ENV_ID = "observer_gym/BallTable-v0"
LEVEL = {"ball_pos_table_m": (0.0, 0.0), "ball_vel_table_mps": (0.0, 0.0)}


def incline_acceleration(env, axis: int, tilt_rad: float) -> tuple[float, float]:
    """(measured, 5/7 g sin(theta)) acceleration down a held incline, m/s^2."""
    command = np.zeros(2, np.float32)
    command[axis] = tilt_rad
    env.reset(seed=0, options=LEVEL)
    for _ in range(30):
        env.step(command)
    slope = np.array([0.0, -1.0]) if axis == 0 else np.array([1.0, 0.0])
    env.unwrapped.scene.place_ball(-0.1 * slope, (0.0, 0.0))
    dt_s = env.unwrapped.config.dt_s
    t, s, theta = [], [], []
    for k in range(1, 16):
        state = env.step(command)[4]["state"]
        t.append(k * dt_s)
        s.append(state[0:2] @ slope)
        theta.append(state[StateIndex.TILT_X + axis])
    measured = 2.0 * np.polyfit(t, s, 2)[0]
    return measured, 5.0 / 7.0 * GRAVITY_MPS2 * np.sin(np.mean(theta))


def step_response(env, axis: int, step_rad: float = 0.05) -> dict[str, float]:
    command = np.zeros(2, np.float32)
    command[axis] = step_rad
    env.reset(seed=0, options=LEVEL)
    dt_s = env.unwrapped.config.dt_s
    tilt = np.array([env.step(command)[4]["state"][StateIndex.TILT_X + axis] for _ in range(50)])
    outside = np.nonzero(np.abs(tilt - step_rad) > 0.05 * step_rad)[0]
    reached = np.nonzero(tilt >= (1 - np.exp(-1)) * step_rad)[0]
    return {
        "63% rise (s)": (reached[0] + 1) * dt_s if len(reached) else np.nan,
        "5% settling (s)": (outside[-1] + 1) * dt_s if len(outside) else 0.0,
        "steady error (rad)": abs(np.mean(tilt[-10:]) - step_rad),
        "overshoot (%)": 100.0 * max(tilt.max() - step_rad, 0.0) / step_rad,
    }


def main() -> None:
    env = gym.make(ENV_ID, obs_mode="state")
    print(f"{ENV_ID}: ball on a held incline (fit over 0.3 s)")
    print("| axis | tilt (rad) | measured (m/s^2) | 5/7 g sin(theta) | ratio |")
    print("|---|---|---|---|---|")
    for axis, name in ((0, "x"), (1, "y")):
        for tilt_rad in (0.05, 0.1):
            measured, expected = incline_acceleration(env, axis, tilt_rad)
            print(
                f"| {name} | {tilt_rad} | {measured:.4f} | {expected:.4f} "
                f"| {measured / expected:.4f} |"
            )
    print("\narm response to a 0.05 rad tilt step")
    rows = {name: step_response(env, axis) for axis, name in ((0, "tilt_x"), (1, "tilt_y"))}
    keys = list(next(iter(rows.values())))
    print("| axis | " + " | ".join(keys) + " |")
    print("|---|" + "---|" * len(keys))
    for name, row in rows.items():
        print(f"| {name} | " + " | ".join(f"{row[k]:.3g}" for k in keys) + " |")
    env.close()


if __name__ == "__main__":
    main()
