"""The BallCatcher observer pipeline: every delivered frame into the viewline Kalman filter.

For each frame of a step (``info["frames"]``, in capture-time order, each with its capture
time, K and ``T_world_cam``), the ball's pixel centre (the detector's on the frame's image
in ``obs_mode="rgb"``, the env's perfect-detector report in ``"measurements"``) updates
:class:`~observer_gym.estimation.ball_catcher.filters.ViewlineKalmanFilter` at the frame's exact
capture time; a frame captured before one already used (latency) is handled by the
filter's re-filtering. The estimate reported at each step is the filter's prediction to
the step's time (frames are 0-30 ms old when they arrive). The box's position and
velocity come from the robot's own kinematics (``info["box_pos_world_m"]``,
``info["box_vel_world_mps"]``): a controller knows where its tool is.

Latency: this pipeline is also the observer ``kf-latency`` (the same class under both
names, estimation/ball_catcher/__init__.py). It already does what ``kf-latency`` means:
every frame is fused at its capture time, frames delivered late or out of capture order
(latency, latency jitter, the random_offsets preset's per-camera latencies) by exact
re-filtering, and the estimate is predicted to the step's time, the time at which the
next action is applied. Checked: at 60 ms latency with random offsets and jitter its
estimate at every step equals, to 5e-10 m, a filter fed every frame delivered so far in
capture order and predicted to the step (tests/estimation/test_ball_catcher_observers.py).
The one limit: the filter keeps 1 s of frames (``DEFAULT_HISTORY_S``) behind the newest
one used, and a frame captured earlier raises ``ValueError``. Within the config's bounds
(latency_s <= 0.5 s, one frame period <= 0.2 s of random_offsets' latency spread,
latency_jitter_s <= 0.1 s) a frame arrives that far behind another only when their
latency jitters differ by more than 0.8 s, 5.7 standard deviations of that difference at
the largest jitter.

NIS: ``Estimate.nis`` sums d^T S^-1 d of this step's accepted frames (two viewline rows
each, so ``nis_dof`` = 2 per frame; a late frame's at its capture time); None when none
was accepted.

Initial estimate: the mean and covariance of the ball's launch state under the env's
declared throw distribution (:func:`throw_prior`, in closed form from the config's launch
region, target disc and flight-time range), so that before the first frame arrives the
reported covariance is what the throws spread over, not the paper's 10^2 variance
(docs/spec/catcher.md, "Initialisation"). Why (measured, kf at latency_s = 0.1, seeds
0-2, intercept): with the 10 m prior every step before the first delivered frame (a
quarter of the 0.44 s flight) reported a 17 m standard deviation against a 0.1 m error,
NEES/dof 0.000, and the flight's mean NEES/dof fell from 0.49-0.74 at no latency to
0.29-0.53; from the first frames on the two runs lay alike (0.2-1.2 per 50 ms bin).
A throw set by hand (``reset(options={"throw": ...})``) can lie outside that
distribution; the first frames then contradict the prior, the gate rejects them and the
re-acquisition below restarts from the wide prior (:func:`wide_prior`: 10 m and 10 m/s
around the same mean, the paper's variance), from which the frames decide.

Re-acquisition. The outlier test (27)-(30) compares a detection with the estimate's own
covariance, so once false detections (another green object, a reflection) have been
accepted, the estimate can be metres off with a covariance of millimetres, and the gate
then rejects every good detection for the rest of the flight; or it sits on one camera's
viewline, off along it, where that camera's frames still fit and the other camera's are
all rejected. So when ``reacquire_after`` (default 3) frames of one camera in a row are
gated out (frames of other cameras in between do not break the run), the observer takes
the estimate as lost, not the detections as wrong: the filter restarts from the wide
prior (:func:`wide_prior`, at time 0, so predicted over the elapsed flight with the
model's exact Phi and R1) and filters again every frame of every camera from the first
of that run on (:meth:`ViewlineKalmanFilter.restart`). Why this and not an inflated
covariance around the lost estimate: that estimate can be anywhere, even near a camera
centre, through which every viewline passes (it fits every frame there, see
:func:`~observer_gym.estimation.viewline.viewline_noise_std`); from the wide prior the
frames decide, whatever the throw. The frames filtered again span at least
``reacquire_after`` frame periods of the failing camera, so with two cameras they hold
both cameras' viewlines, which fix the position at once; with one camera the prior and
gravity fix the depth over the next frames, as at the start of a
flight. A good frame is rejected with probability 0.22 % at p = 3.5, so three in a row
from one camera happen about once in 10^8 frames of a clean flight. Frames without a
detection neither break nor extend a run. ``reacquisitions`` counts the restarts. The
price: a burst of false detections that the gate alone would have rejected also restarts
the filter, from frames that include false ones, so during such a burst the estimate is
poor (metres off); 0.04-0.08 s of good frames after it the error is back at millimetres
(measured over 48 flights with 20 frames of uniform random pixels,
tests/estimation/test_ball_catcher_observer.py). The pixel EKF (``ekf``,
estimation/ball_catcher/pixel_ekf.py) restarts in the same way.
Non-finite pixels (NaN, inf) are no detection.

Frames (``obs_mode="rgb"``) must be uint8 images of the env's size (``image_size_px`` of
the frame, else the env config's), H x W x 3: others raise ``ValueError``.
"""

