"""Discrete-time LQR on the BallTable model (python-control's dlqr)."""

from __future__ import annotations

import control
import numpy as np

from observer_gym.controllers.ball_table.plant import BallTablePlant, check_plant
from observer_gym.controllers.ball_table.weights import ball_table_weights
from observer_gym.controllers.base import StateFeedbackController
from observer_gym.controllers.weights import check_weights

__all__ = ["LQRController"]


class LQRController(StateFeedbackController):
    """u = -K x, saturated at the tilt bound, with K minimising sum x^T Q x + u^T R u on
    the plant's exact discretisation (``control.dlqr``).

    Arguments: ``plant`` (:class:`BallTablePlant`), ``Q`` (6, 6) and ``R`` (2, 2) or their
    diagonals (default :func:`ball_table_weights`). Bad weights (or another plant) raise
    ``ValueError``.
    Attributes: ``K`` (2, 6), ``P`` (the DARE solution), ``closed_loop_poles``.
    """

    name = "lqr"

    def __init__(self, plant: BallTablePlant, Q=None, R=None) -> None:
        check_plant("LQRController", plant)
        super().__init__(plant.obs_dim, *plant.action_bounds)
        Q0, R0 = ball_table_weights()
        self.Q, self.R = check_weights(
            Q0 if Q is None else Q, R0 if R is None else R, plant.model.n, plant.model.m
        )
        self.plant = plant
        self.Phi, self.Gamma = plant.matrices()
        K, P, poles = control.dlqr(self.Phi, self.Gamma, self.Q, self.R)
        self.K = np.asarray(K)
        self.P = np.asarray(P)
        self.closed_loop_poles = np.asarray(poles)

    def act(self, obs: np.ndarray, episode_start: np.ndarray) -> np.ndarray:
        return -obs[:, : self.plant.model.n] @ self.K.T
