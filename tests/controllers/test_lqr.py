"""LQR on the BallTable model against closed forms: the plant's response, the Riccati
equation, the optimal gain's formula, the closed-loop poles; weight checks."""

from __future__ import annotations

import numpy as np
import pytest

from observer_gym.controllers import BallTablePlant, LQRController, make_controller
from observer_gym.envs.ball_table import BallTableConfig
from observer_gym.envs.sim import GRAVITY_MPS2
from observer_gym.estimation.ball_table.control_model import BallTableControlModel
from observer_gym.estimation.ball_table.models import ROLLING_ACCEL_FACTOR


@pytest.fixture(scope="module")
def plant() -> BallTablePlant:
    cfg = BallTableConfig()
    return BallTablePlant(BallTableControlModel.from_config(cfg), cfg.dt_s, cfg.max_tilt_rad)


def test_tilt_to_acceleration_is_the_rolling_ball_closed_form(plant):
    g = ROLLING_ACCEL_FACTOR * GRAVITY_MPS2
    np.testing.assert_allclose(plant.model.G, [[0.0, g], [-g, 0.0]], rtol=1e-8, atol=1e-8)


def test_discrete_model_matches_the_held_command_closed_form(plant):
    """From rest, a held command u: theta = u (1 - e^-t/tau) and
    p = G u (t^2/2 - tau t + tau^2 (1 - e^-t/tau))."""
    Phi, Gamma = plant.matrices()
    tau, u = plant.model.tau_s, np.array([0.03, -0.05])
    x = np.zeros(6)
    for k in range(1, 51):
        x = Phi @ x + Gamma @ u
        t = k * plant.dt_s
        decay = np.exp(-t / tau)
        np.testing.assert_allclose(x[4:6], u * (1 - decay), rtol=1e-10)
        p = plant.model.G @ u * (t**2 / 2 - tau * t + tau**2 * (1 - decay))
        np.testing.assert_allclose(x[0:2], p, rtol=1e-9, atol=1e-14)


def test_dare_residual_gain_formula_and_stable_poles(plant):
    lqr = LQRController(plant)
    A, B, Q, R, P, K = lqr.Phi, lqr.Gamma, lqr.Q, lqr.R, lqr.P, lqr.K
    BtPA = B.T @ P @ A
    residual = A.T @ P @ A - P - BtPA.T @ np.linalg.solve(R + B.T @ P @ B, BtPA) + Q
    assert np.linalg.norm(residual) / np.linalg.norm(P) < 1e-9
    np.testing.assert_allclose(K, np.linalg.solve(R + B.T @ P @ B, BtPA), rtol=1e-8)
    poles = np.linalg.eigvals(A - B @ K)
    assert np.abs(poles).max() < 1.0
    np.testing.assert_allclose(np.sort_complex(poles), np.sort_complex(lqr.closed_loop_poles))
    # The open loop is not stable (a double integrator per axis: poles at 1).
    assert np.abs(np.linalg.eigvals(A)).max() >= 1.0 - 1e-12


def test_lqr_pushes_the_ball_back_along_each_axis(plant):
    lqr = LQRController(plant)
    for axis in (0, 1):
        x = np.zeros(8)
        x[axis] = 0.05
        action, _ = lqr.predict(x)
        accel = plant.model.G @ action
        assert accel[axis] < 0.0
        assert abs(accel[1 - axis]) < 1e-9


@pytest.mark.parametrize(
    ("Q", "R", "message"),
    [
        (np.diag([1, 1, 1, 1, 1, -1.0]), None, "Q must be positive semidefinite"),
        (np.triu(np.ones((6, 6))), None, "Q must be symmetric"),
        (np.eye(5), None, "Q has shape"),
        (None, np.zeros((2, 2)), "R must be positive definite"),
        (None, [1.0, -1.0], "R must be positive definite"),
        (None, [[1.0, np.nan], [np.nan, 1.0]], "R has non-finite"),
        # an int beyond any float (found by the fuzz suite's long profile)
        ([10**400] * 6, None, r"Q = \[1000.*must be a"),
        # blind to the ball: the DARE has no stabilising solution (scipy fails)
        ([0, 0, 0, 0, 1, 1.0], None, "LQR design failed for Q"),
        # blind to everything: python-control returns K = 0, the open-loop double integrator
        (np.zeros(6), None, "does not stabilise the plant .*magnitude 1"),
    ],
)
def test_bad_weights_raise(plant, Q, R, message):
    with pytest.raises(ValueError, match=message):
        LQRController(plant, Q=Q, R=R)


def test_weights_may_be_diagonals(plant):
    full = LQRController(plant, Q=np.diag([1e4, 1e4, 100, 100, 1, 1]), R=np.eye(2) * 1000)
    diag = LQRController(plant, Q=[1e4, 1e4, 100, 100, 1, 1], R=[1000, 1000])
    np.testing.assert_allclose(diag.K, full.K)


def test_make_controller_names_what_is_allowed(make_env):
    env = make_env(obs_mode="state")
    with pytest.raises(ValueError, match="allowed: lqr, mpc, pid"):
        make_controller("lqg", env)
    with pytest.raises(ValueError, match=r"allowed: .*horizon"):
        make_controller("mpc", env, horizn=10)
    assert make_controller("mpc", env, horizon=5).horizon == 5
