"""Configuration of BallCatcher-v1: every ``gym.make`` keyword, validated on construction."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

from observer_gym.envs.ball_catcher import geometry as geo
from observer_gym.envs.config import config_field
from observer_gym.envs.sensor import SensorConfig


@dataclass(frozen=True)
class RobotProfile:
    """Limits on the box's Cartesian motion (the commanded velocity is limited to them)."""

    max_speed_mps: float
    max_accel_mps2: float


# "paper": the ABB IRB 140's limits in docs/spec/catcher.md. "fast": a quicker arm, about what
# the KUKA iiwa's joint speed limits (85-135 deg/s) give at the box's 0.6 m reach.
ROBOT_PROFILES: dict[str, RobotProfile] = {
    "paper": RobotProfile(max_speed_mps=0.5, max_accel_mps2=13.0),
    "fast": RobotProfile(max_speed_mps=1.5, max_accel_mps2=30.0),
}

# Camera timing presets (each camera's frame rate is frame_rate_hz):
# - synchronised: every camera captures at t = k / rate;
# - alternating: the paper's experiment, camera c captures at (k + c / N) / rate, so the
#   merged stream alternates cameras (camera 1 on odd frames, camera 2 on even);
# - random_offsets: each camera's phase uniform in [0, 1 / rate) and its latency uniform in
#   [latency_s, latency_s + 1 / rate), drawn at every reset, so frames arrive out of order;
# - single: one camera (rig camera 0).
CAMERA_PRESETS = ("synchronised", "alternating", "random_offsets", "single")

# The episode's time limit: the longest flight and then AFTER_FLIGHT_S for the ball to end
# (through the hole, off the box, below MISS_HEIGHT_M or past the box), and never under
# MIN_TIME_LIMIT_S: at the default flights (at most 0.48 s) and step (10 ms) that is the
# 2 s (200 steps) every published figure was measured over.
MIN_TIME_LIMIT_S = 2.0
AFTER_FLIGHT_S = 1.52
# The lowest launch point must be this far in front of the box's reach (the workspace's
# front face, x = 0.75 m), so a throw starts in front of the box and flies toward it.
LAUNCH_CLEARANCE_M = 0.5


