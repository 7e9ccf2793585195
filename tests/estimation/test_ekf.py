"""The EKF (estimation/ekf.py): on a linear-Gaussian model it is the linear Kalman filter;
on a nonlinear measurement it linearises at the prediction."""

from __future__ import annotations

import numpy as np
import pytest

from observer_gym.estimation.ekf import ExtendedKalmanFilter, numerical_jacobian
from observer_gym.estimation.filters import KalmanFilter
from observer_gym.estimation.gating import ChiSquareGate


def test_on_a_linear_gaussian_model_the_ekf_is_the_kalman_filter():
    rng = np.random.default_rng(7)
    dt = 0.05
    Phi = np.array([[1.0, dt, 0.0], [0.0, 1.0, dt], [0.0, 0.0, 0.9]])
    Q = np.diag([1e-6, 1e-4, 1e-2])
    C = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.5]])
    R = np.diag([1e-3, 4e-3])
    x0, P0 = rng.normal(size=3), np.eye(3)
    kf = KalmanFilter(x0, P0, gate=ChiSquareGate(probability=0.999))
    ekf = ExtendedKalmanFilter(x0, P0, gate=ChiSquareGate(probability=0.999))
    x_true = rng.normal(size=3)
    for k in range(200):
        x_true = Phi @ x_true + rng.multivariate_normal(np.zeros(3), Q)
        kf.predict(Phi, Q)
        ekf.predict_nonlinear(Phi @ ekf.x, Phi, Q)  # f(x) = Phi x, F = Phi
        y = None if k % 7 == 3 else C @ x_true + rng.multivariate_normal(np.zeros(2), R)
        if k == 50:
            y = np.array([100.0, 100.0])  # an outlier both gates must reject
        a = kf.update(y, C, R)
        b = ekf.update_nonlinear(y, C @ ekf.x, C, R)  # h(x) = C x, H = C
        assert a.accepted == b.accepted
        np.testing.assert_allclose(ekf.x, kf.x, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(ekf.P, kf.P, rtol=1e-9, atol=1e-12)
    assert kf.rejected_count == ekf.rejected_count == 1


def test_central_differences_are_exact_on_an_affine_map_and_close_on_a_smooth_one():
    A = np.array([[1.0, 2.0, -3.0], [0.5, 0.0, 4.0]])
    x = np.array([0.3, -1.2, 2.0])
    np.testing.assert_allclose(numerical_jacobian(lambda v: A @ v + 1.0, x), A, atol=1e-8)
    # d/dx of (sin x0, x0 x1^2) = [[cos x0, 0], [x1^2, 2 x0 x1]]
    fn = lambda v: np.array([np.sin(v[0]), v[0] * v[1] ** 2])  # noqa: E731
    expected = [[np.cos(0.3), 0.0], [1.44, 2 * 0.3 * -1.2]]
    np.testing.assert_allclose(numerical_jacobian(fn, x[:2]), expected, rtol=1e-8, atol=1e-10)


def test_a_range_measurement_is_linearised_at_the_prediction():
    # h(x) = |x| (range to the origin): H = x^T / |x|; one update moves x along x only.
    x0 = np.array([3.0, 4.0])
    ekf = ExtendedKalmanFilter(x0, np.eye(2))
    H = numerical_jacobian(lambda x: np.array([np.linalg.norm(x)]), x0)
    np.testing.assert_allclose(H, [[0.6, 0.8]], rtol=1e-9)
    R = np.array([[1.0]])
    ekf.update_nonlinear(np.array([6.0]), np.array([5.0]), H, R)
    # K = P H^T / (H P H^T + R) = H^T / 2, so x = x0 + H^T (6 - 5) / 2
    np.testing.assert_allclose(ekf.x, x0 + 0.5 * H[0], rtol=1e-9)
    np.testing.assert_allclose(ekf.P, np.eye(2) - 0.5 * np.outer(H[0], H[0]), rtol=1e-9)


def test_a_missed_measurement_changes_nothing():
    ekf = ExtendedKalmanFilter(np.ones(2), np.eye(2))
    result = ekf.update_nonlinear(None, np.zeros(1), np.ones((1, 2)), np.eye(1))
    assert result.missed and np.array_equal(ekf.x, np.ones(2))


def test_a_state_of_the_wrong_size_is_refused():
    ekf = ExtendedKalmanFilter(np.ones(2), np.eye(2))
    with pytest.raises(ValueError, match="expected"):
        ekf.predict_nonlinear(np.ones(3), np.eye(2), np.eye(2))
