"""Closing the loop through the camera: pixel observer + LQR on BallTable-v0.

From a start 10 cm from the centre (random direction, at rest), the LQR acting on the
VisionObserver's estimate (rgb frames -> detector -> Kalman filters) brings the ball
within 1 cm of the centre and keeps it there. With the true state (oracle) the same LQR
settles in 0.7-0.8 s from the env's random starts
(``observer-gym run --observer oracle --controller lqr``); through the observer the bound
is SETTLING_BOUND_S.
"""

from __future__ import annotations

import numpy as np
import pytest

from observer_gym.controllers import make_controller
from observer_gym.estimation import VisionObserver
from observer_gym.train.core.metrics import settling_time_s

START_DISTANCE_M = 0.10
BAND_M = 0.01
SECONDS = 4.0
SETTLING_BOUND_S = 1.2  # measured 0.7-0.8 s over these seeds
FINAL_BOUND_M = 0.004  # the last second's largest distance; measured 0.5-2.5 mm (under 1 mm
# with the hand-tuned Q before the noise rule: it trusted the rolling model 5x more)


@pytest.mark.parametrize(  # seeds 1 and 2: 3-4 s of pixel episodes each (idle), slow
    "seed", [0, pytest.param(1, marks=pytest.mark.slow), pytest.param(2, marks=pytest.mark.slow)]
)
def test_pixel_observer_and_lqr_centre_the_ball(make_env, seed):
    env = VisionObserver(make_env(obs_mode="rgb"))
    controller = make_controller("lqr", env)
    direction = np.random.default_rng(seed).uniform(0, 2 * np.pi)
    start = START_DISTANCE_M * np.array([np.cos(direction), np.sin(direction)])
    obs, info = env.reset(seed=seed, options={"ball_pos_table_m": start})
    dt_s = env.unwrapped.config.dt_s
    distance_m = []
    for _ in range(int(SECONDS / dt_s)):
        action, _ = controller.predict(obs)
        obs, _, terminated, _, info = env.step(action)
        assert not terminated
        distance_m.append(np.hypot(*info["state"][0:2]))
    distance_m = np.array(distance_m)
    time_s = dt_s * np.arange(1, len(distance_m) + 1)
    settling_s = settling_time_s(time_s, distance_m, tolerance_m=BAND_M)
    assert settling_s is not None, "never settled within the band"
    last_second_m = distance_m[-int(1.0 / dt_s) :].max()
    print(f"seed {seed}: settled at {settling_s:.2f} s, last second within {last_second_m:.4f} m")
    assert settling_s <= SETTLING_BOUND_S
    assert last_second_m < FINAL_BOUND_M
