"""Linear MPC on any system's constrained plant: a sparse QP per step, solved by OSQP.

Over the horizon N, with x_0 the observed state (obs[plant.state_slice]) and the plant's
one-step model (A, B) (:class:`~observer_gym.controllers.plant.ConstrainedPlant`):

    minimise   sum_{k<N} (x_k^T Q x_k + u_k^T R u_k) + x_N^T P x_N
    subject to x_{k+1} = A x_k + B u_k                              (the model)
               |C_j x_{k+s_j} + D_j u_k| <= b_j,  k < N, per bound j (the constraints)

with one :class:`~observer_gym.controllers.plant.StageBound` (C_j, D_j, b_j, s_j) per
constraint, in the order given (default: the plant's ``constraints()``; BallTable's are
its tilt command, table tilt, tilt rate and ball bounds, options of its ``BallTableMPC``).
P is the LQR's DARE solution for the same (Q, R), so without constraints
(``constrained=False``) the first move equals the LQR's -K x_0 exactly: the infinite-horizon
cost-to-go is x^T P x. The QP keeps the states as variables (sparse, no condensing), is set
up once, and per step only x_0's bounds change; OSQP warm-starts from the last solution.
When OSQP does not solve the QP (an infeasible start, the iteration limit), the action is
the LQR's saturated at the action bounds, a finite in-bounds action; ``last_status`` and
``failures`` report it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import osqp
import scipy.sparse as sp

from observer_gym.controllers.base import StateFeedbackController, check_number
from observer_gym.controllers.lqr import LQRController
from observer_gym.controllers.plant import ConstrainedPlant, StageBound, check_plant

__all__ = ["DEFAULT_OSQP_SETTINGS", "MAX_HORIZON", "MPCController"]

_SOLVED = {osqp.SolverStatus.OSQP_SOLVED, osqp.SolverStatus.OSQP_SOLVED_INACCURATE}
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
    """Arguments: ``plant`` (a :class:`~observer_gym.controllers.plant.ConstrainedPlant`);
    ``horizon`` N (steps, default 20, at most :data:`MAX_HORIZON` = 50 so that a step
    stays well within BallTable's 20 ms control period); ``Q``, ``R`` as for
    :class:`LQRController`; ``constrained`` (default True); ``bounds`` (a sequence of
    :class:`~observer_gym.controllers.plant.StageBound`, default the plant's
    ``constraints()``); ``osqp_settings`` overriding :data:`DEFAULT_OSQP_SETTINGS`. Numbers
    may be Python's or NumPy's; a bad option raises ``ValueError`` naming it and what it
    allows.

    After each step: ``last_status`` (OSQP's status text), ``last_solve_time_s`` (OSQP's
    setup-free solve time), ``failures`` (steps that fell back to the LQR action),
    ``predicted_states`` (N + 1, n) and ``planned_actions`` (N, m) of the last solve.
    """

    name = "mpc"

    def __init__(
        self,
        plant: ConstrainedPlant,
        horizon: int = 20,
        Q=None,
        R=None,
        constrained: bool = True,
        bounds: Sequence[StageBound] | None = None,
        osqp_settings: dict | None = None,
    ) -> None:
        check_plant("MPCController", plant, ConstrainedPlant)
        super().__init__(plant.obs_dim, *plant.action_bounds)
        owner = "MPCController"
        horizon = check_number(owner, "horizon", horizon, low=1, high=MAX_HORIZON, integer=True)
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
        self.nx, self.nu = self.lqr.Gamma.shape
        self._state = plant.state_slice
        self.constrained = bool(constrained)
        self.bounds = _check_bounds(
            tuple(plant.constraints()) if bounds is None else tuple(bounds), self.nx, self.nu
        )
        self.settings = {**DEFAULT_OSQP_SETTINGS, **(osqp_settings or {})}
        self._setup()
        self.failures = 0
        self.last_status = "not run"
        self.last_solve_time_s = float("nan")
        self.predicted_states: np.ndarray | None = None
        self.planned_actions: np.ndarray | None = None

    # --- the QP -------------------------------------------------------------------------
    def _setup(self) -> None:
        N, nx = self.horizon, self.nx
        Phi, Gamma = self.lqr.Phi, self.lqr.Gamma
        self._n_x_vars = (N + 1) * nx
        cost = sp.block_diag(
            [sp.kron(sp.eye(N), self.lqr.Q), self.lqr.P, sp.kron(sp.eye(N), self.lqr.R)],
            format="csc",
        )
        # x_0 = x(k); x_{k+1} - A x_k - B u_k = 0
        A_x = sp.kron(sp.eye(N + 1), -sp.eye(nx)) + sp.kron(sp.eye(N + 1, k=-1), Phi)
        A_u = sp.kron(sp.vstack([sp.csc_matrix((1, N)), sp.eye(N)]), Gamma)
        rows = [sp.hstack([A_x, A_u])]
        lower = [np.zeros((N + 1) * nx)]
        upper = [np.zeros((N + 1) * nx)]
        if self.constrained and self.bounds:
            rows_c, limits = self._constraint_rows()
            rows.append(rows_c)
            lower.append(-limits)
            upper.append(limits)
        A = sp.vstack(rows, format="csc")
        self._lower, self._upper = np.concatenate(lower), np.concatenate(upper)
        self._solver = osqp.OSQP()
        self._solver.setup(
            cost, np.zeros(cost.shape[0]), A, self._lower, self._upper, **self.settings
        )

    def _constraint_rows(self) -> tuple[sp.csc_matrix, np.ndarray]:
        """Rows G z with limits |G z| <= b of every bound, bound after bound, each over the
        steps k = 0..N-1 (z = (x_0..x_N, u_0..u_{N-1}))."""
        N = self.horizon
        blocks, limits = [], []
        for bound in self.bounds:
            s = 1 if bound.next_state else 0
            # row block k: C x_{k+s} + D u_k
            on_states = sp.kron(sp.eye(N, N + 1, k=s), bound.state_rows)
            on_inputs = sp.kron(sp.eye(N), bound.input_rows)
            blocks.append(sp.hstack([on_states, on_inputs], format="csc"))
            limits.append(np.tile(bound.limit, N))
        G = sp.vstack(blocks, format="csc")
        G.eliminate_zeros()
        return G, np.concatenate(limits)

    # --- per step -----------------------------------------------------------------------
    def solve(self, x0: np.ndarray) -> tuple[np.ndarray, bool]:
        """(u_0, solved) for the plant state x0 (n,); the LQR fallback when not solved."""
        nx = self.nx
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
            # u = sat(-K x_0)
            u = np.clip(-self.lqr.K @ x0, self.action_low, self.action_high)
            return u, False
        N = self.horizon
        self.predicted_states = z[: self._n_x_vars].reshape(N + 1, nx)
        self.planned_actions = z[self._n_x_vars :].reshape(N, self.nu)
        return self.planned_actions[0].copy(), True

    def act(self, obs: np.ndarray, episode_start: np.ndarray) -> np.ndarray:
        return np.array([self.solve(row[self._state])[0] for row in obs])


def _check_bounds(bounds: tuple, n: int, m: int) -> tuple[StageBound, ...]:
    """The bounds as float :class:`StageBound` records, or ValueError naming the bad one."""
    checked = []
    for bound in bounds:
        if not isinstance(bound, StageBound):
            raise ValueError(
                f"MPCController: bounds must be StageBound records, got {type(bound).__name__}"
            )
        try:
            C = np.array(bound.state_rows, dtype=float, ndmin=2)
            D = np.array(bound.input_rows, dtype=float, ndmin=2)
            b = np.array(bound.limit, dtype=float, ndmin=1)
        except (TypeError, ValueError):
            raise ValueError(f"MPCController: bound {bound.name!r} is not numbers") from None
        r = len(b)
        if C.shape != (r, n) or D.shape != (r, m) or b.shape != (r,):
            raise ValueError(
                f"MPCController: bound {bound.name!r} has state_rows {C.shape}, input_rows "
                f"{D.shape}, limit {b.shape}; expected ({r}, {n}), ({r}, {m}), ({r},)"
            )
        if not (np.all(np.isfinite(C)) and np.all(np.isfinite(D))):
            raise ValueError(f"MPCController: bound {bound.name!r} has non-finite rows")
        if not np.all(np.isfinite(b) & (b >= 0.0)):
            raise ValueError(
                f"MPCController: bound {bound.name!r} has limit {b.tolist()}, must be finite "
                "and >= 0"
            )
        checked.append(StageBound(str(bound.name), C, D, b, bool(bound.next_state)))
    return tuple(checked)
