"""The Kalman-filter core against the Riccati equation, the paper's predictor form (8)-(10),
a brute-force conditional Gaussian, textbook formulas and the outlier test (27)-(30)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.stats

from observer_gym.estimation.ball_table.models import RollingBallModel
from observer_gym.estimation.filters import KalmanFilter, predictor_step
from observer_gym.estimation.gating import ChiSquareGate, PSigmaGate
from observer_gym.estimation.steady_state import SteadyStateKalmanFilter, steady_state_gain

DT_S = 0.02


def _random_spd(rng: np.random.Generator, n: int, scale: float = 1.0) -> np.ndarray:
    M = rng.normal(size=(n, n))
    return scale * (M @ M.T / n + 0.1 * np.eye(n))


def _random_joint_noise(
    rng: np.random.Generator, n: int, m: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(Q, R, R12) from one random SPD joint covariance of (v, e)."""
    J = _random_spd(rng, n + m)
    return J[:n, :n], J[n:, n:], J[:n, n:]


def _riccati_residual(Phi, C, Q, R, P) -> float:
    """Relative residual of Phi P Phi^T - P - Phi P C^T (C P C^T + R)^-1 C P Phi^T + Q."""
    PhiPCt = Phi @ P @ C.T
    res = Phi @ P @ Phi.T - P - PhiPCt @ np.linalg.solve(C @ P @ C.T + R, PhiPCt.T) + Q
    return float(np.linalg.norm(res) / np.linalg.norm(P))


def _textbook_update(x, P, y, C, R):
    """Kalman update with explicit inverses, for reference only."""
    S = C @ P @ C.T + R
    K = P @ C.T @ np.linalg.inv(S)
    A = np.eye(len(x)) - K @ C
    d = y - C @ x
    return x + K @ d, A @ P @ A.T + K @ R @ K.T, float(d @ np.linalg.inv(S) @ d)


# --- steady state -------------------------------------------------------------------------


@pytest.mark.parametrize("system", ["rolling_ball", "random"])
def test_iterated_covariance_converges_to_the_dare_solution(system):
    rng = np.random.default_rng(1)
    if system == "rolling_ball":
        model = RollingBallModel()
        Phi, _, Q = model.matrices(DT_S)
        C, R = model.C, model.R
    else:
        n, m = 5, 2
        Phi = rng.normal(size=(n, n))
        Phi *= 0.97 / max(abs(np.linalg.eigvals(Phi)))
        C, Q, R = rng.normal(size=(m, n)), _random_spd(rng, n, 0.1), _random_spd(rng, m)
    K_ss, P_ss = steady_state_gain(Phi, C, Q, R)
    assert _riccati_residual(Phi, C, Q, R, P_ss) < 1e-12

    n = Phi.shape[0]
    kf = KalmanFilter(np.zeros(n), 10.0 * np.eye(n))
    for _ in range(3000):
        result = kf.update(np.zeros(C.shape[0]), C, R)
        kf.predict(Phi, Q)
    np.testing.assert_allclose(kf.P, P_ss, rtol=0, atol=1e-8 * np.abs(P_ss).max())
    np.testing.assert_allclose(result.gain, K_ss, rtol=0, atol=1e-8 * np.abs(K_ss).max())


def test_steady_state_gain_with_cross_covariance_matches_the_iterated_predictor():
    rng = np.random.default_rng(2)
    n, m = 4, 2
    Phi = rng.normal(size=(n, n))
    Phi *= 0.9 / max(abs(np.linalg.eigvals(Phi)))
    C = rng.normal(size=(m, n))
    Q, R, R12 = _random_joint_noise(rng, n, m)
    K_f, P_ss = steady_state_gain(Phi, C, Q, R, R12)
    x, P = np.zeros(n), np.eye(n)
    for _ in range(2000):
        x, P = predictor_step(x, P, np.zeros(m), C, Phi, Q, R, R12)
    np.testing.assert_allclose(P, P_ss, rtol=0, atol=1e-10 * np.abs(P_ss).max())
    np.testing.assert_allclose(K_f, P_ss @ C.T @ np.linalg.inv(C @ P_ss @ C.T + R), atol=1e-12)


# --- predictor form (8)-(10) --------------------------------------------------------------