from __future__ import annotations

import math
import numbers
from typing import Any

import numpy as np

from observer_gym.envs.ball_catcher import BallCatcherEnv
from observer_gym.envs.ball_catcher import geometry as geo
from observer_gym.envs.sim import GRAVITY_MPS2
from observer_gym.estimation.ball_catcher.calibration_consider import CalibrationConsider
from observer_gym.estimation.ball_catcher.detector import BallCatcherDetector
from observer_gym.estimation.ball_catcher.filters import DEFAULT_GATE_P, ViewlineKalmanFilter
from observer_gym.estimation.ball_catcher.frames import FrameReader
from observer_gym.estimation.ball_catcher.state_layout import state_estimate
from observer_gym.estimation.filters import UpdateResult
from observer_gym.estimation.observer import Estimate
from observer_gym.estimation.r_scale import checked_r_scale

WIDE_STD_POS_M = 10.0
WIDE_STD_VEL_MPS = 10.0
# The detector's error model: 0.095 px RMS in view on noiseless frames and 0.19 px (the
# larger axis) at the largest image_noise_std, 64 (tests/estimation/
# test_ball_catcher_observer.py); between them std = hypot(0.095, k sigma_image), k from
# the two ends (an interpolation: only the ends are measured).
RGB_PIXEL_STD_PX = 0.095
RGB_PIXEL_STD_AT_MAX_NOISE_PX = 0.19
MAX_IMAGE_NOISE_STD = 64.0


def rgb_pixel_std_px(image_noise_std: float) -> float:
    """The rgb detector's pixel error (std) at the declared ``image_noise_std``."""
    # k sigma_image with k^2 64^2 = 0.19^2 - 0.095^2
    k = math.sqrt(RGB_PIXEL_STD_AT_MAX_NOISE_PX**2 - RGB_PIXEL_STD_PX**2) / MAX_IMAGE_NOISE_STD
    return math.hypot(RGB_PIXEL_STD_PX, k * float(image_noise_std))


# The ballistic model's white acceleration noise (m/s^2 per sqrt(s)). The default world
# has no drag, so only round-off and the physics integrator depart from (19)-(20): a
# small value lets the filter average over the whole flight. Measured with the
# intercept controller, "paper" profile, measurements mode, 60 throws: 0.5 caught 54,
# 0.05 caught 60 (crossing-point error at 0.1 s to go, median 3.4 mm).
ACCEL_NOISE_STD = 0.05
DEFAULT_REACQUIRE_AFTER = 3  # consecutive gate rejections that restart the filter


def default_pixel_std_px(env: BallCatcherEnv, r_scale: float = 1.0) -> float:
    """The pixel noise the BallCatcher filters assume in R (their noise rule): in
    measurements mode the declared noise, ``env.sensor_spec.measurement_noise_std_px``
    (with its float32 floor); in rgb mode the detector's error model
    (:func:`rgb_pixel_std_px`); R = std^2 I times ``r_scale``. The declared calibration
    uncertainty is not in it: the filters carry it as consider parameters
    (:func:`calibration_consider`)."""
    r_scale = checked_r_scale(r_scale)
    if env.config.obs_mode == "rgb":
        std = rgb_pixel_std_px(env.sensor_spec.image_noise_std)
    else:
        std = env.sensor_spec.measurement_noise_std_px
    return math.sqrt(std**2 * r_scale)


def calibration_consider(env: BallCatcherEnv, enabled: Any = True) -> CalibrationConsider | None:
    """The filters' consider parameters for the declared calibration uncertainty
    (``env.sensor_spec``, every camera of the env; see
    :mod:`~observer_gym.estimation.ball_catcher.calibration_consider`), or None when
    ``enabled`` is False (the offsets left out, to show what they do). ``enabled`` must be
    a bool, else ``ValueError``."""
    if not isinstance(enabled, (bool, np.bool_)):
        raise ValueError(f"consider_calibration = {enabled!r}, must be True or False")
    if not enabled:
        return None
    return CalibrationConsider(env.sensor_spec, env.config.cameras)


