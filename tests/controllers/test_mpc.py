"""MPC (OSQP) on BallTable (BallTableMPC: the generic MPC with the table's bounds): equal
to LQR without active constraints, constraints kept when they bind, a finite in-bounds
action and a status when the QP cannot be solved."""

from __future__ import annotations

import numpy as np
import pytest

from observer_gym.controllers import BallTableMPC, BallTablePlant, LQRController
from observer_gym.envs.ball_table import BallTableConfig
from observer_gym.estimation.ball_table.control_model import BallTableControlModel


@pytest.fixture(scope="module")
def plant() -> BallTablePlant:
    cfg = BallTableConfig()
    return BallTablePlant(BallTableControlModel.from_config(cfg), cfg.dt_s, cfg.max_tilt_rad)


def _random_states(count: int, scale: float) -> np.ndarray:
    rng = np.random.default_rng(0)
    states = np.zeros((count, 8))
    states[:, 0:2] = rng.uniform(-scale, scale, (count, 2))
    states[:, 2:4] = rng.uniform(-scale, scale, (count, 2))
    states[:, 4:6] = rng.uniform(-0.1 * scale, 0.1 * scale, (count, 2))
    return states


@pytest.mark.parametrize("horizon", [1, 5, 20])
def test_unconstrained_mpc_equals_lqr(plant, horizon):
    lqr = LQRController(plant)
    mpc = BallTableMPC(plant, horizon=horizon, constrained=False)
    for x in _random_states(10, 0.05):
        u_lqr = -lqr.K @ x[:6]  # unsaturated
        u_mpc, solved = mpc.solve(x[:6])
        assert solved, mpc.last_status
        np.testing.assert_allclose(u_mpc, u_lqr, rtol=0, atol=1e-6 * max(1, np.abs(u_lqr).max()))


def test_constrained_mpc_equals_lqr_while_no_constraint_binds(plant):
    lqr, mpc = LQRController(plant), BallTableMPC(plant, horizon=20)
    for x in _random_states(10, 0.005):
        np.testing.assert_allclose(mpc.predict(x)[0], lqr.predict(x)[0], atol=1e-6)
    assert mpc.failures == 0


def test_binding_constraints_hold_over_the_plan(plant):
    mpc = BallTableMPC(plant, horizon=20, tilt_limit_rad=0.03, tilt_rate_limit_radps=0.5)
    x = np.zeros(6)
    x[0], x[2] = 0.06, 0.05  # 6 cm out, moving outward: LQR would ask for far more tilt
    u, solved = mpc.solve(x)
    assert solved, mpc.last_status
    tol = 1e-4
    assert np.abs(mpc.planned_actions).max() <= 0.03 + tol
    assert np.abs(mpc.planned_actions).max() >= 0.03 - tol  # the bound binds
    assert np.abs(mpc.predicted_states[1:, 4:6]).max() <= 0.03 + tol
    rates = (mpc.planned_actions - mpc.predicted_states[:-1, 4:6]) / plant.model.tau_s
    assert np.abs(rates).max() <= 0.5 + tol / plant.model.tau_s
    assert np.abs(mpc.predicted_states[1:, 0:2]).max() <= mpc.ball_limit_m + tol
    np.testing.assert_allclose(u, mpc.planned_actions[0])


def test_infeasible_start_gives_a_finite_in_bounds_action_and_its_status(plant):
    mpc = BallTableMPC(plant, horizon=20)
    x = np.zeros(8)
    x[0], x[2] = 0.124, 1.0  # at the border, 1 m/s outward: it cannot stay on the table
    action, _ = mpc.predict(x)
    assert np.all(np.isfinite(action))
    assert np.all(np.abs(action) <= plant.max_tilt_rad)
    assert mpc.failures == 1
    assert "infeasible" in mpc.last_status
    assert mpc.planned_actions is None
    # The next feasible state is solved again.
    assert mpc.solve(np.zeros(6))[1]


@pytest.mark.parametrize(
    ("option", "value"),
    [("horizon", 0), ("horizon", 2.5), ("tilt_limit_rad", -0.1), ("ball_limit_m", np.nan)],
)
def test_bad_options_raise(plant, option, value):
    with pytest.raises(ValueError, match=option):
        BallTableMPC(plant, **{option: value})
