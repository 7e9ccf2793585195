"""The visual state estimator (VSE) of TargetFollower: a Kalman filter on the image state
and the target's image velocity, with the self-tuning R of the spec or a fixed one.

State X_n = (x_i, y_i, d_x, x_i^t', y_i^t', d_x^t') (28)(29); model (30)(31) from
:mod:`observer_gym.estimation.target_follower.models`; predict and update (33)(34) by the KF core
(:class:`observer_gym.estimation.filters.KalmanFilter`, Joseph form) with Q and R_n.
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

Where the numbers come from is the estimator's *noise*: :class:`Table1Noise` is the
spec's (Q_0, R_0, P_0 = p0 I, with :class:`VSEParams`' defaults: the Table 2 study,
train/experiments/reproduce/tsai2009.py); the observers' default is the noise rule of
:mod:`~observer_gym.estimation.target_follower.noise` (R from the declared sensor, Q from
the target's motion model, both at the current estimate), with which they also gate
(``VSEParams.gate_probability``, ``confirm_updates``:
:mod:`~observer_gym.estimation.target_follower.tracks`). ``VSEParams.adaptation`` says how
the self-tuning filter adapts R:

- ``"spec"``: (41), R_n = R_0 + diag((sigma^2)^2), the published rule (its units are
  px^4: it is not a variance, and at sigma_n = 10 px it claims ~1100 px^2 for a noise of
  33 px^2);
- ``"floor"``: R_n = R_rule, unless the register shows, at 1 % significance, more scatter
  than R_rule explains: s_j^2 = eps*_j^T eps*_j / (k - 2), the register's unbiased
  estimate of a white noise's variance (a line through k samples leaves k - 2 dof), is
  chi-square(k - 2) R_rule,jj / (k - 2) on a straight image path with the declared noise;
  when s_j^2 exceeds that distribution's 99 % quantile (2.51 R_rule,jj for k = 10), R_n
  gains s_j^2 - R_rule,jj on that channel. So R never claims less than the declared
  noise, the filter is the conventional one while the detections scatter as declared,
  and R follows the register when they scatter more (a detector worse than its model,
  a partly hidden target).

With a gate, a detection is gated with the R in force before it (a false detection
entering the register would inflate R and so its own gate), and only the main track's
accepted detections enter the register; a rejected one is a missed sample.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from observer_gym.estimation.filters import KalmanFilter, UpdateResult
from observer_gym.estimation.r_scale import checked_r_scale
from observer_gym.estimation.self_tuning import SelfTuningR
from observer_gym.estimation.target_follower.models import (
    MEASUREMENT_MATRIX,
    image_state_transition,
)
from observer_gym.estimation.target_follower.tracks import TrackPair, TrackRule

__all__ = ["Table1Noise", "VSEParams", "VisualStateEstimator"]

ADAPTATIONS = ("spec", "floor")
# "floor": s^2 adapts R when above this quantile of its distribution under the rule's R
ADAPTATION_SIGNIFICANCE = 0.99
# B_i, or a function of the image state X_i giving it
Jacobian = np.ndarray | Callable[[np.ndarray], np.ndarray]


@dataclass(frozen=True)
class VSEParams:
    """Tuning of the visual state estimator (defaults: spec Table 1, no gate).

    ``window`` is k, the length of the self-tuning shift register: the spec leaves it
    open; 10 samples (1 s at T = 100 ms) is long enough for the residual variance of a
    10 px noise to settle and short enough that the target's curving image path adds
    little to it (the Table 2 study, train/experiments/reproduce/tsai2009.py, compares values).
    ``q0``, ``r0`` and ``p0`` are the spec's noise (:class:`Table1Noise`), unused when the
    estimator is given another noise.
    """

    q0: tuple[float, ...] = (5.0, 5.0, 5.0, 20.0, 20.0, 20.0)
    r0: tuple[float, float, float] = (5.0, 5.0, 5.0)
    self_tuning: bool = True
    window: int = 10
    reliability_threshold: float = 4800.0
    p0: float = 1.0  # P_0 = p0 I_6
    gate_probability: float | None = None  # chi-square gate on the innovation
    confirm_updates: int = 0  # detections that confirm a candidate (tracks.py)
    restart_updates: int = 0  # ... that confirm a new track beside the main one
    adaptation: str = "spec"  # how the self-tuning filter adapts R (module docstring)

    def __post_init__(self) -> None:
        if len(self.q0) != 6 or min(self.q0) < 0.0:
            raise ValueError(f"VSEParams.q0 = {self.q0!r}: 6 entries >= 0")
        if len(self.r0) != 3 or min(self.r0) <= 0.0:
            raise ValueError(f"VSEParams.r0 = {self.r0!r}: 3 entries > 0")
        if self.window < 3:
            raise ValueError(f"VSEParams.window = {self.window!r}: must be >= 3")
        if not self.reliability_threshold > 0.0 or not self.p0 > 0.0:
            raise ValueError("VSEParams: reliability_threshold and p0 must be > 0")
        if self.adaptation not in ADAPTATIONS:
            raise ValueError(
                f"VSEParams.adaptation = {self.adaptation!r}: one of {list(ADAPTATIONS)}"
            )
        self.track_rule  # noqa: B018  (validates the gate and the confirmation)

    @property
    def track_rule(self) -> TrackRule:
        return TrackRule(self.gate_probability, self.confirm_updates, self.restart_updates)


class Table1Noise:
    """The spec's noise: Q = Q_0, R = R_0 (times ``r_scale``), P_0 = p0 I_6 (VSEParams)."""

    def __init__(self, params: VSEParams, r_scale: float = 1.0) -> None:
        self.Q0 = np.diag(np.asarray(params.q0, dtype=float))
        self.R0 = checked_r_scale(r_scale) * np.diag(np.asarray(params.r0, dtype=float))
        self.p0 = params.p0

    def reported(
        self, P: np.ndarray, X_i: np.ndarray, image_rate_pxps: np.ndarray | None = None
    ) -> np.ndarray:
        return P

    def R(self, z_px, image_rate_pxps=None, rate_cov=None) -> np.ndarray:
        return self.R0

    def image_Q(self, X_i, tilt_rad, dt_s, applied, robot_image_rate_pxps) -> np.ndarray:
        return self.Q0

    def image_P0(self, z_px, tilt_rad) -> np.ndarray:
        return self.p0 * np.eye(6)


