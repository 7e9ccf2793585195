"""Linear MPC on the BallTable model: a sparse QP per step, solved by OSQP.

Over the horizon N, with x_0 the observed state and the plant's exact discretisation
(Phi, Gamma) of estimation/ball_table/control_model.py:

    minimise   sum_{k<N} (x_k^T Q x_k + u_k^T R u_k) + x_N^T P x_N
    subject to x_{k+1} = Phi x_k + Gamma u_k                 (the model)
               |u_k| <= tilt_limit                           (commanded tilt)
               |theta_k| <= tilt_limit,             k = 1..N (table tilt)
               |u_k - theta_k| <= tau * rate_limit, k < N    (tilt rate (u - theta) / tau)
               |p_k| <= ball_limit,                 k = 1..N (ball on the table)

P is the LQR's DARE solution for the same (Q, R), so without constraints
(``constrained=False``) the first move equals the LQR's -K x_0 exactly: the infinite-horizon
cost-to-go is x^T P x. The QP keeps the states as variables (sparse, no condensing), is set
up once, and per step only x_0's bounds change; OSQP warm-starts from the last solution.
When OSQP does not solve the QP (an infeasible start, the iteration limit), the action is
the LQR's saturated at the tilt bound, a finite in-bounds action; ``last_status`` and
``failures`` report it.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import osqp
import scipy.sparse as sp

from observer_gym.controllers.ball_table.plant import BallTablePlant, check_plant
from observer_gym.controllers.base import StateFeedbackController, check_number
from observer_gym.controllers.lqr import LQRController
from observer_gym.envs.ball_table.geometry import BALL_TRAVEL_M

__all__ = ["MAX_HORIZON", "MPCController"]

_SOLVED = {osqp.SolverStatus.OSQP_SOLVED, osqp.SolverStatus.OSQP_SOLVED_INACCURATE}
DEFAULT_TILT_RATE_LIMIT_RADPS = 1.5
DEFAULT_OSQP_SETTINGS = {
    "eps_abs": 1e-6,
    "eps_rel": 1e-6,
    "max_iter": 4000,
    "polishing": True,
    "warm_starting": True,
    "verbose": False,
}


# The longest horizon allowed. One step must fit well within the control period (BallTable:
# 20 ms, 50 Hz). Measured on a shared 2-core machine (predict's wall time in closed loop
# from the env's random starts, as benchmarks/bench_mpc.py times it, 6 episodes x 100 steps):
# horizon 20: 0.34 ms median warm-started step, 1.4 ms median first (cold) step; 50: 0.75
# and 7.6 ms; 100: 1.4 and 17 ms (a cold step near the period); 150: 6.0 ms median warm;
# 500: 15 ms; 1000: 32 ms; 2000: 70 ms. At 50 both stay well under 20 ms.
MAX_HORIZON = 50


class MPCController(StateFeedbackController):
    """Arguments: ``plant``; ``horizon`` N (steps, default 20, at most :data:`MAX_HORIZON`
    = 50 so that a step stays well within BallTable's 20 ms control period); ``Q``, ``R`` as for
    :class:`LQRController`; ``constrained`` (default True); ``tilt_limit_rad`` (default the
    env's bound), ``tilt_rate_limit_radps`` (default 1.5), ``ball_limit_m`` (default
    L/2 - r, the ball touching a border); ``osqp_settings`` overriding
    :data:`DEFAULT_OSQP_SETTINGS`. Numbers may be Python's or NumPy's; a bad option
    raises ``ValueError`` naming it and what it allows.

    After each step: ``last_status`` (OSQP's status text), ``last_solve_time_s`` (OSQP's
    setup-free solve time), ``failures`` (steps that fell back to the LQR action),
    ``predicted_states`` (N + 1, 6) and ``planned_actions`` (N, 2) of the last solve.
    """

    name = "mpc"

    def __init__(
        self,
        plant: BallTablePlant,
        horizon: int = 20,
        Q=None,
        R=None,
        constrained: bool = True,
        tilt_limit_rad: float | None = None,
        tilt_rate_limit_radps: float = DEFAULT_TILT_RATE_LIMIT_RADPS,
        ball_limit_m: float = BALL_TRAVEL_M,
        osqp_settings: dict | None = None,
    ) -> None:
        check_plant("MPCController", plant)
        super().__init__(plant.obs_dim, *plant.action_bounds)
        owner = "MPCController"
        horizon = check_number(owner, "horizon", horizon, low=1, high=MAX_HORIZON, integer=True)
        tilt_limit = check_number(
            owner, "tilt_limit_rad", tilt_limit_rad, low=0.0, low_inclusive=False, allow_none=True
        )
        tilt_limit = plant.max_tilt_rad if tilt_limit is None else tilt_limit
        tilt_rate_limit_radps = check_number(
            owner, "tilt_rate_limit_radps", tilt_rate_limit_radps, low=0.0, low_inclusive=False
        )
        ball_limit_m = check_number(
            owner, "ball_limit_m", ball_limit_m, low=0.0, low_inclusive=False
        )
        if not isinstance(constrained, bool | np.bool_):
            raise ValueError(f"MPCController: constrained = {constrained!r}, must be True or False")
        if osqp_settings is not None and not isinstance(osqp_settings, Mapping):
            raise ValueError(
                f"MPCController: osqp_settings = {osqp_settings!r}, must be None or a dict of "
                "OSQP settings"
            )
        self.plant = plant
        self.horizon = horizon
        self.lqr = LQRController(plant, Q, R)  # checks Q and R; its P is the terminal cost
        self.constrained = bool(constrained)
        self.tilt_limit_rad = min(tilt_limit, plant.max_tilt_rad)
        self.tilt_rate_limit_radps = tilt_rate_limit_radps
        self.ball_limit_m = ball_limit_m
        self.settings = {**DEFAULT_OSQP_SETTINGS, **(osqp_settings or {})}
        self._setup()
        self.failures = 0
        self.last_status = "not run"
        self.last_solve_time_s = float("nan")
        self.predicted_states: np.ndarray | None = None
        self.planned_actions: np.ndarray | None = None

    # --- the QP -------------------------------------------------------------------------
    def _setup(self) -> None:
        N, nx = self.horizon, self.plant.model.n
        Phi, Gamma = self.lqr.Phi, self.lqr.Gamma
        self._n_x_vars = (N + 1) * nx
        cost = sp.block_diag(
            [sp.kron(sp.eye(N), self.lqr.Q), self.lqr.P, sp.kron(sp.eye(N), self.lqr.R)],
            format="csc",
        )
        # x_0 = x(k); x_{k+1} - Phi x_k - Gamma u_k = 0
        A_x = sp.kron(sp.eye(N + 1), -sp.eye(nx)) + sp.kron(sp.eye(N + 1, k=-1), Phi)
        A_u = sp.kron(sp.vstack([sp.csc_matrix((1, N)), sp.eye(N)]), Gamma)
        rows = [sp.hstack([A_x, A_u])]
        lower = [np.zeros((N + 1) * nx)]
        upper = [np.zeros((N + 1) * nx)]
        if self.constrained:
            rows_c, bounds = self._constraint_rows()
            rows.append(rows_c)
            lower.append(-bounds)
            upper.append(bounds)
        A = sp.vstack(rows, format="csc")
        self._lower, self._upper = np.concatenate(lower), np.concatenate(upper)
        self._solver = osqp.OSQP()
        self._solver.setup(
            cost, np.zeros(cost.shape[0]), A, self._lower, self._upper, **self.settings
        )

    def _constraint_rows(self) -> tuple[sp.csc_matrix, np.ndarray]:
        """Rows G z with bounds |G z| <= b for the inputs, tilts, tilt rates and ball."""
        N, nx, nu = self.horizon, self.plant.model.n, self.plant.model.m
        n_z = self._n_x_vars + N * nu

        def pick(var_index: np.ndarray) -> sp.csc_matrix:
            """Rows selecting the variables ``var_index`` of z."""
            return sp.csc_matrix(
                (np.ones(len(var_index)), (np.arange(len(var_index)), var_index)),
                shape=(len(var_index), n_z),
            )

        steps = np.arange(N)
        u_idx = (self._n_x_vars + nu * steps[:, None] + np.arange(nu)).ravel()
        theta_now = (nx * steps[:, None] + np.arange(4, 6)).ravel()  # theta_k, k < N
        theta_next = (nx * (steps[:, None] + 1) + np.arange(4, 6)).ravel()  # k = 1..N
        ball_next = (nx * (steps[:, None] + 1) + np.arange(0, 2)).ravel()
        tau = self.plant.model.tau_s
        G = sp.vstack(
            [pick(u_idx), pick(theta_next), pick(u_idx) - pick(theta_now), pick(ball_next)]
        )
        b = np.concatenate(
            [
                np.full(N * nu, self.tilt_limit_rad),
                np.full(N * nu, self.tilt_limit_rad),
                np.full(N * nu, tau * self.tilt_rate_limit_radps),
                np.full(N * 2, self.ball_limit_m),
            ]
        )
        return G.tocsc(), b

    # --- per step -----------------------------------------------------------------------
    def solve(self, x0: np.ndarray) -> tuple[np.ndarray, bool]:
        """(u_0, solved) for the state x0 (6,); the LQR fallback when not solved."""
        nx = self.plant.model.n
        self._lower[:nx] = -x0
        self._upper[:nx] = -x0
        self._solver.update(l=self._lower, u=self._upper)
        result = self._solver.solve(raise_error=False)  # a failure is a status, not an error
        self.last_status = result.info.status
        self.last_solve_time_s = float(result.info.solve_time)
        z = result.x
        solved = (
            result.info.status_val in _SOLVED and z is not None and bool(np.all(np.isfinite(z)))
        )
        if not solved:
            self.failures += 1
            self.predicted_states = self.planned_actions = None
            u = np.clip(-self.lqr.K @ x0, self.action_low, self.action_high)
            return u, False
        N = self.horizon
        self.predicted_states = z[: self._n_x_vars].reshape(N + 1, nx)
        self.planned_actions = z[self._n_x_vars :].reshape(N, self.plant.model.m)
        return self.planned_actions[0].copy(), True

    def act(self, obs: np.ndarray, episode_start: np.ndarray) -> np.ndarray:
        nx = self.plant.model.n
        return np.array([self.solve(row[:nx])[0] for row in obs])
