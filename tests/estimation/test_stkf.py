"""The self-tuning Kalman filter (docs/spec/follower.md (30)-(41)): the R update against its
closed form, the procedure's reliability threshold, and the STKF against the KF on a known
image motion with the spec's noise model."""

from __future__ import annotations

import numpy as np
import pytest

from observer_gym.estimation.self_tuning import SelfTuningR, line_residual_projector
from observer_gym.estimation.target_follower.filters import VisualStateEstimator, VSEParams
from observer_gym.estimation.target_follower.models import image_state_transition

R0 = np.diag([5.0, 5.0, 5.0])  # Table 1
T_S = 0.1
NO_INPUT = (np.zeros((3, 3)), np.zeros(3))


def test_projector_removes_lines_and_keeps_what_is_orthogonal_to_them():
    k = 7
    T_st = line_residual_projector(k)
    n = np.arange(1.0, k + 1)
    np.testing.assert_allclose(T_st @ (3.0 * n - 2.0), 0.0, atol=1e-12)
    np.testing.assert_allclose(T_st @ T_st, T_st, atol=1e-12)  # a projector
    np.testing.assert_allclose(T_st, T_st.T, atol=1e-12)
    assert np.linalg.matrix_rank(T_st) == k - 2
    with pytest.raises(ValueError, match="k >= 3"):
        line_residual_projector(2)


def test_R_update_equals_the_closed_form_on_a_known_sequence():
    # k = 3: (1, -2, 1) is orthogonal to every line a n + b, so Y = line + c (1, -2, 1)
    # leaves eps* = c (1, -2, 1) exactly: var(eps*) = 6 c^2 / 3 = 2 c^2 and, by (41),
    # R = R_0 + diag((2 c^2)^2).
    tuner = SelfTuningR(R0, window=3)
    c = np.array([1.0, 0.5, 3.0])
    lines = [np.array([2.0, -1.0, 30.0]) + n * np.array([0.7, 4.0, -1.5]) for n in (1, 2, 3)]
    for n, bump in enumerate((1.0, -2.0, 1.0)):
        np.testing.assert_array_equal(tuner.R(), R0)  # not full yet: R_0
        tuner.push(lines[n] + bump * c)
    np.testing.assert_allclose(tuner.residual_variance(), 2.0 * c**2)
    np.testing.assert_allclose(tuner.R(), R0 + np.diag((2.0 * c**2) ** 2))


def test_R_update_equals_a_least_squares_line_fit():
    rng = np.random.default_rng(4)
    k = 10
    tuner = SelfTuningR(R0, window=k)
    Y = rng.normal(size=(k + 5, 3)) * [1.0, 3.0, 10.0] + np.arange(k + 5)[:, None] * 2.0
    for y in Y:
        tuner.push(y)
    window = Y[-k:]  # the register keeps the last k
    n = np.arange(1, k + 1)
    variances = []
    for channel in range(3):
        slope, intercept = np.polyfit(n, window[:, channel], 1)
        variances.append(np.var(window[:, channel] - (slope * n + intercept)))
    np.testing.assert_allclose(tuner.R(), R0 + np.diag(np.square(variances)), rtol=1e-10)
    tuner.reset()
    np.testing.assert_array_equal(tuner.R(), R0)


def test_conventional_kf_keeps_R0_and_stkf_tunes_it():
    rng = np.random.default_rng(0)
    kf, stkf = (VisualStateEstimator(VSEParams(self_tuning=flag)) for flag in (False, True))
    for _ in range(20):
        z = np.array([0.0, 0.0, 35.0]) + rng.uniform(-10, 10, 3)
        for est in (kf, stkf):
            est.step(z, *NO_INPUT, T_S)
    np.testing.assert_array_equal(kf.R, R0)
    assert np.all(np.diag(stkf.R) > 100.0)  # var ~ 33 px^2, squared (41)