def calibration_pixel_var_px2(env: BallCatcherEnv) -> float:
    """The declared calibration uncertainty (``env.sensor_spec``) as a variance per pixel
    axis (px^2), at the image's corner (its largest): a rotation of s rad about a uniform
    direction moves a pixel by f s about the camera's x and y axes and by r s about its
    optical axis (r: the distance from the principal point, at most the half-diagonal),
    per-axis variance (f^2 + r^2) s^2 / 3; a focal scale error e_f moves it by e_f r;
    a principal-point offset of p px, p^2 / 2 per axis. Translation errors are not in it
    (their pixel shift depends on the ball's depth). Only the triangulating ``raw``
    observer's covariance uses it, as white pixel noise; the filters carry the offsets as
    consider parameters (:func:`calibration_consider`)."""
    sensor = env.sensor_spec
    intrinsics = env.camera_intrinsics()[0]
    f = intrinsics.fx_px
    r = 0.5 * math.hypot(intrinsics.width_px, intrinsics.height_px)
    s = math.radians(sensor.calib_rotation_error_deg)
    # (f^2 + r^2) s^2 / 3 + (e_f r)^2 + p^2 / 2
    return (
        (f * f + r * r) * s * s / 3.0
        + (sensor.calib_focal_error * r) ** 2
        + sensor.calib_principal_point_error_px**2 / 2.0
    )


class RejectionRuns:
    """Per camera, the current run of frames in a row a filter did not use (gated out):
    the capture time of its first and its length. When one camera's run reaches
    ``reacquire_after`` the estimate is taken as lost (not the frames wrong): the filter
    restarts from the first frame of that run on, and every run starts anew."""

    def __init__(self, reacquire_after: int) -> None:
        self.reacquire_after = reacquire_after
        self._runs: dict[Any, tuple[float, int]] = {}  # camera -> (first capture, count)

    def used(self, camera: Any) -> None:
        """A frame of ``camera`` was used: its run ends."""
        self._runs.pop(camera, None)

    def not_used(self, camera: Any, capture_time_s: float) -> float | None:
        """A frame of ``camera`` captured at ``capture_time_s`` was not used: the capture
        time to restart from when its run reached ``reacquire_after`` (every run then
        ends), else None."""
        first_s, count = self._runs.get(camera, (capture_time_s, 0))
        first_s, count = min(first_s, capture_time_s), count + 1
        if count < self.reacquire_after:
            self._runs[camera] = (first_s, count)
            return None
        self._runs.clear()
        return first_s

    def oldest_start_s(self, default_s: float) -> float:
        """The first capture time of the oldest open run, or ``default_s`` if earlier."""
        return min([default_s] + [first_s for first_s, _ in self._runs.values()])


def checked_reacquire_after(reacquire_after: Any, owner: str) -> int:
    """``reacquire_after`` as an int: an integer >= 1 (a Python or NumPy integer, not a
    bool), else ``ValueError`` naming ``owner``."""
    if (
        isinstance(reacquire_after, bool)
        or not isinstance(reacquire_after, numbers.Integral)
        or reacquire_after < 1
    ):
        raise ValueError(f"{owner}: reacquire_after = {reacquire_after!r}, must be an integer >= 1")
    return int(reacquire_after)


