"""The sensor model shared by every camera of every env: timing, noise, calibration error.

:class:`SensorConfig` holds the ``gym.make`` options every env takes for its cameras; each
env's config dataclass inherits them (and may redeclare a field to give it another
default or range). The defaults are a perfect, synchronous camera: one frame per env
step, captured at the end of the step and delivered at once, no noise, the nominal
calibration exact.

- Timing: camera frames are captured at ``frame_phase_s + k / frame_rate_hz`` (plus a
  Gaussian ``jitter_s``), rounded to the physics tick, and delivered ``latency_s`` later
  (plus a Gaussian ``latency_jitter_s``, never before the capture): a step's observation
  is the newest frame delivered by the end of the step. A frame is lost with probability
  ``frame_drop_prob``; frames captured at reset are never lost.
- Noise: ``measurement_noise_px`` on a perfect detector's pixels (``obs_mode=
  "measurements"``), ``image_noise_std`` on every pixel intensity (``obs_mode="rgb"``).
- Calibration error: the world's camera differs from the nominal calibration that
  ``info`` reports. Its focal length is scaled by ``1 + calib_focal_error`` (or
  ``1 - calib_focal_error``), its principal point is moved by
  ``calib_principal_point_error_px`` and its pose (in the nominal camera's frame) is
  rotated by ``calib_rotation_error_deg`` and moved by ``calib_translation_error_m``.
  Each error has exactly the option's size; its direction (and the focal error's sign) is
  fixed (``calib_error_draw="fixed"``: +, and the diagonal (1, 1) or (1, 1, 1) direction)
  or drawn per episode and per camera (``"per_episode"``: a uniform direction).

Randomness: the timing draws (jitters, drops) come from the env's ``np_random`` in a
fixed order, so they are the same in every obs_mode; noise and calibration errors come
from generators spawned from it at each reset (see :class:`observer_gym.envs.camera_rig.
CameraRig`).
"""

from __future__ import annotations

from dataclasses import dataclass

from observer_gym.envs.config import EnvConfig, config_field

OBS_MODES = ("rgb", "state", "measurements")
CALIBRATION_DRAWS = ("per_episode", "fixed")


@dataclass(frozen=True)
class SensorConfig(EnvConfig):
    """The camera options of every env (see the module docstring)."""

    obs_mode: str = config_field("rgb", "what the agent observes", choices=OBS_MODES)
    image_width_px: int = config_field(320, "camera image width", low=32, high=1280)
    image_height_px: int = config_field(240, "camera image height", low=32, high=960)
    frame_rate_hz: float = config_field(50.0, "camera frame rate", low=1.0, high=500.0)
    frame_phase_s: float = config_field(
        0.0,
        "capture time of the first frame after reset's; frames at phase + k / frame_rate_hz "
        "(must be below one frame period)",
        low=0.0,
        high=1.0,
    )
    latency_s: float = config_field(
        0.0, "time from a frame's capture to its delivery", low=0.0, high=0.5
    )
    latency_jitter_s: float = config_field(
        0.0, "std of a Gaussian added to each frame's latency (kept >= 0)", low=0.0, high=0.1
    )
    jitter_s: float = config_field(
        0.0,
        "std of the capture time's jitter (capture times stay on physics ticks)",
        low=0.0,
        high=0.01,
    )
    frame_drop_prob: float = config_field(
        0.0, "probability a captured frame is never delivered", low=0.0, high=1.0
    )
    measurement_noise_px: float = config_field(
        0.0,
        "measurements mode: std of Gaussian noise on every pixel coordinate",
        low=0.0,
        high=20.0,
    )
    image_noise_std: float = config_field(
        0.0, "rgb mode: std of Gaussian noise on every pixel intensity (0-255)", low=0.0, high=64.0
    )
    calib_focal_error: float = config_field(
        0.0,
        "relative error of the real camera's focal length against the nominal calibration",
        low=0.0,
        high=0.5,
    )
    calib_principal_point_error_px: float = config_field(
        0.0, "offset of the real camera's principal point from the nominal one", low=0.0, high=50.0
    )
    calib_rotation_error_deg: float = config_field(
        0.0, "rotation of the real camera from its nominal pose", low=0.0, high=10.0
    )
    calib_translation_error_m: float = config_field(
        0.0, "displacement of the real camera from its nominal pose", low=0.0, high=0.2
    )
    calib_error_draw: str = config_field(
        "per_episode",
        "the calibration errors' directions: drawn per episode and camera, or fixed",
        choices=CALIBRATION_DRAWS,
    )

    def __post_init__(self) -> None:
        super().__post_init__()
        period_s = 1.0 / self.frame_rate_hz
        if self.frame_phase_s >= period_s:
            raise ValueError(
                f"frame_phase_s={self.frame_phase_s!r} must be below one frame period "
                f"(1 / frame_rate_hz = {period_s:g} s)"
            )

    @property
    def has_calibration_error(self) -> bool:
        return (
            self.calib_focal_error > 0.0
            or self.calib_principal_point_error_px > 0.0
            or self.calib_rotation_error_deg > 0.0
            or self.calib_translation_error_m > 0.0
        )
