"""PID per axis: the control law's numbers, per-row memory, anti-windup."""

from __future__ import annotations

import numpy as np
import pytest

from observer_gym.controllers import BallTablePlant, PIDController
from observer_gym.envs.ball_table import BallTableConfig
from observer_gym.estimation.ball_table.control_model import BallTableControlModel


@pytest.fixture(scope="module")
def plant() -> BallTablePlant:
    cfg = BallTableConfig()
    return BallTablePlant(BallTableControlModel.from_config(cfg), cfg.dt_s, cfg.max_tilt_rad)


def test_first_action_is_the_pid_law_through_the_inverse_tilt_gain(plant):
    pid = PIDController(plant, omega_radps=2.0, damping=0.8)
    assert (pid.kp, pid.kd, pid.ki) == pytest.approx((4.0, 3.2, 0.8))
    obs = np.array([0.02, -0.01, 0.05, 0.0, 0, 0, 0, 0])
    action, _ = pid.predict(obs)
    pos, vel = obs[0:2], obs[2:4]
    accel = -(pid.kp * pos + pid.ki * pos * plant.dt_s + pid.kd * vel)
    np.testing.assert_allclose(plant.model.G @ action, accel, rtol=1e-6)
    # x is driven by +tilt_y, y by -tilt_x: the ball at +x moving +x needs tilt_y < 0,
    # the ball at -y needs a_y > 0, so tilt_x < 0.
    assert action[0] < 0 and action[1] < 0


def test_memory_is_per_row_and_cleared_by_episode_start(plant):
    batched, fresh = PIDController(plant), PIDController(plant)
    obs = np.tile([0.01, 0.02, 0.0, 0.0, 0, 0, 0, 0], (2, 1))
    for _ in range(20):
        batched.predict(obs, episode_start=np.array([False, False]))
    action, _ = batched.predict(obs, episode_start=np.array([True, False]))
    reference, _ = fresh.predict(obs[0])
    np.testing.assert_allclose(action[0], reference)
    assert np.abs(action[1]).max() > np.abs(action[0]).max()  # row 1 kept its integral


def test_integral_is_clamped_and_frozen_while_saturated(plant):
    pid = PIDController(plant, kp=0.0, kd=0.0, ki=1.0)
    obs = np.array([0.1, 0.0, 0, 0, 0, 0, 0, 0])
    for _ in range(10_000):
        action, _ = pid.predict(obs)
    assert np.abs(action).max() == pytest.approx(plant.max_tilt_rad)
    gain = np.abs(plant.model.G).max()
    assert np.abs(pid._integral).max() <= plant.max_tilt_rad * gain / pid.ki + 1e-12
    pid.reset()
    action, _ = pid.predict(obs)
    np.testing.assert_allclose(plant.model.G @ action, [-0.1 * plant.dt_s, 0.0], atol=1e-9)


@pytest.mark.parametrize("option", ["omega_radps", "damping", "kp", "ki", "kd"])
def test_bad_gains_raise(plant, option):
    with pytest.raises(ValueError, match=option):
        PIDController(plant, **{option: -1.0})
