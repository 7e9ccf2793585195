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

Randomness: the sensor draws from streams of its own, spawned from the env's
``np_random`` at each reset (``Generator.spawn`` draws nothing from it): one for the
timing (capture jitter, latency jitter, drops), one for pixel and image noise, one for the
calibration errors' directions (see :class:`observer_gym.envs.camera_rig.CameraRig`). So a
seed gives the same world (pushes, throws, target motion) whatever the sensor options.

What an observer may know of the sensor is :class:`SensorSpec`: the nominal (declared)
specification a calibrated rig comes with, the same numbers as the options but never the
realised draws. Every env gives it as ``env.unwrapped.sensor_spec`` and in the ``info``
of ``reset`` (``info["sensor"]``).
"""

from __future__ import annotations

import math
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

    def sensor_spec(self, **system: float) -> SensorSpec:
        """The declared sensor specification of these options (see :class:`SensorSpec`);
        ``system`` overrides the entries an env computes itself (its pixel-noise model,
        the spread of its cameras' latencies)."""
        return SensorSpec(
            frame_rate_hz=self.frame_rate_hz,
            frame_phase_s=self.frame_phase_s,
            latency_s=self.latency_s,
            latency_jitter_s=self.latency_jitter_s,
            jitter_s=self.jitter_s,
            frame_drop_prob=self.frame_drop_prob,
            measurement_noise_px=self.measurement_noise_px,
            image_noise_std=self.image_noise_std,
            calib_focal_error=self.calib_focal_error,
            calib_principal_point_error_px=self.calib_principal_point_error_px,
            calib_rotation_error_deg=self.calib_rotation_error_deg,
            calib_translation_error_m=self.calib_translation_error_m,
            image_size_px=(self.image_width_px, self.image_height_px),
            **system,
        )

    @property
    def has_calibration_error(self) -> bool:
        return (
            self.calib_focal_error > 0.0
            or self.calib_principal_point_error_px > 0.0
            or self.calib_rotation_error_deg > 0.0
            or self.calib_translation_error_m > 0.0
        )


# float32 keeps 24 significant bits: a pixel coordinate below 2048 px is stored to within
# half of 2^-13 px, a uniform rounding error of variance ulp^2 / 12.
_FLOAT32_ULP_PX = 2.0**-13


@dataclass(frozen=True, slots=True)
class SensorSpec:
    """The nominal sensor: what a calibrated rig's data sheet and calibration report say.

    The options of :class:`SensorConfig` as declared numbers (sizes of the calibration
    errors, not their drawn directions; std of the jitters, not their draws), plus what
    the env knows of its own measurement model:

    - ``measurement_noise_std_px``: the std of the error of every reported pixel
      coordinate in ``obs_mode="measurements"`` (the noise's std under the env's noise
      model, with the rounding it applies; at least the float32 storage's);
    - ``latency_spread_s``: how much later than ``latency_s`` a camera of the rig may
      deliver by design (BallCatcher's ``random_offsets`` preset: one frame period).

    An observer derives its measurement noise and how far back it keeps its past from
    these numbers and nothing it could not know on a real rig.
    """

    frame_rate_hz: float
    frame_phase_s: float
    latency_s: float
    latency_jitter_s: float
    jitter_s: float
    frame_drop_prob: float
    measurement_noise_px: float
    image_noise_std: float
    calib_focal_error: float
    calib_principal_point_error_px: float
    calib_rotation_error_deg: float
    calib_translation_error_m: float
    image_size_px: tuple[int, int]
    measurement_noise_std_px: float = -1.0  # -1: Gaussian of measurement_noise_px
    latency_spread_s: float = 0.0

    def __post_init__(self) -> None:
        if self.measurement_noise_std_px < 0.0:
            # Gaussian noise of the declared std, stored as float32 (its rounding floor).
            std = math.hypot(self.measurement_noise_px, _FLOAT32_ULP_PX / math.sqrt(12.0))
            object.__setattr__(self, "measurement_noise_std_px", std)

    @property
    def frame_period_s(self) -> float:
        return 1.0 / self.frame_rate_hz

    @property
    def max_latency_s(self) -> float:
        """The latest a frame arrives after its capture, to five standard deviations of
        the latency jitter."""
        return self.latency_s + self.latency_spread_s + 5.0 * self.latency_jitter_s

    def history_s(self, step_s: float) -> float:
        """How far back an observer that fuses frames at their capture time must keep its
        past: the latest delivery (:attr:`max_latency_s`) with five standard deviations
        of the capture jitter, and two control steps ``step_s``."""
        return self.max_latency_s + 5.0 * self.jitter_s + 2.0 * step_s

    @property
    def has_calibration_error(self) -> bool:
        return (
            self.calib_focal_error > 0.0
            or self.calib_principal_point_error_px > 0.0
            or self.calib_rotation_error_deg > 0.0
            or self.calib_translation_error_m > 0.0
        )
