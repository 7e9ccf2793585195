"""The BallTable observer ``raw`` (:class:`RawObserver`): the detector alone, no filter.

The ball's position and the tilt are the newest detection's, held through misses; the
ball's velocity and the tilt rates are finite differences of successive detections of
each part, over their capture times (also held). Its covariance is a nominal one, not a
filter's: the detection's error as ``kf`` models it (sigma_v on the position,
``tilt_meas_std_rad`` on the tilt) and that of a difference of two such detections over
their interval; it does not grow while a detection is held.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from observer_gym.envs.ball_table import STATE_DIM, BallTableEnv
from observer_gym.envs.ball_table.layout import BALL_POS, BALL_VEL, TILT, TILT_RATE
from observer_gym.estimation.ball_table.frames import FrameReader, detected_parts
from observer_gym.estimation.ball_table.geometry_stage import BallTableDetector
from observer_gym.estimation.ball_table.observer import BallTableObserverParams
from observer_gym.estimation.observer import Estimate

__all__ = ["RawObserver"]


class RawObserver:
    """``raw`` for BallTable-v0: see the module docstring.

    Args:
        env: the (unwrapped) env, made with ``obs_mode="rgb"`` or ``"measurements"``.
        params: the detection's nominal errors (``kf``'s parameters) and the prior before
            the first detection.
        detector: the geometry stage (default :class:`BallTableDetector`).
    """

    def __init__(
        self,
        env: BallTableEnv,
        params: BallTableObserverParams | None = None,
        detector: BallTableDetector | None = None,
    ) -> None:
        self.params = params or BallTableObserverParams()
        self.reader = FrameReader(env, detector, type(self).__name__)
        self._frame_period_s = env.config.dt_s
        p = self.params
        # (value slice, rate slice, the detection's std per entry, the prior's std)
        self._parts = (
            (BALL_POS, BALL_VEL, np.full(2, p.ball.sigma_v_m), p.start_pos_std_m),
            (TILT, TILT_RATE, np.asarray(p.tilt_meas_std_rad, dtype=float), p.start_tilt_std_rad),
        )
        self.reset()

    def reset(self) -> None:
        self.reader.reset()
        p = self.params
        self._mean = np.zeros(STATE_DIM)
        self._variance = np.empty(STATE_DIM)
        for value, _, _, prior_std in self._parts:
            self._variance[value] = prior_std**2
        self._variance[BALL_VEL] = p.start_speed_std_mps**2
        self._variance[TILT_RATE] = (p.start_tilt_std_rad / self._frame_period_s) ** 2
        self._last_capture_s: list[float | None] = [None, None]

    def observe(self, obs: Any, info: dict, action: np.ndarray | None) -> Estimate:
        frame, obs = self.reader.new_frame(obs, info)
        detection, used = None, False
        if frame is not None:
            detection = self.reader.detect(obs, frame)
            capture_s = float(frame["capture_time_s"])
            tilt, ball = detected_parts(detection)
            for i, found in enumerate((ball, tilt)):
                if found is not None:
                    self._detected(i, found, capture_s)
                    used = True
        covariance = np.diag(self._variance)
        return Estimate(self._mean.copy(), covariance, used, detection, float(info["time_s"]))

    def _detected(self, part: int, found: np.ndarray, capture_s: float) -> None:
        value, rate, std, _ = self._parts[part]
        last_s = self._last_capture_s[part]
        if last_s is not None:  # a difference of this detection and the last one
            interval_s = capture_s - last_s
            self._mean[rate] = (found - self._mean[value]) / interval_s
            self._variance[rate] = 2.0 * (std / interval_s) ** 2
        self._mean[value] = found
        self._variance[value] = std**2
        self._last_capture_s[part] = capture_s
