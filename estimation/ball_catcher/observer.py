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

Initial estimate (docs/spec/catcher.md, "Initialisation"): the centre of the throw
distribution's launch region with the velocity of a throw from there to the hole's home
in the middle of the flight-time range, both with a standard deviation of 10 m and
10 m/s (the paper's 10^2 variance): large enough that the first frames decide, small
enough for no round-off in (10).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from observer_gym.envs.ball_catcher import BallCatcherEnv
from observer_gym.envs.ball_catcher import geometry as geo
from observer_gym.envs.ball_catcher.layout import BALL, BOX_POS, BOX_VEL, STATE_DIM
from observer_gym.envs.ball_catcher.throws import throw_through
from observer_gym.estimation.ball_catcher.detector import BallCatcherDetector
from observer_gym.estimation.ball_catcher.filters import DEFAULT_GATE_P, ViewlineKalmanFilter
from observer_gym.estimation.observer import Estimate

INITIAL_STD_POS_M = 10.0
INITIAL_STD_VEL_MPS = 10.0
RGB_PIXEL_STD_PX = (
    0.2  # the detector: 0.09 px RMS in view (tests/estimation/test_ball_catcher_observer.py)
)
# The ballistic model's white acceleration noise (m/s^2 per sqrt(s)). The default world
# has no drag, so only round-off and the physics integrator depart from (19)-(20): a
# small value lets the filter average over the whole flight. Measured with the
# intercept controller, "paper" profile, measurements mode, 60 throws: 0.5 caught 54,
# 0.05 caught 60 (crossing-point error at 0.1 s to go, median 3.4 mm).
ACCEL_NOISE_STD = 0.05


class BallCatcherObserver:
    """Detector + viewline Kalman filter for BallCatcher-v0.

    Args:
        env: the (unwrapped) BallCatcher env, made with obs_mode "rgb" or "measurements".
        pixel_std_px: the pixel noise the filter assumes (default: the env's
            ``measurement_noise_px`` in measurements mode, floored at 0.1 px for
            round-off, and RGB_PIXEL_STD_PX for the rgb detector).
        gate_p: p of the outlier test (30); None switches the gate off.
        accel_noise_std: the ballistic model's white acceleration noise (m/s^2 per sqrt(s)).
        detector: the rgb detector (default :class:`BallCatcherDetector`).
    """

    def __init__(
        self,
        env: BallCatcherEnv,
        pixel_std_px: float | None = None,
        gate_p: float | None = DEFAULT_GATE_P,
        accel_noise_std: float = ACCEL_NOISE_STD,
        detector: BallCatcherDetector | None = None,
    ) -> None:
        if not isinstance(env, BallCatcherEnv):
            raise ValueError(
                f"BallCatcherObserver needs a BallCatcherEnv, got {type(env).__name__}"
            )
        cfg = env.config
        self.rgb = cfg.obs_mode == "rgb"
        if pixel_std_px is None:
            pixel_std_px = RGB_PIXEL_STD_PX if self.rgb else max(cfg.measurement_noise_px, 0.1)
        self.pixel_std_px = float(pixel_std_px)
        self.gate_p = gate_p
        self.accel_noise_std = float(accel_noise_std)
        self.detector = detector if detector is not None else BallCatcherDetector()
        launch = np.array([cfg.launch_x_m, 0.0, cfg.launch_height_m])
        mid_flight_s = 0.5 * (cfg.flight_time_min_s + cfg.flight_time_max_s)
        typical = throw_through(launch, geo.HOLE_HOME_WORLD, mid_flight_s)
        self.x0 = np.concatenate([launch, typical.launch_vel_world])
        self.P0 = np.diag([INITIAL_STD_POS_M**2] * 3 + [INITIAL_STD_VEL_MPS**2] * 3)
        self.filter: ViewlineKalmanFilter | None = None
        self.reset()

    def reset(self) -> None:
        self.filter = ViewlineKalmanFilter(
            self.x0,
            self.P0,
            pixel_std_px=self.pixel_std_px,
            gate_p=self.gate_p,
            accel_noise_std=self.accel_noise_std,
        )

    def observe(self, obs: Any, info: dict, action: np.ndarray | None) -> Estimate:
        kf = self.filter
        used_before = kf.accepted_count
        measurements = []
        for frame in info["frames"]:
            uv = self.detector.detect(frame["image"]) if self.rgb else frame["uv_px"]
            measurements.append({"camera_id": frame["camera_id"], "uv_px": uv})
            kf.add_frame(frame["capture_time_s"], frame["K"], frame["T_world_cam"], uv)
        now_s = float(info["time_s"])
        x_ball, P_ball = kf.predicted(now_s)
        mean = np.zeros(STATE_DIM)
        mean[BALL] = x_ball
        mean[BOX_POS] = info["box_pos_world_m"]
        mean[BOX_VEL] = info["box_vel_world_mps"]
        covariance = np.zeros((STATE_DIM, STATE_DIM))
        covariance[BALL, BALL] = P_ball
        return Estimate(
            mean=mean,
            covariance=covariance,
            measurement_used=kf.accepted_count > used_before,
            measurement=measurements or None,
            time_s=now_s,
        )