@dataclass(frozen=True)
class BallCatcherConfig(SensorConfig):
    """BallCatcher-v1's options: every camera's sensor model (:class:`SensorConfig`) and
    these."""

    # Cameras.
    camera_preset: str = config_field(
        "alternating", "camera timing preset (see CAMERA_PRESETS)", choices=CAMERA_PRESETS
    )
    num_cameras: int = config_field(
        0,
        "cameras of the rig used (0: the preset's count, 1 for 'single', else 2)",
        low=0,
        high=geo.MAX_CAMERAS,
    )
    hfov_deg: float = config_field(60.0, "horizontal field of view", low=20.0, high=120.0)
    frame_rate_hz: float = config_field(50.0, "every camera's frame rate", low=5.0, high=500.0)
    measurement_noise_px: float = config_field(
        0.5,
        "measurements mode: std of Gaussian noise on the ball's pixel coordinates",
        low=0.0,
        high=20.0,
    )
    hole_measurements: bool = config_field(
        False,
        "measurements mode: also report the hole centre's pixels in every camera that has it "
        "in view (a detector of the box's outline), with measurement_noise_px of noise",
    )
    # Robot and box.
    robot_profile: str = config_field(
        "paper", "limits of the box's motion (see ROBOT_PROFILES)", choices=tuple(ROBOT_PROFILES)
    )
    hole_diameter_m: float = config_field(
        geo.HOLE_DIAMETER_M, "diameter of the box's hole", low=0.052, high=0.15
    )
    arm_position_gain: float = config_field(
        0.2, "joint motor gain k_p (lag time constant ~ physics_dt_s / k_p)", low=0.01, high=1.0
    )
    # Throws: launch point, time of flight to the box's front plane, where they cross it.
    # The defaults keep the ball's descent at the box between about 10 and 30 deg (a ball
    # arriving steeper than about 45 deg cannot pass a 6 cm hole cleanly) and every
    # crossing reachable by the "paper" profile (0.08 m at 0.5 m/s takes 0.2 s).
    launch_x_m: float = config_field(
        3.2, "launch point's mean x (distance from the robot's base)", low=1.5, high=8.0
    )
    launch_height_m: float = config_field(0.55, "launch point's mean height", low=0.0, high=3.0)
    launch_spread_m: float = config_field(
        0.1,
        "launch point uniform within +- this of its mean, per axis (the lowest launch at "
        "least 0.15 m high, the nearest at least 1.25 m out)",
        low=0.0,
        high=1.0,
    )
    flight_time_min_s: float = config_field(
        0.40, "shortest time of flight to the box's plane", low=0.1, high=3.0
    )
    flight_time_max_s: float = config_field(
        0.48, "longest time of flight to the box's plane", low=0.1, high=3.0
    )
    target_radius_m: float = config_field(
        0.08,
        "the ball crosses the box's plane uniformly within this radius of the hole's home",
        low=0.0,
        high=0.3,
    )
    air_drag: bool = config_field(
        False, "quadratic air drag on the ball (model mismatch for a drag-free observer)"
    )
    # Reward.
    shaping_weight: float = config_field(
        1.0,
        "weight of the potential-based shaping: reward per metre the predicted miss shrinks",
        low=0.0,
        high=10.0,
    )
    # Simulation.
    control_dt_s: float = config_field(0.01, "env step (control period)", low=0.002, high=0.05)
    physics_dt_s: float = config_field(
        0.001, "physics step; a divisor of control_dt_s", low=0.0002, high=0.005
    )

    # Options whose allowed values, the others fixed, are no interval but a lattice: a
    # domain randomisation draws them from choices, never from a range (train/rl/randomize.py).
    discrete_options: ClassVar[dict[str, str]] = {
        "control_dt_s": "a whole multiple of physics_dt_s",
        "physics_dt_s": "a divisor of control_dt_s",
    }

    def __post_init__(self) -> None:
        super().__post_init__()
        ratio = self.control_dt_s / self.physics_dt_s
        if abs(ratio - round(ratio)) > 1e-9:
            raise ValueError(
                f"control_dt_s={self.control_dt_s} must be a whole multiple of "
                f"physics_dt_s={self.physics_dt_s}"
            )
        if self.flight_time_min_s > self.flight_time_max_s:
            raise ValueError(
                f"flight_time_min_s={self.flight_time_min_s} must be <= "
                f"flight_time_max_s={self.flight_time_max_s}"
            )
        lowest_m = self.launch_height_m - self.launch_spread_m
        if lowest_m < geo.MISS_HEIGHT_M - 1e-9:  # 1e-9: 1.15 - 1.0 is 0.1499...
            raise ValueError(
                f"launch_height_m={self.launch_height_m} with launch_spread_m="
                f"{self.launch_spread_m} launches as low as {lowest_m:.4g} m, below the "
                f"{geo.MISS_HEIGHT_M} m where a ball counts as missed (or under the floor); "
                f"allowed: launch_height_m - launch_spread_m >= {geo.MISS_HEIGHT_M}"
            )
        nearest_m = self.launch_x_m - self.launch_spread_m
        front_m = float(geo.WORKSPACE_HIGH_WORLD[0]) + LAUNCH_CLEARANCE_M
        if nearest_m < front_m - 1e-9:
            raise ValueError(
                f"launch_x_m={self.launch_x_m} with launch_spread_m={self.launch_spread_m} "
                f"launches as near as x = {nearest_m:.4g} m, at or behind the box's reach; "
                f"allowed: launch_x_m - launch_spread_m >= {front_m:g}"
            )
        if self.camera_preset == "single" and self.num_cameras > 1:
            raise ValueError(
                f"num_cameras={self.num_cameras} contradicts camera_preset='single'; "
                "use num_cameras=0 or 1"
            )

    @property
    def cameras(self) -> int:
        """The number of cameras in use."""
        if self.num_cameras:
            return self.num_cameras
        return 1 if self.camera_preset == "single" else 2

    @property
    def time_limit_s(self) -> float:
        """The episode's time limit (s): the longest flight and AFTER_FLIGHT_S after it,
        at least MIN_TIME_LIMIT_S (2 s at the defaults)."""
        return max(MIN_TIME_LIMIT_S, self.flight_time_max_s + AFTER_FLIGHT_S)

    @property
    def max_episode_steps(self) -> int:
        """The time limit in env steps of control_dt_s, rounded up (200 at the defaults)."""
        return math.ceil(round(self.time_limit_s / self.control_dt_s, 9))

    @property
    def physics_substeps(self) -> int:
        return round(self.control_dt_s / self.physics_dt_s)

    @property
    def profile(self) -> RobotProfile:
        return ROBOT_PROFILES[self.robot_profile]
