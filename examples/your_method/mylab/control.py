"""A PD controller for BallTable-v0, written outside observer-gym: tilt the table against
the ball's offset and velocity. With a_x = (5/7) g tilt_y and a_y = -(5/7) g tilt_x
(docs/spec/table_ball.md), the gains put each axis's poles at ``omega_radps`` with
``damping``; the table's lag comes on top."""

import numpy as np

G_MPS2 = 9.81


class BallPD:
    def __init__(self, env, omega_radps=3.0, damping=0.8):
        rolling = 5 / 7 * G_MPS2  # ball acceleration per radian of tilt
        self.kp, self.kd = omega_radps**2 / rolling, 2 * damping * omega_radps / rolling
        self.low, self.high = env.action_space.low, env.action_space.high

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        x, y, vx, vy = obs[:4]
        tilt_x = self.kp * y + self.kd * vy
        tilt_y = -(self.kp * x + self.kd * vx)
        return np.clip([tilt_x, tilt_y], self.low, self.high), state


def make_controller(env, omega_radps=3.0, damping=0.8):
    """observer-gym's controller factory: ``factory(env, **options) -> object with predict``."""
    return BallPD(env, omega_radps, damping)


# The systems it is made for: elsewhere observer-gym refuses it before any episode, and
# 'observer-gym list' shows these.
make_controller.systems = ("BallTable-v0",)
