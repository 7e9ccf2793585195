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
        try:
            K, P, poles = control.dlqr(self.Phi, self.Gamma, self.Q, self.R)
        except (np.linalg.LinAlgError, ValueError) as exc:
            raise ValueError(
                f"LQR design failed for Q = {self.Q.tolist()} and R = {self.R.tolist()} "
                f"({exc}): the DARE has a stabilising solution only if Q weighs every mode "
                "of the plant that does not decay by itself ((A, Q^1/2) detectable)"
            ) from None
        # the DARE's solution stabilises only if every closed-loop pole is inside the unit
        # circle; with a Q blind to an undamped mode python-control returns P = 0, K = 0
        largest = float(np.abs(np.asarray(poles)).max())
        if not largest < 1.0 - 1e-9:
            raise ValueError(
                f"LQR design with Q = {self.Q.tolist()} does not stabilise the plant (a "
                f"closed-loop pole of magnitude {largest:.6g}): Q must weigh every mode that "
                "does not decay by itself ((A, Q^1/2) detectable)"
            )
        self.K = np.asarray(K)
        self.P = np.asarray(P)
        self.closed_loop_poles = np.asarray(poles)

    def act(self, obs: np.ndarray, episode_start: np.ndarray) -> np.ndarray:
        # u = -K x
        return -obs[:, self._state] @ self.K.T
