"""BallCatcher's self-calibrating observers: ``selfcal`` estimates each camera's
calibration error together with the ball; ``endpoint`` adds the box's hole, whose world
position the robot's kinematics give, as a landmark seen by the cameras that have it in
view (docs/results/ball_catcher_calibration.md).

The model. Each camera's calibration error is the parameter vector c_j of
:mod:`~observer_gym.estimation.ball_catcher.calibration_consider` (rotation about the
camera's axes, translation along them, focal scale, principal point: the kinds
``env.sensor_spec`` declares uncertain), constant over a throw, prior N(0, V) from the
declared sizes. :class:`SelfCalibratingObserver` is the pixel EKF
(:mod:`~observer_gym.estimation.ball_catcher.pixel_ekf`) on the augmented state
(ball, c_1, ..., c_N) with the kinds in ``estimated`` as states (by default all four;
the others stay consider parameters, as in ``ekf``):

    y = h(p; camera moved by c_j) + e          a frame of camera j (the ball's pixel)
    y = h(p_hole; camera moved by c_j) + e     a landmark: the hole's pixel, p_hole known

both relinearised at the estimate in c as well as in p (the iterated update), so the
camera a frame is projected through is the one the filter believes in. A landmark row
is zero on the ball: it reaches the ball's estimate through Cov(x, c).

Why the endpoint closed loop works. A camera that sees both the ball and the hole sees
both moved by its own error: a principal-point offset moves them alike, a small rotation
w about the camera's y axis moves a pixel (x, y) (normalised) by -f (1 + x^2) w, so
their difference only by -f (x_b^2 - x_h^2) w, a tenth or less of either's near the box
(tests/estimation/test_ball_catcher_self_calibrating.py). In the filter: each frame of
the hole measures that camera's c, and the ball's pixels in the same camera are then
read through the corrected camera. At the default placement camera 1 has the box in view
and camera 0 does not; camera 0 gets its error only from the ball seen by both.

Why an estimating filter and not a least-squares fit over the throw: the controller needs
an estimate with its covariance at every 10 ms step, late frames are re-fused at their
capture times by the pixel EKF's machinery, and over one throw the iterated filter and a
Gauss-Newton fit of the same model differ only by the relinearisation of early frames.
Why the pixel EKF and not the viewline filter: it projects through the estimated camera
(the viewline rows are built from the nominal camera and the measured pixel), and it
models the field level's air drag. A viewline version (the same rows plus J c) was tried
and caught alike at lab (0.475 of 200 throws, seeds 5000-5199).

What the frames can and cannot tell (measured, docs/results/ball_catcher_calibration.md):
the ball alone says little of the cameras. A rotation and translation of the whole rig
about the vertical moves every trajectory the cameras see and leaves gravity as it is,
and a principal-point offset and a rotation about the image axes move the image alike;
``selfcal`` catches as ``ekf`` does at lab. The hole pins camera 1 to 0.1-0.3 px within
one throw; ``endpoint`` catches 0.45 of lab's official throws against ``ekf``'s 0.30.

One rig over many throws (``calib_error_draw="fixed"``, the env's own declaration of a
rig that keeps its cameras): with ``carry_over`` (default: on exactly then) each throw
starts from the previous throw's estimate of the cameras, taken at the last step of free
flight (the ball's estimated centre more than its radius in front of the box's plane,
the first time it gets there: later frames of a ball touching the box, and a restart on
them, would be fitted by moving the cameras). Measured over 20 throws
(docs/results/ball_catcher_calibration.md): camera 1, measured by the hole, goes from
1.4 px off at the hole to 0.01-0.08 px after four throws; camera 0, the ball its only
evidence, from 0.95 px along its view of the flight to 0.3-0.7 px, and no further (what
the flights cannot see of it stays). The catch rate does not gain from it (0.53 [0.46,
0.59] of 200 throws with, 0.52 [0.45, 0.59] without): within one throw the hole already
puts camera 1 within 0.1-0.25 px.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from observer_gym.envs.ball_catcher import BallCatcherEnv
from observer_gym.envs.ball_catcher import geometry as geo
from observer_gym.envs.ball_catcher.layout import BALL_POS
from observer_gym.estimation.ball_catcher.calibration_consider import CalibrationConsider
from observer_gym.estimation.ball_catcher.pixel_ekf import LandmarkMeasurement, PixelEKFObserver
from observer_gym.estimation.latency import TimedMeasurement
from observer_gym.estimation.observer import Estimate

__all__ = ["BoxTrack", "EndpointObserver", "SelfCalibratingObserver"]

ESTIMATED_KINDS = ("rotation", "principal_point", "focal", "translation")


def checked_hole_pixel(value: Any) -> np.ndarray | None:
    """A frame's ``hole_uv_px`` as a float (2,) array; None for no detection (None, NaN or
    inf, as for the ball); ``ValueError`` for anything but two real numbers."""
    if value is None:
        return None
    try:
        uv = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        uv = None
    if uv is None or uv.shape != (2,) or np.iscomplexobj(value):
        raise ValueError(f"endpoint: hole_uv_px = {value!r}, must be two real numbers or None")
    return uv if np.all(np.isfinite(uv)) else None


class BoxTrack:
    """Where the hole was at a past time, from the robot's kinematics at each step
    (``info["box_pos_world_m"]`` and ``info["box_vel_world_mps"]`` at ``info["time_s"]``):
    linear between the steps around it, along the velocity past the newest."""

    def __init__(self) -> None:
        self.times_s: list[float] = []
        self.positions_m: list[np.ndarray] = []
        self._velocity_mps = np.zeros(3)

    def add(self, info: dict) -> None:
        t_s = float(info["time_s"])
        if self.times_s and t_s <= self.times_s[-1]:
            return
        self.times_s.append(t_s)
        self.positions_m.append(np.asarray(info["box_pos_world_m"], dtype=float).copy())
        self._velocity_mps = np.asarray(info["box_vel_world_mps"], dtype=float).copy()

    def at(self, t_s: float) -> np.ndarray:
        times = self.times_s
        if not times:
            raise ValueError("BoxTrack.at: no step recorded yet")
        if t_s >= times[-1]:
            return self.positions_m[-1] + self._velocity_mps * (t_s - times[-1])
        if t_s <= times[0]:
            return self.positions_m[0].copy()
        i = int(np.searchsorted(times, t_s))
        w = (t_s - times[i - 1]) / (times[i] - times[i - 1])
        return (1.0 - w) * self.positions_m[i - 1] + w * self.positions_m[i]


class SelfCalibratingObserver(PixelEKFObserver):
    """``selfcal``: :class:`PixelEKFObserver` with each camera's declared-uncertain
    calibration parameters of the kinds ``estimated`` as states of the filter (see the
    module docstring).

    Args:
        env: the (unwrapped) BallCatcher env, made with obs_mode "rgb" or "measurements".
        estimated: the calibration kinds estimated, of "rotation", "translation",
            "focal", "principal_point" (only the ones the env declares uncertain take
            part; the others stay consider parameters, as in ``ekf``); () estimates none.
        landmarks: fuse the hole's pixels of every frame that reports them
            (``hole_measurements=True``) as a landmark (:class:`EndpointObserver`).
        carry_over: start each throw from the previous throw's estimate of the cameras;
            None (default): exactly when the env declares one rig over the throws
            (``calib_error_draw="fixed"``).
        **options: the pixel EKF's (:class:`PixelEKFObserver`).

    A bad option raises ``ValueError`` naming it; so does a frame's ``hole_uv_px`` that is
    not two real numbers (NaN or inf is no detection, as for the ball).
    """

    def __init__(
        self,
        env: BallCatcherEnv,
        estimated: tuple[str, ...] = ESTIMATED_KINDS,
        landmarks: bool = False,
        carry_over: bool | None = None,
        **options: Any,
    ) -> None:
        super().__init__(env, **options)
        if not isinstance(landmarks, (bool, np.bool_)):
            raise ValueError(
                f"SelfCalibratingObserver: landmarks = {landmarks!r}, must be True or False"
            )
        if carry_over is not None and not isinstance(carry_over, (bool, np.bool_)):
            raise ValueError(
                f"SelfCalibratingObserver: carry_over = {carry_over!r}, must be True, False or None"
            )
        self.parameters = CalibrationConsider(
            env.sensor_spec, env.config.cameras, estimated=estimated
        )
        self.calibration = self.parameters  # what the pixel EKF's core reads
        self.landmarks = bool(landmarks)
        fixed = env.config.calib_error_draw == "fixed"
        self.carry_over = (fixed if carry_over is None else bool(carry_over)) and bool(
            self.parameters.estimated
        )
        self._in_flight: tuple[np.ndarray, np.ndarray] | None = None
        self.reset()

    def reset(self) -> None:
        snapshot: tuple[np.ndarray, np.ndarray] | None = getattr(self, "_in_flight", None)
        if snapshot is not None and self.carry_over and self.parameters.active:
            self.parameters.carry_over(snapshot[0], snapshot[1])
        self._in_flight = None
        self._reached_box = False
        self.box = BoxTrack()
        super().reset()

    def estimate_in_flight(self) -> np.ndarray:
        """The filter's augmented state (ball, then each camera's parameters) as the last
        step of free flight left it (what the next throw's prior is taken from); the
        current one before that step."""
        if self._in_flight is None:
            return self.core.ekf.x.copy()
        return self._in_flight[0].copy()

    def forget_calibration(self) -> None:
        """Back to the declared calibration prior (a rig whose cameras were moved)."""
        self.parameters.forget()
        self._in_flight = None
        self.reset()

    def _landmarks(self, info: dict) -> list[TimedMeasurement]:
        if not (self.landmarks and self.parameters.active):
            return []
        found = []
        for frame in info["frames"]:
            uv = checked_hole_pixel(frame.get("hole_uv_px"))
            if uv is None:
                continue
            t_s = float(frame["capture_time_s"])
            m = LandmarkMeasurement(
                frame["camera_id"], frame["K"], frame["T_world_cam"], uv, self.box.at(t_s)
            )
            found.append(TimedMeasurement(t_s, m))
        return found

    def observe(self, obs: Any, info: dict, action: np.ndarray | None) -> Estimate:
        self.box.add(info)
        estimate = super().observe(obs, info, action)
        # What the next throw starts from: the estimate while the ball still flies freely,
        # its centre more than its radius in front of the box's front plane; not after
        # it first reached that (a restart on frames of a ball bouncing off the box would
        # start the cameras over from their prior).
        plane_x_m = float(info["box_pos_world_m"][0])
        if not self._reached_box:
            if float(estimate.mean[BALL_POS][0]) > plane_x_m + geo.BALL_RADIUS_M:
                self._in_flight = (self.core.ekf.x.copy(), self.core.ekf.P.copy())
            else:
                self._reached_box = True
        return estimate


class EndpointObserver(SelfCalibratingObserver):
    """``endpoint``: :class:`SelfCalibratingObserver` with the hole as a landmark; the env
    must report the hole's pixels (``hole_measurements=True``, measurements mode), else
    ``ValueError``."""

    def __init__(self, env: BallCatcherEnv, **options: Any) -> None:
        cfg = env.config
        if cfg.obs_mode != "measurements" or not cfg.hole_measurements:
            raise ValueError(
                "endpoint needs the hole's pixels: an env made with obs_mode='measurements' "
                f"and hole_measurements=True, got obs_mode={cfg.obs_mode!r}, "
                f"hole_measurements={cfg.hole_measurements!r}"
            )
        if "landmarks" in options:
            raise ValueError("endpoint: landmarks is always on (selfcal is without)")
        super().__init__(env, landmarks=True, **options)
