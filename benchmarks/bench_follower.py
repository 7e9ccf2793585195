"""TargetFollower-v0 speed: rendering per frame (the scene as built, with the occluder
filling the view, and with a ground plane added for comparison), env steps per obs_mode,
the detector, and the observer pipeline's filter step.

    python benchmarks/bench_follower.py
"""

from __future__ import annotations

import time

import gymnasium as gym
import numpy as np

import observer_gym.envs  # noqa: F401  (registers the envs)
from observer_gym.estimation import VisionObserver
from observer_gym.estimation.target_follower.detector import TargetFollowerDetector
from observer_gym.train.reports.outputs import format_table

ENV_ID = "observer_gym/TargetFollower-v0"
REPEATS = 200


def _per_call_ms(fn, repeats: int = REPEATS) -> float:
    fn()  # warm-up
    tic = time.perf_counter()
    for _ in range(repeats):
        fn()
    return 1e3 * (time.perf_counter() - tic) / repeats


def render_rows() -> list[list[str]]:
    env = gym.make(ENV_ID, obs_mode="rgb", target_motion="static")
    base = env.unwrapped
    rows = []
    try:
        env.reset(seed=0)
        pose = base.scene.camera_pose()
        rows.append(
            ["render: target only (as built)", _per_call_ms(lambda: base.camera.render(pose))]
        )
        env.reset(seed=0, options={"occlusions_s": (0.0,)})
        for _ in range(20):
            env.step(np.zeros(3, np.float32))
        pose = base.scene.camera_pose()
        rows.append(
            ["render: occluder filling the view", _per_call_ms(lambda: base.camera.render(pose))]
        )
        env.reset(seed=0)
        base.sim.client.loadURDF("plane.urdf")
        base.scene.tilt_rad = -0.3  # look down at the floor ahead
        tilted = base.scene.camera_pose()
        rows.append(
            [
                "render: + ground plane, camera tilted down 0.3 rad",
                _per_call_ms(lambda: base.camera.render(tilted)),
            ]
        )
    finally:
        env.close()
    return [[name, f"{ms:.2f}"] for name, ms in rows]


def step_rows() -> list[list[str]]:
    rows = []
    for mode in ("state", "measurements", "rgb"):
        env = gym.make(ENV_ID, obs_mode=mode, max_episode_steps=10**6)
        env.reset(seed=0)
        rows.append(
            [
                f"env.step, obs_mode={mode}",
                _per_call_ms(lambda e=env: e.step(np.zeros(3, np.float32))),
            ]
        )
        env.close()
    for mode in ("measurements", "rgb"):
        env = VisionObserver(gym.make(ENV_ID, obs_mode=mode, max_episode_steps=10**6))
        env.reset(seed=0)
        rows.append(
            [
                f"VisionObserver(stkf).step, {mode}",
                _per_call_ms(lambda e=env: e.step(np.zeros(3, np.float32))),
            ]
        )
        env.close()
    env = gym.make(ENV_ID, obs_mode="rgb")
    obs, info = env.reset(seed=0)
    detector = TargetFollowerDetector()
    rows.append(
        ["detector on one frame", _per_call_ms(lambda: detector.detect(obs, info["camera"]["K"]))]
    )
    env.close()
    return [[name, f"{ms:.2f}"] for name, ms in rows]


def main() -> None:
    print("TargetFollower-v0, 320x240, TinyRenderer, ms per call (mean of 200)")
    print(format_table(["what", "ms"], render_rows() + step_rows()))


if __name__ == "__main__":
    main()