def test_predictor_form_without_cross_covariance_equals_filter_form_then_predict():
    rng = np.random.default_rng(3)
    n, m_max, p = 4, 3, 2
    x_pred, P_pred = rng.normal(size=n), _random_spd(rng, n, 5.0)
    kf = KalmanFilter(x_pred, P_pred)
    for k in range(200):  # a random LTV sequence, measurement size varying
        m = 1 + k % m_max
        Phi, Gamma, C = rng.normal(size=(n, n)), rng.normal(size=(n, p)), rng.normal(size=(m, n))
        Phi /= max(1.0, max(abs(np.linalg.eigvals(Phi))))
        Q, R, u, y = _random_spd(rng, n, 0.3), _random_spd(rng, m), rng.normal(size=p), None
        if k % 7 != 3:  # every 7th step has no measurement
            y = rng.normal(size=m)
        x_pred, P_pred = predictor_step(x_pred, P_pred, y, C, Phi, Q, R, Gamma=Gamma, u=u)
        kf.update(y, C, R)
        x_filt = kf.x.copy()
        kf.predict(Phi, Q, Gamma, u)
        np.testing.assert_allclose(x_pred, Phi @ x_filt + Gamma @ u, rtol=1e-10, atol=1e-10)
        np.testing.assert_allclose(kf.x, x_pred, rtol=1e-10, atol=1e-10)
        np.testing.assert_allclose(kf.P, P_pred, rtol=1e-10, atol=1e-10)


def test_predictor_form_with_cross_covariance_equals_the_decorrelated_system():
    """y = C x + e gives e = y - C x, so x(k+1) = (Phi - J C) x + Gamma u + J y + (v - J e)
    with J = R12 R2^-1; v - J e is uncorrelated with e and has covariance
    R1 - R12 R2^-1 R12^T: a standard predictor (R12 = 0) on that system is the same filter."""
    rng = np.random.default_rng(4)
    n, m, p = 4, 2, 1
    x_a, P_a = rng.normal(size=n), _random_spd(rng, n, 5.0)
    x_b, P_b = x_a.copy(), P_a.copy()
    kf = KalmanFilter(x_a, P_a)
    for _ in range(100):
        Phi, Gamma, C = rng.normal(size=(n, n)), rng.normal(size=(n, p)), rng.normal(size=(m, n))
        Phi /= max(1.0, max(abs(np.linalg.eigvals(Phi))))
        Q, R, R12 = _random_joint_noise(rng, n, m)
        u, y = rng.normal(size=p), rng.normal(size=m)
        x_a, P_a = predictor_step(x_a, P_a, y, C, Phi, Q, R, R12, Gamma, u)

        J = R12 @ np.linalg.inv(R)
        Phi_star, Q_star = Phi - J @ C, Q - J @ R12.T
        x_b, P_b = predictor_step(
            x_b, P_b, y, C, Phi_star, Q_star, R, None, np.hstack([Gamma, J]), np.r_[u, y]
        )
        kf.update(y, C, R, R12)  # filter form, R12 carried into the next predict
        kf.predict(Phi, Q, Gamma, u)
        for x, P in ((x_b, P_b), (kf.x, kf.P)):
            np.testing.assert_allclose(x, x_a, rtol=1e-9, atol=1e-9)
            np.testing.assert_allclose(P, P_a, rtol=1e-9, atol=1e-9)


