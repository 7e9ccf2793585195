"""The visual tracking controller (VTC) of TargetFollower (docs/spec/follower.md, (5)-(19)).

With the error X_e = X_i* - X_i (desired minus estimated image state), X_e' = -X_i^t' -
B_i u (5)(6), and the feedback-linearising law

    u = B_i^-1 (K_g X_e - X_i^t'),   K_g = diag(alpha_1, alpha_2, alpha_3) > 0     (13)

gives X_e' = -K_g X_e: each channel's error decays as exp(-alpha_i t) (7)-(13). B_i is
:func:`~observer_gym.estimation.target_follower.models.robot_jacobian` at the estimate and the
tilt, with the controller's nominal camera parameters. Near the singularity of B_i
(f_y = (y_i + S d_x) tan(phi), (18)(19): |m| below ``singular_margin_px``) the controller
stops (u = 0), as it does while the observation's ``tracking_valid`` is 0 (the estimator
has stopped). A command beyond the action bounds is scaled down as a whole (its direction
kept), as the spec's robot scales its commands.
"""

from __future__ import annotations

import numpy as np

from observer_gym.controllers.base import StateFeedbackController
from observer_gym.controllers.target_follower.plant import TargetFollowerPlant
from observer_gym.envs.target_follower import IMAGE, IMAGE_RATE, StateIndex
from observer_gym.estimation.target_follower.models import (
    TargetFollowerCameraParams,
    robot_jacobian,
    singularity_margin,
)

__all__ = ["SIMULATION_GAINS", "VisualTrackingController"]

SIMULATION_GAINS = (0.5, 0.75, 1.0 / 3.0)  # Table 1, simulation
ROBOT_GAINS = (1.25, 3.0, 0.5)  # Table 1, the real robot


class VisualTrackingController(StateFeedbackController):
    """u = B_i^-1 (K_g X_e - X_i^t') (13).

    Arguments: ``plant`` (:class:`TargetFollowerPlant`), ``gains`` (alpha_1..3, default Table 1's
    simulation gains), ``camera`` (the f_x, f_y, W, delta_y of B_i; default the plant's),
    ``singular_margin_px`` (stop when |m| of (18) is below this; default 5 % of f_y).
    Attributes: ``K_g``, ``desired``, ``stops`` (count of rows where it stopped).
    """

    name = "vtc"

    def __init__(
        self,
        plant: TargetFollowerPlant,
        gains=SIMULATION_GAINS,
        camera: TargetFollowerCameraParams | None = None,
        singular_margin_px: float | None = None,
    ) -> None:
        super().__init__(plant.obs_dim, plant.action_low, plant.action_high)
        alphas = np.asarray(gains, dtype=float)
        if alphas.shape != (3,) or not np.all(np.isfinite(alphas)) or np.any(alphas <= 0.0):
            raise ValueError(f"VisualTrackingController: gains {gains!r} must be 3 numbers > 0")
        self.plant = plant
        self.K_g = np.diag(alphas)
        self.camera = camera or plant.camera
        self.desired = np.asarray(plant.desired_px, dtype=float)
        self.singular_margin_px = (
            0.05 * self.camera.fy_px if singular_margin_px is None else float(singular_margin_px)
        )
        self.stops = 0

    def command(self, X_i: np.ndarray, X_rate: np.ndarray, tilt_rad: float) -> np.ndarray | None:
        """The unbounded u of (13), or None at the singularity (18)."""
        if abs(singularity_margin(X_i, tilt_rad, self.camera)) < self.singular_margin_px:
            return None
        B_i = robot_jacobian(X_i, tilt_rad, self.camera)
        X_e = self.desired - X_i  # (5): desired minus estimated
        return np.linalg.solve(B_i, self.K_g @ X_e - X_rate)  # (13)

    def act(self, obs: np.ndarray, episode_start: np.ndarray) -> np.ndarray:
        actions = np.zeros((len(obs), len(self.action_high)))
        for row, state in enumerate(obs):
            u = None
            if state[StateIndex.TRACKING_VALID] >= 0.5:
                u = self.command(state[IMAGE], state[IMAGE_RATE], float(state[StateIndex.TILT]))
            if u is None:
                self.stops += 1
                continue
            ratio = np.max(np.abs(u) / self.action_high)
            actions[row] = u / ratio if ratio > 1.0 else u
        return actions
