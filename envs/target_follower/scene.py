"""The TargetFollower world: the robot, the target and the occluder, all moved kinematically.

Nothing here is driven by contact dynamics: the spec's robot model is kinematic (a
unicycle with a tilt platform, spec "Kinematics") and so is the target's motion, so the
scene integrates both exactly and places the bodies; PyBullet holds the world and renders
it. There is no floor: the camera looks at head height, and a floor filling the background
would cost most of the rendering time (benchmarks/bench_follower.py).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from observer_gym.envs.sim import Simulation, asset_path
from observer_gym.envs.target_follower import geometry as geo
from observer_gym.envs.target_follower.drive import (
    DriveLimits,
    applied_wheel_speeds,
    body_velocity,
    integrate_unicycle,
)
from observer_gym.envs.target_follower.layout import (
    APPLIED,
    IMAGE,
    IMAGE_RATE,
    STATE_DIM,
    StateIndex,
)
from observer_gym.envs.target_follower.measurements import fully_hidden, in_image
from observer_gym.envs.target_follower.motion import OCCLUDER_PARKED_WORLD, TargetMotion

TARGET_URDF_WIDTH_M = 0.12  # target_follower_target.urdf's sphere diameter; scaled to W
_OCCLUDER_PARKED = OCCLUDER_PARKED_WORLD.tolist()
# ground_truth writes the state in this order.
assert (IMAGE, IMAGE_RATE, APPLIED) == (slice(0, 3), slice(3, 6), slice(10, 13))
assert (StateIndex.ROBOT_X, StateIndex.ROBOT_YAW, StateIndex.TILT, STATE_DIM) == (6, 8, 9, 15)
assert (StateIndex.TRACKING_VALID, StateIndex.TARGET_VISIBLE) == (13, 14)


def _yaw_quaternion(yaw_rad: float) -> list[float]:
    return [0.0, 0.0, math.sin(0.5 * yaw_rad), math.cos(0.5 * yaw_rad)]


def wrap_angle(angle_rad: float) -> float:
    """The angle in [-pi, pi)."""
    return (angle_rad + math.pi) % (2.0 * math.pi) - math.pi


@dataclass
class GroundTruth:
    """Everything the simulator knows after a step."""

    state: np.ndarray  # STATE_NAMES layout
    T_world_cam: np.ndarray  # 4x4
    target_pos_world: np.ndarray  # (3,)
    target_vel_world: np.ndarray  # (3,)
    depth_m: float  # the target centre's depth z_c in the camera frame
    in_image: bool  # its centre is in front of the camera and on the image
    occluded: bool  # the occluder hides all of it


class TargetFollowerScene:
    """Builds the world in ``sim`` and moves its bodies.

    Args:
        sim: the (empty) world to build in.
        K: the camera matrix (for the ground-truth image state).
        image_size_px: (width, height) of the camera image.
        target_width_m: W.
        delta_y_m: the camera's offset above the tilt axis.
        tilt_range_rad: (lowest, highest) tilt; the tilt stops at either end.
        limits: the drive's wheel limits.
        with_occluder: load the occluder body.
    """

    def __init__(
        self,
        sim: Simulation,
        K: np.ndarray,
        image_size_px: tuple[int, int],
        target_width_m: float,
        delta_y_m: float,
        tilt_range_rad: tuple[float, float],
        limits: DriveLimits,
        with_occluder: bool,
    ) -> None:
        self.sim = sim
        self.K = K
        self.T_nominal_true: np.ndarray | None = None  # None: the nominal pose is true
        self.image_size_px = image_size_px
        self.target_width_m = target_width_m
        self.delta_y_m = delta_y_m
        self.tilt_range_rad = tilt_range_rad
        self.limits = limits
        client = sim.client
        self.robot = client.loadURDF(asset_path("target_follower_robot.urdf"), useFixedBase=True)
        self.target = client.loadURDF(
            asset_path("target_follower_target.urdf"),
            [0.0, 0.0, -10.0],
            globalScaling=target_width_m / TARGET_URDF_WIDTH_M,
        )
        self.occluder = None
        if with_occluder:
            self.occluder = client.loadURDF(
                asset_path("target_follower_occluder.urdf"), list(OCCLUDER_PARKED_WORLD)
            )
        self.occluder_pose: tuple[np.ndarray, float] | None = None
        # Kinematic state.
        self.robot_xy_m = np.zeros(2)
        self.yaw_rad = 0.0
        self.tilt_rad = 0.0
        self.wheels_mps = np.zeros(2)
        self.applied = np.zeros(3)  # (v, omega, omega_t) over the last step
        self.motion: TargetMotion | None = None

    # --- commands ---------------------------------------------------------------------
    def start(self, tilt_rad: float, motion: TargetMotion) -> None:
        """Robot at the origin facing +x with the given tilt, at rest; the target's motion."""
        self.robot_xy_m = np.zeros(2)
        self.yaw_rad = 0.0
        self.tilt_rad = float(tilt_rad)
        self.wheels_mps = np.zeros(2)
        self.applied = np.zeros(3)
        self.motion = motion
        self._place()

    def advance(
        self,
        command: np.ndarray,
        dt_s: float,
        substeps: int,
        stops: Callable[[int], bool] | None = None,
        on_stop: Callable[[int], None] | None = None,
    ) -> None:
        """Drive for ``dt_s`` with the command (v, omega, omega_t) and move the target in
        ``substeps`` steps. The bodies are placed in the world at the end, and after
        substep k (0-based, not the last) where ``stops(k)``: the robot at its exact arc
        there, the target where its integration is; then ``on_stop(k)`` is called."""
        v_cmd, omega_cmd, tilt_rate_cmd = command.tolist()
        self.wheels_mps = applied_wheel_speeds(v_cmd, omega_cmd, self.wheels_mps, dt_s, self.limits)
        v, omega = body_velocity(self.wheels_mps, self.limits.wheel_base_m)
        low, high = self.tilt_range_rad
        tilt_start = self.tilt_rad
        tilt_end = min(max(tilt_start + tilt_rate_cmd * dt_s, low), high)
        omega_t = (tilt_end - tilt_start) / dt_s  # the tilt stops at its end stops
        x0, y0 = self.robot_xy_m.tolist()
        start = (x0, y0, self.yaw_rad)
        self.applied = np.array([v, omega, omega_t])

        def place_robot(t_s: float, tilt_rad: float) -> None:
            x, y, yaw = integrate_unicycle(*start, v, omega, t_s)
            self.robot_xy_m = np.array([x, y])
            self.yaw_rad = wrap_angle(yaw)
            self.tilt_rad = tilt_rad

        after_substep: Callable[[int], None] | None = None
        if stops is not None:

            def after_substep(k: int) -> None:
                if k < substeps - 1 and stops(k):
                    t_s = (k + 1) * dt_s / substeps
                    place_robot(t_s, tilt_start + omega_t * t_s)
                    self._place()
                    if on_stop is not None:
                        on_stop(k)

        assert self.motion is not None, "start an episode first"
        self.motion.advance(dt_s, substeps, after_substep)
        place_robot(dt_s, tilt_end)
        self._place()

    def place_occluder(self, pose: tuple[np.ndarray, float] | None) -> None:
        """``pose`` (centre_world, yaw_rad), or None to park it out of sight."""
        if self.occluder is None:
            return
        self.occluder_pose = pose
        centre, yaw = (_OCCLUDER_PARKED, 0.0) if pose is None else (list(pose[0]), pose[1])
        self.sim.client.resetBasePositionAndOrientation(self.occluder, centre, _yaw_quaternion(yaw))

    def _place(self) -> None:
        self._T_world_cam = geo.camera_pose(
            self.robot_xy_m, self.yaw_rad, self.tilt_rad, self.delta_y_m
        )
        client = self.sim.client
        x, y = self.robot_xy_m.tolist()
        client.resetBasePositionAndOrientation(
            self.robot, [x, y, 0.0], _yaw_quaternion(self.yaw_rad)
        )
        client.resetJointState(self.robot, 0, self.tilt_rad)
        assert self.motion is not None, "start an episode first"
        client.resetBasePositionAndOrientation(
            self.target, self.motion.pos.tolist(), [0.0, 0.0, 0.0, 1.0]
        )

    # --- ground truth -----------------------------------------------------------------
    def set_true_camera(self, K: np.ndarray, T_nominal_true: np.ndarray | None) -> None:
        """The real camera: its intrinsics and its pose in the nominal camera's frame (the
        ground truth is what the real camera sees)."""
        self.K = K
        self.T_nominal_true = T_nominal_true

    def camera_pose(self) -> np.ndarray:
        """The nominal ``T_world_cam``: where the calibration says the camera is (computed
        when the robot was last placed; do not modify)."""
        self.sim.check_open("scene.camera_pose()")
        return self._T_world_cam

    def ground_truth(self) -> GroundTruth:
        """The truth now, from this object's state (the world is kinematic); raises
        EnvClosedError once the world is closed, as every read of the world does."""
        T = self.camera_pose()
        if self.T_nominal_true is not None:
            T = T @ self.T_nominal_true
        assert self.motion is not None, "start an episode first"
        pos, vel = self.motion.pos.copy(), self.motion.velocity
        W = self.target_width_m
        # The target in the camera frame, once for the depth, the image state and its rate
        # (geo.target_in_camera, image_state, target_image_velocity).
        R_cam_world = T[:3, :3].T
        p = (R_cam_world @ (pos - T[:3, 3])).tolist()
        pdot = (R_cam_world @ vel).tolist()
        depth = p[2]
        x_i, y_i, d_x = geo.image_state_in_camera(self.K, p[0], p[1], p[2], W)
        in_front = depth > geo.MIN_DEPTH_M
        on_image = in_front and in_image(self.K, self.image_size_px, x_i, y_i)
        occluded = fully_hidden(T, pos, 0.5 * W, self.occluder_pose)
        state = np.array(  # STATE_NAMES
            [
                x_i,
                y_i,
                d_x,
                *geo.image_velocity_in_camera(self.K, p, pdot, W),
                *self.robot_xy_m.tolist(),
                self.yaw_rad,
                self.tilt_rad,
                *self.applied.tolist(),
                float(in_front),
                float(on_image and not occluded),
            ]
        )
        return GroundTruth(state, T, pos, vel, depth, bool(on_image), bool(occluded))
