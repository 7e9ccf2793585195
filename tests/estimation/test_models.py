"""Process models against closed forms: exact discretisation, the Gauss-Markov disturbance,
the rolling ball's 5/7 g sin(theta) and its sign, the border clamp, N-step prediction."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg

from observer_gym.envs.ball_table import geometry as geo
from observer_gym.envs.sim import GRAVITY_MPS2
from observer_gym.estimation.ball_table.models import RollingBallModel, RollingBallParams
from observer_gym.estimation.models import ConstantVelocityModel, discretize

DT_S = 0.02


def _double_integrator_closed_form(dt: float, q: float):
    Phi = np.array([[1.0, dt], [0.0, 1.0]])
    Gamma = np.array([[dt**2 / 2.0], [dt]])
    Qd = q * np.array([[dt**3 / 3.0, dt**2 / 2.0], [dt**2 / 2.0, dt]])
    return Phi, Gamma, Qd


@pytest.mark.parametrize("dt", [1e-3, 0.02, 0.5, 3.0])
def test_discretize_matches_the_double_integrator_closed_forms(dt):
    q = 0.7
    A = np.array([[0.0, 1.0], [0.0, 0.0]])
    B = np.array([[0.0], [1.0]])
    Phi, Gamma, Qd = discretize(A, B, B, np.array([[q]]), dt)
    Phi_ref, Gamma_ref, Qd_ref = _double_integrator_closed_form(dt, q)
    np.testing.assert_allclose(Phi, Phi_ref, rtol=1e-13, atol=1e-15)
    np.testing.assert_allclose(Gamma, Gamma_ref, rtol=1e-12)
    np.testing.assert_allclose(Qd, Qd_ref, rtol=1e-10)


def _euler(A, B, G, Qc, dt, steps):
    """Euler integration of Phi' = A Phi, Gamma' = A Gamma + B, Q' = A Q + Q A^T + G Qc G^T."""
    n = A.shape[0]
    h = dt / steps
    Phi, Gamma, Q = np.eye(n), np.zeros_like(B), np.zeros((n, n))
    GQG = G @ Qc @ G.T
    for _ in range(steps):
        Phi, Gamma, Q = (
            Phi + h * A @ Phi,
            Gamma + h * (A @ Gamma + B),
            Q + h * (A @ Q + Q @ A.T + GQG),
        )
    return Phi, Gamma, Q


def test_discretize_matches_fine_euler_integration_and_the_error_halves_with_the_step():
    rng = np.random.default_rng(0)
    n, p, k = 4, 2, 3
    A = rng.normal(size=(n, n))
    A -= (max(np.linalg.eigvals(A).real) + 0.5) * np.eye(n)  # stable
    B, G = rng.normal(size=(n, p)), rng.normal(size=(n, k))
    M = rng.normal(size=(k, k))
    Qc = M @ M.T
    dt = 0.3
    exact = discretize(A, B, G, Qc, dt)
    errors = []
    for steps in (4000, 8000):
        approx = _euler(A, B, G, Qc, dt, steps)
        errors.append(
            max(np.abs(a - e).max() / np.abs(e).max() for a, e in zip(approx, exact, strict=True))
        )
    assert errors[0] < 2e-4
    assert errors[1] / errors[0] == pytest.approx(0.5, abs=0.02)  # first order, toward ours


def test_gauss_markov_block_has_the_closed_form_variance_and_stationary_std_sigma_w():
    params = RollingBallParams(sigma_w=0.8, beta=3.0)
    Phi, _, Q = RollingBallModel(params).matrices(DT_S)
    w = slice(4, 6)
    decay = np.exp(-params.beta * DT_S)
    np.testing.assert_allclose(Phi[w, w], decay * np.eye(2), rtol=1e-14)
    var_d = params.sigma_w**2 * (1.0 - np.exp(-2.0 * params.beta * DT_S))
    np.testing.assert_allclose(Q[w, w], var_d * np.eye(2), rtol=1e-12, atol=1e-18)
    stationary = scipy.linalg.solve_discrete_lyapunov(Phi[w, w], Q[w, w])
    np.testing.assert_allclose(stationary, params.sigma_w**2 * np.eye(2), rtol=1e-12)


def test_rolling_model_noise_intensities_in_units():
    """w1 alone drives v like a random walk: Var(v) grows at sigma_w^2 * 1 s per second."""
    params = RollingBallParams(sigma_w=2.0, beta=4.0, w1_psd_time_s=1.0)
    model = RollingBallModel(params)
    _, _, _, Qc = model.continuous()
    assert Qc[0, 0] == pytest.approx(4.0)  # (m/s^2)^2 s
    assert Qc[2, 2] == pytest.approx(2.0 * 4.0 * 4.0)  # 2 beta sigma_w^2, (m/s^3)^2 s
    _, _, Q = model.matrices(1e-4)  # short step: Var(v) ~ (q_w1) dt, w2 adds O(dt^3)
    assert Q[2, 2] == pytest.approx(4.0 * 1e-4, rel=1e-3)


def test_matrices_are_cached_per_dt_and_read_only():
    model = RollingBallModel()
    first = model.matrices(DT_S)
    assert model.matrices(DT_S)[0] is first[0]
    assert model.matrices(0.01)[0] is not first[0]
    with pytest.raises(ValueError):
        first[2][0, 0] = 1.0


