"""TargetFollower-v0 in ``observer-gym run``: keep the target centred at its set size
through occlusions (see the :class:`Task` interface).

Metrics per episode, from the ground truth of the record (state layout of
:mod:`observer_gym.envs.target_follower.layout`):
- image error: |(x_i, y_i)| (px) and |d_x - d*| (px), mean over the steps with the target
  in front of the camera;
- fraction of time the target's centre is on the image, and the fraction it is seen
  (on the image and not hidden);
- occlusions: runs of steps with the target on the image but hidden (those still running
  when the episode ends are not counted); the recovery time of each is the time from its
  end until |(x_i, y_i)| is back within ``RECOVERED_PX`` (None if it never is);
- for an observer: RMSE of the estimated X_i and X_i^t' while its estimate is valid, and
  the fraction of steps it is valid.

Every metric in pixels is in the default camera's pixels (f_x 393.4, f_y 391.8 px: an
angle, 1 px about 2.5 mrad), whatever camera the episode had: an agent with its own,
smaller camera (``ppo:target_follower-rgb``, 84 x 63 px) is scored on the same scale as
every other entry (:func:`default_camera_factors`). The plots show the episode's own
pixels.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from observer_gym.envs.target_follower.config import TargetFollowerConfig
from observer_gym.envs.target_follower.layout import IMAGE, IMAGE_RATE, StateIndex
from observer_gym.train.core.metrics import rmse

OBSERVERS: dict[str, tuple[str, dict[str, Any] | None]] = {
    "oracle": ("state", {}),
    "kf": ("rgb", {"filter": "kf"}),
    "stkf": ("rgb", {"filter": "stkf"}),
    "kf-measurements": ("measurements", {"filter": "kf"}),
    "stkf-measurements": ("measurements", {"filter": "stkf"}),
    "pixels": ("rgb", None),  # the camera frames, unfiltered: for agents trained on rgb
    # the newest delivered measurement, unfiltered: for agents trained on measurements
    "detections": ("measurements", None),
    # the other observers of estimation/target_follower/__init__.py, from the camera
    # frames and from perfect-detector measurements
    "raw": ("rgb", {"observer": "raw"}),
    "raw-measurements": ("measurements", {"observer": "raw"}),
    "kf-latency": ("rgb", {"observer": "kf-latency"}),
    "kf-latency-measurements": ("measurements", {"observer": "kf-latency"}),
    "stkf-latency": ("rgb", {"observer": "stkf-latency"}),
    "stkf-latency-measurements": ("measurements", {"observer": "stkf-latency"}),
    "ekf": ("rgb", {"observer": "ekf"}),
    "ekf-measurements": ("measurements", {"observer": "ekf"}),
    # reads the ground truth while the target is detected: for analysis only
    "oracle-visible": ("rgb", {"observer": "oracle-visible"}),
    "oracle-visible-measurements": ("measurements", {"observer": "oracle-visible"}),
    # the network trained on the perfect detector's measurements, alone and as kf's
    # measurement model; from frames through the learned detector
    "learned": ("rgb", {"observer": "learned"}),
    "learned-measurements": ("measurements", {"observer": "learned"}),
    "learned-kf": ("rgb", {"observer": "learned-kf"}),
    "learned-kf-measurements": ("measurements", {"observer": "learned-kf"}),
}
# what an agent trained with --obs estimate reads, by --estimate-from
ESTIMATE_OBSERVERS = {"measurements": "stkf-measurements", "rgb": "stkf"}
RECOVERED_PX = 10.0  # back "in the centre" after an occlusion: |(x_i, y_i)| below this
CONFIG = {"recovered_px": RECOVERED_PX}
PLOT_EPISODES = 5

# summary key -> (label, unit, scale from the stored value to the shown unit, digits)
SUMMARY_ROWS: dict[str, tuple[str, str, float, int]] = {
    "episodes": ("episodes", "", 1.0, 0),
    "centre_error_px": ("image error ‖(x_i, y_i)‖, mean", "px", 1.0, 2),
    "width_error_px": ("width error abs(d_x - d*), mean", "px", 1.0, 2),
    "fraction_in_image": ("fraction of time the target is on the image", "", 1.0, 3),
    "fraction_visible": ("fraction of time the target is seen", "", 1.0, 3),
    "occlusions": ("occlusions (total)", "", 1.0, 0),
    "fraction_recovered": ("occlusions recovered (back within 10 px)", "", 1.0, 3),
    "recovery_time_median_s": ("recovery time after an occlusion, median", "s", 1.0, 2),
    "recovery_time_max_s": ("recovery time after an occlusion, max", "s", 1.0, 2),
    "image_rmse_px": ("estimation RMSE of X_i (valid estimates), mean", "px", 1.0, 3),
    "rate_rmse_pxps": ("estimation RMSE of X_i^t' (valid estimates), mean", "px/s", 1.0, 3),
    "fraction_estimate_valid": ("fraction of time the estimate is reliable", "", 1.0, 3),
    "return": ("return, mean", "", 1.0, 1),
    "terminated": ("terminated (target lost)", "", 1.0, 0),
}
# observer-gym compare's table: episode metric (or compare_extras value) -> (label, unit,
# scale from the stored value to the unit, digits, "lower" or "higher" is better); the
# first is the primary one ("terminated" is a boolean per episode: a rate)
COMPARE_METRICS: dict[str, tuple[str, str, float, int, str]] = {
    "centre_error_px": ("image error ‖(x_i, y_i)‖", "px", 1.0, 2, "lower"),
    "width_error_px": ("width error abs(d_x - d*)", "px", 1.0, 2, "lower"),
    "fraction_in_image": ("time on the image", "%", 100.0, 1, "higher"),
    "recovery_time_mean_s": ("recovery after an occlusion", "s", 1.0, 2, "lower"),
    "terminated": ("target lost", "%", 100.0, 1, "lower"),
    "image_rmse_px": ("estimate RMSE of X_i", "px", 1.0, 3, "lower"),
}


def _image_limits(record: Mapping[str, Any]) -> tuple[float, float]:
    config = record["env_config"]
    return config["image_width_px"] / 2.0, config["image_height_px"] / 2.0


def default_camera_factors(record: Mapping[str, Any]) -> np.ndarray:
    """(x, y) factors from the episode camera's pixels to the default camera's: the
    default focal lengths over the episode's (1, 1 for the default camera)."""
    config, default = record["env_config"], TargetFollowerConfig()
    return np.array([default.fx_px / config["fx_px"], default.fy_px / config["fy_px"]])


