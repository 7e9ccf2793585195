"""Configuration of BallTable-v0: every ``gym.make`` keyword, validated on construction."""

from __future__ import annotations

from dataclasses import dataclass

from observer_gym.envs.config import config_field
from observer_gym.envs.sensor import SensorConfig


@dataclass(frozen=True)
class BallTableConfig(SensorConfig):
    """BallTable-v0's options: the camera's sensor model (:class:`SensorConfig`) and these."""

    # Camera (spec: 320x240, 90 deg horizontal field of view, 50 frames/s).
    hfov_deg: float = config_field(90.0, "horizontal field of view", low=20.0, high=120.0)
    frame_rate_hz: float = config_field(
        50.0, "camera frame rate; one frame and one action per step", low=5.0, high=200.0
    )
    camera_motion: str = config_field(
        "fixed",
        "the robot's eye: fixed, or a small scripted head motion",
        choices=("fixed", "head"),
    )
    head_motion_deg: float = config_field(
        2.0, "amplitude of the head motion's pan and tilt", low=0.0, high=15.0
    )
    head_motion_period_s: float = config_field(4.0, "period of the head motion", low=0.5, high=60.0)
    # Plant.
    physics_substeps: int = config_field(
        5, "physics steps per env step (5 at 50 Hz: 250 Hz physics)", low=1, high=50
    )
    max_tilt_rad: float = config_field(
        0.1, "bound on the commanded tilt about each axis", low=0.01, high=0.3
    )
    arm_position_gain: float = config_field(
        0.1, "joint motor gain k_p; tilt lag time constant ~ dt_physics / k_p", low=0.01, high=1.0
    )
    # Start state.
    start_radius_m: float = config_field(
        0.1, "ball starts uniformly in the disc of this radius", low=0.0, high=0.125
    )
    start_speed_mps: float = config_field(
        0.05, "ball's initial speed, uniform in [0, this], random direction", low=0.0, high=0.5
    )
    # Reward.
    effort_weight: float = config_field(
        0.1, "weight of the squared normalised tilt command in the reward", low=0.0, high=10.0
    )
    # Disturbances (all drawn from the env's np_random; all off by default).
    push_rate_hz: float = config_field(
        0.0, "mean rate of random pushes on the ball", low=0.0, high=10.0
    )
    push_impulse_ns: float = config_field(
        0.005, "largest push impulse (N s); each push is uniform in [0, this]", low=0.0, high=0.1
    )
    occluder_rate_hz: float = config_field(
        0.0, "mean rate at which an occluder starts passing over the table", low=0.0, high=5.0
    )
    occluder_pass_s: float = config_field(
        1.0, "time an occluder takes to cross the camera's view of the table", low=0.1, high=10.0
    )

    @property
    def dt_s(self) -> float:
        return 1.0 / self.frame_rate_hz

    @property
    def physics_dt_s(self) -> float:
        return self.dt_s / self.physics_substeps
