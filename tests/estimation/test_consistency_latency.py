"""Every system's classical estimating observers under latency with jitter (issue 45):
median episode NEES/dof within [1/3, 3] at latency_s 0, 0.08 and 0.15 s, each with a
latency jitter of 0.01 s (``latency_jitter_s``), from the perfect detector's
measurements under the system's reference controller, with the consistency study's
step caps and env options (train/experiments/consistency_study.py, SYSTEMS; 3 episodes,
seeds 0-2). ``raw`` makes no covariance claim and is left out; the learned families are
tests/estimation/test_learned_*'s.

Measured with this code (median of the 3 at 0 / 0.08 / 0.15 s):
BallTable kf 0.54 / 0.72 / 1.39, kf-latency 0.55 / 0.72 / 0.65 (0.55 / 0.71 / 0.63
before its tilt filter's Q was the arm's measured departure from the lag model), ekf
0.61 / 0.61 / 0.52
(0.10 / 0.17 / 0.17 before it had kf's measured model error); TargetFollower kf 0.61 /
0.49 / 1.25, stkf 0.63 / 0.52 / 1.18,
kf-latency 0.55 / 0.51 / 0.46, stkf-latency 0.53 / 0.46 / 0.42, ekf 0.52 / 0.55 / 0.45;
BallCatcher kf, ekf, selfcal and endpoint 0.66 / 0.68 / 0.65 (the four alike: the
intercept episodes' filters share their start). The study's table is in
docs/results/consistency.md ("Latency"). BallTable kf and kf-latency on seeds no change
was tuned on, at 0, 0.05, 0.1 and 0.15 s: tests/estimation/
test_consistency_latency_held_out.py.

One cell per system runs by default; the rest are ``slow`` (CI's slow step). Cells outside
the band are ``xfail(strict=True)`` with their measured value: fixing one fails the test
until its mark goes.
"""

from __future__ import annotations

import pytest
from consistency_cells import HIGH, LOW, band_cells, median_nees

from observer_gym.train.experiments.consistency_study import SYSTEMS

LATENCY_JITTER_S = 0.01
LATENCIES_S = (0.0, 0.08, 0.15)
EPISODES = 3
FAMILIES = {
    "BallTable-v0": ("kf", "kf-latency", "ekf"),
    "TargetFollower-v0": ("kf", "stkf", "kf-latency", "stkf-latency", "ekf"),
    "BallCatcher-v1": ("kf", "ekf", "selfcal", "endpoint"),
}
# Measured outside the band (median of the 3 episodes) and left open: none.
OUTSIDE: dict[tuple[str, str], str] = {}
CELLS = [
    (f"{system}/{family}", f"{latency:g}")
    for system, families in FAMILIES.items()
    for family in families
    for latency in LATENCIES_S
]
DEFAULT_RUN = [
    ("BallTable-v0/kf-latency", "0.15"),
    ("TargetFollower-v0/kf", "0.15"),
    ("BallCatcher-v1/kf", "0.15"),
]


@pytest.mark.parametrize(("observer", "latency"), band_cells(CELLS, OUTSIDE, DEFAULT_RUN))
def test_median_nees_per_dof_is_within_the_band_under_latency(observer, latency):
    system, family = observer.split("/")
    study = SYSTEMS[system]
    env_kwargs = {
        **study.env_kwargs,
        "latency_s": float(latency),
        "latency_jitter_s": LATENCY_JITTER_S,
    }
    ratio = median_nees(
        f"observer_gym/{system}",
        f"{family}-measurements",
        study.controller,
        EPISODES,
        study.steps,
        env_kwargs,
    )
    assert LOW <= ratio <= HIGH, ratio


def test_the_study_sweeps_latency_with_jitter_to_at_least_0_15_s():
    """The consistency study's latency sweep covers what this file checks."""
    from observer_gym.train.experiments.consistency_study import OPTION_ENV_KWARGS, OPTIONS

    assert OPTIONS["latency_s"][0] == 0.0 and max(OPTIONS["latency_s"]) >= 0.15
    assert OPTION_ENV_KWARGS["latency_s"]["latency_jitter_s"] > 0.0
