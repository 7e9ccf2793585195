"""The generic LQR, MPC and PID design from a plant protocol (controllers/plant.py).

A point mass defined here (no BallTable anywhere) runs all three against closed forms:
the LQR's gain from control.dare, the MPC equal to the LQR while no bound binds and
keeping its bounds when they do, the PID's law step by step. BallTable keeps its numbers
bit for bit: the LQR gain equals control.dlqr on the plant's matrices with a frozen copy
of the Bryson weights, and the MPC's QP and actions and the PID's actions equal those of
frozen copies of the BallTable-only code the generic designs replaced (issue 28).
"""

from __future__ import annotations

import ast
from dataclasses import dataclass, field
from pathlib import Path

import control
import numpy as np
import osqp
import pytest
import scipy.sparse as sp

from observer_gym.controllers import (
    AxesPlant,
    BallTableMPC,
    BallTablePlant,
    ConstrainedPlant,
    DoubleIntegratorAxes,
    LinearPlant,
    LQRController,
    MPCController,
    PIDController,
    StageBound,
)
from observer_gym.controllers.mpc import DEFAULT_OSQP_SETTINGS
from observer_gym.envs.ball_table import BallTableConfig
from observer_gym.envs.ball_table.geometry import BALL_TRAVEL_M
from observer_gym.estimation.ball_table.control_model import BallTableControlModel

CONTROLLERS_DIR = Path(__file__).resolve().parents[2] / "controllers"
GENERIC_MODULES = ("base.py", "lqr.py", "mpc.py", "pid.py", "plant.py", "registry.py", "weights.py")
SYSTEMS = ("ball_table", "ball_catcher", "target_follower")


# --- a toy plant: a point mass in the plane, pushed by a bounded force -------------------
@dataclass(frozen=True)
class PointMass:
    """x = (p_x, p_y, v_x, v_y), u the force (N): p'' = u / mass. Its observation is
    (time, p, v): the state is obs[1:5]."""

    dt_s: float = 0.1
    mass_kg: float = 0.5
    max_force_n: float = 1.0
    max_position_m: float = 2.0
    obs_dim: int = 5
    Q: np.ndarray = field(default_factory=lambda: np.diag([1.0, 1.0, 0.1, 0.1]))
    R: np.ndarray = field(default_factory=lambda: 0.5 * np.eye(2))

    @property
    def state_slice(self) -> slice:
        return slice(1, 5)

    @property
    def action_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        bound = np.full(2, self.max_force_n)
        return -bound, bound

    def matrices(self) -> tuple[np.ndarray, np.ndarray]:
        # exact zero-order hold of p'' = u / m: p += v dt + u dt^2 / (2 m), v += u dt / m
        dt, eye = self.dt_s, np.eye(2)
        A = np.block([[eye, dt * eye], [np.zeros((2, 2)), eye]])
        B = np.vstack([dt**2 / (2 * self.mass_kg) * eye, dt / self.mass_kg * eye])
        return A, B

    def weights(self) -> tuple[np.ndarray, np.ndarray]:
        return self.Q, self.R

    def constraints(self) -> tuple[StageBound, ...]:
        position_of_x = np.hstack([np.eye(2), np.zeros((2, 2))])
        return (
            StageBound("force", np.zeros((2, 4)), np.eye(2), np.full(2, self.max_force_n)),
            StageBound(
                "position", position_of_x, np.zeros((2, 2)), np.full(2, self.max_position_m), True
            ),
        )

    def axes(self) -> DoubleIntegratorAxes:
        return DoubleIntegratorAxes(slice(1, 3), slice(3, 5), np.eye(2) / self.mass_kg)


@pytest.fixture(scope="module")
def mass() -> PointMass:
    return PointMass()


