"""What the BallCatcher learned observers' closed-loop tests (test_learned_ball_catcher.py
from measurements, test_learned_ball_catcher_frames.py from frames) share: the intercept
planner on an observer's estimate over a run of seeds, with the ball's estimate error and
NEES/dof over its free flight."""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import NamedTuple

import gymnasium as gym
import numpy as np

from observer_gym.controllers import make_controller
from observer_gym.envs.ball_catcher.layout import BALL
from observer_gym.estimation import VisionObserver

FROM_S = 0.1  # errors from this long after the launch (tasks/ball_catcher.py SETTLE_S)


class Throws(NamedTuple):
    errors: list[np.ndarray]  # per step: the ball's estimate error (position m, velocity m/s)
    nees_per_dof: list[float]  # per step: its NEES over the ball's six entries, per dof
    catches: int


def intercept_throws(
    make_env: Callable[[], gym.Env], observer: str, seeds: Iterable[int]
) -> Throws:
    """``intercept`` on ``observer``'s estimate, one throw per seed in an env from
    ``make_env``; the steps from :data:`FROM_S` after the launch to the crossing of the
    box's plane, while the ball is in flight."""
    errors, nees, catches = [], [], 0
    for seed in seeds:
        env = VisionObserver(make_env(), observer=observer)
        try:
            controller = make_controller("intercept", env)
            estimate, info = env.reset(seed=seed)
            while True:
                controller.observe_info(info)
                action, _ = controller.predict(estimate, deterministic=True)
                estimate, _, terminated, truncated, info = env.step(action)
                crossing_s = info["throw"]["crossing_time_s"]
                if info["ball_in_flight"] and FROM_S <= info["time_s"] < crossing_s:
                    e = info["estimate"]["mean"][BALL] - info["state"][BALL]
                    P = info["estimate"]["covariance"][BALL, BALL]
                    errors.append(e)
                    nees.append(e @ np.linalg.solve(P, e) / 6)
                if terminated or truncated:
                    break
            catches += bool(info["caught"])
        finally:
            env.close()
    return Throws(errors, nees, catches)
