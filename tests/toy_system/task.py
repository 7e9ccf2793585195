"""PointMass-v0 in ``observer-gym run``: bring the mass to the origin (the Task interface
of observer_gym.train.core.tasks)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from observer_gym.train.core.plots import plot_distances

OBSERVERS: dict[str, tuple[str, dict[str, Any] | None]] = {
    "oracle": ("state", {}),
    "kf": ("rgb", {}),
    "kf-measurements": ("measurements", {}),
    "pixels": ("rgb", None),
}
ESTIMATE_OBSERVERS = {"measurements": "kf-measurements", "rgb": "kf"}
CONFIG: dict[str, Any] = {}
SUMMARY_ROWS: dict[str, tuple[str, str, float, int]] = {
    "episodes": ("episodes", "", 1.0, 0),
    "mean_distance_m": ("distance from origin, mean", "mm", 1e3, 2),
    "final_distance_m": ("final distance, mean", "mm", 1e3, 2),
    "position_rmse_m": ("estimation RMSE position, mean", "mm", 1e3, 2),
    "return": ("return, mean", "", 1.0, 1),
}
COMPARE_METRICS: dict[str, tuple[str, str, float, int, str]] = {
    "mean_distance_m": ("distance from origin", "mm", 1e3, 2, "lower"),
    "final_distance_m": ("final distance", "mm", 1e3, 2, "lower"),
    "return": ("return", "", 1.0, 1, "higher"),
}
# train's hyperparameters for this system (it has no entry in the package's YAML files)
HYPERPARAMS = {
    algo: {"n_envs": 1, "vec_env": "dummy", "eval_freq": 1_000_000, "checkpoint_freq": 64}
    for algo in ("ppo", "sac", "td3")
}


def episode_metrics(record: Mapping[str, Any]) -> dict[str, Any]:
    state = np.asarray(record["state"], float)
    distance_m = np.hypot(state[:, 0], state[:, 1])
    estimate = record["estimate"]
    rmse_m = 0.0
    if estimate is not None:
        error = np.asarray(estimate, float)[:, :2] - state[:, :2]
        rmse_m = float(np.sqrt(np.mean(np.sum(error**2, axis=1))))
    return {
        "mean_distance_m": float(distance_m.mean()),
        "final_distance_m": float(distance_m[-1]),
        "position_rmse_m": rmse_m,
        "return": float(np.sum(record["rewards"])),
    }


def summarize(episodes: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    keys = ("mean_distance_m", "final_distance_m", "position_rmse_m", "return")
    return {
        "episodes": len(episodes),
        **{key: float(np.mean([e[key] for e in episodes])) for key in keys},
    }


def plot(records: Sequence[Mapping[str, Any]], observer: str, out_dir: Path) -> list[str]:
    plot_distances(
        [r["time_s"] for r in records],
        [np.hypot(r["state"][:, 0], r["state"][:, 1]) for r in records],
        out_dir / "error.png",
    )
    return ["error.png"]