def test_reliability_threshold_stops_and_reinitialises():
    # Detections for 5 s, then none: the estimate is predicted (P grows by F P F^T + Q)
    # until a diagonal element of P passes 4800, and not before.
    rng = np.random.default_rng(1)
    est = VisualStateEstimator()
    for n in range(50):
        z = np.array([20.0 + 3.0 * n * T_S, 0.0, 35.0]) + rng.uniform(-2, 2, 3)
        est.step(z, *NO_INPUT, T_S)
    F, _ = image_state_transition(T_S, np.zeros((3, 3)))
    P = est.P.copy()
    expected_steps = 0
    while np.max(np.diag(P)) <= 4800.0:
        P = F @ P @ F.T + est.Q
        expected_steps += 1
    steps = 0
    while est.initialised:
        est.step(None, *NO_INPUT, T_S)
        steps += 1
    print(f"\nunreliable after {steps} predictions ({steps * T_S:.1f} s of full occlusion)")
    assert steps == expected_steps
    assert steps * T_S > 3.0  # the spec: T = 100 ms handled ~3 s of full occlusion
    assert est.reinitialisations == 1
    est.step(np.array([1.0, 2.0, 30.0]), *NO_INPUT, T_S)  # (2) again: X_0 = (Z, 0), P_0 = I
    np.testing.assert_array_equal(est.x, [1.0, 2.0, 30.0, 0.0, 0.0, 0.0])
    np.testing.assert_array_equal(est.P, np.eye(6))


def test_prediction_uses_the_applied_velocity_through_B_i():
    est = VisualStateEstimator()
    est.step(np.array([10.0, -5.0, 35.0]), *NO_INPUT, T_S)
    B = np.array([[1.0, 390.0, 0.0], [0.0, 0.0, -390.0], [20.0, 0.0, 0.0]])
    u = np.array([0.1, 0.05, -0.02])
    est.step(None, B, u, T_S)  # no detection: the prediction (30)
    np.testing.assert_allclose(est.x[:3], [10.0, -5.0, 35.0] + T_S * B @ u)


def _synthetic_mse(self_tuning: bool, sigma_px: float, seed: int) -> np.ndarray:
    """MSE of (X_i, X_i^t') on a target drifting at a constant image velocity, detected
    as Z = round(X + sigma (2 w - 1)) (Table 2's model), over 30 s."""
    rng = np.random.default_rng(seed)
    est = VisualStateEstimator(VSEParams(self_tuning=self_tuning))
    rate = np.array([4.0, -2.0, 0.5])
    errors = []
    for n in range(300):
        X = np.array([-60.0, 20.0, 30.0]) + rate * n * T_S
        z = np.round(X + sigma_px * (2.0 * rng.uniform(size=3) - 1.0))
        est.step(z, *NO_INPUT, T_S)
        if n >= 50:
            errors.append(est.x - np.concatenate([X, rate]))
    return np.mean(np.square(errors), axis=0)


def test_stkf_beats_kf_under_noise_and_matches_it_without():
    kf = np.mean([_synthetic_mse(False, 10.0, s) for s in range(5)], axis=0)
    stkf = np.mean([_synthetic_mse(True, 10.0, s) for s in range(5)], axis=0)
    print(f"\nsigma 10: KF {np.round(kf, 2)}, STKF {np.round(stkf, 2)}")
    assert np.all(stkf < 0.5 * kf)
    # Noise-free but rounded: R stays ~R_0, so the two filters nearly agree.
    kf0, stkf0 = _synthetic_mse(False, 0.0, 0), _synthetic_mse(True, 0.0, 0)
    np.testing.assert_allclose(stkf0, kf0, rtol=0.05, atol=1e-3)
    assert np.all(kf0[:3] < 0.1)


def test_a_missed_detection_restarts_the_register():
    # The line fit assumes k consecutive samples: after a gap R_n is R_0 again, so the
    # target found 80 px away after an occlusion is believed, not read as noise.
    rng = np.random.default_rng(2)
    est = VisualStateEstimator()
    for _ in range(20):
        est.step(np.array([0.0, 0.0, 35.0]) + rng.uniform(-10, 10, 3), *NO_INPUT, T_S)
    assert np.all(np.diag(est.R) > 100.0)
    for _ in range(10):
        est.step(None, *NO_INPUT, T_S)
    np.testing.assert_array_equal(est.R, R0)
    est.step(np.array([80.0, 0.0, 35.0]), *NO_INPUT, T_S)
    assert est.x[0] == pytest.approx(80.0, abs=2.0)
