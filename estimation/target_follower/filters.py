"""The visual state estimator (VSE) of TargetFollower: a Kalman filter on the image state
and the target's image velocity, with the self-tuning R of the spec or a fixed one.

State X_n = (x_i, y_i, d_x, x_i^t', y_i^t', d_x^t') (28)(29); model (30)(31) from
:mod:`observer_gym.estimation.target_follower.models`; predict and update (33)(34) by the KF core
(:class:`observer_gym.estimation.filters.KalmanFilter`, Joseph form) with Q = Q_0 and R_n.
The spec's procedure, one call of :meth:`VisualStateEstimator.step` per sample:

1. Q_0, R_0 chosen (Table 1: diag(5, 5, 5, 20, 20, 20) and diag(5, 5, 5)).
2. At the first detection: X_0 = (Z_0, 0, 0, 0), P_0 = I_6.
3. A detection Z_n enters the length-k shift register; R_n by (41) once it is full,
   else R_0 (the conventional KF keeps R_0 always). The register holds consecutive
   samples only (its line fit assumes them): a missed detection empties it. Without
   that, the first detection after an occlusion, far from the line through the samples
   before it, read as noise: R grew by (41) to ~10^5 px^2 and the filter ignored the
   target's new place.
4. Predict with the robot's applied velocity u_{n-1} through B_i (30).
5. Update if the target was detected, else keep the prediction.
6. Reliability: if a diagonal element of P exceeds the threshold (4800 in the spec),
   the estimate is unreliable: stop (``reliable`` False) and reinitialise at the next
   detection (back to 2).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from observer_gym.estimation.filters import KalmanFilter, UpdateResult
from observer_gym.estimation.self_tuning import SelfTuningR
from observer_gym.estimation.target_follower.models import (
    MEASUREMENT_MATRIX,
    image_state_transition,
)

__all__ = ["VSEParams", "VisualStateEstimator"]


@dataclass(frozen=True)
class VSEParams:
    """Tuning of the visual state estimator (defaults: spec Table 1).

    ``window`` is k, the length of the self-tuning shift register: the spec leaves it
    open; 10 samples (1 s at T = 100 ms) is long enough for the residual variance of a
    10 px noise to settle and short enough that the target's curving image path adds
    little to it (the Table 2 study, train/reproduce/tsai2009.py, compares values).
    """

    q0: tuple[float, ...] = (5.0, 5.0, 5.0, 20.0, 20.0, 20.0)
    r0: tuple[float, float, float] = (5.0, 5.0, 5.0)
    self_tuning: bool = True
    window: int = 10
    reliability_threshold: float = 4800.0
    p0: float = 1.0  # P_0 = p0 I_6

    def __post_init__(self) -> None:
        if len(self.q0) != 6 or min(self.q0) < 0.0:
            raise ValueError(f"VSEParams.q0 = {self.q0!r}: 6 entries >= 0")
        if len(self.r0) != 3 or min(self.r0) <= 0.0:
            raise ValueError(f"VSEParams.r0 = {self.r0!r}: 3 entries > 0")
        if self.window < 3:
            raise ValueError(f"VSEParams.window = {self.window!r}: must be >= 3")
        if not self.reliability_threshold > 0.0 or not self.p0 > 0.0:
            raise ValueError("VSEParams: reliability_threshold and p0 must be > 0")


class VisualStateEstimator:
    """The STKF (``params.self_tuning``) or the conventional KF of the spec."""

    def __init__(self, params: VSEParams | None = None) -> None:
        self.params = params or VSEParams()
        self.Q = np.diag(np.asarray(self.params.q0, dtype=float))
        self.R0 = np.diag(np.asarray(self.params.r0, dtype=float))
        self.tuner = SelfTuningR(self.R0, self.params.window)
        self.reset()

    def reset(self) -> None:
        self.kf: KalmanFilter | None = None
        self.R = self.R0.copy()
        self.tuner.reset()
        self.reinitialisations = 0
        self.last_update: UpdateResult | None = None  # the last update (34), for its NIS

    @property
    def initialised(self) -> bool:
        return self.kf is not None

    @property
    def x(self) -> np.ndarray | None:
        return None if self.kf is None else self.kf.x

    @property
    def P(self) -> np.ndarray | None:
        return None if self.kf is None else self.kf.P

    def step(self, z: np.ndarray | None, B_i: np.ndarray, u: np.ndarray, dt_s: float) -> bool:
        """One sample: ``z`` the detection (3,) or None, ``B_i`` evaluated at the previous
        estimate, ``u`` the velocity applied over the last ``dt_s``. Returns whether a
        measurement was used (a (re)initialisation counts)."""
        self.last_update = None
        if self.kf is None:  # (2): start at the first detection
            return self.start(z)
        self.register(z)  # (3)
        self.predict(B_i, u, dt_s)  # (4)
        used = self.update(z)  # (5)
        self.check_reliability()  # (6)
        return used

    # The procedure's parts, which step() composes; the latency-aware drive
    # (estimation/target_follower/latency.py) calls them at capture and step times.
    def start(self, z: np.ndarray | None) -> bool:
        """(2): X_0 = (Z_0, 0), P_0 = p0 I_6 at a detection ``z`` (None: stay uninitialised).
        Returns whether it started."""
        if z is None:
            return False
        z = np.asarray(z, dtype=float)
        self.kf = KalmanFilter(np.concatenate([z, np.zeros(3)]), self.params.p0 * np.eye(6))
        if self.params.self_tuning:
            self.tuner.push(z)
        return True

    def register(self, z: np.ndarray | None) -> None:
        """(3): shift ``z`` into the register and set R_n by (41) (the STKF; the KF keeps
        R_0). A missed sample (None) empties the register: the line fit's fixed regressor
        A = [[1, 1], ..., [k, 1]] assumes k consecutive samples, so R_n = R_0 until it is
        full again."""
        if not self.params.self_tuning:
            return
        if z is None:
            self.tuner.reset()
        else:
            self.tuner.push(z)
        self.R = self.tuner.R()

    def predict(self, B_i: np.ndarray, u: np.ndarray, dt_s: float) -> None:
        """(4): X <- F X + G u, P <- F P F^T + Q with (F, G) of (30) over ``dt_s``."""
        F, G = image_state_transition(dt_s, B_i)
        self.kf.predict(F, self.Q, G, np.asarray(u, dtype=float))  # (30), (33)

    def update(self, z: np.ndarray | None) -> bool:
        """(5): the update (34) with R_n if the target was detected (``z`` not None), else
        keep the prediction. Returns whether the measurement was used; the update's
        :class:`~observer_gym.estimation.filters.UpdateResult` is kept in ``last_update``."""
        if z is None:
            return False
        self.last_update = self.kf.update(np.asarray(z, dtype=float), MEASUREMENT_MATRIX, self.R)
        return self.last_update.accepted

    def unreliable(self) -> bool:
        """(6): a diagonal element of P exceeds the reliability threshold."""
        return bool(np.max(np.diag(self.kf.P)) > self.params.reliability_threshold)

    def check_reliability(self) -> None:
        """(6): if the estimate is unreliable, stop: back to uninitialised (R = R_0, the
        register emptied); the next detection restarts it (2)."""
        if self.unreliable():
            self.kf = None
            self.R = self.R0.copy()
            self.tuner.reset()
            self.reinitialisations += 1