def throw_prior(config: Any) -> tuple[np.ndarray, np.ndarray]:
    """The mean x0 (6,) and covariance P0 (6, 6) of the ball's launch state (position m,
    velocity m/s, world frame) at time 0 under ``config``'s throw distribution
    (envs/ball_catcher/throws.py ``sample_throw``): launch l uniform in the cube of
    half-side s around l0, crossing c uniform in the disc of radius r around the hole's
    home in the plane x = const, flight time T uniform in [T1, T2], independent, and
    v = (c - l) / T + e_z g T / 2. With w = c - l (mean m = c0 - l0, covariance
    W = s^2/3 I + r^2/4 diag(0, 1, 1)) and a = 1 / T:

        E[a] = ln(T2 / T1) / (T2 - T1),  E[a^2] = 1 / (T1 T2),  Var T = (T2 - T1)^2 / 12
        E[v] = m E[a] + e_z g E[T] / 2
        Cov(v) = E[a^2] (W + m m^T) - E[a]^2 m m^T + (g/2)^2 Var T e_z e_z^T
                 + (g/2) (1 - E[a] E[T]) (m e_z^T + e_z m^T)
        Cov(l) = s^2/3 I,  Cov(l, v) = -E[a] s^2/3 I

    (checked against sampled throws in tests/estimation/test_ball_catcher_prior.py)."""
    g = GRAVITY_MPS2
    launch_m = np.array([config.launch_x_m, 0.0, config.launch_height_m])
    t1, t2 = float(config.flight_time_min_s), float(config.flight_time_max_s)
    # E[1/T] = ln(T2/T1) / (T2 - T1), 1/T when T1 = T2
    mean_inv_t = math.log(t2 / t1) / (t2 - t1) if t2 > t1 else 1.0 / t1
    mean_inv_t2 = 1.0 / (t1 * t2)  # E[1/T^2]
    mean_t, var_t = 0.5 * (t1 + t2), (t2 - t1) ** 2 / 12.0
    launch_var_m2 = config.launch_spread_m**2 / 3.0  # uniform in [-s, s]
    disc_var_m2 = config.target_radius_m**2 / 4.0  # uniform in a disc, per in-plane axis
    m = geo.HOLE_HOME_WORLD - launch_m
    W = launch_var_m2 * np.eye(3) + disc_var_m2 * np.diag([0.0, 1.0, 1.0])
    e_z = np.array([0.0, 0.0, 1.0])
    # E[v] = m E[a] + e_z g E[T] / 2
    mean_v = m * mean_inv_t + e_z * (0.5 * g * mean_t)
    # Cov(v) = E[a^2] (W + m m^T) - E[a]^2 m m^T + (g/2)^2 Var T e_z e_z^T
    #          + (g/2) (1 - E[a] E[T]) (m e_z^T + e_z m^T)
    mm = np.outer(m, m)
    cross = np.outer(m, e_z)
    cov_v = (
        mean_inv_t2 * (W + mm)
        - mean_inv_t**2 * mm
        + (0.5 * g) ** 2 * var_t * np.outer(e_z, e_z)
        + 0.5 * g * (1.0 - mean_inv_t * mean_t) * (cross + cross.T)
    )
    P0 = np.zeros((6, 6))
    P0[:3, :3] = launch_var_m2 * np.eye(3)  # Cov(l)
    P0[:3, 3:] = P0[3:, :3] = -mean_inv_t * launch_var_m2 * np.eye(3)  # Cov(l, v)
    P0[3:, 3:] = 0.5 * (cov_v + cov_v.T)
    return np.concatenate([launch_m, mean_v]), P0


def wide_prior(config: Any) -> tuple[np.ndarray, np.ndarray]:
    """The prior a lost estimate restarts from (see the module docstring): the mean of
    :func:`throw_prior` with standard deviations 10 m and 10 m/s (the paper's 10^2
    variance), large enough that the frames decide, small enough for no round-off in (10)."""
    x0, _ = throw_prior(config)
    return x0, np.diag([WIDE_STD_POS_M**2] * 3 + [WIDE_STD_VEL_MPS**2] * 3)


def initial_estimate(config: Any) -> tuple[np.ndarray, np.ndarray]:
    """The prior (x0, P0) every flight's filter starts from: :func:`throw_prior`."""
    return throw_prior(config)


# when a frame is fused: at its capture time, or at its delivery as if captured then
FUSE_AT = ("capture", "delivery")


