"""BallTable's random disturbances and the robot's head motion, drawn from the env's
``np_random`` so that a seed fixes them, in the same order in every obs_mode (the
camera's timing and noise belong to the camera rig, envs/camera_rig.py).

- pushes: a Poisson process of rate ``push_rate_hz``; each push is a horizontal impulse
  on the ball, uniform in [0, ``push_impulse_ns``] with a uniform direction.
- occluder: passes start as a Poisson process of rate ``occluder_rate_hz`` (never while
  one is under way); a pass crosses the table along the world y axis, 0.2 m above it, in
  ``occluder_pass_s``, at a random offset along x.
- head motion: pan and tilt of the camera about its centre, sinusoids of amplitude
  ``head_motion_deg`` with random phases (frequency ratio 1 : 0.7, a Lissajous figure).
"""

from __future__ import annotations

import numpy as np

from observer_gym.envs.ball_table import geometry as geo
from observer_gym.envs.ball_table.config import BallTableConfig
from observer_gym.envs.camera import look_at
from observer_gym.envs.transforms import pose_matrix, rot_x, rot_y

OCCLUDER_SWEEP_M = 0.35  # the pass runs from y = -this to +this around the table centre
OCCLUDER_X_SPREAD_M = 0.08


class Disturbances:
    def __init__(self, config: BallTableConfig) -> None:
        self.config = config
        self.dt_s = config.dt_s
        # The robot's eye looks at the table centre; image 'up' is world +x (away from
        # the arm's base), so the arm enters the image from the bottom.
        self.T_world_cam_nominal = look_at(
            geo.CAMERA_EYE_WORLD, geo.TABLE_CENTRE_HOME_WORLD, up_world=(1.0, 0.0, 0.0)
        )
        self._head_phase = np.zeros(2)
        self._occluder_start_s: float | None = None
        self._occluder_x_m = 0.0

    def reset(self, rng: np.random.Generator) -> None:
        if self.config.camera_motion == "head":
            self._head_phase = rng.uniform(0.0, 2.0 * np.pi, size=2)
        self._occluder_start_s = None

    def push_impulse(self, rng: np.random.Generator) -> np.ndarray | None:
        """The push to apply this step (N s, world frame), or None."""
        rate = self.config.push_rate_hz
        if rate <= 0.0 or rng.random() >= rate * self.dt_s:
            return None
        angle = rng.uniform(0.0, 2.0 * np.pi)
        magnitude = rng.uniform(0.0, self.config.push_impulse_ns)
        return magnitude * np.array([np.cos(angle), np.sin(angle), 0.0])

    def occluder_position(self, time_s: float, rng: np.random.Generator) -> np.ndarray | None:
        """Where the occluder is at ``time_s`` (world), or None when no pass is under way."""
        rate = self.config.occluder_rate_hz
        if rate <= 0.0:
            return None
        if self._occluder_start_s is None:
            if rng.random() >= rate * self.dt_s:
                return None
            self._occluder_start_s = time_s
            self._occluder_x_m = rng.uniform(-OCCLUDER_X_SPREAD_M, OCCLUDER_X_SPREAD_M)
        progress = (time_s - self._occluder_start_s) / self.config.occluder_pass_s
        if progress > 1.0:
            self._occluder_start_s = None
            return None
        return geo.TABLE_CENTRE_HOME_WORLD + np.array(
            [self._occluder_x_m, OCCLUDER_SWEEP_M * (2.0 * progress - 1.0), geo.OCCLUDER_HEIGHT_M]
        )

    def camera_pose(self, time_s: float) -> np.ndarray:
        """T_world_cam at ``time_s``."""
        if self.config.camera_motion == "fixed":
            return self.T_world_cam_nominal
        amplitude = np.radians(self.config.head_motion_deg)
        phase = 2.0 * np.pi * time_s / self.config.head_motion_period_s
        pan = amplitude * np.sin(phase + self._head_phase[0])
        tilt = amplitude * np.sin(0.7 * phase + self._head_phase[1])
        R = self.T_world_cam_nominal[:3, :3] @ rot_y(pan) @ rot_x(tilt)
        return pose_matrix(R, self.T_world_cam_nominal[:3, 3])
