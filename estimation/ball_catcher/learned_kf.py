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
m^2, times ``learned``'s variance scale at the newest frame's age:
estimation/learned/variance_scale.py) as R is
one measurement at that time. Its velocity outputs are not used: the filter
makes its own from the ballistic model. NIS: d^T S^-1 d of the accepted position (3 dof).

Its errors are correlated: the network reads each camera's last eight frames, so
consecutive outputs share seven of them per camera. The autocorrelation of ``learned``'s
normalised error at lags of 1 to 8 steps, on validation throws (seeds 2000000-2000029,
``python benchmarks/learned_variance_scale.py --env BallCatcher-v1 --observer learned
--episodes 30``), is 0.82, 0.71, 0.56, 0.46, 0.33, 0.24, 0.15, 0.07: it dies out where
the windows stop overlapping (roughly first-order Gauss-Markov, 0.82 per step, for the
first lags). Fusing every output as independent
made NEES/dof 6.36 on validation throws (seeds 2000000-2000029, 1 px, the intercept
controller). Fusing only one output in :data:`FUSE_EVERY` steps keeps ``kf``'s filter as
it is (state augmentation with a Gauss-Markov error, or Bryson-Henrikson differencing,
would change it); on those throws (ball position RMSE x, y, z mm; median NEES/dof;
catches of 30) every step gave 12.5, 5.8, 5.4, 6.36, 14; every 2nd 12.9, 6.2, 5.5, 3.80,
13; every 4th 13.2, 7.1, 5.5, 2.28, 11; every 8th (no shared frame) 15.2, 8.2, 6.8,
1.61, 9; ``learned`` alone 12.0, 5.8, 5.2, 0.93, 8 (these without the variance scale;
with it, on the tests' throws every 4th gives 1.23 at 1 px and 2.41 at 2 px, where it
gave 3.72, docs/results/consistency.md). Every 4th is the smallest spacing
inside [1/3, 3]; every 8th would sit nearer 1 but errs by a fifth more and catches
fewer: the intercept trusts the covariance, and the filter's gain is in the late flight.
The honest covariance costs catches at every spacing (14 of 30 fusing every output
against 11), and nothing of the network's own bias is in R.

Four steps apart the errors are still correlated (0.46), and once ``learned``'s scale
came to read the declared sensor (estimation/learned/variance_scale.py) every 4th with
R the scaled variance claimed too little where the network is precise: at 0 px median
NEES/dof 2.52 in the consistency study, 3.12 on the tests' throws. So R is
:data:`R_INFLATION` times that variance, of 1, 2 and 3 the smallest whose medians on
validation throws all lie in [1/2, 2] (``python benchmarks/learned_variance_scale.py
--env BallCatcher-v1 --observer learned-kf --r-inflation R --seed 3000000 --episodes 60
--ranges study --estimator geometric``, and ``--episodes 40 --noise-px 0`` and ``1``;
the first 60 of the 500 throws the scale was fitted on). Median over the episodes of
each one's median NEES/dof for the noise, latency and drops episodes; then 0 px and
1 px (median NEES/dof, catches of 40, ball position RMSE x, y, z mm):

    R x 1: 1.64, 1.69, 1.27; 0 px 2.47, 38; 1 px 1.54, 21, 13.5, 5.8, 4.6
    R x 2: 0.94, 1.17, 0.77; 0 px 1.46, 38; 1 px 0.91, 19, 14.0, 6.0, 4.7
    R x 3: 0.76, 0.93, 0.61; 0 px 1.09, 39; 1 px 0.71, 18, 14.6, 6.2, 4.8

Doubling R costs half a millimetre along the throw at 1 px and two catches of 40 there
(on the tests' 100 throws 49 against 50, docs/results/consistency.md). From frames R
stays the scaled variance once: ``learned``'s frames scale reads the age alone, and with
it ``learned-kf``'s cells of the study's frames part are 0.92-1.49 (docs/results/
consistency.md; not chosen again on validation throws).

The filter runs without ``kf``'s calibration consider parameters (the network's
position goes through no camera model); like ``learned`` it is trained on the perfect
detector's measurements, with the two cameras of the default presets, and outside
``learned``'s training ranges its estimate is not claimed (its covariance is measured
where ``learned``'s is). From rendered frames (``learned-kf``, obs_mode "rgb") the learned detector
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
from observer_gym.estimation.learned.variance_scale import FuseEvery, checked_r_inflation
from observer_gym.estimation.observer import Estimate
from observer_gym.extras import TORCH_MODULES

__all__ = ["FUSE_EVERY", "R_INFLATION", "LearnedKFObserver"]

NETWORK = "network"  # the rejection runs' key for the network's measurements
FUSE_EVERY = 4  # one network output fused in every four steps showing the ball: see above
# R = this x learned's scaled variance, per observation mode: see above
R_INFLATION: dict[str, float] = {"measurements": 2.0, "rgb": 1.0}


class LearnedKFObserver(BallCatcherObserver):
    """``learned-kf`` for BallCatcher-v1 (see the module docstring).

    Args:
        env: the (unwrapped) env, made with ``obs_mode="rgb"`` (frames through the learned
            detector) or ``"measurements"``, and two cameras.
        weights: the network's weight file (default: ``learned``'s shipped one; refused
            if changed).
        detector_weights: the learned detector's weight file, from frames (default: the
            shipped one; refused if changed).
        fuse_every: fuse the network's output of one step showing the ball in this many
            (default :data:`FUSE_EVERY`; 1 fuses every one).
        r_inflation: R is ``learned``'s (scaled) position variance times this (>= 1;
            default :data:`R_INFLATION` of the env's observation mode).
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
        fuse_every: int = FUSE_EVERY,
        r_inflation: float | None = None,
        **options: Any,
    ) -> None:
        checked_env(env, "LearnedKFObserver", 2)  # the cheap checks before torch
        self.gate = FuseEvery(fuse_every)  # refuses a bad value before torch loads
        if r_inflation is None:
            r_inflation = R_INFLATION[env.config.obs_mode]
        self.r_inflation = checked_r_inflation(r_inflation, "learned-kf of BallCatcher-v1")
        # refuses a changed weight file; from frames, loads the learned detector
        self.learned = LearnedObserver(env, weights, detector_weights)
        super().__init__(env, consider_calibration=False, **options)

    def reset(self) -> None:
        super().reset()
        self.learned.reset()
        self.gate.reset()

    def observe(self, obs: Any, info: dict, action: np.ndarray | None) -> Estimate:
        self._nis, self._nis_dof = 0.0, 0
        detected, measurements = self.learned.read_frames(info)
        now_s = float(info["time_s"])
        used = False
        if detected and self.gate.new_frame():  # else its window overlaps the last fused
            ball, covariance = self.learned.predict(now_s)  # the variance scaled as learned's
            # one 3-D position (3 rows); rejections in a row restart the filter as kf's do
            R_m2 = self.r_inflation * covariance[BALL_POS, BALL_POS]
            result = self.filter.add_position(now_s, ball[BALL_POS], R_m2)
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
