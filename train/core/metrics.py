"""Closed-loop metrics of one episode and their summary over episodes: pure functions.

An episode is recorded as samples after the reset and after every step, at the times
``time_s`` (t_0 = 0, t_k = k dt): T + 1 samples for T steps. Sample k > 0 stands for the
step interval (t_{k-1}, t_k]. Undefined numbers (the settling time of an episode that
never settles, statistics over no episode) are None, so they stay valid JSON.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

TOLERANCE_M = 0.01  # the "at the centre" band: the ball within 1 cm of the table's centre


def distance_from_centre_m(ball_pos_m: np.ndarray) -> np.ndarray:
    """Distance (m) of the ball from the table's centre (0, 0); ``ball_pos_m`` is (T, 2)."""
    return np.linalg.norm(np.asarray(ball_pos_m, dtype=float), axis=-1)


def settling_time_s(
    time_s: np.ndarray, distance_m: np.ndarray, tolerance_m: float = TOLERANCE_M
) -> float | None:
    """The first sample time after which ``distance_m`` stays below ``tolerance_m`` until
    the end (inclusive); None if the last sample is not below it.

    Distances [0.05, 0.005, 0.02, 0.008, 0.004] at t = [0, 1, 2, 3, 4] settle at t = 3:
    the band is entered at t = 1 but left again at t = 2.
    """
    time_s, distance_m = _checked_series(time_s, distance_m)
    outside = np.flatnonzero(~(distance_m < tolerance_m))
    if len(outside) == 0:
        return float(time_s[0])
    last_outside = int(outside[-1])
    if last_outside == len(distance_m) - 1:
        return None
    return float(time_s[last_outside + 1])


def time_within_s(
    time_s: np.ndarray, distance_m: np.ndarray, tolerance_m: float = TOLERANCE_M
) -> float:
    """Total time (s) within the band: the intervals (t_{k-1}, t_k] whose end sample k has
    ``distance_m`` below ``tolerance_m`` (the reset sample ends no interval)."""
    time_s, distance_m = _checked_series(time_s, distance_m)
    inside = distance_m[1:] < tolerance_m
    return float(np.sum(np.diff(time_s)[inside]))


def rms_norm(vectors: np.ndarray) -> float:
    """Root mean square of the Euclidean norm of the rows of ``vectors`` (T, d):
    sqrt(mean_k |v_k|^2); 0 for no rows."""
    v = np.asarray(vectors, dtype=float)
    if v.ndim != 2:
        raise ValueError(f"expected a (T, d) array, got shape {v.shape}")
    if len(v) == 0:
        return 0.0
    return float(np.sqrt(np.mean(np.sum(v**2, axis=1))))


def rmse(estimate: np.ndarray, truth: np.ndarray) -> float:
    """Root mean square of the Euclidean error |estimate_k - truth_k| over the rows."""
    estimate, truth = np.asarray(estimate, dtype=float), np.asarray(truth, dtype=float)
    if estimate.shape != truth.shape:
        raise ValueError(f"estimate {estimate.shape} and truth {truth.shape} differ in shape")
    return rms_norm(estimate - truth)


def episode_metrics(
    time_s: np.ndarray,
    state: np.ndarray,
    actions_rad: np.ndarray,
    rewards: np.ndarray,
    estimate: np.ndarray | None = None,
    terminated: bool = False,
    solver_failures: int = 0,
    tolerance_m: float = TOLERANCE_M,
) -> dict[str, Any]:
    """The metrics of one BallTable episode.

    Args:
        time_s: (T + 1,) sample times, reset first.
        state: (T + 1, 8) ground truth ``info["state"]`` (ball x, y, vx, vy, tilts, rates).
        actions_rad: (T, 2) commanded tilts.
        rewards: (T,) step rewards.
        estimate: (T + 1, 8) what the controller saw, in the state layout; None for the
            oracle (estimation errors are then 0).
        terminated: the ball left the table.
        solver_failures: MPC steps whose QP was not solved in this episode.
        tolerance_m: the radius of the "at the centre" band.
    """
    state = np.asarray(state, dtype=float)
    actions_rad = np.asarray(actions_rad, dtype=float).reshape(-1, 2)
    steps = len(actions_rad)
    if state.shape != (steps + 1, 8) or len(rewards) != steps:
        raise ValueError(
            f"inconsistent record: state {state.shape}, actions {actions_rad.shape}, "
            f"rewards {len(rewards)}; expected (T + 1, 8), (T, 2), T"
        )
    distance_m = distance_from_centre_m(state[:, 0:2])
    if estimate is None:
        position_rmse_m = velocity_rmse_mps = 0.0
    else:
        estimate = np.asarray(estimate, dtype=float)
        position_rmse_m = rmse(estimate[:, 0:2], state[:, 0:2])
        velocity_rmse_mps = rmse(estimate[:, 2:4], state[:, 2:4])
    return {
        "steps": steps,
        "duration_s": float(time_s[-1] - time_s[0]),
        "terminated": bool(terminated),
        "return": float(np.sum(rewards)),
        "start_distance_m": float(distance_m[0]),
        "mean_distance_m": float(np.mean(distance_m)),
        "final_distance_m": float(distance_m[-1]),
        "settling_time_s": settling_time_s(time_s, distance_m, tolerance_m),
        "time_within_s": time_within_s(time_s, distance_m, tolerance_m),
        "effort_rms_rad": rms_norm(actions_rad),
        "position_rmse_m": position_rmse_m,
        "velocity_rmse_mps": velocity_rmse_mps,
        "solver_failures": int(solver_failures),
    }


def summarize(episodes: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """Summary of :func:`episode_metrics` dicts: settling statistics over the settled
    episodes, means of the other metrics, totals of failures and terminations."""
    if not episodes:
        raise ValueError("no episodes to summarize")
    settled = [e["settling_time_s"] for e in episodes if e["settling_time_s"] is not None]

    def mean_of(key: str) -> float:
        return float(np.mean([e[key] for e in episodes]))

    return {
        "episodes": len(episodes),
        "fraction_settled": len(settled) / len(episodes),
        "settling_time_mean_s": float(np.mean(settled)) if settled else None,
        "settling_time_median_s": float(np.median(settled)) if settled else None,
        "settling_time_max_s": float(np.max(settled)) if settled else None,
        "mean_distance_m": mean_of("mean_distance_m"),
        "final_distance_m": mean_of("final_distance_m"),
        "time_within_s": mean_of("time_within_s"),
        "effort_rms_rad": mean_of("effort_rms_rad"),
        "position_rmse_m": mean_of("position_rmse_m"),
        "velocity_rmse_mps": mean_of("velocity_rmse_mps"),
        "return": mean_of("return"),
        "solver_failures": int(sum(e["solver_failures"] for e in episodes)),
        "terminated": int(sum(bool(e["terminated"]) for e in episodes)),
    }


def _checked_series(time_s: np.ndarray, distance_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    time_s = np.asarray(time_s, dtype=float)
    distance_m = np.asarray(distance_m, dtype=float)
    if time_s.ndim != 1 or time_s.shape != distance_m.shape or len(time_s) == 0:
        raise ValueError(
            f"time_s {time_s.shape} and distance_m {distance_m.shape} must be the same "
            "non-empty 1-D shape"
        )
    return time_s, distance_m
