"""The rolling-ball model's acceleration error and the arm's tilt-rate error on
BallTable-v0 against the simulator, and how well ``kf``'s variance models of them
(estimation/ball_table/noise.py, ``motion_accel_var``; estimation/ball_table/observer.py,
``rate_model_var``) claim them:

    python benchmarks/ball_table_model_error.py [--seeds 10] [--steps 300] [--push-rate-hz 0]

The LQR on the true state, ``seeds`` episodes of up to ``steps`` steps. Over each 20 ms
step the ball's true acceleration in the table frame, (v(k+1) - v(k)) / dt, against what
the rolling model predicts given the true tilt: (5/7) g sin(tilt) at the interval's mean
tilt, and (``rotation``) the table's angular acceleration h theta'' with the tilt rate
from the arm's lag model, g (u - theta_lag), at both ends (RollingBallModel.
rotation_increment), h the ball's radius; ``kf's heights`` with h per tilt axis as kf has
it (models.KF_ROTATION_HEIGHTS_M). Prints per axis the RMS, 99th percentile and lag-one
correlation of each; the least-squares height the x error still asks of the tilt_y
angular acceleration; non-negative least-squares fits of the squared error on kf's
variance model's terms (1, |alpha|^2, |theta'|^4), and the ratio mean(e^2) / mean(sigma^2)
of kf's constants over the first 15 steps (the swings from a 10 cm start), steps 15-50
and the rest; the same for the tilt rate's departure from g (u - theta) against
``rate_model_var``.
"""

from __future__ import annotations

import argparse

import gymnasium as gym
import numpy as np
from scipy.optimize import nnls

import observer_gym.envs  # noqa: F401  (registers the envs)
from observer_gym.controllers import make_controller
from observer_gym.envs.ball_table.geometry import up_in_table
from observer_gym.estimation.ball_table.models import (
    KF_ROTATION_HEIGHTS_M,
    RollingBallModel,
    TiltLagModel,
)
from observer_gym.estimation.ball_table.noise import KF_ACCEL_FLOOR_MPS2, motion_accel_var
from observer_gym.estimation.ball_table.observer import rate_model_var

ENV_ID = "observer_gym/BallTable-v0"
WINDOWS = ((0, 15), (15, 50), (50, None))


def model_errors(seeds: int, steps: int, push_rate_hz: float = 0.0) -> dict[str, np.ndarray]:
    """Per step (n rows): ``plain``, ``rotation``, ``kf`` acceleration errors (n, 2) m/s^2,
    ``rate_error`` (n, 2) rad/s, the lag model's angular acceleration ``alpha`` (n, 2)
    rad/s^2 and mean rate ``rate`` (n, 2) rad/s over the step, the lag model's rate at its
    end ``rate_end`` (n, 2) and the step's index in its episode ``k`` (n,)."""
    env = gym.make(ENV_ID, obs_mode="state", push_rate_hz=push_rate_hz)
    cfg = env.unwrapped.config
    lag = TiltLagModel.from_arm(cfg.arm_position_gain, cfg.physics_dt_s, 0.0)
    Phi, Gamma, _ = lag.matrices(cfg.dt_s)
    controller = make_controller("lqr", env)
    dt_s = cfg.dt_s
    out: dict[str, list] = {
        k: [] for k in ("plain", "rotation", "kf", "rate_error", "alpha", "rate", "rate_end", "k")
    }
    for seed in range(seeds):
        _, info = env.reset(seed=seed)
        x, command = info["state"], np.zeros(2)
        lag_tilt = np.array(x[4:6], dtype=float)
        for k in range(steps):
            action, _ = controller.predict(np.asarray(x, np.float32))
            _, _, terminated, truncated, info = env.step(action)
            x_next, applied = info["state"], np.asarray(info["applied_action"], float)
            tilt0, tilt1 = x[4:6], x_next[4:6]
            gravity = RollingBallModel.gravity_acceleration(up_in_table(*(0.5 * (tilt0 + tilt1))))
            error = (x_next[2:4] - x[2:4]) / dt_s - gravity
            # the lag model's tilt from the commands alone, as kf has it
            lag_next = Phi @ lag_tilt + Gamma @ applied
            rate0, rate1 = lag.rate(lag_tilt, command), lag.rate(lag_next, applied)
            turned = RollingBallModel.rotation_increment(rate0, rate1, lag_next - lag_tilt, dt_s)
            turned_kf = RollingBallModel.rotation_increment(
                rate0, rate1, lag_next - lag_tilt, dt_s, KF_ROTATION_HEIGHTS_M
            )
            out["plain"].append(error)
            out["rotation"].append(error - turned[2:4] / dt_s)
            out["kf"].append(error - turned_kf[2:4] / dt_s)
            out["rate_error"].append(x_next[6:8] - lag.rate(tilt1, applied))
            out["alpha"].append((rate1 - rate0) / dt_s)
            out["rate"].append(0.5 * (rate0 + rate1))
            out["rate_end"].append(rate1)
            out["k"].append(k)
            x, command, lag_tilt = x_next, applied, lag_next
            if terminated or truncated:
                break
    env.close()
    return {k: np.array(v) for k, v in out.items()}


