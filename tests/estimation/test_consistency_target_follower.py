"""TargetFollower's estimating observers say how large their error is (issue 23): median
episode NEES/dof within [1/3, 3] under the sensor options, R x 100 outside; the noise
rule's Q against the target's motion; the self-tuning R; and bursts of false detections
(issue 29 item 10): the gate and the restart bound the recovery, and the covariance
grows while the false detections are rejected.

Cells: 3 episodes (seeds 0-2) x 150 steps, closed loop with the VTC on the observer's own
estimate, perfect-detector measurements. Measured with this code (median of the 3):
0.47-0.69 at 0, 0.5 and 2 px for every observer, 0.42 (stkf-latency) to 0.56 (ekf) at
a latency of 0.1 s, 0.54-0.59 at 20 % drops; its episodes lie within 0.1 of the median.
With R x 100: 0.19-0.26. The band [1/3, 3] is the issue's; the filters sit below 1
because the white acceleration taken for the target's smooth walk overstates its change
over a step (test_process_noise_covers_the_target_motion).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from consistency_cells import (
    CONDITIONS,
    HIGH,
    LOW,
    NOT_POSITIVE,
    assert_r_scale_refused,
    band_cells,
    median_nees,
)

from observer_gym.controllers import make_controller
from observer_gym.envs.target_follower import DETECTED, TARGET_PX, StateIndex
from observer_gym.estimation.observer import default_pipeline
from observer_gym.estimation.target_follower.filters import VisualStateEstimator, VSEParams
from observer_gym.estimation.target_follower.noise import NoiseRule
from observer_gym.estimation.target_follower.observer import RESTART_UPDATES
from observer_gym.train.reports.consistency import nees_per_step

ENV_ID = "observer_gym/TargetFollower-v0"
OBSERVERS = ("kf", "stkf", "kf-latency", "stkf-latency", "ekf")
LATENCY_AWARE = ("kf-latency", "stkf-latency", "ekf")
EPISODES, STEPS = 3, 150
CELLS = [(o, c) for o in OBSERVERS for c in ("0px", "0.5px", "2px", "drops")] + [
    (o, "latency") for o in LATENCY_AWARE
]
# in the default run: one cell per observer family (the rest are slow, 0.3-0.5 s each idle)
DEFAULT_RUN = [("kf", "2px"), ("stkf", "2px"), ("stkf-latency", "latency"), ("ekf", "2px")]


def _median_nees(observer: str, env_kwargs: dict, **options) -> float:
    return median_nees(ENV_ID, observer, "vtc", EPISODES, STEPS, env_kwargs, **options)


@pytest.mark.parametrize(("observer", "condition"), band_cells(CELLS, {}, DEFAULT_RUN))
def test_median_nees_per_dof_is_within_the_band(observer, condition):
    ratio = _median_nees(f"{observer}-measurements", CONDITIONS[condition])
    assert LOW <= ratio <= HIGH, ratio


@pytest.mark.parametrize("observer", OBSERVERS)
@pytest.mark.parametrize("condition", [pytest.param("0px", marks=pytest.mark.slow), "2px"])
def test_a_hundredfold_R_fails_the_band(observer, condition):
    ratio = _median_nees(f"{observer}-measurements", CONDITIONS[condition], r_scale=100.0)
    assert ratio < LOW, ratio


@pytest.mark.slow
@pytest.mark.parametrize("observer", OBSERVERS)
def test_from_rendered_frames_at_the_defaults(observer):
    """The detector's error model (detector_error.json) in R: measured 0.32-0.63 per
    episode, median 0.45-0.46, for every observer."""
    ratio = _median_nees(observer, {})
    assert LOW <= ratio <= HIGH, ratio


@pytest.mark.slow
@pytest.mark.parametrize("observer", ["stkf", "ekf"])
def test_from_rendered_frames_with_image_noise(observer):
    """image_noise_std 32: the detector's error is mostly its bias (d_x -9 %), reported
    in the covariance and left out of R; measured medians 0.57 (stkf), 0.63 (ekf)."""
    ratio = _median_nees(observer, {"image_noise_std": 32.0})
    assert LOW <= ratio <= HIGH, ratio


@pytest.mark.parametrize("bad", NOT_POSITIVE)
def test_r_scale_must_be_a_positive_number(make_env, bad):
    assert_r_scale_refused(make_env(ENV_ID, obs_mode="measurements"), OBSERVERS, bad)


def test_process_noise_covers_the_target_motion(make_env):
    """The rule's Q for the target-induced rate summed over h steps against the rate's
    change over h steps along the truth (random walk, the VTC on the truth): never less,
    at any horizon from 0.1 to 3 s; over 1-3 s (an occlusion) at most ~2x more for the
    horizontal image motion. Measured ratios (x_i^t', y_i^t', d_x^t') at 0.1, 1, 3 s:
    (0.13, 0.03, 0.11), (0.67, 0.19, 0.52), (0.65, 0.19, 0.41) (y_i: the vertical walk
    is 4x slower than the isotropic rule takes it)."""
    env = make_env(ENV_ID, obs_mode="state")
    rule = NoiseRule.for_env(env.unwrapped)
    controller = make_controller("vtc", env)
    runs = []
    for seed in range(2):
        obs, info = env.reset(seed=seed)
        states = [info["state"]]
        for _ in range(300):
            action, _ = controller.predict(obs)
            obs, *_, info = env.step(action)
            states.append(info["state"])
        runs.append(np.array(states))
    for h in (1, 10, 20, 30):
        change, predicted = np.zeros(3), np.zeros(3)
        for states in runs:
            for n in range(len(states) - h):
                change += (states[n + h, 3:6] - states[n, 3:6]) ** 2
                Q = rule.image_Q(states[n, :3], states[n, 12], 0.1, np.zeros(3), np.zeros(3))
                predicted += h * np.diag(Q)[3:]
        ratio = change / predicted
        print(f"\nhorizon {0.1 * h:.1f} s: measured / rule {np.round(ratio, 3)}")
        assert np.all(ratio <= 1.0), (h, ratio)
        if h >= 10:
            assert ratio[0] >= 0.5, (h, ratio)


class _DeclaredNoise:
    """A noise rule stub: R = ``declared`` px^2 on every entry, a small Q."""

    def __init__(self, declared: float) -> None:
        self.declared = declared

    def R(self, z_px, image_rate_pxps=None, rate_cov=None):
        return self.declared * np.eye(3)

    def image_Q(self, X_i, tilt_rad, dt_s, applied, robot_image_rate_pxps):
        return np.diag([0.01, 0.01, 0.01, 1.0, 1.0, 1.0])

    def image_P0(self, z_px, tilt_rad):
        return np.diag([self.declared] * 3 + [100.0] * 3)

    def reported(self, P):
        return P


def _adapted_R(actual_var: float, declared: float, seed: int = 0) -> np.ndarray:
    """R_n's diagonal (steps, 3) of the rule's self-tuning filter on a straight image
    path detected with white noise of variance ``actual_var``."""
    rng = np.random.default_rng(seed)
    params = VSEParams(adaptation="floor")  # the rule's adaptation, no gate
    vse = VisualStateEstimator(params, _DeclaredNoise(declared))
    diagonals = []
    for n in range(400):
        X = np.array([-60.0, 20.0, 30.0]) + np.array([4.0, -2.0, 0.5]) * 0.1 * n
        vse.step(X + rng.normal(0.0, math.sqrt(actual_var), 3), np.zeros((3, 3)), np.zeros(3), 0.1)
        if n >= params.window:
            diagonals.append(np.diag(vse.R).copy())
    return np.array(diagonals)


def test_self_tuning_R_is_the_rule_while_the_noise_is_as_declared_and_follows_more():
    """The register's unbiased variance adapts R when above its 99 % quantile under the
    declared R (2.51 R for k = 10): with the declared noise R stays the rule's on ~99 % of
    the steps per channel; with 9x the declared variance R follows it (its mean within
    20 %)."""
    as_declared = _adapted_R(1.0, 1.0)
    assert np.mean(as_declared == 1.0) > 0.97
    assert np.all(as_declared >= 1.0)
    noisier = _adapted_R(9.0, 1.0)
    assert np.all(np.abs(noisier.mean(axis=0) / 9.0 - 1.0) < 0.2), noisier.mean(axis=0)


# --- bursts of false detections (issue 29 item 10) ---------------------------------------
BURST = (60, 90)  # steps fed garbage: 3 s


def _burst(make_env, observer: str, garbage, obs_mode: str = "measurements", steps: int = 130):
    """Run the env with the VTC on the truth (the world does not depend on the observer)
    and feed ``observer``'s pipeline ``garbage(k, obs, info, rng)`` in place of the
    observation during BURST. Returns per step: NEES/dof, the largest image-state error
    (px), the largest reported image-state std (px), valid, measurement used."""
    env = make_env(ENV_ID, obs_mode=obs_mode)
    pipeline = default_pipeline(env.unwrapped, observer)
    controller = make_controller("vtc", env)
    rng = np.random.default_rng(7)
    obs, info = env.reset(seed=0)
    pipeline.observe(obs, info, None)
    rows = []
    for k in range(1, steps):
        action, _ = controller.predict(info["state"].astype(np.float32))
        obs, _, terminated, _, info = env.step(action)
        assert not terminated
        if BURST[0] <= k < BURST[1]:
            obs = garbage(k, obs, info, rng)
        e = pipeline.observe(obs, info, info["applied_action"])
        nees, dof = nees_per_step([e.mean], [e.covariance], [info["state"]])
        rows.append(
            (
                nees[0] / dof[0],
                np.abs(e.mean[:3] - info["state"][:3]).max(),
                np.sqrt(np.diag(e.covariance)[:3]).max(),
                e.mean[StateIndex.TRACKING_VALID] == 1.0,
                e.measurement_used,
            )
        )
    return np.array(rows, dtype=float)


def _measurement(z: np.ndarray) -> dict:
    return {TARGET_PX: np.asarray(z, np.float32), DETECTED: np.ones(1, np.int8)}


def _scattered(k, obs, info, rng):
    """A detection anywhere on the image, of any size, in every frame."""
    return _measurement([rng.uniform(-159, 159), rng.uniform(-119, 119), rng.uniform(5, 100)])


def _impostor(k, obs, info, rng):
    """Another object, 115 px right of the target and as large, moving with it."""
    return _measurement(np.round(info["state"][:3] + np.array([115.0, 0.0, 0.0])))


def _check_recovery(rows, frames: int) -> None:
    """Back on the target at the burst's ``frames``-th frame after it (the first is step
    BURST[1]), and consistent after it."""
    back = BURST[1] + frames - 2  # rows[k - 1] is step k
    assert rows[back, 3] and rows[back, 1] < 1.0, rows[back]
    after = rows[back:, 0]
    assert LOW <= np.mean(after) <= HIGH, np.mean(after)


@pytest.mark.parametrize("observer", ["kf", "stkf-latency", "ekf"])
def test_scattered_false_detections_are_rejected_and_the_covariance_grows(make_env, observer):
    rows = _burst(make_env, observer, _scattered)
    during = rows[BURST[0] - 1 : BURST[1] - 1]
    print(f"\n{observer}: NEES/dof during {np.round(during[:, 0], 2)}")
    assert not during[:, 4].any()  # no false detection used
    assert np.all(during[:, 0] <= HIGH)  # it never claims less error than it has
    assert during[-1, 2] > 10.0 * rows[BURST[0] - 2, 2]  # and says it grew
    _check_recovery(rows, frames=2)  # a candidate at the first frame, confirmed at the next


@pytest.mark.parametrize("observer", ["kf", "ekf"])
def test_another_objects_burst_costs_a_bounded_recovery(make_env, observer):
    """A consistent impostor is rejected for RESTART_UPDATES frames (the covariance still
    honest), then followed: from one detector's blob nothing tells it from the target.
    After the burst the target is back after RESTART_UPDATES + 1 frames."""
    rows = _burst(make_env, observer, _impostor)
    first = rows[BURST[0] - 1 : BURST[0] - 1 + RESTART_UPDATES]
    assert not first[:, 4].any() and np.all(first[:, 0] <= HIGH)
    _check_recovery(rows, frames=RESTART_UPDATES + 1)


def test_noise_frames_through_the_rgb_pipeline(make_env):
    """Uniform noise images (no orange blob the detector takes): the estimate is predicted
    and its covariance grows (to the reliability threshold, 69 px, after ~3 s); the target
    is back 2 frames after."""

    def noise(k, obs, info, rng):
        return rng.integers(0, 256, obs.shape, dtype=np.uint8)

    rows = _burst(make_env, "stkf", noise, obs_mode="rgb")
    during = rows[BURST[0] - 1 : BURST[1] - 1]
    assert not during[:, 4].any() and np.all(during[:, 0] <= HIGH)
    assert during[-1, 2] > 10.0 * rows[BURST[0] - 2, 2]
    _check_recovery(rows, frames=2)


@pytest.mark.slow
def test_another_envs_frames_through_the_rgb_pipeline(make_env):
    """BallTable's frames (its orange ball): followed after RESTART_UPDATES + 1 frames,
    the target back RESTART_UPDATES + 1 frames after the burst."""
    other = make_env("observer_gym/BallTable-v0", obs_mode="rgb")
    other.reset(seed=0)

    def ball_table(k, obs, info, rng):
        frame, *_ = other.step(np.zeros(other.action_space.shape, np.float32))
        return frame

    rows = _burst(make_env, "stkf", ball_table, obs_mode="rgb")
    first = rows[BURST[0] - 1 : BURST[0] - 1 + RESTART_UPDATES]
    assert not first[:, 4].any() and np.all(first[:, 0] <= HIGH)
    _check_recovery(rows, frames=RESTART_UPDATES + 1)