def _observations(count: int, scale: float, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    obs = rng.uniform(-scale, scale, (count, 5))
    obs[:, 0] = rng.uniform(0, 100, count)  # time: not part of the state
    return obs


def test_the_generic_modules_import_no_system():
    """What `grep ball_table controllers/{lqr,mpc,pid,base,registry}.py` checks, for every
    system and every import of the generic modules."""
    for name in GENERIC_MODULES:
        tree = ast.parse((CONTROLLERS_DIR / name).read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.Import | ast.ImportFrom):
                names = [alias.name for alias in node.names]
                module = getattr(node, "module", None) or ""
                for imported in [module, *names]:
                    assert not any(s in imported for s in SYSTEMS), (name, imported)


def test_the_point_mass_and_ball_table_are_plants(mass):
    cfg = BallTableConfig()
    table = BallTablePlant(BallTableControlModel.from_config(cfg), cfg.dt_s, cfg.max_tilt_rad)
    for plant in (mass, table):
        assert isinstance(plant, LinearPlant)
        assert isinstance(plant, ConstrainedPlant)
        assert isinstance(plant, AxesPlant)
    for cls, protocol in (
        (LQRController, "LinearPlant"),
        (MPCController, "ConstrainedPlant"),
        (PIDController, "AxesPlant"),
    ):
        with pytest.raises(ValueError, match=f"plant must be an? {protocol}"):
            cls(object())


def test_lqr_gain_is_the_dare_closed_form(mass):
    """K = (R + B^T P B)^-1 B^T P A with P from control.dare; u = sat(-K obs[1:5])."""
    lqr = LQRController(mass)
    A, B = mass.matrices()
    P, _, _ = control.dare(A, B, mass.Q, mass.R)
    K = np.linalg.solve(mass.R + B.T @ P @ B, B.T @ P @ A)
    np.testing.assert_allclose(lqr.P, P, rtol=1e-10)
    np.testing.assert_allclose(lqr.K, K, rtol=1e-10, atol=1e-12)
    assert np.abs(np.linalg.eigvals(A - B @ K)).max() < 1.0
    obs = _observations(20, 1.0)
    actions, _ = lqr.predict(obs)
    expected = np.clip(-obs[:, 1:5] @ K.T, -mass.max_force_n, mass.max_force_n)
    np.testing.assert_allclose(actions, expected.astype(np.float32), rtol=1e-6, atol=1e-7)


def test_mpc_equals_lqr_while_no_bound_binds(mass):
    lqr = LQRController(mass)
    free = MPCController(mass, horizon=10, constrained=False)
    bounded = MPCController(mass, horizon=10)
    for obs in _observations(10, 0.05, seed=1):
        u_lqr = -lqr.K @ obs[1:5]
        assert np.abs(u_lqr).max() < mass.max_force_n  # small states: nothing binds
        for mpc in (free, bounded):
            u, solved = mpc.solve(obs[1:5])
            assert solved, mpc.last_status
            np.testing.assert_allclose(u, u_lqr, rtol=0, atol=1e-6)
        np.testing.assert_allclose(bounded.predict(obs)[0], lqr.predict(obs)[0], atol=1e-6)
    assert bounded.failures == 0


def test_mpc_keeps_the_plants_bounds_when_they_bind(mass):
    mpc = MPCController(mass, horizon=20)
    x = np.array([1.0, 0.0, 1.5, 0.0])  # 1 m out, 1.5 m/s outward: LQR asks for far more
    u, solved = mpc.solve(x)
    assert solved, mpc.last_status
    tol = 1e-4
    assert np.abs(mpc.planned_actions).max() <= mass.max_force_n + tol
    assert np.abs(mpc.planned_actions).max() >= mass.max_force_n - tol  # binds
    assert np.abs(mpc.predicted_states[1:, 0:2]).max() <= mass.max_position_m + tol
    A, B = mass.matrices()
    for k in range(mpc.horizon):  # the plan follows the model
        np.testing.assert_allclose(
            mpc.predicted_states[k + 1],
            A @ mpc.predicted_states[k] + B @ mpc.planned_actions[k],
            atol=1e-5,
        )
    np.testing.assert_allclose(u, mpc.planned_actions[0])


def test_mpc_rejects_bad_bounds(mass):
    with pytest.raises(ValueError, match="bound 'force' has state_rows"):
        MPCController(mass, bounds=[StageBound("force", np.zeros((2, 3)), np.eye(2), [1, 1])])
    with pytest.raises(ValueError, match="bound 'force' has limit"):
        MPCController(mass, bounds=[StageBound("force", np.zeros((2, 4)), np.eye(2), [1, -1])])
    with pytest.raises(ValueError, match="StageBound"):
        MPCController(mass, bounds=[(np.zeros((2, 4)), np.eye(2), [1, 1])])


def test_pid_is_the_law_through_the_inverse_gain(mass):
    """a = -(kp p + ki sum(p dt) + kd v), u = G^-1 a = m a, two steps (the integral)."""
    pid = PIDController(mass, omega_radps=2.0, damping=0.7)
    assert (pid.kp, pid.kd, pid.ki) == pytest.approx((4.0, 2.8, 0.8))
    first = np.array([7.0, 0.1, -0.05, 0.02, 0.01])
    second = np.array([7.1, 0.09, -0.04, 0.01, 0.02])
    integral = first[1:3] * mass.dt_s
    u1 = mass.mass_kg * -(pid.kp * first[1:3] + pid.ki * integral + pid.kd * first[3:5])
    np.testing.assert_allclose(pid.predict(first)[0], u1, rtol=1e-6)
    integral = integral + second[1:3] * mass.dt_s
    u2 = mass.mass_kg * -(pid.kp * second[1:3] + pid.ki * integral + pid.kd * second[3:5])
    np.testing.assert_allclose(pid.predict(second)[0], u2, rtol=1e-6)


def test_pid_integral_is_clamped_at_the_bound(mass):
    """The I term alone never asks for more than the bound: |integral| <= u_max |G| / ki."""
    pid = PIDController(mass, kp=0.0, kd=0.0, ki=1.0)
    obs = np.array([0.0, 1.0, 0.0, 0.0, 0.0])
    for _ in range(1000):
        action, _ = pid.predict(obs)
    assert np.abs(action).max() == pytest.approx(mass.max_force_n)
    assert np.abs(pid._integral).max() <= mass.max_force_n / mass.mass_kg / pid.ki + 1e-12


# --- BallTable, bit for bit against frozen copies of the code before issue 28 -----------
@pytest.fixture(scope="module")
def table() -> BallTablePlant:
    cfg = BallTableConfig()
    return BallTablePlant(BallTableControlModel.from_config(cfg), cfg.dt_s, cfg.max_tilt_rad)


def _table_states(count: int = 60) -> np.ndarray:
    rng = np.random.default_rng(28)
    scale = np.repeat([0.002, 0.02, 0.06, 0.12], count // 4)[:, None]
    states = np.zeros((count, 8))
    states[:, 0:2] = rng.uniform(-1, 1, (count, 2)) * scale
    states[:, 2:4] = rng.uniform(-3, 3, (count, 2)) * scale
    states[:, 4:6] = rng.uniform(-0.5, 0.5, (count, 2)) * scale
    states[:, 6:8] = rng.uniform(-1, 1, (count, 2)) * scale
    states[-1] = [0.124, 0, 1.0, 0, 0, 0, 0, 0]  # an infeasible start: the LQR fallback
    return states


def _frozen_bryson_weights() -> tuple[np.ndarray, np.ndarray]:
    # 1 cm, 10 cm/s, 0.1 rad of tilt, 0.02 rad of command (controllers/ball_table/weights.py)
    Q = np.diag([0.01**-2] * 2 + [0.1**-2] * 2 + [0.1**-2] * 2)
    return Q, np.eye(2) * 0.02**-2


def test_ball_table_lqr_gain_is_dlqr_on_the_frozen_weights(table):
    lqr = LQRController(table)
    A, B = table.matrices()
    Q, R = _frozen_bryson_weights()
    K, P, _ = control.dlqr(A, B, Q, R)
    assert np.array_equal(lqr.K, K) and np.array_equal(lqr.P, P)
    states = _table_states()
    expected = np.clip(-states[:, :6] @ K.T, -0.1, 0.1).astype(np.float32)
    assert np.array_equal(lqr.predict(states)[0], expected)


def _frozen_ball_table_qp(table, lqr, horizon, tilt_limit, rate_limit, ball_limit):
    """The QP of controllers/mpc.py before issue 28 (BallTable only), copied."""
    N, nx, nu = horizon, 6, 2
    Phi, Gamma = lqr.Phi, lqr.Gamma
    n_x_vars = (N + 1) * nx
    cost = sp.block_diag(
        [sp.kron(sp.eye(N), lqr.Q), lqr.P, sp.kron(sp.eye(N), lqr.R)], format="csc"
    )
    A_x = sp.kron(sp.eye(N + 1), -sp.eye(nx)) + sp.kron(sp.eye(N + 1, k=-1), Phi)
    A_u = sp.kron(sp.vstack([sp.csc_matrix((1, N)), sp.eye(N)]), Gamma)
    n_z = n_x_vars + N * nu

    def pick(var_index):
        return sp.csc_matrix(
            (np.ones(len(var_index)), (np.arange(len(var_index)), var_index)),
            shape=(len(var_index), n_z),
        )

    steps = np.arange(N)
    u_idx = (n_x_vars + nu * steps[:, None] + np.arange(nu)).ravel()
    theta_now = (nx * steps[:, None] + np.arange(4, 6)).ravel()
    theta_next = (nx * (steps[:, None] + 1) + np.arange(4, 6)).ravel()
    ball_next = (nx * (steps[:, None] + 1) + np.arange(0, 2)).ravel()
    G = sp.vstack([pick(u_idx), pick(theta_next), pick(u_idx) - pick(theta_now), pick(ball_next)])
    b = np.concatenate(
        [
            np.full(N * nu, tilt_limit),
            np.full(N * nu, tilt_limit),
            np.full(N * nu, table.model.tau_s * rate_limit),
            np.full(N * 2, ball_limit),
        ]
    )
    A = sp.vstack([sp.hstack([A_x, A_u]), G.tocsc()], format="csc")
    lower = np.concatenate([np.zeros((N + 1) * nx), -b])
    upper = np.concatenate([np.zeros((N + 1) * nx), b])
    return cost, A, lower, upper


class _Recorder:
    """osqp.OSQP whose setup keeps its arguments."""

    def __init__(self):
        self.calls = []
        self._osqp = osqp.OSQP

    def __call__(self):
        solver = self._osqp()
        setup = solver.setup

        def recording_setup(P, q, A, lower, upper, **settings):
            self.calls.append((P, A, np.array(lower), np.array(upper)))
            return setup(P, q, A, lower, upper, **settings)

        solver.setup = recording_setup
        return solver


def _same_sparse(a, b) -> bool:
    a, b = a.tocsc(), b.tocsc()
    return (
        a.shape == b.shape
        and np.array_equal(a.indptr, b.indptr)
        and np.array_equal(a.indices, b.indices)
        and np.array_equal(a.data, b.data)
    )


@pytest.mark.parametrize(
    "options",
    [{}, {"tilt_limit_rad": 0.03, "tilt_rate_limit_radps": 0.5, "ball_limit_m": 0.1}],
)
def test_ball_table_mpc_is_the_frozen_qp_bit_for_bit(table, monkeypatch, options):
    recorder = _Recorder()
    monkeypatch.setattr(osqp, "OSQP", recorder)
    mpc = BallTableMPC(table, horizon=20, **options)
    generic = MPCController(table, horizon=20, bounds=mpc.bounds)
    cost, A, lower, upper = _frozen_ball_table_qp(
        table,
        mpc.lqr,
        20,
        min(options.get("tilt_limit_rad", 0.1), 0.1),
        options.get("tilt_rate_limit_radps", 1.5),
        options.get("ball_limit_m", BALL_TRAVEL_M),
    )
    assert len(recorder.calls) == 2
    for P_new, A_new, l_new, u_new in recorder.calls:
        assert _same_sparse(P_new, cost) and _same_sparse(A_new, A)
        assert np.array_equal(l_new, lower) and np.array_equal(u_new, upper)
    frozen = recorder._osqp()
    frozen.setup(cost, np.zeros(cost.shape[0]), A, lower, upper, **DEFAULT_OSQP_SETTINGS)
    solved_statuses = {osqp.SolverStatus.OSQP_SOLVED, osqp.SolverStatus.OSQP_SOLVED_INACCURATE}
    expected = []
    for x in _table_states()[:, :6]:
        lower[:6], upper[:6] = -x, -x
        frozen.update(l=lower, u=upper)
        result = frozen.solve(raise_error=False)
        if result.info.status_val in solved_statuses and np.all(np.isfinite(result.x)):
            expected.append(result.x[21 * 6 : 21 * 6 + 2])
        else:
            expected.append(np.clip(-mpc.lqr.K @ x, -0.1, 0.1))
    expected = np.clip(expected, -0.1, 0.1).astype(np.float32)
    for controller in (mpc, generic):
        actions = np.array([controller.predict(s)[0] for s in _table_states()])
        assert np.array_equal(actions, expected)
    assert mpc.failures >= 1  # the fallback was taken and matched


def test_generic_mpc_on_ball_table_defaults_to_its_bounds(table):
    default, named = MPCController(table), BallTableMPC(table)
    states = _table_states()
    assert np.array_equal(default.predict(states)[0], named.predict(states)[0])


@pytest.mark.parametrize(
    "gains",
    [{}, {"omega_radps": 2.0, "damping": 0.8}, {"ki": 5.0}, {"kp": 0.0, "kd": 0.0, "ki": 50.0}],
)
def test_ball_table_pid_is_the_frozen_law_bit_for_bit(table, gains):
    """controllers/pid.py before issue 28 (BallTable only), copied, over a batch with
    episode starts; the last states saturate the tilt, the I-only gains reach the
    integral's clamp."""
    pid = PIDController(table, **gains)
    G = table.model.G
    G_inv = np.linalg.inv(G)
    limit = table.max_tilt_rad * float(np.abs(G).max()) / pid.ki
    states = _table_states()
    integral = np.zeros((len(states), 2))
    for k in range(25):
        starts = np.arange(len(states)) % (k + 2) == 0
        obs = states * (1.0 + 0.02 * k)
        integral[starts] = 0.0
        pos, vel = obs[:, 0:2], obs[:, 2:4]
        new_integral = np.clip(integral + pos * table.dt_s, -limit, limit)
        tilt = -(pid.kp * pos + pid.ki * new_integral + pid.kd * vel) @ G_inv.T
        saturated = np.any(np.abs(tilt) > table.max_tilt_rad, axis=1)
        integral[~saturated] = new_integral[~saturated]
        expected = np.clip(tilt, -0.1, 0.1).astype(np.float32)
        assert np.array_equal(pid.predict(obs, episode_start=starts)[0], expected)
