"""BallCatcher's declared calibration uncertainty as consider parameters (Schmidt-Kalman).

Each camera's calibration error (envs/camera_rig.py: a rotation, translation, focal scale
and principal-point offset drawn once per episode and camera) is a constant offset of
every frame of that camera. The filters carry it as consider parameters: c_j (m,), the
calibration parameters of camera j that ``env.sensor_spec`` declares uncertain (the
parameters and variances of :func:`~observer_gym.estimation.calibration.
calibration_variances`), zero mean, covariance V = diag(var), constant over the episode,
independent between cameras. A frame of camera j measures

    y = H x + J_j c_j + e,    J_j = dr / dc_j

with r the filter's own measurement function (the viewline rows' residual, or the
pixel) at the predicted state, J_j by central differences along each calibration
parameter (:func:`~observer_gym.estimation.calibration.calibration_jacobian`). The
filter's :class:`~observer_gym.estimation.filters.KalmanFilter` runs on the augmented
state (x, c_1, ..., c_N), Phi = diag(Phi_x, I), Q = diag(Q_x, 0), so S, the gate and the
gain include each camera's offset and its correlation with the estimate; after every
update the consider part is set back to c = 0, Cov(c) = V (the Schmidt-Kalman filter:
the offsets are not estimated), while Cov(x) and Cov(x, c) keep the update's values, the
error covariances of that filter. The covariance reported is Cov(x), which holds the
offsets' effect.

Why this rule and not another:

- Not pixel variance in R (what the filters did before): an offset is the same on every
  frame of a camera, and white noise averages away over frames, so over a flight of ~22
  frames per camera the claimed error shrank far below the offset's: median NEES/dof
  3.2-4.7 at 0.5-2 degrees of rotation error (and NIS 0.04-0.12, from the inflated R);
  with this rule 0.92-1.04 and NIS 0.72-0.77 (measured, docs/results/consistency.md).
- Not BallTable's added term alone (the estimate's sensitivity to each calibration
  parameter added to the reported covariance): BallTable's estimate is one frame's
  geometry, whose sensitivity one evaluation gives; here each estimate is a filter's over
  many frames of two cameras, and its sensitivity to each camera's parameters builds up
  frame by frame through the gains, which is what Cov(x, c) carries.
- Not a bias state that is estimated, in ``kf`` and ``ekf``: within a 0.44 s flight two
  cameras' offsets are at best partly observable (a rotation of both cameras together
  moves the whole trajectory they see), and J depends on the estimate. The
  self-calibrating observers (estimation/ball_catcher/self_calibrating.py) do estimate
  them (``estimated``: the kinds that are states, the rest stay consider parameters,
  a partial Schmidt filter), with the box's hole as a landmark where a camera sees it;
  they measure what that wins.

Without declared calibration uncertainty (the default) m = 0 and the filters run on x
alone, as before. With ``estimated`` kinds, :meth:`CalibrationConsider.carry_over` takes a
throw's estimate of them as the next throw's prior (one rig over many throws).
"""

from __future__ import annotations

from collections.abc import Callable, Collection

import numpy as np

from observer_gym.envs.sensor import SensorSpec
from observer_gym.estimation.calibration import (
    calibration_jacobian,
    calibration_variances,
    moved_camera,
)

__all__ = ["CalibrationConsider"]


