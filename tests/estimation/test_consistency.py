"""Filter consistency (Bar-Shalom's NEES test) on the rolling-ball model's own discrete
model and noise: a correctly tuned filter's NEES averages to the state dimension within
chi-square bounds; a mis-tuned one does not."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from observer_gym.envs.ball_table import geometry as geo
from observer_gym.estimation.ball_table.models import RollingBallModel
from observer_gym.estimation.filters import KalmanFilter

DT_S = 0.02
RUNS = 50
STEPS = 400
BURN_IN = 25
# Filtering errors decorrelate within ~1 / -ln(0.888) ~ 8 steps (the slowest closed-loop
# pole of the steady-state filter at 20 ms); the NEES autocorrelation measured at lag 25 is
# < 0.01. The grand average's band counts one independent sample per 25 steps and run, a
# conservative count (the integrated autocorrelation time is ~4 steps): the band assuming
# every step independent would be too narrow for correlated samples and fail a correct
# filter.
DECORRELATION_STEPS = 25
N_STATE = RollingBallModel.n
P0_DIAG = np.array([0.02, 0.02, 0.1, 0.1, 1.0, 1.0]) ** 2


def _inputs(rng: np.random.Generator) -> np.ndarray:
    """Gravity accelerations (STEPS, 2) for a table wobbling by 0.05 rad at 0.5 Hz."""
    t = DT_S * np.arange(STEPS)
    phase = rng.uniform(0.0, 2.0 * np.pi)
    tilts = 0.05 * np.stack([np.sin(np.pi * t + phase), np.cos(np.pi * t + phase)], axis=1)
    return np.array(
        [RollingBallModel.gravity_acceleration(geo.up_in_table(*tilt)) for tilt in tilts]
    )


def _nees(q_scale: float = 1.0, r_scale: float = 1.0, seed: int = 2024) -> np.ndarray:
    """NEES of the filtered estimate, (RUNS, STEPS), truth simulated from the model itself."""
    model = RollingBallModel()
    Phi, Gamma, Q = model.matrices(DT_S)
    C, R = model.C, model.R
    L_Q, L_R, L_0 = np.linalg.cholesky(Q), np.linalg.cholesky(R), np.sqrt(P0_DIAG)
    Q_filter, R_filter = q_scale * Q, r_scale * R
    rng = np.random.default_rng(seed)
    nees = np.empty((RUNS, STEPS))
    for run in range(RUNS):
        us = _inputs(rng)
        process = rng.standard_normal((STEPS, N_STATE)) @ L_Q.T
        noise = rng.standard_normal((STEPS, 2)) @ L_R.T
        x = L_0 * rng.standard_normal(N_STATE)  # truth ~ N(0, P0)
        kf = KalmanFilter(np.zeros(N_STATE), np.diag(P0_DIAG))
        for k in range(STEPS):
            kf.update(C @ x + noise[k], C, R_filter)
            error = x - kf.x
            nees[run, k] = error @ np.linalg.solve(kf.P, error)
            kf.predict(Phi, Q_filter, Gamma, us[k])
            x = Phi @ x + Gamma @ us[k] + process[k]
    return nees


def _per_step_band() -> np.ndarray:
    return chi2.ppf([0.025, 0.975], RUNS * N_STATE) / RUNS


def _consistency(nees: np.ndarray) -> tuple[float, float, np.ndarray]:
    """(fraction of steps after the burn-in whose ensemble-average NEES is inside the 95 %
    band, grand average over those steps and all runs, the grand average's 95 % band)."""
    lo, hi = _per_step_band()
    after = nees[:, BURN_IN:]
    per_step = after.mean(axis=0)
    inside = float(np.mean((per_step >= lo) & (per_step <= hi)))
    independent = RUNS * (after.shape[1] // DECORRELATION_STEPS)
    grand_band = chi2.ppf([0.025, 0.975], independent * N_STATE) / independent
    return inside, float(after.mean()), grand_band


@pytest.fixture(scope="module")
def tuned_nees() -> np.ndarray:
    return _nees()


def test_correctly_tuned_filter_is_consistent(tuned_nees):
    inside, grand, (lo, hi) = _consistency(tuned_nees)
    assert inside >= 0.90, f"only {inside:.0%} of steps inside the 95 % band"
    assert lo <= grand <= hi, f"grand average NEES {grand:.3f} outside [{lo:.3f}, {hi:.3f}]"


@pytest.mark.parametrize(
    ("q_scale", "r_scale"), [(0.01, 1.0), (1.0, 100.0)], ids=["Q_x0.01", "R_x100"]
)
def test_mis_tuned_filter_fails_the_same_test(q_scale, r_scale):
    inside, grand, (lo, hi) = _consistency(_nees(q_scale, r_scale))
    assert inside < 0.5
    assert not lo <= grand <= hi
