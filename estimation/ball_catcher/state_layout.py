"""A BallCatcher observer's output in the env's state layout
(envs/ball_catcher/layout.py), filled the same way by every observer of this package:
the ball's position and velocity (and their 6x6 covariance) from the observer, the box's
position and velocity from the robot's own kinematics (``info["box_pos_world_m"]``,
``info["box_vel_world_mps"]``), known exactly, their covariance 0."""

from __future__ import annotations

import numpy as np

from observer_gym.envs.ball_catcher.layout import BALL, BOX_POS, BOX_VEL, STATE_DIM

__all__ = ["state_estimate"]


def state_estimate(
    ball: np.ndarray, ball_covariance: np.ndarray, info: dict
) -> tuple[np.ndarray, np.ndarray]:
    """(mean (12,), covariance (12, 12)): the ball's (6,) and (6, 6), the box's from
    ``info`` with zero variance."""
    mean = np.zeros(STATE_DIM)
    mean[BALL] = ball
    mean[BOX_POS] = info["box_pos_world_m"]
    mean[BOX_VEL] = info["box_vel_world_mps"]
    covariance = np.zeros((STATE_DIM, STATE_DIM))
    covariance[BALL, BALL] = ball_covariance
    return mean, covariance