class CalibrationConsider:
    """The consider parameters of ``cameras`` cameras (ids 0 .. cameras - 1) under the
    calibration uncertainty ``sensor`` declares, appended to a state of ``n`` entries (see
    the module docstring). ``m``: parameters per camera (0: nothing declared uncertain,
    every method then leaves its input as it is); ``dim``: the augmented state's size."""

    def __init__(
        self,
        sensor: SensorSpec,
        cameras: int,
        n: int = 6,
        estimated: Collection[str] = (),
    ) -> None:
        if isinstance(cameras, bool) or not isinstance(cameras, int) or cameras < 1:
            raise ValueError(f"CalibrationConsider: cameras = {cameras!r}, must be an integer >= 1")
        self.variances = calibration_variances(sensor)
        self.n = int(n)
        self.cameras = cameras
        kinds_axes = {"rotation": 3, "translation": 3, "focal": 1, "principal_point": 2}
        self.m = sum(kinds_axes[kind] for kind in self.variances)
        self.dim = self.n + self.m * cameras
        # V = diag(var) per camera, block-diagonal over the cameras
        var = np.concatenate([[v] * kinds_axes[k] for k, v in self.variances.items()] or [[]])
        self._V = np.diag(np.tile(var, cameras)) if self.m else np.zeros((0, 0))
        unknown = sorted(set(estimated) - set(kinds_axes))
        if isinstance(estimated, str) or unknown:
            raise ValueError(
                f"CalibrationConsider: estimated = {estimated!r}, must be a collection of "
                f"{sorted(kinds_axes)}"
            )
        # The declared-uncertain kinds estimated as states (the others stay consider
        # parameters), and their place in the parameter block of every camera.
        self.estimated = tuple(kind for kind in self.variances if kind in set(estimated))
        mask = np.concatenate(
            [[kind in self.estimated] * kinds_axes[kind] for kind in self.variances] or [[]]
        ).astype(bool)
        self._estimated_mask = np.tile(mask, cameras)
        # The parameters' prior: zero mean and the declared V, or (estimated, one rig over
        # many throws) what earlier throws left (:meth:`carry_over`).
        self.prior_mean = np.zeros(self.m * cameras)
        self.prior_cov = self._V.copy()

    @property
    def active(self) -> bool:
        """Whether any calibration parameter is uncertain (m > 0)."""
        return self.m > 0

    def augmented(self, x: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(x, P) of the state with the consider parameters appended: c and Cov(c) their
        prior (c = 0, Cov(c) = V unless :meth:`carry_over` set another), Cov(x, c) = 0 (a
        prior independent of the calibration)."""
        x = np.asarray(x, dtype=float)
        P = np.asarray(P, dtype=float)
        if not self.active:
            return x.copy(), P.copy()
        x_aug = np.zeros(self.dim)
        x_aug[: self.n] = x[: self.n]
        x_aug[self.n :] = self.prior_mean
        P_aug = np.zeros((self.dim, self.dim))
        P_aug[: self.n, : self.n] = P[: self.n, : self.n]
        P_aug[self.n :, self.n :] = self.prior_cov
        return x_aug, P_aug

    def carry_over(self, x_aug: np.ndarray, P_aug: np.ndarray) -> None:
        """Take the parameters' estimate (mean and covariance) in an augmented state as
        the prior of the next throw: one rig over many throws (``calib_error_draw=
        "fixed"``), so each throw's evidence adds to the last. Estimated parameters
        only: a consider filter's are not estimated (``ValueError``)."""
        if not self.estimated:
            raise ValueError("CalibrationConsider.carry_over: no parameter is estimated")
        if not self.active:
            return
        e = self._estimated_mask
        c = np.asarray(x_aug, dtype=float)[self.n :]
        cov = np.asarray(P_aug, dtype=float)[self.n :, self.n :]
        self.forget()  # the consider parameters' prior stays the declared one
        self.prior_mean[e] = c[e]
        self.prior_cov[np.ix_(e, e)] = 0.5 * (cov[np.ix_(e, e)] + cov[np.ix_(e, e)].T)

    @property
    def considered_index(self) -> np.ndarray:
        """The consider parameters' places in the augmented state (the ones not estimated)."""
        return self.n + np.flatnonzero(~self._estimated_mask)

    def camera_at(
        self, x_aug: np.ndarray, camera: int, K: np.ndarray, T_world_cam: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """(K, T_world_cam) of ``camera``'s nominal calibration moved by its parameters in
        the augmented state ``x_aug`` (:func:`~observer_gym.estimation.calibration.
        moved_camera`): the camera the filter's estimate describes."""
        c = self.offsets(x_aug)[int(camera)]
        return moved_camera(K, T_world_cam, self.variances, c)

    def forget(self) -> None:
        """Back to the declared prior (c = 0, Cov(c) = V)."""
        self.prior_mean = np.zeros(self.m * self.cameras)
        self.prior_cov = self._V.copy()

    def offsets(self, x_aug: np.ndarray) -> np.ndarray:
        """The parameters' part of an augmented state, (cameras, m): camera j's row holds
        its parameters in :func:`~observer_gym.estimation.calibration.calibration_jacobian`'s
        order."""
        return np.asarray(x_aug, dtype=float)[self.n :].reshape(self.cameras, self.m)

    def transition(
        self, Phi: np.ndarray, Q: np.ndarray, Gamma: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """(Phi, Q, Gamma) of the augmented state: diag(Phi, I), diag(Q, 0), (Gamma; 0):
        the offsets are constant."""
        if not self.active:
            return Phi, Q, Gamma
        Phi_aug = np.eye(self.dim)
        Phi_aug[: self.n, : self.n] = Phi
        Q_aug = np.zeros((self.dim, self.dim))
        Q_aug[: self.n, : self.n] = Q
        Gamma_aug = None
        if Gamma is not None:
            Gamma_aug = np.zeros((self.dim, Gamma.shape[1]))
            Gamma_aug[: self.n] = Gamma
        return Phi_aug, Q_aug, Gamma_aug

    def jacobian(
        self,
        r: Callable[[np.ndarray, np.ndarray], np.ndarray | None],
        K: np.ndarray,
        T_world_cam: np.ndarray,
    ) -> np.ndarray | None:
        """J (k, m) = dr/dc of a frame's measurement function ``r(K, T_world_cam)`` (k,)
        at the nominal camera; None when ``r`` gives None beside it."""
        found = calibration_jacobian(r, K, T_world_cam, self.variances)
        return None if found is None else found[0]

    def rows(self, H: np.ndarray, J: np.ndarray | None, camera: int) -> np.ndarray:
        """H (k, n) of x and J (k, m) of camera ``camera``'s parameters as one (k, dim)
        row block of the augmented state (zero for the other cameras)."""
        if not self.active:
            return H
        if isinstance(camera, bool) or not isinstance(camera, (int, np.integer)):
            raise ValueError(f"CalibrationConsider: camera = {camera!r}, must be an integer")
        if not 0 <= camera < self.cameras:
            raise ValueError(
                f"CalibrationConsider: camera {camera!r} outside 0..{self.cameras - 1}"
            )
        if J is None:
            raise ValueError("CalibrationConsider.rows: J is None with calibration uncertainty")
        H_aug = np.zeros((H.shape[0], self.dim))
        H_aug[:, : self.n] = H
        start = self.n + self.m * int(camera)
        H_aug[:, start : start + self.m] = J
        return H_aug

    def reset_consider(self, x: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(x, P) with the consider part set back after an update (Schmidt): c = 0 and
        Cov(c) = V; x, Cov(x) and Cov(x, c) kept. Fresh arrays. Estimated parameters
        (``estimated``) are states of the filter and keep the update's values; so do their
        covariances with the consider parameters (a partial Schmidt filter)."""
        if not self.active:
            return x, P
        x = np.array(x, dtype=float)
        P = np.array(P, dtype=float)
        considered = self.considered_index
        x[considered] = 0.0
        P[np.ix_(considered, considered)] = self._V[
            np.ix_(considered - self.n, considered - self.n)
        ]
        return x, P