def test_predictor_with_cross_covariance_equals_brute_force_conditional_gaussian():
    """x(N|N-1) and P(N|N-1) from the joint Gaussian of (x0, v0, e0, ..., v_{N-1}, e_{N-1})."""
    rng = np.random.default_rng(5)
    n, m, N = 2, 1, 5
    Phi, C = rng.normal(size=(n, n)), rng.normal(size=(m, n))
    Q, R, R12 = _random_joint_noise(rng, n, m)
    m0, P0 = rng.normal(size=n), _random_spd(rng, n, 3.0)
    ys = rng.normal(size=(N, m))

    block = n + m  # (v_k, e_k)
    dim = n + N * block
    Sigma = np.zeros((dim, dim))
    Sigma[:n, :n] = P0
    joint = np.block([[Q, R12], [R12.T, R]])
    for k in range(N):
        s = n + k * block
        Sigma[s : s + block, s : s + block] = joint
    # x_k = X[k] @ xi + mean, y_k = C x_k + e_k, as linear maps of xi = (x0, v0, e0, ...).
    X = np.zeros((n, dim))
    X[:, :n] = np.eye(n)
    Y_rows, mean_x = [], m0.copy()
    y_means = []
    for k in range(N):
        s = n + k * block
        E = np.zeros((m, dim))
        E[:, s + n : s + block] = np.eye(m)
        Y_rows.append(C @ X + E)
        y_means.append(C @ mean_x)
        V = np.zeros((n, dim))
        V[:, s : s + n] = np.eye(n)
        X = Phi @ X + V
        mean_x = Phi @ mean_x
    Y = np.vstack(Y_rows)
    Syy, Sxy = Y @ Sigma @ Y.T, X @ Sigma @ Y.T
    x_bf = mean_x + Sxy @ np.linalg.solve(Syy, ys.reshape(-1) - np.concatenate(y_means))
    P_bf = X @ Sigma @ X.T - Sxy @ np.linalg.solve(Syy, Sxy.T)

    x, P = m0, P0
    for k in range(N):
        x, P = predictor_step(x, P, ys[k], C, Phi, Q, R, R12)
    np.testing.assert_allclose(x, x_bf, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(P, P_bf, rtol=1e-10, atol=1e-10)


def test_sequential_updates_with_cross_covariance_equal_one_batch_update():
    """Two blocks e1, e2 (independent of each other, both correlated with v) one after the
    other, then predict, equals one stacked update with R12 = [R12_1, R12_2]."""
    rng = np.random.default_rng(6)
    n, m1, m2 = 4, 2, 1
    J = _random_spd(rng, n + m1 + m2)
    J[n : n + m1, n + m1 :] = J[n + m1 :, n : n + m1] = 0.0  # e1, e2 independent
    J += np.eye(n + m1 + m2)  # still SPD
    Q, R1, R2 = J[:n, :n], J[n : n + m1, n : n + m1], J[n + m1 :, n + m1 :]
    R12_1, R12_2 = J[:n, n : n + m1], J[:n, n + m1 :]
    Phi, C1, C2 = rng.normal(size=(n, n)), rng.normal(size=(m1, n)), rng.normal(size=(m2, n))
    y1, y2 = rng.normal(size=m1), rng.normal(size=m2)
    x0, P0 = rng.normal(size=n), _random_spd(rng, n, 2.0)

    seq = KalmanFilter(x0, P0)
    seq.update(y1, C1, R1, R12_1)
    seq.update(y2, C2, R2, R12_2)
    seq.predict(Phi, Q)
    x_ref, P_ref = predictor_step(
        x0, P0, np.r_[y1, y2], np.vstack([C1, C2]), Phi, Q, J[n:, n:], J[:n, n:]
    )
    np.testing.assert_allclose(seq.x, x_ref, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(seq.P, P_ref, rtol=1e-10, atol=1e-10)


# --- measurement update -------------------------------------------------------------------


@pytest.mark.parametrize("m", [1, 2, 3])
def test_update_matches_textbook_formulas_for_each_measurement_size(m):
    rng = np.random.default_rng(10 + m)
    n = 6
    x, P = rng.normal(size=n), _random_spd(rng, n)
    C, R, y = rng.normal(size=(m, n)), _random_spd(rng, m, 0.1), rng.normal(size=m)
    kf = KalmanFilter(x, P)
    result = kf.update(y, C, R)
    x_ref, P_ref, nis_ref = _textbook_update(x, P, y, C, R)
    assert result.accepted and kf.accepted_count == 1
    np.testing.assert_allclose(kf.x, x_ref, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(kf.P, P_ref, rtol=1e-12, atol=1e-12)
    assert result.nis == pytest.approx(nis_ref, rel=1e-12)
    np.testing.assert_allclose(result.innovation, y - C @ x, rtol=1e-14)
    np.testing.assert_allclose(result.innovation_cov, C @ P @ C.T + R, rtol=1e-14)


def test_sequential_update_equals_batch_update():
    rng = np.random.default_rng(20)
    n = 5
    x, P = rng.normal(size=n), _random_spd(rng, n, 3.0)
    C1, C2 = rng.normal(size=(2, n)), rng.normal(size=(1, n))
    R1, R2 = _random_spd(rng, 2, 0.2), _random_spd(rng, 1, 0.2)
    y1, y2 = rng.normal(size=2), rng.normal(size=1)

    seq = KalmanFilter(x, P)
    seq.update(y1, C1, R1)
    seq.update(y2, C2, R2)
    batch = KalmanFilter(x, P)
    R_batch = np.zeros((3, 3))
    R_batch[:2, :2], R_batch[2:, 2:] = R1, R2
    batch.update(np.r_[y1, y2], np.vstack([C1, C2]), R_batch)
    np.testing.assert_allclose(seq.x, batch.x, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(seq.P, batch.P, rtol=1e-12, atol=1e-12)


def test_missed_measurement_leaves_the_estimate_exactly_unchanged():
    rng = np.random.default_rng(21)
    kf = KalmanFilter(rng.normal(size=4), _random_spd(rng, 4))
    x_before, P_before = kf.x.copy(), kf.P.copy()
    result = kf.update(None, rng.normal(size=(2, 4)), np.eye(2))
    assert np.array_equal(kf.x, x_before) and np.array_equal(kf.P, P_before)
    assert not result.accepted and result.missed and np.isnan(result.nis)
    assert kf.accepted_count == 0 and kf.rejected_count == 0


@pytest.mark.slow  # 1e5 filter cycles; its cost is bench_filters.py's business, not a test's
def test_covariance_stays_symmetric_positive_definite_over_1e5_ill_conditioned_steps():
    """R = 1e-12 I and P0 = 1e12 I: the first updates span 24 orders of magnitude, more than
    double precision resolves (eps ~ 2e-16), so any covariance-form update returns
    eigenvalues of either sign at the ~1e-4 rounding level there. The filter must detect
    it and repair P at the precision floor, in those first steps only."""
    rng = np.random.default_rng(22)
    n, m, steps = 4, 2, 100_000
    kf = KalmanFilter(np.zeros(n), 1e12 * np.eye(n))
    R = 1e-12 * np.eye(m)
    Phi = np.linalg.qr(rng.normal(size=(n, n)))[0]  # orthogonal: neither growing nor decaying
    Q = np.diag([1e-10, 1e-8, 1e-6, 1e-4])
    Cs = rng.normal(size=(steps, m, n))
    ys = rng.normal(size=(steps, m))
    min_eigs = []
    for k in range(steps):
        kf.predict(Phi, Q)
        kf.update(ys[k], Cs[k], R)
        if k < 10 or k % 1000 == 999:
            assert np.array_equal(kf.P, kf.P.T)  # symmetrised, exactly
            min_eigs.append(np.linalg.eigvalsh(kf.P)[0])
        if k == 9:
            early_repairs = kf.pd_repairs
    assert 1 <= early_repairs <= 3 and kf.pd_repairs == early_repairs
    assert np.all(np.isfinite(kf.P)) and np.all(np.isfinite(kf.x))
    assert min(min_eigs) > 0.0
    np.linalg.cholesky(kf.P)  # positive definite: factorable
    # Once the 1e12 directions are measured, P is at the scale the model implies.
    assert np.linalg.eigvalsh(kf.P)[-1] < 1e-3


def test_repair_raises_eigenvalues_only_to_the_precision_floor():
    P = np.diag([1e12, 1e12, 1e-3, -1e-4])  # indefinite at the 1e12 rounding level
    kf = KalmanFilter(np.zeros(4), np.eye(4))
    repaired = kf._repair(P)
    lam = np.linalg.eigvalsh(repaired)
    assert kf.pd_repairs == 1 and lam[0] > 0.0
    assert lam[0] <= 1e3 * 4 * np.finfo(float).eps * 1e12  # at most 3 decades above n eps |P|
    np.testing.assert_allclose(np.sort(np.diag(repaired))[1:], [1e-3, 1e12, 1e12], rtol=1e-6)


def test_update_with_an_indefinite_innovation_covariance_raises():
    kf = KalmanFilter(np.zeros(2), np.eye(2))
    with pytest.raises(np.linalg.LinAlgError, match="not positive definite"):
        kf.update(np.zeros(2), np.eye(2), -10.0 * np.eye(2))


# --- gates ------------------------------------------------------------------------------


def _gate_setup():
    P = np.array([[2.0, 0.3, 0.0], [0.3, 1.0, 0.1], [0.0, 0.1, 0.5]])
    C = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 1.0]])
    R = np.array([[0.5, 0.1], [0.1, 0.4]])
    return np.zeros(3), P, C, R


@pytest.mark.parametrize("gate", [PSigmaGate(3.0), ChiSquareGate(0.997)])
def test_gates_reject_a_20_sigma_outlier_and_accept_a_1_sigma_measurement(gate):
    x, P, C, R = _gate_setup()
    S = C @ P @ C.T + R
    L = np.linalg.cholesky(S)
    kf = KalmanFilter(x, P, gate=gate)
    outlier = L @ np.array([20.0, 0.0])  # NIS = 400
    result = kf.update(outlier, C, R)
    assert not result.accepted and result.gain is None
    assert result.nis == pytest.approx(400.0, rel=1e-12)
    assert np.array_equal(kf.x, x) and np.array_equal(kf.P, P)
    assert kf.rejected_count == 1 and kf.accepted_count == 0

    one_sigma = L @ np.array([0.6, 0.8])  # NIS = 1
    result = kf.update(one_sigma, C, R)
    assert result.accepted and result.nis == pytest.approx(1.0, rel=1e-12)
    assert kf.rejected_count == 1 and kf.accepted_count == 1


def test_p_sigma_gate_matches_a_hand_computation_of_29_30():
    x, P, C, R2 = _gate_setup()
    d = np.array([1.2, -0.7])
    # (28): R = R2 + C P C^T = [[0.5 + 2.0, 0.1 + 0.3], [0.1 + 0.3, 0.4 + 1.0 + 0.2 + 0.5]]
    R_28 = np.array([[2.5, 0.4], [0.4, 2.1]])
    np.testing.assert_allclose(R2 + C @ P @ C.T, R_28, rtol=1e-15)
    # (29): sigma^2 = d^T R d / d^T d = (2.5 * 1.44 - 2 * 0.4 * 0.84 + 2.1 * 0.49) / 1.93
    sigma2 = (3.6 - 0.672 + 1.029) / 1.93
    ratio = np.sqrt(1.93 / sigma2)  # ||d|| / sigma = 0.97023...
    assert ratio == pytest.approx(0.970229, abs=1e-6)
    for p, accepted in ((ratio * 1.001, True), (ratio * 0.999, False)):  # (30)
        kf = KalmanFilter(x, P, gate=PSigmaGate(p))
        assert kf.update(d, C, R2).accepted is accepted


def test_chi_square_gate_threshold_is_the_closed_form_quantile():
    gate = ChiSquareGate(0.997)
    assert gate.threshold(2) == pytest.approx(-2.0 * np.log(0.003), rel=1e-12)  # chi2(2)
    assert gate.threshold(3) == pytest.approx(scipy.stats.chi2.ppf(0.997, 3), rel=1e-12)
    S = np.diag([4.0, 1.0])
    just_in = np.array([2.0 * np.sqrt(gate.threshold(2) * 0.999), 0.0])
    just_out = np.array([0.0, np.sqrt(gate.threshold(2) * 1.001)])
    assert gate.accepts(just_in, S, np.eye(2), S - np.eye(2))
    assert not gate.accepts(just_out, S, np.eye(2), S - np.eye(2))


# --- steady-state filter ------------------------------------------------------------------


def test_steady_state_filter_matches_the_converged_kalman_filter():
    rng = np.random.default_rng(30)
    model = RollingBallModel()
    Phi, Gamma, Q = model.matrices(DT_S)
    C, R = model.C, model.R
    kf = KalmanFilter(np.zeros(6), np.eye(6))
    steps = 600
    us = rng.normal(scale=0.5, size=(steps, 2))
    ys = rng.normal(scale=0.05, size=(steps, 2))
    for k in range(300):  # converge
        kf.predict(Phi, Q, Gamma, us[k])
        kf.update(ys[k], C, R)
    ss = SteadyStateKalmanFilter.from_model(kf.x, Phi, C, Q, R)
    for k in range(300, steps):
        kf.predict(Phi, Q, Gamma, us[k])
        ss.predict(Phi, Gamma, us[k])
        np.testing.assert_allclose(ss.x, kf.x, rtol=0, atol=1e-10)
        kf.update(ys[k], C, R)
        ss.update(ys[k])
        np.testing.assert_allclose(ss.x, kf.x, rtol=0, atol=1e-10)
    np.testing.assert_allclose(ss.P_filt, kf.P, rtol=1e-10, atol=1e-16)
    x_before = ss.x.copy()
    ss.update(None)  # a missed frame keeps the prediction
    assert np.array_equal(ss.x, x_before)


def _rolling_ball_run(kf: KalmanFilter, seed: int, steps: int = 1500) -> np.ndarray:
    """Estimates over a simulated rolling-ball run with a stretch of 10 % missed
    measurements, an outlier burst the gate rejects, a P assigned from outside and a
    change of dt."""
    rng = np.random.default_rng(seed)
    model = RollingBallModel()
    x_true, u = np.zeros(6), np.array([0.3, -0.2])
    estimates = np.empty((steps, 6))
    for k in range(steps):
        dt_s = DT_S if k < 1200 else 2 * DT_S
        Phi, Gamma, Q = model.matrices(dt_s)
        x_true = Phi @ x_true + Gamma @ u + rng.multivariate_normal(np.zeros(6), Q)
        y = model.C @ x_true + rng.normal(0.0, model.params.sigma_v_m, 2)
        if 400 <= k < 403:
            y = y + 1.0  # an outlier burst, far outside the gate
        kf.predict(Phi, Q, Gamma, u)
        if k == 800:
            kf.P = kf.P.copy()  # assigned from outside, like a border clamp would
        missed = rng.random() < 0.1 and 1000 <= k < 1100
        kf.update(None if missed else y, model.C, model.R)
        estimates[k] = kf.x
    return estimates


def test_converged_gain_path_equals_the_full_recursion():
    """A filter with converged_rtol takes the cheap path for most steps and its estimates
    match the full recursion's through dropouts, rejections, an outside P and a new dt."""
    P0 = np.diag([1e-4, 1e-4, 1e-2, 1e-2, 1.0, 1.0])
    full = KalmanFilter(np.zeros(6), P0, gate=ChiSquareGate(0.9999))
    fast = KalmanFilter(np.zeros(6), P0, gate=ChiSquareGate(0.9999), converged_rtol=1e-9)
    reference, estimates = _rolling_ball_run(full, seed=3), _rolling_ball_run(fast, seed=3)
    assert fast.steady_cycles > 500
    assert full.steady_cycles == 0
    assert fast.rejected_count == full.rejected_count >= 3
    # Each state's largest difference, relative to its range over the run: ~5e-9 measured.
    scale = np.abs(reference).max(axis=0)
    assert np.all(np.abs(estimates - reference).max(axis=0) <= 1e-7 * scale)
    np.testing.assert_allclose(fast.P, full.P, rtol=1e-7, atol=0)


def test_converged_gain_path_holds_the_dare_covariance():
    model = RollingBallModel()
    Phi, _, Q = model.matrices(DT_S)
    kf = KalmanFilter(np.zeros(6), np.eye(6), converged_rtol=1e-9)
    for _ in range(400):
        kf.predict(Phi, Q)
        kf.update(np.zeros(2), model.C, model.R)
    assert kf.steady_cycles > 100
    _, P_pred = steady_state_gain(Phi, model.C, Q, model.R)
    kf.predict(Phi, Q)
    np.testing.assert_allclose(kf.P, P_pred, rtol=1e-6)


@pytest.mark.parametrize("rtol", [0.0, 1.0, -1e-9, float("nan")])
def test_converged_rtol_out_of_range_raises(rtol):
    with pytest.raises(ValueError, match="converged_rtol"):
        KalmanFilter(np.zeros(2), np.eye(2), converged_rtol=rtol)


def test_predict_requires_gamma_and_u_together():
    kf = KalmanFilter(np.zeros(2), np.eye(2))
    with pytest.raises(ValueError, match="Gamma and u"):
        kf.predict(np.eye(2), np.eye(2), Gamma=np.ones((2, 1)))
