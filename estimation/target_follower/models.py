"""The dual-Jacobian image model of TargetFollower (docs/spec/follower.md, Tsai et al. 2009).

Image state X_i = (x_i, y_i, d_x) in pixels (x_i right, y_i up from the principal point,
d_x = f_x W / z_c; envs/target_follower/geometry.py), robot input u = (v, omega, omega_t):

    X_i' = J_t V_t + B_i u                                                     (3)(4)

B_i is the robot image Jacobian. We derived it from the appendix geometry
X_c = R(phi, theta)(X_t - X_m) - (0, delta_y, 0), X_i = diag(-k_x, k_y, k_x k_w) X_c:
with p = R (X_t - X_m) = X_c + (0, delta_y, 0), the robot's motion moves p at
p' = v (0, sin phi, -cos phi) + omega (sin phi p_y - cos phi p_z, -sin phi p_x,
cos phi p_x) + omega_t (0, -p_z, p_y), and the chain rule through the projection gives
exactly the matrix the spec prints (2), which is therefore right as printed.
tests/estimation/test_target_follower_models.py checks it against finite differences of the
env's simulated projection at random configurations.

Its determinant in closed form (derived with SymPy, also checked in the tests) is

    det B_i = -d_x^2 m^2 / (W f_y),   m = f_y cos(phi) - (y_i + S d_x) sin(phi),

S = f_y delta_y / (f_x W), so B_i is singular exactly when f_y = (y_i + S d_x) tan(phi)
(18)(19): the target straight above (or below) the robot.

The estimator's discrete model (28)-(31), state X_n = (X_i[n], X_i^t'[n]) with the
target's image velocity held over a sample of length T:

    X_n = [[I, T I], [0, I]] X_{n-1} + [[T B_i], [0]] u_{n-1},   Z_n = [I 0] X_n.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

__all__ = [
    "TargetFollowerCameraParams",
    "image_state_transition",
    "robot_jacobian",
    "singularity_margin",
]

# Z_n = [I3 0] X_n (31)
MEASUREMENT_MATRIX = np.hstack([np.eye(3), np.zeros((3, 3))])
MEASUREMENT_MATRIX.flags.writeable = False


@dataclass(frozen=True)
class TargetFollowerCameraParams:
    """The parameters B_i depends on: f_x, f_y (px), W (m), delta_y (m) (spec Table 1)."""

    fx_px: float = 393.4
    fy_px: float = 391.8
    target_width_m: float = 0.12
    delta_y_m: float = 0.10

    def __post_init__(self) -> None:
        for name in ("fx_px", "fy_px", "target_width_m"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"TargetFollowerCameraParams.{name} = {value!r}, must be > 0")
        if not (math.isfinite(self.delta_y_m) and self.delta_y_m >= 0.0):
            raise ValueError(
                f"TargetFollowerCameraParams.delta_y_m = {self.delta_y_m!r}, must be >= 0"
            )

    @classmethod
    def from_calibration(cls, calibration: dict) -> TargetFollowerCameraParams:
        """From a TargetFollower env's ``info["calibration"]`` (or ``env.calibration``)."""
        return cls(
            calibration["fx_px"],
            calibration["fy_px"],
            calibration["target_width_m"],
            calibration["delta_y_m"],
        )

    def scaled(self, rho: np.ndarray) -> TargetFollowerCameraParams:
        """f_x, f_y, W, delta_y each scaled by (1 + rho_j): the spec's parametric
        uncertainty of the Table 2 study."""
        r = np.broadcast_to(np.asarray(rho, dtype=float), (4,))
        return replace(
            self,
            fx_px=self.fx_px * (1.0 + r[0]),
            fy_px=self.fy_px * (1.0 + r[1]),
            target_width_m=self.target_width_m * (1.0 + r[2]),
            delta_y_m=self.delta_y_m * (1.0 + r[3]),
        )


def robot_jacobian(
    X_i: np.ndarray, tilt_rad: float, params: TargetFollowerCameraParams
) -> np.ndarray:
    """B_i (3, 3) of (2)-(4) at the image state X_i = (x_i, y_i, d_x) and tilt phi."""
    x, y, d = float(X_i[0]), float(X_i[1]), float(X_i[2])
    fx, fy = params.fx_px, params.fy_px
    dy = params.delta_y_m
    kx = d / params.target_width_m  # k_x = d_x / W = f_x / z_c
    ky = kx * fy / fx  # k_y = f_y / z_c
    c, s = math.cos(tilt_rad), math.sin(tilt_rad)
    lever = ky * dy + y  # k_y delta_y + y_i: the point's height above the tilt axis, in px
    tilt_row = s + y * c / fy
    return np.array(
        [
            [x * kx * c / fx, (x * x + fx * fx) * c / fx - fx * lever * s / fy, -x * lever / fy],
            [ky * tilt_row, fy * x * tilt_row / fx, -(y * y + fy * fy + ky * y * dy) / fy],
            [kx * d * c / fx, x * d * c / fx, -d * lever / fy],
        ]
    )


def singularity_margin(
    X_i: np.ndarray, tilt_rad: float, params: TargetFollowerCameraParams
) -> float:
    """m = f_y cos(phi) - (y_i + S d_x) sin(phi), S = f_y delta_y / (f_x W), in pixels:
    B_i is singular where m = 0 (18)(19); det B_i = -d_x^2 m^2 / (W f_y)."""
    S = params.fy_px * params.delta_y_m / (params.fx_px * params.target_width_m)  # (19)
    return params.fy_px * math.cos(tilt_rad) - (float(X_i[1]) + S * float(X_i[2])) * math.sin(
        tilt_rad
    )


def image_state_transition(dt_s: float, B_i: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(F, G) of (30): F = [[I, T I], [0, I]], G = [[T B_i], [0]]."""
    F = np.eye(6)
    F[:3, 3:] = dt_s * np.eye(3)
    G = np.zeros((6, 3))
    G[:3, :] = dt_s * B_i
    return F, G
