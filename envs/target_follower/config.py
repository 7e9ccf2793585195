"""Configuration of TargetFollower-v0: every ``gym.make`` keyword, validated on construction."""

from __future__ import annotations

import math
from dataclasses import dataclass

from observer_gym.envs.config import config_field
from observer_gym.envs.sensor import SensorConfig
from observer_gym.envs.target_follower.motion import PROFILE_TURN_RATE_RADPS


@dataclass(frozen=True)
class TargetFollowerConfig(SensorConfig):
    """TargetFollower-v0's options: the camera's sensor model (:class:`SensorConfig`) and
    these."""

    # Camera (spec Table 1: f_x, f_y = 393.4, 391.8 px; T = 100 ms).
    fx_px: float = config_field(393.4, "focal length f_x", low=20.0, high=5000.0)
    fy_px: float = config_field(391.8, "focal length f_y", low=20.0, high=5000.0)
    frame_rate_hz: float = config_field(
        10.0,
        "camera frame rate; one frame and one action per step (T = 1 / this)",
        low=1.0,
        high=100.0,
    )
    substeps: int = config_field(
        10, "integration steps of the robot and target motion per env step", low=1, high=100
    )
    # Robot (spec Table 1: D = 40 cm, delta_y = 10 cm).
    delta_y_m: float = config_field(
        0.10, "offset of the camera above the tilt axis (spec delta y)", low=0.0, high=0.5
    )
    wheel_base_m: float = config_field(0.40, "wheel base D", low=0.1, high=2.0)
    max_speed_mps: float = config_field(0.6, "bound on the commanded v", low=0.05, high=2.0)
    max_yaw_rate_radps: float = config_field(
        1.0, "bound on the commanded omega", low=0.05, high=6.0
    )
    max_tilt_rate_radps: float = config_field(
        1.0, "bound on the commanded tilt rate omega_t", low=0.05, high=6.0
    )
    tilt_min_rad: float = config_field(-0.35, "lowest tilt of the camera", low=-1.2, high=0.0)
    tilt_max_rad: float = config_field(1.2, "highest tilt of the camera", low=0.0, high=1.5)
    wheel_speed_max_mps: float = config_field(
        1.27, "wheel speeds are scaled together to stay within this", low=0.05, high=5.0
    )
    wheel_accel_max_mps2: float = config_field(
        0.0,
        "wheel speed changes are scaled together to stay within this (0: off)",
        low=0.0,
        high=50.0,
    )
    wheel_quantization: bool = config_field(
        False, "send wheel speeds as 8-bit integers in cm/s, rounded down (the spec's robot)"
    )
    # Target (spec Table 1: W = 12 cm).
    target_width_m: float = config_field(
        0.12, "the target's width W (a sphere's diameter)", low=0.02, high=1.0
    )
    target_motion: str = config_field(
        "random_walk", "how the target moves", choices=("random_walk", "profile", "static")
    )
    profile_turn_rate_radps: float = config_field(
        PROFILE_TURN_RATE_RADPS,
        "profile: the turn rate of the target's heading (spec (44): 5 pi / 72 rad/s)",
        low=-2.0,
        high=2.0,
    )
    walk_speed_mps: float = config_field(
        0.1,
        "random_walk: scale of the horizontal speed (mean speed ~0.11 m/s, as (44)'s 0.095)",
        low=0.0,
        high=1.0,
    )
    start_distance_min_m: float = config_field(
        1.1, "nearest start of the target ahead of the camera", low=0.3, high=10.0
    )
    start_distance_max_m: float = config_field(
        1.7, "farthest start of the target ahead of the camera", low=0.3, high=10.0
    )
    start_bearing_max_rad: float = config_field(
        0.2, "the target starts within this bearing of the camera's axis", low=0.0, high=0.6
    )
    start_height_min_m: float = config_field(
        1.35, "lowest start height of the target's centre", low=0.2, high=3.0
    )
    start_height_max_m: float = config_field(
        1.6, "highest start height of the target's centre", low=0.2, high=3.0
    )
    desired_width_px: float = config_field(
        35.0,
        "the set point d_x of the target's width (spec: X_i = (0, 0, 35))",
        low=2.0,
        high=500.0,
    )
    # Disturbances (all from the env's np_random; all off by default).
    push_rate_hz: float = config_field(
        0.0, "mean rate of random pushes on the target", low=0.0, high=10.0
    )
    push_speed_mps: float = config_field(
        0.2, "largest velocity kick of a push (decays in 1 s)", low=0.0, high=2.0
    )
    measurement_noise_px: float = config_field(
        0.0,
        "measurements mode: sigma_n of Z = round(X + sigma_n (2 w - 1)), w ~ U[0, 1]",
        low=0.0,
        high=50.0,
    )
    measurement_rounding: bool = config_field(
        True, "measurements mode: round to whole pixels, as the spec's noise model does"
    )
    occluder_rate_hz: float = config_field(
        0.0,
        "mean rate at which a second body walks in front of the target",
        low=0.0,
        high=1.0,
    )
    occluder_hold_s: float = config_field(
        3.0, "how long the second body hides the target fully", low=0.0, high=30.0
    )
    # Episode.
    lost_timeout_s: float = config_field(
        5.0, "terminate after the target is out of the image this long", low=0.1, high=600.0
    )
    min_distance_m: float = config_field(
        0.3, "terminate when the target comes this close to the camera", low=0.05, high=2.0
    )

    def __post_init__(self) -> None:
        super().__post_init__()
        pairs = (
            ("start_distance_min_m", "start_distance_max_m"),
            ("start_height_min_m", "start_height_max_m"),
        )
        for low_name, high_name in pairs:
            low, high = getattr(self, low_name), getattr(self, high_name)
            if low > high:
                raise ValueError(f"{low_name}={low!r} must not exceed {high_name}={high!r}")
        # The nearest start's depth ahead of the level camera (at the widest bearing) must
        # be beyond the stop distance, else an episode can end at its first step.
        nearest_depth_m = self.start_distance_min_m * math.cos(self.start_bearing_max_rad)
        if nearest_depth_m <= self.min_distance_m:
            raise ValueError(
                f"start_distance_min_m={self.start_distance_min_m!r} at "
                f"start_bearing_max_rad={self.start_bearing_max_rad!r} starts the target "
                f"{nearest_depth_m:.4g} m ahead of the camera, within min_distance_m="
                f"{self.min_distance_m!r} where an episode ends; allowed: "
                "start_distance_min_m * cos(start_bearing_max_rad) > min_distance_m"
            )

    @property
    def dt_s(self) -> float:
        return 1.0 / self.frame_rate_hz