def _window_ratios(err: np.ndarray, var: np.ndarray, k: np.ndarray) -> str:
    """mean(e^2) / mean(sigma^2) per axis over each of WINDOWS and over all steps."""
    cells = []
    for lo, hi in (*WINDOWS, (0, None)):
        s = (k >= lo) & (k < (np.inf if hi is None else hi))
        ratio = np.mean(err[s] ** 2, axis=0) / np.mean(var[s], axis=0)
        cells.append(f"{ratio[0]:.2f}, {ratio[1]:.2f}")
    return " | ".join(cells)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--push-rate-hz", type=float, default=0.0)
    args = parser.parse_args()
    d = model_errors(args.seeds, args.steps, args.push_rate_hz)
    k = d["k"]
    print(f"{ENV_ID}: {len(k)} steps, pushes at {args.push_rate_hz} Hz")
    print("\nacceleration error (m/s^2)")
    print("| model | RMS x | RMS y | 99th pct x | 99th pct y | lag-one corr x | y |")
    print("|---|---|---|---|---|---|---|")
    models = (("5/7 g sin(tilt)", "plain"), ("rotation", "rotation"), ("kf's heights", "kf"))
    for name, key in models:
        err = d[key]
        rms = np.sqrt(np.mean(err**2, axis=0))
        p99 = np.percentile(np.abs(err), 99, axis=0)
        lag1 = [np.corrcoef(err[:-1, i], err[1:, i])[0, 1] for i in (0, 1)]
        print(
            f"| {name} | {rms[0]:.3g} | {rms[1]:.3g} | {p99[0]:.3g} | {p99[1]:.3g} "
            f"| {lag1[0]:.2f} | {lag1[1]:.2f} |"
        )
    alpha_y = d["alpha"][:, 1]
    height = -float(alpha_y @ d["rotation"][:, 0] / (alpha_y @ alpha_y))
    print(f"\nthe x error's least-squares height on tilt_y's angular acceleration: {height:.4f} m")
    err = d["kf"]
    for lo, hi in WINDOWS:
        s = (k >= lo) & (k < (np.inf if hi is None else hi))
        print(f"kf's heights, steps {lo}-{hi or 'end'}: RMS {np.sqrt(np.mean(err[s] ** 2, 0))}")
    terms = np.column_stack(
        [np.ones(len(k)), np.sum(d["alpha"] ** 2, 1), np.sum(d["rate"] ** 2, 1) ** 2]
    )
    for axis in (0, 1):
        c, _ = nnls(terms, err[:, axis] ** 2)
        print(
            f"NNLS of e_{'xy'[axis]}^2 on (1, |alpha|^2, |rate|^4): std {np.sqrt(c[0]):.3g} "
            f"m/s^2, {np.sqrt(c[1]):.3g} m, {np.sqrt(c[2]):.3g} m"
        )
    var = KF_ACCEL_FLOOR_MPS2**2 + np.array(
        [motion_accel_var(a, r) for a, r in zip(d["alpha"], d["rate"], strict=True)]
    )
    rate, rate_err = d["rate_end"], d["rate_error"]
    # the tilt rate's error is quadratic in the rate: e_x ~ theta_x' theta_y', e_y ~ theta_x'^2
    terms = np.column_stack([rate[:, 0] * rate[:, 1], rate[:, 0] ** 2])
    coef = np.sum(terms * rate_err, axis=0) / np.sum(terms**2, axis=0)
    left = rate_err - coef * terms
    calm = k >= WINDOWS[-1][0]
    print(
        f"\ntilt rate error: RMS {np.sqrt(np.mean(rate_err**2, 0))} rad/s; least squares "
        f"e_x = {coef[0]:.4f} s theta_x' theta_y', e_y = {coef[1]:.4f} s theta_x'^2 leave "
        f"{np.sqrt(np.mean(left**2, 0))}, steps {WINDOWS[-1][0]}-end "
        f"{np.sqrt(np.mean(left[calm] ** 2, 0))} rad/s RMS"
    )
    rate_var = np.array([rate_model_var(r) for r in rate])
    print("\nmean(e^2) / mean(sigma^2) (x, y), steps 0-15 | 15-50 | 50-end | all")
    print(f"acceleration (motion_accel_var): {_window_ratios(err, var, k)}")
    print(f"tilt rate (rate_model_var):     {_window_ratios(rate_err, rate_var, k)}")


if __name__ == "__main__":
    main()