def test_gravity_acceleration_points_to_the_lower_side_at_five_sevenths_g_sin_theta():
    tilt = 0.1
    R_home_table = geo.tilt_rotation(0.0, tilt)
    plus_x_edge_world = R_home_table @ np.array([geo.TABLE_SIDE_M / 2, 0.0, 0.0])
    assert plus_x_edge_world[2] < 0.0  # the +x edge is the lower one
    a = RollingBallModel.gravity_acceleration(geo.up_in_table(0.0, tilt))
    assert a[0] > 0.0
    assert a[0] == pytest.approx(5.0 / 7.0 * GRAVITY_MPS2 * np.sin(tilt) * np.cos(0.0), rel=1e-14)
    assert a[1] == pytest.approx(0.0, abs=1e-15)
    # About x: a_y = -(5/7) g sin(tilt_x) (geometry.py's convention).
    a = RollingBallModel.gravity_acceleration(geo.up_in_table(0.1, 0.0))
    assert a[1] == pytest.approx(-5.0 / 7.0 * GRAVITY_MPS2 * np.sin(0.1), rel=1e-14)
    assert a[0] == pytest.approx(0.0, abs=1e-15)


def test_clamp_to_border_clamps_position_and_zeroes_only_that_velocity():
    limit = geo.BALL_TRAVEL_M
    x = np.array([0.2, 0.05, 0.3, -0.1, 0.4, 0.5])
    P = np.diag(np.arange(1.0, 7.0))
    clamped, P_out = RollingBallModel.clamp_to_border(x, P)
    np.testing.assert_array_equal(clamped, [limit, 0.05, 0.0, -0.1, 0.4, 0.5])
    np.testing.assert_array_equal(P_out, P)
    assert x[0] == 0.2  # input untouched

    clamped, P_none = RollingBallModel.clamp_to_border(np.array([0.0, -0.2, 0.3, -0.4, 0, 0]))
    np.testing.assert_array_equal(clamped, [0.0, -limit, 0.3, 0.0, 0.0, 0.0])
    assert P_none is None
    inside = np.array([limit, -limit, 1.0, -1.0, 0.0, 0.0])  # on the border: unchanged
    np.testing.assert_array_equal(RollingBallModel.clamp_to_border(inside)[0], inside)


def test_predict_ahead_follows_constant_acceleration_until_the_border_then_stays():
    model = RollingBallModel()
    limit = geo.BALL_TRAVEL_M
    p0, v0, a = np.array([0.0, 0.02]), np.array([0.1, -0.05]), np.array([0.5, 0.3])
    x0 = np.r_[p0, v0, 0.0, 0.0]
    n_steps = 40
    pred = model.predict_ahead(x0, n_steps, DT_S, a)
    assert pred.shape == (n_steps, 6)
    t = DT_S * np.arange(1, n_steps + 1)
    p_free = p0 + np.outer(t, v0) + 0.5 * np.outer(t**2, a)
    v_free = v0 + np.outer(t, a)
    hit = np.argmax(p_free[:, 0] > limit)  # x reaches the border at step `hit` (0-based)
    assert 10 < hit < n_steps - 5 and np.all(p_free[:, 1] < limit)
    np.testing.assert_allclose(pred[:hit, 0], p_free[:hit, 0], rtol=0, atol=1e-14)
    np.testing.assert_allclose(pred[:hit, 2], v_free[:hit, 0], rtol=0, atol=1e-13)
    np.testing.assert_array_equal(pred[hit:, 0], limit)
    np.testing.assert_array_equal(pred[hit:, 2], 0.0)
    np.testing.assert_allclose(pred[:, 1], p_free[:, 1], rtol=0, atol=1e-14)  # y never hits
    np.testing.assert_allclose(pred[:, 3], v_free[:, 1], rtol=0, atol=1e-13)
    np.testing.assert_array_equal(pred[:, 4:], 0.0)


def test_predict_ahead_takes_one_input_per_step():
    model = RollingBallModel()
    u = np.zeros((5, 2))
    u[2:] = [1.0, 0.0]
    pred = model.predict_ahead(np.zeros(6), 5, DT_S, u)
    assert np.all(pred[:2, 0] == 0.0) and pred[2, 0] == pytest.approx(0.5 * DT_S**2, rel=1e-12)


def test_rolling_model_measures_position_with_sigma_v():
    model = RollingBallModel(RollingBallParams(sigma_v_m=0.004))
    x = np.arange(6.0)
    np.testing.assert_array_equal(model.C @ x, [0.0, 1.0])
    np.testing.assert_allclose(model.R, 1.6e-5 * np.eye(2), rtol=1e-15)


@pytest.mark.parametrize("field", ["sigma_w", "beta", "sigma_v_m", "w1_psd_time_s"])
def test_rolling_params_reject_non_positive_values(field):
    with pytest.raises(ValueError, match=field):
        RollingBallParams(**{field: 0.0})


def test_constant_velocity_model_matches_the_closed_form_per_coordinate():
    model = ConstantVelocityModel(dim=2, accel_std=0.3)
    dt = 0.05
    Phi, Gamma, Q = model.matrices(dt)
    Phi1, Gamma1, Q1 = _double_integrator_closed_form(dt, 0.3**2)
    for i in range(2):
        idx = np.ix_([i, 2 + i], [i, 2 + i])
        np.testing.assert_allclose(Phi[idx], Phi1, rtol=1e-14)
        np.testing.assert_allclose(Q[idx], Q1, rtol=1e-10)
        np.testing.assert_allclose(Gamma[[i, 2 + i], i], Gamma1[:, 0], rtol=1e-12)
    assert Phi[0, 1] == 0.0 and Q[0, 1] == 0.0 and Q[0, 3] == 0.0  # coordinates decoupled
    np.testing.assert_array_equal(model.C, [[1, 0, 0, 0], [0, 1, 0, 0]])