def occlusion_intervals(state: np.ndarray, half_w: float, half_h: float) -> list[tuple[int, int]]:
    """(first, last) sample indices of each run with the target on the image but not seen."""
    on_image = (
        (state[:, StateIndex.TRACKING_VALID] == 1.0)
        & (np.abs(state[:, StateIndex.X_I]) <= half_w)
        & (np.abs(state[:, StateIndex.Y_I]) <= half_h)
    )
    hidden = on_image & (state[:, StateIndex.TARGET_VISIBLE] == 0.0)
    runs, start = [], None
    for k, flag in enumerate(hidden):
        if flag and start is None:
            start = k
        elif not flag and start is not None:
            runs.append((start, k - 1))
            start = None
    if start is not None:
        runs.append((start, len(hidden) - 1))
    return runs


def episode_metrics(record: Mapping[str, Any]) -> dict[str, Any]:
    state = np.asarray(record["state"], dtype=float)
    time_s = np.asarray(record["time_s"], dtype=float)
    desired = record["env_config"]["desired_width_px"]
    half_w, half_h = _image_limits(record)
    in_front = state[:, StateIndex.TRACKING_VALID] == 1.0
    to_default_x, to_default_y = default_camera_factors(record)
    # x_i, y_i, d_x in the default camera's pixels (d_x is a width along x)
    in_default_px = np.array([to_default_x, to_default_y, to_default_x])
    centre = np.hypot(
        to_default_x * state[:, StateIndex.X_I], to_default_y * state[:, StateIndex.Y_I]
    )
    on_image = (
        in_front
        & (np.abs(state[:, StateIndex.X_I]) <= half_w)
        & (np.abs(state[:, StateIndex.Y_I]) <= half_h)
    )
    recoveries = []
    for _, last in occlusion_intervals(state, half_w, half_h):
        if last == len(state) - 1:
            continue  # hidden until the episode ended: no recovery to measure
        back = np.flatnonzero(centre[last + 1 :] <= RECOVERED_PX)
        recoveries.append(
            None if len(back) == 0 else float(time_s[last + 1 + back[0]] - time_s[last])
        )
    metrics: dict[str, Any] = {
        "steps": len(record["actions"]),
        "centre_error_px": float(np.mean(centre[in_front])) if np.any(in_front) else None,
        "width_error_px": (
            float(to_default_x * np.mean(np.abs(state[in_front, StateIndex.D_X] - desired)))
            if np.any(in_front)
            else None
        ),
        "fraction_in_image": float(np.mean(on_image)),
        "fraction_visible": float(np.mean(state[:, StateIndex.TARGET_VISIBLE])),
        "occlusions": len(recoveries),
        "recovery_times_s": recoveries,
        "image_rmse_px": None,
        "rate_rmse_pxps": None,
        "fraction_estimate_valid": None,
        "return": float(np.sum(record["rewards"])),
        "terminated": bool(record["terminated"]),
    }
    if record["estimate"] is not None:
        estimate = np.asarray(record["estimate"], dtype=float)
        valid = estimate[:, StateIndex.TRACKING_VALID] == 1.0
        metrics["fraction_estimate_valid"] = float(np.mean(valid))
        if np.any(valid):
            metrics["image_rmse_px"] = rmse(
                in_default_px * estimate[valid][:, IMAGE], in_default_px * state[valid][:, IMAGE]
            )
            metrics["rate_rmse_pxps"] = rmse(
                in_default_px * estimate[valid][:, IMAGE_RATE],
                in_default_px * state[valid][:, IMAGE_RATE],
            )
    return metrics


