"""BallCatcher-v1 in ``observer-gym run``: catch rate with its 95 % interval, the misses
counted by reason, the miss at the box's plane, and the observer's error (see the
:class:`Task` interface).

A record's arrays follow the env's state layout: ball position and velocity, box (hole
centre) position and velocity, world frame.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from observer_gym.envs.ball_catcher import MISS_REASONS
from observer_gym.envs.ball_catcher import geometry as geo
from observer_gym.envs.ball_catcher.layout import BALL_POS, BALL_VEL, BOX_POS
from observer_gym.train.core.metrics import rmse

OBSERVERS: dict[str, tuple[str, dict[str, Any] | None]] = {
    "oracle": ("state", {}),
    "kf": ("rgb", {}),
    "kf-measurements": ("measurements", {}),
    "pixels": ("rgb", None),  # the camera frames, unfiltered: for agents trained on rgb
    # the newest delivered measurement, unfiltered: for agents trained on measurements
    "detections": ("measurements", None),
    # triangulated detections, no filter
    "raw": ("rgb", {"observer": "raw"}),
    "raw-measurements": ("measurements", {"observer": "raw"}),
    # the same pipeline as kf (kf is already latency-aware)
    "kf-latency": ("rgb", {"observer": "kf-latency"}),
    "kf-latency-measurements": ("measurements", {"observer": "kf-latency"}),
    # kf fusing each frame at its delivery as if captured then: no latency handling
    "kf-at-delivery": ("rgb", {"observer": "kf-at-delivery"}),
    "kf-at-delivery-measurements": ("measurements", {"observer": "kf-at-delivery"}),
    # iterated EKF on the pixels
    "ekf": ("rgb", {"observer": "ekf"}),
    "ekf-measurements": ("measurements", {"observer": "ekf"}),
    # ground truth while the ball is seen: analysis only
    "oracle-visible": ("rgb", {"observer": "oracle-visible"}),
    "oracle-visible-measurements": ("measurements", {"observer": "oracle-visible"}),
    # the pixel EKF estimating each camera's calibration error with the ball; and with
    # the box's hole as a landmark (it needs the env's hole_measurements, which make_env
    # sets: estimation/ball_catcher's ENV_OPTIONS)
    "selfcal": ("rgb", {"observer": "selfcal"}),
    "selfcal-measurements": ("measurements", {"observer": "selfcal"}),
    "endpoint-measurements": ("measurements", {"observer": "endpoint"}),
    # the network trained on the perfect detector's measurements, alone and as kf's
    # measurement model; from frames through the learned detector, or from measurements
    "learned": ("rgb", {"observer": "learned"}),
    "learned-kf": ("rgb", {"observer": "learned-kf"}),
    "learned-measurements": ("measurements", {"observer": "learned"}),
    "learned-kf-measurements": ("measurements", {"observer": "learned-kf"}),
}
# what an agent trained with --obs estimate reads, by --estimate-from
ESTIMATE_OBSERVERS = {"measurements": "kf-measurements", "rgb": "kf"}
CONFIDENCE = 0.95
# Estimation errors are measured from this long after the launch (the first 5-10 frames
# only bring the estimate from its prior, the throw distribution's, to the track) until
# the ball reaches the box's plane (after that it bounces in the box or off it: no
# ballistic model applies).
SETTLE_S = 0.1
CONFIG = {"catch_rate_interval": f"Wilson score, {CONFIDENCE:.0%}", "estimate_from_s": SETTLE_S}
# Why an episode was not caught: the env's info["miss_reason"] on a miss (see the env's
# Episode End), or UNFINISHED for an episode cut before the catch was judged (the ball still
# flying at the time limit or at --steps). Every episode not caught has one.
UNFINISHED = "unfinished"
NOT_CAUGHT_REASONS = (*MISS_REASONS, UNFINISHED)

# summary key -> (label, unit, scale from the stored SI value to the shown unit, digits)
SUMMARY_ROWS: dict[str, tuple[str, str, float, int]] = {
    "episodes": ("episodes", "", 1.0, 0),
    "catches": ("catches", "", 1.0, 0),
    "catch_rate": ("catch rate", "%", 100.0, 1),
    "catch_rate_low": ("catch rate, 95 % interval low", "%", 100.0, 1),
    "catch_rate_high": ("catch rate, 95 % interval high", "%", 100.0, 1),
    **{f"misses_{reason}": (f"misses: {reason}", "", 1.0, 0) for reason in NOT_CAUGHT_REASONS},
    "miss_distance_median_m": ("ball centre to hole centre at the plane, median", "mm", 1e3, 1),
    "miss_distance_p90_m": (
        "ball centre to hole centre at the plane, 90th percentile",
        "mm",
        1e3,
        1,
    ),
    "position_rmse_m": ("estimation RMSE ball position (0.1 s to the plane), mean", "mm", 1e3, 2),
    "velocity_rmse_mps": (
        "estimation RMSE ball velocity (0.1 s to the plane), mean",
        "mm/s",
        1e3,
        1,
    ),
    "box_travel_m": ("box travel, mean", "mm", 1e3, 1),
    "return": ("return, mean", "", 1.0, 2),
}
# observer-gym compare's table: episode metric -> (label, unit, scale from the stored SI
# value to the unit, digits, "lower" or "higher" is better); the first is the primary one
# ("caught" is a boolean per episode: a rate with its Wilson interval)
COMPARE_METRICS: dict[str, tuple[str, str, float, int, str]] = {
    "caught": ("catch rate", "%", 100.0, 1, "higher"),
    "miss_distance_m": ("miss at the box's plane", "mm", 1e3, 1, "lower"),
    "position_rmse_m": ("estimate RMSE, ball position", "mm", 1e3, 2, "lower"),
    "box_travel_m": ("box travel", "mm", 1e3, 1, "lower"),
}
# observer-gym compare's counted columns, beside the primary metric: episode metric ->
# (label, its values in the order shown); a cell counts the pair's episodes of each value
# (None is not counted: here, the catches)
COMPARE_COUNTS: dict[str, tuple[str, tuple[str, ...]]] = {
    "miss_reason": ("misses by reason", NOT_CAUGHT_REASONS),
}


def plane_offset_m(record: Mapping[str, Any]) -> np.ndarray | None:
    """(y, z) of the ball's centre minus the hole's centre where the ball's centre first
    crosses the box's front plane, interpolated linearly between the two samples around
    the crossing; None if it never crossed."""
    state = np.asarray(record["state"], dtype=float)
    ahead = state[:, 0] - state[:, BOX_POS][:, 0]  # ball x minus the plane's x
    crossed = np.flatnonzero((ahead[:-1] > 0.0) & (ahead[1:] <= 0.0))
    if len(crossed) == 0:
        return None
    k = int(crossed[0])
    w = ahead[k] / (ahead[k] - ahead[k + 1])
    offset = (1.0 - w) * (state[k, 1:3] - state[k, 7:9]) + w * (
        state[k + 1, 1:3] - state[k + 1, 7:9]
    )
    return offset


def miss_reason(final_info: Mapping[str, Any]) -> str | None:
    """Why the episode was not caught (one of NOT_CAUGHT_REASONS; None if it was): the env's
    ``miss_reason`` on a miss, UNFINISHED if it ended with the ball still flying."""
    if final_info.get("caught", False):
        return None
    if final_info.get("outcome") == "missed":
        return str(final_info["miss_reason"])
    return UNFINISHED


def episode_metrics(record: Mapping[str, Any]) -> dict[str, Any]:
    state = np.asarray(record["state"], dtype=float)
    info = record["final_info"]
    offset = plane_offset_m(record)
    in_flight = (state[:, 0] > state[:, BOX_POS][:, 0]) & (np.asarray(record["time_s"]) >= SETTLE_S)
    if record["estimate"] is None or not np.any(in_flight):
        position_rmse_m = velocity_rmse_mps = 0.0
    else:
        estimate = np.asarray(record["estimate"], dtype=float)[in_flight]
        position_rmse_m = rmse(estimate[:, BALL_POS], state[in_flight][:, BALL_POS])
        velocity_rmse_mps = rmse(estimate[:, BALL_VEL], state[in_flight][:, BALL_VEL])
    box = state[:, BOX_POS]
    return {
        "steps": len(record["actions"]),
        "duration_s": float(record["time_s"][-1] - record["time_s"][0]),
        "outcome": info.get("outcome"),
        "caught": bool(info.get("caught", False)),
        "miss_reason": miss_reason(info),
        "terminated": bool(record["terminated"]),
        "return": float(np.sum(record["rewards"])),
        "plane_offset_m": None if offset is None else [float(v) for v in offset],
        "miss_distance_m": None if offset is None else float(np.linalg.norm(offset)),
        "position_rmse_m": position_rmse_m,
        "velocity_rmse_mps": velocity_rmse_mps,
        "box_travel_m": float(np.sum(np.linalg.norm(np.diff(box, axis=0), axis=1))),
        "solver_failures": int(record["solver_failures"]),
    }


def summarize(episodes: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """Catch rate with its Wilson score interval (SciPy's ``binomtest``), the episodes not
    caught by reason (``miss_reasons`` and one ``misses_<reason>`` count each), the miss
    distance's median and 90th percentile, and means of the rest."""
    from scipy.stats import binomtest  # imported on use: scipy.stats takes ~0.6 s to import

    if not episodes:
        raise ValueError("no episodes to summarize")
    n = len(episodes)
    catches = sum(bool(e["caught"]) for e in episodes)
    interval = binomtest(catches, n).proportion_ci(confidence_level=CONFIDENCE, method="wilson")
    misses = [e["miss_distance_m"] for e in episodes if e["miss_distance_m"] is not None]

    def mean_of(key: str) -> float:
        return float(np.mean([e[key] for e in episodes]))

    outcomes: dict[str, int] = {}
    for e in episodes:
        outcomes[str(e["outcome"])] = outcomes.get(str(e["outcome"]), 0) + 1
    reasons = dict.fromkeys(NOT_CAUGHT_REASONS, 0)
    for e in episodes:
        if e["miss_reason"] is not None:
            reasons[e["miss_reason"]] = reasons.get(e["miss_reason"], 0) + 1
    return {
        "episodes": n,
        "catches": catches,
        "catch_rate": catches / n,
        "catch_rate_low": float(interval.low),
        "catch_rate_high": float(interval.high),
        "outcomes": outcomes,
        "miss_reasons": reasons,
        **{f"misses_{reason}": reasons[reason] for reason in NOT_CAUGHT_REASONS},
        "miss_distance_median_m": float(np.median(misses)) if misses else None,
        "miss_distance_p90_m": float(np.percentile(misses, 90)) if misses else None,
        "position_rmse_m": mean_of("position_rmse_m"),
        "velocity_rmse_mps": mean_of("velocity_rmse_mps"),
        "box_travel_m": mean_of("box_travel_m"),
        "return": mean_of("return"),
        "solver_failures": int(sum(e["solver_failures"] for e in episodes)),
    }


def plot(records: Sequence[Mapping[str, Any]], observer: str, out_dir: Path) -> list[str]:
    """``plane.png``: where each ball crossed the box's plane relative to the hole
    (caught / missed), with the hole and the ball's size; ``estimate.png`` for an
    observer: episode 0's ball-position error and its 2-sigma band over time."""
    from observer_gym.train.core.plots import (  # imported on use: matplotlib
        new_figure,
        save_figure,
    )

    fig = new_figure((5.2, 5.0))
    ax = fig.add_subplot()
    phase = np.linspace(0.0, 2.0 * np.pi, 200)
    hole_r_mm = 1e3 * records[0]["env_config"]["hole_diameter_m"] / 2
    ax.plot(hole_r_mm * np.cos(phase), hole_r_mm * np.sin(phase), "k-", lw=1.5, label="hole")
    clear_mm = hole_r_mm - 1e3 * geo.BALL_RADIUS_M
    ax.plot(clear_mm * np.cos(phase), clear_mm * np.sin(phase), "k:", lw=1, label="clean pass")
    crossings = [(bool(r["final_info"].get("caught")), plane_offset_m(r)) for r in records]
    for caught, colour, marker in ((True, "tab:green", "o"), (False, "tab:red", "x")):
        offsets = [1e3 * offset for c, offset in crossings if c == caught and offset is not None]
        if offsets:
            points = np.array(offsets)
            ax.scatter(
                points[:, 0],
                points[:, 1],
                s=14,
                label="caught" if caught else "missed",
                c=colour,
                marker=marker,
            )
    ax.set_aspect("equal")
    limit = 3.0 * hole_r_mm
    ax.set_xlim(-limit, limit)
    ax.set_ylim(-limit, limit)
    ax.set_xlabel("y offset at the box's plane (mm)")
    ax.set_ylabel("z offset at the box's plane (mm)")
    ax.set_title(f"Where the ball crossed the box's front plane ({len(records)} episodes)")
    ax.legend(loc="upper right", fontsize=8)
    save_figure(fig, out_dir / "plane.png")
    files = ["plane.png"]
    if records[0]["estimate"] is not None:
        first = records[0]
        t = np.asarray(first["time_s"])
        error_mm = 1e3 * (first["estimate"][:, BALL_POS] - first["state"][:, BALL_POS])
        std_mm = 1e3 * first["estimate_std"][:, BALL_POS]
        fig = new_figure((7.0, 5.5))
        axes = fig.subplots(3, 1, sharex=True)
        for i, (ax, name) in enumerate(zip(axes, "xyz", strict=True)):
            ax.fill_between(t, -2 * std_mm[:, i], 2 * std_mm[:, i], color="0.85", label="±2σ")
            ax.plot(t, error_mm[:, i], "tab:blue", lw=1, label="error")
            ax.set_ylabel(f"{name} (mm)")
            ax.set_ylim(-30, 30)
        axes[0].legend(loc="upper right", fontsize=8)
        axes[-1].set_xlabel("time (s)")
        axes[0].set_title(f"Observer '{observer}': ball position error, episode 0")
        save_figure(fig, out_dir / "estimate.png")
        files.append("estimate.png")
    return files
