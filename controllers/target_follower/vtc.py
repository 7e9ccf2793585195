"""The visual tracking controller (VTC) of TargetFollower (docs/spec/follower.md, (5)-(19)).

With the error X_e = X_i* - X_i (desired minus estimated image state), X_e' = -X_i^t' -
B_i u (5)(6), and the feedback-linearising law

    u = B_i^-1 (K_g X_e - X_i^t'),   K_g = diag(alpha_1, alpha_2, alpha_3) > 0     (13)

gives X_e' = -K_g X_e: each channel's error decays as exp(-alpha_i t) (7)-(13). B_i is
:func:`~observer_gym.estimation.target_follower.models.robot_jacobian` at the estimate and the
tilt, with the controller's nominal camera parameters. Near the singularity of B_i
(f_y = (y_i + S d_x) tan(phi), (18)(19): |m| below ``singular_margin_px``) the controller
stops (u = 0), as it does while the observation's ``tracking_valid`` is 0 (the estimator
has stopped). It stops likewise where B_i cannot be inverted reliably although |m| is
large: a target width d_x <= 0 (det B_i = -d_x^2 m^2 / (W f_y) = 0), entries that
overflow (observations of 1e30 px), or a condition number above :data:`MAX_CONDITION`
(1e8: half the digits of the solve lost; over the image, widths of 3-300 px and tilts of
-0.6..0.9 rad it stays below 3.3e3 outside the margin). Every such stop is reported:
``last_singular`` marks the rows of the last ``predict`` stopped at a singular B_i,
``singular_stops`` counts them, and the first one warns (``RuntimeWarning``). A command
beyond the action bounds is scaled down as a whole (its direction kept), as the spec's
robot scales its commands.
"""

from __future__ import annotations

import warnings

import numpy as np

from observer_gym.controllers.base import StateFeedbackController, check_number
from observer_gym.controllers.target_follower.plant import TargetFollowerPlant
from observer_gym.envs.target_follower import IMAGE, IMAGE_RATE, StateIndex
from observer_gym.estimation.target_follower.models import (
    TargetFollowerCameraParams,
    robot_jacobian,
    singularity_margin,
)

__all__ = ["MAX_CONDITION", "SIMULATION_GAINS", "VisualTrackingController"]

SIMULATION_GAINS = (0.5, 0.75, 1.0 / 3.0)  # Table 1, simulation
ROBOT_GAINS = (1.25, 3.0, 0.5)  # Table 1, the real robot
MAX_CONDITION = 1e8  # B_i with a larger condition number counts as singular


class VisualTrackingController(StateFeedbackController):
    """u = B_i^-1 (K_g X_e - X_i^t') (13).

    Arguments: ``plant`` (:class:`TargetFollowerPlant`), ``gains`` (alpha_1..3, default Table 1's
    simulation gains: 3 finite numbers > 0), ``camera`` (the f_x, f_y, W, delta_y of B_i, a
    :class:`TargetFollowerCameraParams`; default the plant's), ``singular_margin_px`` (stop
    when |m| of (18) is below this: a finite number >= 0; default 5 % of f_y). Bad options
    raise ``ValueError``.
    Attributes: ``K_g``, ``desired``, ``stops`` (count of rows where it stopped, for any
    reason), ``singular_stops`` (of those, the rows stopped at a singular B_i) and
    ``last_singular`` (bool per row of the last ``predict``).
    """

    name = "vtc"

    def __init__(
        self,
        plant: TargetFollowerPlant,
        gains=SIMULATION_GAINS,
        camera: TargetFollowerCameraParams | None = None,
        singular_margin_px: float | None = None,
    ) -> None:
        if not isinstance(plant, TargetFollowerPlant):
            raise ValueError(
                "VisualTrackingController: plant must be a TargetFollowerPlant "
                f"(TargetFollowerPlant.from_env(env)), got {type(plant).__name__}"
            )
        super().__init__(plant.obs_dim, plant.action_low, plant.action_high)
        try:
            alphas = np.asarray(gains, dtype=float)
        except (TypeError, ValueError):
            alphas = np.full(0, np.nan)
        if alphas.shape != (3,) or not np.all(np.isfinite(alphas)) or np.any(alphas <= 0.0):
            raise ValueError(f"VisualTrackingController: gains {gains!r} must be 3 numbers > 0")
        if camera is not None and not isinstance(camera, TargetFollowerCameraParams):
            raise ValueError(
                f"VisualTrackingController: camera = {camera!r}, must be None or a "
                "TargetFollowerCameraParams"
            )
        margin = check_number(
            "VisualTrackingController",
            "singular_margin_px",
            singular_margin_px,
            low=0.0,
            allow_none=True,
        )
        self.plant = plant
        self.K_g = np.diag(alphas)
        self.camera = camera or plant.camera
        self.desired = np.asarray(plant.desired_px, dtype=float)
        self.singular_margin_px = 0.05 * self.camera.fy_px if margin is None else margin
        self.stops = 0
        self.singular_stops = 0
        self.last_singular = np.zeros(0, dtype=bool)
        self._warned_singular = False

    def command(self, X_i: np.ndarray, X_rate: np.ndarray, tilt_rad: float) -> np.ndarray | None:
        """The unbounded u of (13), or None where B_i is singular: |m| of (18) below
        ``singular_margin_px``, d_x <= 0, B_i or u not finite, or cond(B_i) above
        :data:`MAX_CONDITION` (see the module docstring)."""
        if not abs(singularity_margin(X_i, tilt_rad, self.camera)) >= self.singular_margin_px:
            return None  # also for a NaN margin (overflow)
        if not X_i[2] > 0.0:
            return None  # no width: det B_i = 0
        with np.errstate(over="ignore", invalid="ignore"):
            B_i = robot_jacobian(X_i, tilt_rad, self.camera)
            if not np.all(np.isfinite(B_i)) or not np.linalg.cond(B_i) <= MAX_CONDITION:
                return None
            X_e = self.desired - X_i  # (5): desired minus estimated
            try:
                u = np.linalg.solve(B_i, self.K_g @ X_e - X_rate)  # (13)
            except np.linalg.LinAlgError:
                return None
        return u if bool(np.all(np.isfinite(u))) else None

    def act(self, obs: np.ndarray, episode_start: np.ndarray) -> np.ndarray:
        actions = np.zeros((len(obs), len(self.action_high)))
        singular = np.zeros(len(obs), dtype=bool)
        for row, state in enumerate(obs):
            u = None
            if state[StateIndex.TRACKING_VALID] >= 0.5:
                u = self.command(state[IMAGE], state[IMAGE_RATE], float(state[StateIndex.TILT]))
                singular[row] = u is None
            if u is None:
                self.stops += 1
                continue
            ratio = np.max(np.abs(u) / self.action_high)
            actions[row] = u / ratio if ratio > 1.0 else u
        self.last_singular = singular
        self.singular_stops += int(np.count_nonzero(singular))
        if np.any(singular) and not self._warned_singular:
            self._warned_singular = True
            warnings.warn(
                "VisualTrackingController: B_i is singular at observation "
                f"{obs[singular][0].tolist()} (spec (18)); the controller stops there (u = 0). "
                "Later stops are counted in singular_stops and marked in last_singular, not "
                "warned.",
                RuntimeWarning,
                stacklevel=3,
            )
        return actions
