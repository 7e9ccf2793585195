"""BallCatcher's ``learned-kf`` observer: the ``learned`` network as the measurement model of
``kf``'s filter. The network (estimation/ball_catcher/learned.py) replaces the detector's
viewlines; the filter (:class:`~observer_gym.estimation.ball_catcher.filters.ViewlineKalmanFilter`:
the ballistic model, its prior from the declared throw distribution, the p-sigma gate, the
re-acquisition after rejections in a row, prediction to the step's time) stays.

The viewline filter measures pixels through each camera's viewline rows and cannot take a
3-D point, so it got the smallest model that can
(:meth:`~observer_gym.estimation.ball_catcher.filters.ViewlineKalmanFilter.add_position`):

    y = H x + e,   H = [I_3 0_3],   E[e e^T] = R

At each step that delivers a frame showing the ball, the network reads the newest frames
of both cameras as ``learned`` does, at the step's time (the time it was trained at), and
its ball position y (m) with the position block of the covariance it predicts (diagonal,
m^2) as R is one measurement at that time. Its velocity outputs are not used: the filter
makes its own from the ballistic model. NIS: d^T S^-1 d of the accepted position (3 dof).

What this takes for granted: R treats each step's network error as independent of the
last step's, but the network reads each camera's last eight frames, so consecutive
outputs share seven of them per camera; and nothing of the network's own bias is in R.
Both make the filter trust it more than it should (the NEES/dof it reports is measured in
tests/estimation/test_learned_ball_catcher.py). The filter runs without ``kf``'s
calibration consider parameters (the network's position goes through no camera model);
like ``learned`` it is trained on the perfect detector's measurements, with the two
cameras of the default presets, and outside ``learned``'s training ranges nothing is
claimed. From rendered frames (``learned-kf``, obs_mode "rgb") the learned detector
(estimation/ball_catcher/learned_detector.py) reads each frame in the perfect
detector's place, as for ``learned``; from measurements (``learned-kf-measurements``)
the perfect detector's report is read.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from observer_gym.envs.ball_catcher import BallCatcherEnv
from observer_gym.envs.ball_catcher.layout import BALL_POS
from observer_gym.estimation.ball_catcher.learned import LearnedObserver, checked_env
from observer_gym.estimation.ball_catcher.observer import BallCatcherObserver
from observer_gym.estimation.ball_catcher.state_layout import state_estimate
from observer_gym.estimation.observer import Estimate
from observer_gym.extras import TORCH_MODULES

__all__ = ["LearnedKFObserver"]

NETWORK = "network"  # the rejection runs' key for the network's measurements


class LearnedKFObserver(BallCatcherObserver):
    """``learned-kf`` for BallCatcher-v1 (see the module docstring).

    Args:
        env: the (unwrapped) env, made with ``obs_mode="rgb"`` (frames through the learned
            detector) or ``"measurements"``, and two cameras.
        weights: the network's weight file (default: ``learned``'s shipped one; refused
            if changed).
        detector_weights: the learned detector's weight file, from frames (default: the
            shipped one; refused if changed).
        **options: the filter's options as for ``kf`` (``gate_p``, ``accel_noise_std``,
            ``reacquire_after``); its pixel noise is not used.
    """

    # PyTorch runs the network: the [rl] extra (observer_gym.extras)
    NEEDS_MODULES = TORCH_MODULES

    def __init__(
        self,
        env: BallCatcherEnv,
        weights: str | Path | None = None,
        detector_weights: str | Path | None = None,
        **options: Any,
    ) -> None:
        checked_env(env, "LearnedKFObserver", 2)  # the cheap checks before torch
        # refuses a changed weight file; from frames, loads the learned detector
        self.learned = LearnedObserver(env, weights, detector_weights)
        super().__init__(env, consider_calibration=False, **options)

    def reset(self) -> None:
        super().reset()
        self.learned.reset()

    def observe(self, obs: Any, info: dict, action: np.ndarray | None) -> Estimate:
        self._nis, self._nis_dof = 0.0, 0
        detected, measurements = self.learned.read_frames(info)
        now_s = float(info["time_s"])
        used = False
        if detected:
            ball, covariance = self.learned.net.predict(self.learned.features.vector(now_s))
            # one 3-D position (3 rows); rejections in a row restart the filter as kf's do
            result = self.filter.add_position(now_s, ball[BALL_POS], covariance[BALL_POS, BALL_POS])
            used = self._counted(result, NETWORK, now_s, dof=3)
        mean, covariance = state_estimate(*self.filter.predicted(now_s), info)
        return Estimate(
            mean=mean,
            covariance=covariance,
            measurement_used=used,
            measurement=measurements or None,
            time_s=now_s,
            nis=self._nis if self._nis_dof else None,
            nis_dof=self._nis_dof,
        )