def compare_extras(episode: Mapping[str, Any]) -> dict[str, Any]:
    """Per-episode values of COMPARE_METRICS that :func:`episode_metrics` keeps as a list:
    ``recovery_time_mean_s``, the mean recovery time (s) of the episode's recovered
    occlusions (None if none was recovered)."""
    recovered = [t for t in episode["recovery_times_s"] if t is not None]
    return {"recovery_time_mean_s": float(np.mean(recovered)) if recovered else None}


def summarize(episodes: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """Means over episodes (of the episodes where a metric is defined); recovery times
    pooled over every occlusion."""
    if not episodes:
        raise ValueError("no episodes to summarize")

    def mean_of(key: str) -> float | None:
        values = [e[key] for e in episodes if e[key] is not None]
        return float(np.mean(values)) if values else None

    recoveries = [t for e in episodes for t in e["recovery_times_s"]]
    recovered = [t for t in recoveries if t is not None]
    return {
        "episodes": len(episodes),
        "centre_error_px": mean_of("centre_error_px"),
        "width_error_px": mean_of("width_error_px"),
        "fraction_in_image": mean_of("fraction_in_image"),
        "fraction_visible": mean_of("fraction_visible"),
        "occlusions": len(recoveries),
        "fraction_recovered": len(recovered) / len(recoveries) if recoveries else None,
        "recovery_time_median_s": float(np.median(recovered)) if recovered else None,
        "recovery_time_max_s": float(np.max(recovered)) if recovered else None,
        "image_rmse_px": mean_of("image_rmse_px"),
        "rate_rmse_pxps": mean_of("rate_rmse_pxps"),
        "fraction_estimate_valid": mean_of("fraction_estimate_valid"),
        "return": mean_of("return"),
        "terminated": int(sum(e["terminated"] for e in episodes)),
    }


def plot(records: Sequence[Mapping[str, Any]], observer: str, out_dir: Path) -> list[str]:
    """``image.png`` (the target's image path, first episodes, with the image's border),
    ``error.png`` (|(x_i, y_i)| and d_x - d* vs time, every episode, occlusions shaded in
    episode 0) and, for an observer, ``estimate.png`` (episode 0's estimate of X_i vs
    truth with +-2 sigma)."""
    from observer_gym.train.core.plots import (  # imported on use: matplotlib
        new_figure,
        save_figure,
    )

    half_w, half_h = _image_limits(records[0])
    fig = new_figure((6.0, 4.8))
    ax = fig.add_subplot()
    ax.plot(
        [-half_w, half_w, half_w, -half_w, -half_w],
        [-half_h, -half_h, half_h, half_h, -half_h],
        "k-",
        lw=1.2,
        label="image border",
    )
    for i, r in enumerate(records[:PLOT_EPISODES]):
        s = np.asarray(r["state"])
        ax.plot(s[:, StateIndex.X_I], s[:, StateIndex.Y_I], lw=0.8, label=f"episode {i}")
        ax.plot(s[0, StateIndex.X_I], s[0, StateIndex.Y_I], "ko", ms=3)
    ax.set_xlim(-1.3 * half_w, 1.3 * half_w)
    ax.set_ylim(-1.3 * half_h, 1.3 * half_h)
    ax.set_aspect("equal")
    ax.set_xlabel("x_i (px, right)")
    ax.set_ylabel("y_i (px, up)")
    ax.set_title("Target centre in the image (start: dot)")
    ax.legend(fontsize=7, loc="upper right")
    save_figure(fig, out_dir / "image.png")

    fig = new_figure((8.0, 5.0))
    axes = fig.subplots(2, 1, sharex=True)
    for r in records:
        s, t = np.asarray(r["state"]), np.asarray(r["time_s"])
        axes[0].plot(t, np.hypot(s[:, StateIndex.X_I], s[:, StateIndex.Y_I]), lw=0.6, alpha=0.6)
        desired = r["env_config"]["desired_width_px"]
        axes[1].plot(t, s[:, StateIndex.D_X] - desired, lw=0.6, alpha=0.6)
    first = np.asarray(records[0]["state"])
    t0 = np.asarray(records[0]["time_s"])
    for a, b in occlusion_intervals(first, half_w, half_h):
        for ax in axes:
            ax.axvspan(t0[a], t0[b], color="0.85", lw=0)
    axes[0].axhline(RECOVERED_PX, color="k", ls=":", lw=1)
    axes[0].set_yscale("symlog", linthresh=1.0)
    axes[0].set_ylabel("|(x_i, y_i)| (px)")
    axes[1].set_ylabel("d_x - d* (px)")
    axes[1].set_xlabel("time (s)")
    axes[0].set_title(f"Image error, {len(records)} episodes (grey: episode 0's occlusions)")
    save_figure(fig, out_dir / "error.png")
    files = ["image.png", "error.png"]
    if records[0]["estimate"] is not None:
        r = records[0]
        s, e, sd = (np.asarray(r[k]) for k in ("state", "estimate", "estimate_std"))
        t = np.asarray(r["time_s"])
        fig = new_figure((8.0, 6.0))
        axes = fig.subplots(3, 1, sharex=True)
        for ax, index, name in zip(axes, (0, 1, 2), ("x_i", "y_i", "d_x"), strict=True):
            ax.fill_between(
                t,
                e[:, index] - 2 * sd[:, index],
                e[:, index] + 2 * sd[:, index],
                color="0.85",
                label="±2σ",
            )
            ax.plot(t, s[:, index], "k-", lw=1, label="truth")
            ax.plot(t, e[:, index], "tab:blue", lw=0.8, label="estimate")
            ax.set_ylabel(f"{name} (px)")
        axes[0].legend(fontsize=8, loc="upper right")
        axes[-1].set_xlabel("time (s)")
        axes[0].set_title(f"Observer '{observer}': image state, episode 0")
        save_figure(fig, out_dir / "estimate.png")
        files.append("estimate.png")
    return files
