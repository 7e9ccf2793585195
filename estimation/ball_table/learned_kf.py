"""BallTable's ``learned-kf`` observer: the ``learned`` network as ``kf``'s measurement
model. The network (estimation/ball_table/learned.py) replaces the detector; the filters
(estimation/ball_table/observer.py, :class:`TiltBallFilters`) stay.

Per new frame, the network reads the newest frames' detections as ``learned`` does, with
the frame's own capture time as "now" (the newest frame's age 0), so what it estimates is
the state at the capture, as a detector's measurement is. Its tilt (4:6) and ball
position (0:2) are ``kf``'s tilt and ball measurements, and the diagonal covariance it
predicts for them is their R (plus ``kf``'s frame-age term when fused at delivery). Its
velocity and rate outputs are not used: the filters make their own from the models.

What this takes for granted: R treats each frame's network error as independent of the
last frame's, but the network reads the last four frames, so consecutive errors share
three of them; and the network's own covariance claims about half its error (its
NEES/dof on new seeds is 2.2, tests/estimation/test_learned_ball_table.py). Both make
the filter trust it more than it should; the NEES/dof this observer reports is measured
in tests/estimation/test_learned_ball_table.py. Like ``learned`` its network is trained
on the perfect detector's measurements and knows no calibration error: nothing of the
calibration's offset is reported. From rendered frames (``learned-kf``, obs_mode "rgb")
the learned detector (estimation/ball_table/learned_detector.py) reads each frame in the
perfect detector's place, as for ``learned``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from observer_gym.envs.ball_table import BallTableEnv
from observer_gym.estimation.ball_table.fusion import Fused
from observer_gym.estimation.ball_table.learned import LearnedObserver
from observer_gym.estimation.ball_table.observer import BallTableObserver, TiltBallDetection
from observer_gym.estimation.learned.inputs import require_frames_or_measurements
from observer_gym.estimation.observer import Estimate
from observer_gym.extras import TORCH_MODULES

__all__ = ["LearnedKFObserver"]


class LearnedKFObserver(BallTableObserver):
    """``learned-kf`` (and, with ``latency_aware=True``, fused at the capture time) for
    BallTable-v0: see the module docstring.

    Args:
        env: the (unwrapped) env, made with ``obs_mode="rgb"`` (frames through the learned
            detector) or ``"measurements"``.
        weights: the network's weight file (default: ``learned``'s shipped one; refused
            if changed).
        latency_aware: fuse each frame at its capture time, as ``kf-latency``.
        detector_weights: the learned detector's weight file, from frames (default: the
            shipped one; refused if changed).
    """

    # PyTorch runs the network: the [rl] extra (observer_gym.extras)
    NEEDS_MODULES = TORCH_MODULES

    def __init__(
        self,
        env: BallTableEnv,
        weights: str | Path | None = None,
        latency_aware: bool = False,
        detector_weights: str | Path | None = None,
    ) -> None:
        require_frames_or_measurements(env, "learned-kf of BallTable-v0")
        # refuses a changed weight file; from frames, loads the learned detector
        self.learned = LearnedObserver(env, weights, detector_weights)
        self._action: np.ndarray | None = None
        super().__init__(env, latency_aware=latency_aware)

    def reset(self) -> None:
        super().reset()
        self.learned.reset()
        self._action = None

    def observe(self, obs: Any, info: dict, action: np.ndarray | None) -> Estimate:
        self._action = action  # the network reads the last action with the frames
        return super().observe(obs, info, action)

    def _start_calibration(self) -> None:
        """None: the network's tilt is not PnP's, so the gravity-offset states that kf
        sizes from the geometry stage's calibration sensitivity do not apply to it."""
        return None

    def _read(self, obs: Any, frame: dict):
        self.reader.mark_seen(frame)  # the image stage is the network's, not kf's
        capture_s = float(frame["capture_time_s"])
        measurement = self.learned.measurement(obs)
        features = self.learned.features
        features.new_frame(measurement, capture_s)
        mean, cov = self.learned.net.predict(features.vector(capture_s, self._action))
        detection = TiltBallDetection(mean[4:6], mean[0:2], cov[4:6, 4:6], cov[0:2, 0:2])
        return measurement, Fused(detection)
