"""The TargetFollower observer: detector + the visual state estimator (docs/spec/follower.md).

Per step:
1. The detection: in ``obs_mode="rgb"`` the orange-blob detector
   (:class:`~observer_gym.estimation.target_follower.detector.TargetFollowerDetector`) on
   the frame, in ``"measurements"`` the perfect detector's (x_i, y_i, d_x); none when the frame was
   dropped or the target not found.
2. The robot's proprioception: its pose and tilt from the frame's calibration
   ``T_world_cam`` (envs/target_follower/geometry.robot_pose_from_camera) and the velocity
   applied over the last step (``info["applied_action"]``: after the drive's scaling and
   quantisation, spec "the previous applied u feeds the estimator").
3. The estimator (:class:`~observer_gym.estimation.target_follower.filters.VisualStateEstimator`):
   the self-tuning KF by default (``filter="stkf"``) or the conventional KF
   (``filter="kf"``), predicting with B_i at the previous estimate and tilt (30).

Its noise is the noise rule (:mod:`~observer_gym.estimation.target_follower.noise`: R from
the declared sensor, ``env.sensor_spec``, times ``r_scale``; Q from the target's motion
model) with :data:`RULE_PARAMS`: a chi-square gate on the innovation, a detection after a
gap used once the next frame confirms it, a new track replacing the old after a run of
rejected detections that agree (:mod:`~observer_gym.estimation.target_follower.tracks`),
and the self-tuning filter's R never below the rule's (``adaptation="floor"``). Given
``params``, it is the spec's procedure with Table 1's noise (the Table 2 study,
train/experiments/reproduce/tsai2009.py).

The output has the env's state layout; ``tracking_valid`` is 1 while the estimate is
valid (a track, every diagonal element of P below the threshold), else 0, and
the image entries then hold the last valid estimate with zero rates; ``target_visible`` is
1 when this step's frame gave a detection. A detection with a non-finite entry (NaN,
inf) is no detection (the estimator's missed-measurement step). ``Estimate.nis`` is the
update's d^T S^-1 d (3 dof) on steps with an update, else None. The covariance of
(x_i, y_i) includes the declared principal-point error of an rgb camera (a constant
offset of every detection: ``NoiseRule.image_bias_cov``).

The measurement is fused when it is delivered, whatever its capture time; the
latency-aware drive of the same estimator is
:mod:`~observer_gym.estimation.target_follower.latency`.

Frames (``obs_mode="rgb"``) must be uint8 images of the env's size (``image_size_px`` of
the frame, else the env config's), H x W x 3: others raise ``ValueError``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from observer_gym.envs.target_follower import TargetFollowerEnv
from observer_gym.estimation.observer import Estimate
from observer_gym.estimation.target_follower.detector import TargetFollowerDetector
from observer_gym.estimation.target_follower.filters import (
    Table1Noise,
    VisualStateEstimator,
    VSEParams,
)
from observer_gym.estimation.target_follower.frames import FrameReader
from observer_gym.estimation.target_follower.models import (
    TargetFollowerCameraParams,
    robot_jacobian,
)
from observer_gym.estimation.target_follower.noise import NoiseRule
from observer_gym.estimation.target_follower.state_layout import (
    RobotStep,
    lost_estimate,
    state_estimate,
)

FILTERS = ("stkf", "kf")
# The observers' procedure with the noise rule: a chi-square gate at this probability of
# the innovation's chi-square(3) (its quantile 21.1); a detection after a gap confirmed
# by the next frame's; a new track replacing the old after a run of three rejected
# detections that agree (0.3 s at 10 Hz); the self-tuning R floored at the rule's.
GATE_PROBABILITY = 0.9999
CONFIRM_UPDATES = 1
RESTART_UPDATES = 2
RULE_PARAMS = VSEParams(
    gate_probability=GATE_PROBABILITY,
    confirm_updates=CONFIRM_UPDATES,
    restart_updates=RESTART_UPDATES,
    adaptation="floor",
)


def filter_params(filter: str, params: VSEParams | None = None) -> VSEParams:
    """``params`` (default: :data:`RULE_PARAMS`) with ``self_tuning`` set by ``filter``,
    "stkf" (self-tuning R) or "kf" (R = the rule's); ValueError for another name."""
    if filter not in FILTERS:
        raise ValueError(f"filter={filter!r} is not allowed; choose one of {list(FILTERS)}")
    base = params or RULE_PARAMS
    return VSEParams(**{**base.__dict__, "self_tuning": filter == "stkf"})


def estimator_setup(
    env: TargetFollowerEnv,
    filter: str,
    params: VSEParams | None,
    r_scale: float,
    fused_at_delivery: bool,
) -> tuple[VSEParams, NoiseRule | Table1Noise]:
    """The parameters and noise of an observer's estimator: the noise rule with
    :data:`RULE_PARAMS` when ``params`` is None, else the spec's procedure ``params`` with
    Table 1's noise."""
    chosen = filter_params(filter, params)
    if params is None:
        return chosen, NoiseRule.for_env(env, r_scale, fused_at_delivery)
    return chosen, Table1Noise(chosen, r_scale)


class TargetFollowerObserver:
    """The default observer pipeline for TargetFollower-v0 (see the module docstring).

    Args:
        env: the TargetFollower env (its calibration and obs_mode are read).
        filter: "stkf" (self-tuning R, the default) or "kf" (the rule's R).
        params: the spec's procedure with Table 1's noise (default: the noise rule with
            :data:`RULE_PARAMS`); its ``self_tuning`` is set from ``filter``.
        camera_params: the f_x, f_y, W, delta_y that B_i uses (default: the env's
            calibration; the Table 2 study passes perturbed ones).
        detector: the rgb detector.
        r_scale: the measurement noise covariance the rule gives, times this (for
            sensitivity studies; the consistency tests check that 100 fails); > 0.
    """

    def __init__(
        self,
        env: TargetFollowerEnv,
        filter: str = "stkf",
        params: VSEParams | None = None,
        camera_params: TargetFollowerCameraParams | None = None,
        detector: TargetFollowerDetector | None = None,
        r_scale: float = 1.0,
    ) -> None:
        self.params, noise = estimator_setup(env, filter, params, r_scale, True)
        self.vse = VisualStateEstimator(self.params, noise)
        self.filter = filter
        self.camera_params = camera_params or TargetFollowerCameraParams.from_calibration(
            env.calibration
        )
        self.delta_y_m = env.calibration["delta_y_m"]
        self.frames = FrameReader(env, detector)
        self.detector = self.frames.detector
        self.reset()

    def reset(self) -> None:
        self.vse.reset()
        self._time_s: float | None = None
        self._tilt_rad = 0.0
        self._last_image = np.zeros(3)

    def detect(self, obs: Any, frame: dict) -> np.ndarray | None:
        """(x_i, y_i, d_x) of one frame, or None (also when an entry is NaN or inf)."""
        return self.frames.detect(obs, frame)

    def observe(self, obs: Any, info: dict, action: np.ndarray | None) -> Estimate:
        frames = info["frames"]
        z = self.detect(obs, frames[0]) if frames else None
        robot = RobotStep.from_info(info, action, self.delta_y_m)
        vse = self.vse
        if action is None or self._time_s is None:  # after a reset
            vse.reset()
            used = vse.step(z, np.zeros((3, 3)), np.zeros(3), 1.0, robot.tilt_rad)
        else:
            dt_s = round(robot.time_s - self._time_s, 9)
            tilt_rad, params = self._tilt_rad, self.camera_params

            def B_i(X_i: np.ndarray) -> np.ndarray:  # at each track's estimate
                return robot_jacobian(X_i, tilt_rad, params)

            used = vse.step(z, B_i, robot.applied, dt_s, tilt_rad)
        self._time_s = robot.time_s
        self._tilt_rad = robot.tilt_rad
        visible = z is not None
        kf = vse.kf if vse.valid else None  # the main track's filter, while valid
        if kf is not None:
            self._last_image = kf.x[:3].copy()
            # the image of the frames' capture: plus what it did over their age
            P = vse.noise.reported(kf.P, kf.x, kf.x[3:] + vse.robot_rate)
            mean, cov = state_estimate(kf.x[:3], kf.x[3:], P, robot, True, visible)
        else:
            mean, cov = lost_estimate(
                self._last_image, self.params.reliability_threshold, robot, visible
            )
        update = vse.last_update
        if update is not None and update.accepted:
            return Estimate(mean, cov, used, z, robot.time_s, update.nis, 3)
        return Estimate(mean, cov, used, z, robot.time_s)
