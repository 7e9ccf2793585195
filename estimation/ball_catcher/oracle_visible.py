"""BallCatcher's ``oracle-visible`` observer: the true ball state while the ball is seen.

FOR ANALYSIS ONLY: it reads the env's ground truth (``info["state"]``), which no real
observer has. It tells apart what occlusion and latency cost (the ball not seen, or seen
late) from what the filters cost: it knows the ball exactly whenever a filter could have
had a measurement, and nothing more.

At each step: if at least one frame delivered this step shows the ball (through the same
detection as the other observers, :class:`~observer_gym.estimation.ball_catcher.frames.FrameReader`:
the rgb detector on the image, the perfect detector's report in measurements mode), the
ball's true position and velocity now (at the step's time, whatever the frame's capture
time); otherwise the last true state so read, predicted to the step's time by the ball's
flight model (:class:`~observer_gym.estimation.ball_catcher.models.BallFlight`: gravity,
and the env's air drag when it has it), which is exact for free flight up to the physics
integrator (and wrong once the ball has hit something). Before the first such step: the
viewline filter's prior (:func:`~observer_gym.estimation.ball_catcher.observer.initial_estimate`),
predicted from time 0. The box part is the robot's kinematics, as for every observer.

Covariance: zero (it reads the truth; while predicting, the prediction's error is not
modelled). No innovation, so no NIS.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from observer_gym.envs.ball_catcher import BallCatcherEnv
from observer_gym.envs.ball_catcher.layout import BALL
from observer_gym.estimation.ball_catcher.detector import BallCatcherDetector
from observer_gym.estimation.ball_catcher.frames import FrameReader
from observer_gym.estimation.ball_catcher.models import BallFlight, env_drag_per_m
from observer_gym.estimation.ball_catcher.observer import initial_estimate
from observer_gym.estimation.ball_catcher.state_layout import state_estimate
from observer_gym.estimation.observer import Estimate

__all__ = ["OracleVisibleObserver"]


class OracleVisibleObserver:
    """The ``oracle-visible`` observer of BallCatcher-v1: ground truth while the ball is
    detected, predicted otherwise (see the module docstring; for analysis only).

    Args:
        env: the (unwrapped) BallCatcher env, made with obs_mode "rgb" or "measurements".
        detector: the rgb detector (default :class:`BallCatcherDetector`).
    """

    def __init__(self, env: BallCatcherEnv, detector: BallCatcherDetector | None = None) -> None:
        if not isinstance(env, BallCatcherEnv):
            raise ValueError(
                f"OracleVisibleObserver needs a BallCatcherEnv, got {type(env).__name__}"
            )
        cfg = env.config
        self.pixels = FrameReader(cfg, detector, owner="OracleVisibleObserver")
        self.flight = BallFlight(env_drag_per_m(cfg.air_drag), accel_noise_std=0.0)
        self.x0, _ = initial_estimate(cfg)
        self.reset()

    def reset(self) -> None:
        self._seen_s, self._seen_ball = 0.0, self.x0.copy()  # the last truth read (or prior)
        self.seen_steps = 0

    def observe(self, obs: Any, info: dict, action: np.ndarray | None) -> Estimate:
        reports, detected = [], False
        for frame in info["frames"]:
            uv = self.pixels.detect(frame)
            reports.append({"camera_id": frame["camera_id"], "uv_px": uv})
            detected |= uv is not None
        now_s = float(info["time_s"])
        if detected:
            self._seen_s, self._seen_ball = now_s, np.array(info["state"][BALL], dtype=float)
            self.seen_steps += 1
            ball = self._seen_ball.copy()
        else:
            ball = self.flight.state_at(self._seen_ball, now_s - self._seen_s)
        mean, covariance = state_estimate(ball, np.zeros((6, 6)), info)  # the truth: 0
        return Estimate(
            mean=mean,
            covariance=covariance,
            measurement_used=detected,
            measurement=reports or None,
            time_s=now_s,
        )
