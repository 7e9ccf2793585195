"""An alpha-beta observer for BallTable-v0, written outside observer-gym.

observer-gym's ``raw`` pipeline turns each frame into a detection (the ball's position and
the tilt, in the table frame); an alpha-beta filter smooths the position and gives the
velocity. Its covariance is the filter's steady-state error under the detection's noise
alone (a discrete Lyapunov equation): it knows nothing of the ball's acceleration.
"""

import numpy as np
from scipy.linalg import solve_discrete_lyapunov

from observer_gym.estimation import Estimate, default_pipeline

POS, VEL = [0, 1], [2, 3]  # the ball's entries in the state layout


class AlphaBeta:
    def __init__(self, env, alpha=0.5, beta=0.2):
        self.detector = default_pipeline(env, "raw")
        dt_s = env.dt_s
        self.F = np.array([[1.0, dt_s], [0.0, 1.0]])  # constant velocity over one step
        self.K = np.array([[alpha], [beta / dt_s]])  # the fixed gains
        # the error's dynamics between updates: e <- (I - K H) F e + K v
        self.A = (np.eye(2) - self.K @ np.array([[1.0, 0.0]])) @ self.F

    def reset(self):
        self.detector.reset()
        self.x = None  # rows: position, velocity; columns: the two axes

    def observe(self, obs, info, action):
        detection = self.detector.observe(obs, info, action)
        z = detection.mean[POS]
        if self.x is None:
            self.x = np.stack([z, np.zeros(2)])
        else:
            self.x = self.F @ self.x  # x = F x
            if detection.measurement_used:
                self.x = self.x + self.K @ (z - self.x[0])[None, :]  # x += K (z - H x)
        mean, cov = detection.mean.copy(), detection.covariance.copy()
        mean[POS], mean[VEL] = self.x
        cov[:4, :] = cov[:, :4] = 0.0
        for axis in (0, 1):
            # P = A P A^T + K sigma^2 K^T, sigma^2 the detection's variance on this axis
            P = solve_discrete_lyapunov(
                self.A, detection.covariance[axis, axis] * self.K @ self.K.T
            )
            cov[np.ix_([axis, axis + 2], [axis, axis + 2])] = P
        return Estimate(
            mean, cov, detection.measurement_used, detection.measurement, detection.time_s
        )


def make_observer(env, alpha=0.5, beta=0.2):
    """observer-gym's observer factory: ``factory(env, **options) -> pipeline``."""
    return AlphaBeta(env, alpha, beta)


# The systems it is made for: elsewhere observer-gym refuses it before any episode, and
# 'observer-gym list' shows these.
make_observer.systems = ("BallTable-v0",)
