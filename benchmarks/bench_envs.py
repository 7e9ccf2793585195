"""Env step throughput on one core, per obs_mode, against the engine's floor.

The floor is what any env built on this scene must pay per rgb step: the physics
substeps plus one bare ``getCameraImage`` of the same scene from the same camera. The
overhead ratio is (rgb step time) / (floor time), both measured in this run.

    python benchmarks/bench_envs.py [--steps 2000] [--rgb-steps 300]
"""

from __future__ import annotations

import argparse
import os
import time

import gymnasium as gym
import numpy as np
import pybullet

import observer_gym.envs  # noqa: F401  (registers the envs)
from observer_gym.envs.camera import gl_view_matrix


def steps_per_second(env: gym.Env, steps: int, seed: int = 0) -> float:
    env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    low, high = env.action_space.low, env.action_space.high
    actions = rng.uniform(low, high, size=(steps, *low.shape)).astype(np.float32)
    start = time.perf_counter()
    for action in actions:
        _, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            env.reset()
    return steps / (time.perf_counter() - start)


def floor_steps_per_second(env_id: str, steps: int) -> float:
    """Physics substeps plus one bare getCameraImage per step, same scene and camera."""
    env = gym.make(env_id, obs_mode="rgb")
    env.reset(seed=0)
    base = env.unwrapped
    client = base.sim.client
    intr = base.intrinsics
    view = gl_view_matrix(base.disturbances.camera_pose(0.0))
    projection = intr.gl_projection(0.05, 3.0)
    substeps = base.config.physics_substeps
    start = time.perf_counter()
    for _ in range(steps):
        for _ in range(substeps):
            client.stepSimulation()
        client.getCameraImage(
            intr.width_px,
            intr.height_px,
            viewMatrix=view,
            projectionMatrix=projection,
            renderer=pybullet.ER_TINY_RENDERER,
            flags=pybullet.ER_NO_SEGMENTATION_MASK,
            shadow=0,
        )
    rate = steps / (time.perf_counter() - start)
    env.close()
    return rate


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=3000, help="steps for state/measurements")
    parser.add_argument("--rgb-steps", type=int, default=300, help="steps for rgb and the floor")
    args = parser.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})  # one core

    env_id = "observer_gym/BallTable-v0"
    rows = []
    for mode, steps in (
        ("state", args.steps),
        ("measurements", args.steps),
        ("rgb", args.rgb_steps),
    ):
        env = gym.make(env_id, obs_mode=mode)
        rows.append((mode, steps_per_second(env, steps)))
        env.close()
    floor = floor_steps_per_second(env_id, args.rgb_steps)
    rgb = dict(rows)["rgb"]

    print(f"{env_id}, one core, 320x240 TinyRenderer frames, arm in view")
    print(f"| {'obs_mode':<26} | {'steps/s':>9} | {'ms/step':>8} |")
    print(f"|{'-' * 28}|{'-' * 11}|{'-' * 10}|")
    for mode, rate in [*rows, ("floor (physics + 1 render)", floor)]:
        print(f"| {mode:<26} | {rate:9.0f} | {1e3 / rate:8.3f} |")
    print(f"rgb overhead ratio (rgb step time / floor time): {floor / rgb:.3f}")


if __name__ == "__main__":
    main()
