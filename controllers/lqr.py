"""Discrete-time LQR on any system's linear plant (python-control's dlqr)."""

from __future__ import annotations

import numpy as np

from observer_gym.controllers.base import StateFeedbackController
from observer_gym.controllers.plant import LinearPlant, check_plant
from observer_gym.controllers.weights import check_weights

__all__ = ["LQRController"]


class LQRController(StateFeedbackController):
    """u = -K x with x = obs[plant.state_slice], saturated at the action bounds, with K
    minimising sum x^T Q x + u^T R u on the plant's one-step model (A, B)
    (``control.dlqr``).

    Arguments: ``plant`` (a :class:`~observer_gym.controllers.plant.LinearPlant`, e.g.
    ``BallTablePlant``), ``Q`` (n, n) and ``R`` (m, m) or their diagonals (default the
    plant's ``weights()``). Bad weights (or a plant without the protocol's members) raise
    ``ValueError``.
    Attributes: ``K`` (m, n), ``P`` (the DARE solution), ``closed_loop_poles``, ``Phi`` and
    ``Gamma`` (the plant's A and B).
    """

    name = "lqr"

    def __init__(self, plant: LinearPlant, Q=None, R=None) -> None:
        check_plant("LQRController", plant, LinearPlant)
        super().__init__(plant.obs_dim, *plant.action_bounds)
        self.plant = plant
        self.Phi, self.Gamma = plant.matrices()
        n, m = self.Gamma.shape
        Q0, R0 = plant.weights()
        self.Q, self.R = check_weights(Q0 if Q is None else Q, R0 if R is None else R, n, m)
        self._state = plant.state_slice
        import control  # imported on use: python-control loads matplotlib (~0.7 s)

        # K = (R + B^T P B)^-1 B^T P A, P the stabilising solution of the DARE
        K, P, poles = control.dlqr(self.Phi, self.Gamma, self.Q, self.R)
        self.K = np.asarray(K)
        self.P = np.asarray(P)
        self.closed_loop_poles = np.asarray(poles)

    def act(self, obs: np.ndarray, episode_start: np.ndarray) -> np.ndarray:
        # u = -K x
        return -obs[:, self._state] @ self.K.T