class BallCatcherObserver:
    """Detector + viewline Kalman filter for BallCatcher-v1.

    Args:
        env: the (unwrapped) BallCatcher env, made with obs_mode "rgb" or "measurements".
        pixel_std_px: the pixel noise the filter assumes (default:
            :func:`default_pixel_std_px`, the declared noise).
        gate_p: p of the outlier test (30); None switches the gate off.
        accel_noise_std: the ballistic model's white acceleration noise (m/s^2 per sqrt(s)).
        detector: the rgb detector (default :class:`BallCatcherDetector`).
        reacquire_after: consecutive gate rejections after which the filter restarts
            from the prior and the rejected frames (see the module docstring); an
            integer >= 1.
        r_scale: the default pixel noise's R times this (> 0; sensitivity studies).
        consider_calibration: carry the declared calibration uncertainty as consider
            parameters (default True; False leaves it out, to show its effect).
        fuse_at: "capture" (default): each frame at its capture time (latency-aware);
            "delivery": each frame as if captured when it is delivered (the observer
            ``kf-at-delivery``: a filter without latency handling, the reference that
            shows what the capture time buys).
    """

    def __init__(
        self,
        env: BallCatcherEnv,
        pixel_std_px: float | None = None,
        gate_p: float | None = DEFAULT_GATE_P,
        accel_noise_std: float = ACCEL_NOISE_STD,
        detector: BallCatcherDetector | None = None,
        reacquire_after: int = DEFAULT_REACQUIRE_AFTER,
        r_scale: float = 1.0,
        consider_calibration: bool = True,
        fuse_at: str = "capture",
    ) -> None:
        if not isinstance(env, BallCatcherEnv):
            raise ValueError(
                f"BallCatcherObserver needs a BallCatcherEnv, got {type(env).__name__}"
            )
        if fuse_at not in FUSE_AT:
            raise ValueError(
                f"BallCatcherObserver: fuse_at must be one of {', '.join(FUSE_AT)}, got {fuse_at!r}"
            )
        # the frame's time the filter takes as its capture time
        self.time_key = f"{fuse_at}_time_s"
        self.calibration = calibration_consider(env, consider_calibration)
        self.reacquire_after = checked_reacquire_after(reacquire_after, "BallCatcherObserver")
        cfg = env.config
        self.pixels = FrameReader(cfg, detector, owner="BallCatcherObserver")
        self.rgb = self.pixels.rgb
        self.detector = self.pixels.detector
        self.pixel_std_px = float(
            default_pixel_std_px(env, r_scale) if pixel_std_px is None else pixel_std_px
        )
        self.gate_p = gate_p
        self.accel_noise_std = float(accel_noise_std)
        self.x0, self.P0 = initial_estimate(cfg)
        self.x_lost, self.P_lost = wide_prior(cfg)  # a restart's prior
        self.reset()  # makes self.filter

    def reset(self) -> None:
        self.filter: ViewlineKalmanFilter = ViewlineKalmanFilter(
            self.x0,
            self.P0,
            pixel_std_px=self.pixel_std_px,
            gate_p=self.gate_p,
            accel_noise_std=self.accel_noise_std,
            calibration=self.calibration,
        )
        self._rejected = RejectionRuns(self.reacquire_after)
        self.reacquisitions = 0
        self._nis, self._nis_dof = 0.0, 0  # this step's accepted frames' NIS and dimension

    def detect(self, frame: dict) -> np.ndarray | None:
        """The ball's pixel (u, v) in one delivered frame, or None (also for NaN, inf or beyond
        MAX_PIXEL_PX); see :class:`FrameReader`."""
        return self.pixels.detect(frame)

    def observe(self, obs: Any, info: dict, action: np.ndarray | None) -> Estimate:
        measurements = []
        used = False
        self._nis, self._nis_dof = 0.0, 0
        for frame in info["frames"]:
            uv = self.detect(frame)
            measurements.append({"camera_id": frame["camera_id"], "uv_px": uv})
            used |= self._add_frame(frame, uv)
        kf = self.filter
        now_s = float(info["time_s"])
        mean, covariance = state_estimate(*kf.predicted(now_s), info)
        return Estimate(
            mean=mean,
            covariance=covariance,
            measurement_used=used,
            measurement=measurements or None,
            time_s=now_s,
            nis=self._nis if self._nis_dof else None,
            nis_dof=self._nis_dof,
        )

    def _add_frame(self, frame: dict, uv: np.ndarray | None) -> bool:
        """Filter one frame; restart after ``reacquire_after`` rejections in a row of its
        camera. Whether the frame was used (at a restart: any frame filtered again)."""
        kf = self.filter
        t_s = float(frame[self.time_key])
        camera = frame["camera_id"]
        result = kf.add_frame(t_s, frame["K"], frame["T_world_cam"], uv, camera)
        if uv is None:
            return False
        # d^T S^-1 d of the frame's two viewline rows (a late frame's: at its capture time)
        return self._counted(result, camera, t_s, dof=2)

    def _counted(self, result: UpdateResult, source: Any, t_s: float, dof: int) -> bool:
        """Book one measurement of ``source`` (a camera, or another measurement stream)
        taken at ``t_s``: its NIS (``dof`` rows) if accepted, else a rejection, and after
        ``reacquire_after`` in a row of that source a restart from the wide prior and the
        measurements since. Whether it was used (at a restart: anything filtered again)."""
        kf = self.filter
        if result.accepted:
            self._rejected.used(source)
            self._nis += result.nis
            self._nis_dof += dof
            return True
        since_s = self._rejected.not_used(source, t_s)
        if since_s is None:
            return False
        self.reacquisitions += 1
        accepted_before = kf.accepted_count
        kf.restart(self.x_lost, self.P_lost, 0.0, since_s)
        return kf.accepted_count > accepted_before