class VisualStateEstimator:
    """The STKF (``params.self_tuning``) or the conventional KF of the spec.

    Args:
        params: the procedure's parameters (default: Table 1, no gate).
        noise: R, Q and P_0 (``R(z, v, P_rate)``, ``image_Q(X_i, tilt, dt, u, B_i u)``,
            ``image_P0(z, tilt)``; default: :class:`Table1Noise` of ``params``).
    """

    def __init__(self, params: VSEParams | None = None, noise=None) -> None:
        self.params = params or VSEParams()
        self.noise = noise or Table1Noise(self.params)
        self.Q = self.noise.image_Q(np.array([0.0, 0.0, 1.0]), 0.0, 0.0, np.zeros(3), np.zeros(3))
        self.R0 = self.noise.R(np.array([0.0, 0.0, 35.0]))
        self.tuner = SelfTuningR(np.zeros((3, 3)), self.params.window)
        import scipy.stats  # imported on use: scipy.stats takes ~0.6 s to import

        dof = self.params.window - 2
        self._significant = float(scipy.stats.chi2.ppf(ADAPTATION_SIGNIFICANCE, dof) / dof)
        self.tracks: TrackPair[KalmanFilter] = TrackPair(self.params.track_rule)
        self.reset()

    def reset(self) -> None:
        self.tracks.reset()
        self.R = self.R0.copy()
        self.tuner.reset()
        self.reinitialisations = 0
        self.last_update: UpdateResult | None = None  # the last update (34), for its NIS
        self.tilt_rad = 0.0  # the tilt of the last predict (Q, P_0 and R's timing term)
        self.robot_rate = np.zeros(3)  # B_i u of the last predict

    @property
    def kf(self) -> KalmanFilter | None:
        """The main track's filter (None before the first detection and after a loss)."""
        return self.tracks.main

    @property
    def initialised(self) -> bool:
        return self.tracks.main is not None

    @property
    def valid(self) -> bool:
        """Initialised and reliable (6)."""
        return self.kf is not None and not self.unreliable()

    @property
    def x(self) -> np.ndarray | None:
        return None if self.kf is None else self.kf.x

    @property
    def P(self) -> np.ndarray | None:
        return None if self.kf is None else self.kf.P

    def step(
        self,
        z: np.ndarray | None,
        B_i: Jacobian,
        u: np.ndarray,
        dt_s: float,
        tilt_rad: float = 0.0,
    ) -> bool:
        """One sample: ``z`` the detection (3,) or None, ``B_i`` evaluated at the previous
        estimate (or a function of the image state giving it), ``u`` the velocity applied
        over the last ``dt_s``, ``tilt_rad`` the tilt at its start. Returns whether a
        measurement was used (a (re)initialisation counts)."""
        self.last_update = None
        if not self.tracks.filters():  # (2): start at the first detection
            self.tilt_rad = float(tilt_rad)
            return self.measure(z)
        self.predict(B_i, u, dt_s, tilt_rad)  # (4)
        used = self.measure(z)  # (3), (5)
        self.check_reliability()  # (6)
        return used

    # The procedure's parts, which step() composes; the latency-aware drive
    # (estimation/target_follower/latency.py) calls them at capture and step times.
    def predict(self, B_i: Jacobian, u: np.ndarray, dt_s: float, tilt_rad: float = 0.0) -> None:
        """(4): X <- F X + G u, P <- F P F^T + Q with (F, G) of (30) over ``dt_s``, for
        the main track and the candidate (each with B_i at its own estimate when ``B_i``
        is a function)."""
        u = np.asarray(u, dtype=float)
        self.tilt_rad = float(tilt_rad)
        for f in self.tracks.filters():
            B = B_i(f.x[:3]) if callable(B_i) else B_i
            robot_rate = B.dot(u)
            if f is self.kf:
                self.robot_rate = robot_rate
            F, G = image_state_transition(dt_s, B)
            Q = self.noise.image_Q(f.x[:3], self.tilt_rad, dt_s, u, robot_rate)
            f.predict(F, Q, G, u)  # (30), (33)
            self.Q = Q if f is self.kf else self.Q

    def measure(self, z: np.ndarray | None) -> bool:
        """(2), (3), (5): start a track at the detection ``z``, or use it through the
        gate (:class:`TrackPair`), the register and the update (34); None is a missed
        sample. Returns whether it was used; the main track's update is in
        ``last_update``."""
        self.last_update = None
        if z is None:
            self.miss()
            return False
        z = np.asarray(z, dtype=float)
        measured = self.tracks.measure(z, self._start, self._innovation, self._update)
        if measured.event != "update":
            self.skip()  # the register holds the main track's consecutive samples only
            if measured.used and self.params.self_tuning:  # a new main track's first
                self.tuner.push(z)
        self.last_update = measured.update
        return measured.used

    def miss(self) -> None:
        """A frame without a detection, or a dropped one: the tracks lose their lock and
        the candidate (:class:`~observer_gym.estimation.target_follower.tracks.TrackPair`),
        and the register empties (:meth:`skip`)."""
        self.tracks.miss()
        self.skip()

    def skip(self) -> None:
        """A missed sample: the register empties (its line fit's fixed regressor
        A = [[1, 1], ..., [k, 1]] assumes k consecutive samples) and R_n is the rule's."""
        self.tuner.reset()
        self.R = self.R0.copy()

    def _R_rule(self, z: np.ndarray, f: KalmanFilter | None) -> np.ndarray:
        if f is None:
            return self.noise.R(z)
        return self.noise.R(z, f.x[3:] + self.robot_rate, f.P[3:, 3:])

    def _adapted(self, R_rule: np.ndarray) -> np.ndarray:
        """R_n from the register (the self-tuning filter; the KF keeps the rule's)."""
        if not (self.params.self_tuning and self.tuner.full):
            return R_rule
        var_eps = self.tuner.residual_variance()  # eps*^T eps* / k per channel
        if self.params.adaptation == "spec":
            return R_rule + np.diag(var_eps**2)  # (41): variance squared
        k = self.params.window
        unbiased = var_eps * k / (k - 2)  # s^2 = eps*^T eps* / (k - 2)
        declared = np.diag(R_rule)
        # s^2 > R_rule,jj chi2_0.99(k - 2) / (k - 2): R_rule + diag(s^2 - R_rule,jj) there
        excess = np.where(unbiased > self._significant * declared, unbiased - declared, 0.0)
        return R_rule + np.diag(excess)

    def _start(self, z: np.ndarray) -> KalmanFilter:
        P0 = self.noise.image_P0(z, self.tilt_rad)
        self.R = self.noise.R(z)
        return KalmanFilter(np.concatenate([z, np.zeros(3)]), P0)

    def _innovation(self, f: KalmanFilter, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        # the R in force before z: the rule's, adapted by the register without z
        R = self._adapted(self._R_rule(z, f)) if f is self.kf else self._R_rule(z, f)
        # d = z - C x, S = C P C^T + R
        return z - f.x[:3], f.P[:3, :3] + R

    def _update(self, f: KalmanFilter, z: np.ndarray, is_main: bool) -> UpdateResult:
        R = self._R_rule(z, f)
        if is_main:
            if self.params.self_tuning:
                self.tuner.push(z)  # (3)
            R = self._adapted(R)
            self.R = R
        return f.update(z, MEASUREMENT_MATRIX, R)

    def unreliable(self) -> bool:
        """(6): a diagonal element of P exceeds the reliability threshold (only with a
        main track: :attr:`initialised`)."""
        kf = self.kf
        if kf is None:
            raise RuntimeError("VisualStateEstimator.unreliable: no main track (not initialised)")
        return bool(np.max(np.diag(kf.P)) > self.params.reliability_threshold)

    def check_reliability(self) -> None:
        """(6): if the estimate is unreliable, stop: back to uninitialised (the register
        emptied; a candidate track, if any, takes its place); the next detection
        restarts it (2)."""
        if self.kf is not None and self.unreliable():
            self.tracks.lose_main()
            self.R = self.R0.copy()
            self.tuner.reset()
            self.reinitialisations += 1

    # The latency-aware drive rewinds the estimator to earlier step times.
    def snapshot(self) -> tuple:
        return (
            self.tracks.snapshot(),
            self.R,
            self.tuner.samples,
            self.reinitialisations,
            self.tilt_rad,
            self.robot_rate,
        )

    def restore(self, snapshot: tuple) -> None:
        tracks, self.R, register, self.reinitialisations, self.tilt_rad, self.robot_rate = snapshot
        self.tracks.restore(tracks, KalmanFilter)
        self.tuner.refill(register)
