"""BallTable's estimating observers say how large their error is (issue 23): median
episode NEES/dof within [1/3, 3] under the sensor options, R x 100 outside; the noise
rule's R against the detections' scatter; the model floors against the simulator.

Cells: 3 episodes (seeds 0-2) x 300 steps with pushes at 0.5 Hz (the consistency study's
conditions), closed loop with the LQR on the observer's own estimate, perfect-detector
measurements. Measured with this code (median of the 3, episodes in brackets): kf and
kf-latency 0.49 (0.70, 0.49, 0.26) at 0 px, 0.85 at 0.5 px, 0.79 at 2 px, 0.44 (0.82,
0.44, 0.29) at 20 % drops; kf 1.01 (1.17, 1.01, 0.75) and kf-latency 0.64 (1.16, 0.64,
0.43) at a latency of 0.1 s (0.84, 0.74 and 0.63 at 0.5 px, 2 px and 0.1 s before their
tilt filter's Q was the arm's measured departure from the lag model); ekf 1.06, 0.51,
0.96, 0.85 and 0.52 at 0.1 s (0.66, 0.46,
1.19, 0.52 and 1.30 before it had kf's lever arm and measured model error). Before kf's
measured model errors (estimation/ball_table/noise.py, "Q"; observer.py,
``measured_model_error``) kf read 0.10, 0.61, 1.94, 0.09 and 0.47, kf-latency the same
and 2.19 at 0.1 s, which was a limit cycle (seeds 0-4: the table's tilt_y swinging at
41-49 mrad RMS over the last 150 steps, the ball 17 mm from the centre on average);
with the tilt_y axis's lever arm in kf's model it settles (0.1-9 mrad, 8.6 mm). ekf's
0.1 s cell is that limit cycle too (40-50 mrad): with the same lever arm in ekf's model
it settles and reads 0.20 (its sigma_w, 0.5 m/s^2, then claims too much); ekf has it
since issue 45, and kf's measured model error with it (0.52 at 0.1 s; 0.17 with the
lever arm alone). ekf has the table centre's translation and its pixel floor is what its
model leaves out, 0.003 px (before: 0.26, 0.45, 1.19, 0.18 and 0.59); under calibration
error (0 px) it reads 0.93 at 1 degree of rotation error and 1.10 at 2 % focal error
(0.63 and 0.70 before the lever arm; 754 and 4.2 in the consistency study before the
translation states: a pose error read as tilt).
With R x 100 at 0 px the ratio falls (the tests below): kf and kf-latency to 0.326
(0.37, 0.326, 0.17; 0.322 before the tilt's measured Q), just below the band's 1/3,
because at 0 px R governs only the ball's position and the tilt: the ball's velocity is
the pushes' (Q) and the tilt rate's variance its model error's.
On perfect pixels kf's tilt reads 0.03-0.04 per dof (2 of the 8; 0.005 before its Q was
the arm's measured departure from the lag model, 0.001 under latency): the geometry
stage's floor on the ball, 3e-5 m, is twice its RMS (0.016 and 0.008 mm on x and y over 20
episodes), and both it and the declared float32 rounding of the pixels (2^-13 px /
sqrt(12), the spacing of float32 at 1024-2048 px, where a 320 x 240 image needs 2^-15)
are larger than the errors they stand for; both cover what kf's calibration report
leaves out under a focal error: with the ball's RMS per axis as its floor and the
rounding of a 320 px coordinate, kf read 0.22 at 0 px in the study (0.10 then), and 17
and 104 at 2 % and 5 % focal error (1.9 and 12). With these floors, since kf's tilt
filter carries the calibration's tilt offset as states, 0.57 and 0.64
(test_ball_table_kf_calibration.py); tightened floors were not measured since.

Cells outside the band are marked ``xfail(strict=True)`` with their measured value (none
now), so that fixing one makes the test fail until the mark goes.
"""

from __future__ import annotations

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
from observer_gym.envs.ball_table.geometry import TABLE_CENTRE_HOME_WORLD, up_in_table
from observer_gym.envs.ball_table.layout import CORNERS_PX
from observer_gym.estimation import VisionObserver
from observer_gym.estimation.ball_table import pixel_ekf
from observer_gym.estimation.ball_table.features import (
    RED_TOP,
    BallTableFeatures,
    features_from_measurement,
)
from observer_gym.estimation.ball_table.geometry_stage import (
    BallTableDetector,
    model_corners_table,
)
from observer_gym.estimation.ball_table.models import (
    KF_ROTATION_HEIGHTS_M,
    RollingBallModel,
    TiltLagModel,
)
from observer_gym.estimation.ball_table.noise import (
    KF_ACCEL_FLOOR_MPS2,
    PERFECT_PIXELS_BALL_STD_M,
    BallTableNoiseRule,
    motion_accel_var,
)
from observer_gym.estimation.ball_table.observer import (
    TILT_RATE_MODEL_STD_RADPS,
    rate_model_var,
)
from observer_gym.estimation.ball_table.pixel_ekf import (
    MEASUREMENT_FLOOR_PX,
    T_world_table,
    project,
)

ENV_ID = "observer_gym/BallTable-v0"
OBSERVERS = ("kf", "kf-latency", "ekf")
LATENCY_AWARE = ("kf-latency", "ekf")
# The consistency study's conditions (train/experiments/consistency_study.py): 300 steps
# with pushes at 0.5 Hz. (At 150 steps the swings of the first ~15 steps weigh twice as
# much in each episode's mean: kf's 0 px cell then reads 0.15, not 0.10.)
EPISODES, STEPS = 3, 300
STUDY_KWARGS = {"push_rate_hz": 0.5}
# Measured outside the band (median of the 3 episodes) and left open: none.
OUTSIDE: dict[tuple[str, str], str] = {}
CELLS = [(o, c) for o in OBSERVERS for c in ("0px", "0.5px", "2px", "drops")] + [
    (o, "latency") for o in ("kf", *LATENCY_AWARE)
]
# in the default run: one cell per observer family (the rest are slow: 6-15 s each at
# load 7)
DEFAULT_RUN = [("kf", "2px"), ("kf-latency", "latency"), ("ekf", "2px")]


def _median_nees(observer: str, env_kwargs: dict, **options) -> float:
    kwargs = {**STUDY_KWARGS, **env_kwargs}
    return median_nees(ENV_ID, observer, "lqr", EPISODES, STEPS, kwargs, **options)


@pytest.mark.parametrize(("observer", "condition"), band_cells(CELLS, OUTSIDE, DEFAULT_RUN))
def test_median_nees_per_dof_is_within_the_band(observer, condition):
    ratio = _median_nees(f"{observer}-measurements", CONDITIONS[condition])
    assert LOW <= ratio <= HIGH, ratio


CALIBRATION = {
    "rotation 1 deg": {"calib_rotation_error_deg": 1.0},
    "focal 2 %": {"calib_focal_error": 0.02},
}


@pytest.mark.parametrize(  # the rotation cell (3.2 s at load 2) in the slow step
    "condition",
    [
        pytest.param(c, marks=pytest.mark.slow) if c.startswith("rotation") else c
        for c in CALIBRATION
    ],
)
def test_ekf_is_within_the_band_under_calibration_error(condition):
    """The pixel EKF absorbs a camera pose error as the table's translation and reports
    the rest (estimation/ball_table/pixel_ekf.py, fit_calibration_cov): measured 0.93
    (episodes 0.93, 1.34, 0.93) at 1 degree, 1.10 (1.82, 1.10, 0.73) at 2 % (0.63 and 0.70
    before ekf had the arm's lever arm)."""
    ratio = _median_nees("ekf-measurements", CALIBRATION[condition])
    assert LOW <= ratio <= HIGH, ratio


def test_a_hundredfold_R_fails_the_focal_cell():
    """Measured 0.25 (episodes 0.27, 0.25, 0.18). At 1 degree of rotation R x 100 stays in
    the band (0.48): there the reported calibration offset, which R does not scale,
    dominates the tilt's covariance; the next test holds that cell to its report."""
    ratio = _median_nees("ekf-measurements", CALIBRATION["focal 2 %"], r_scale=100.0)
    assert ratio < LOW, ratio


def test_without_the_calibration_report_the_rotation_cell_fails(monkeypatch):
    """The reported calibration offset is what keeps the rotation cell in the band: without
    it the tilt's constant offset (about 10 mrad) is unclaimed (measured 15490)."""
    monkeypatch.setattr(pixel_ekf, "fit_calibration_cov", lambda *args: None)
    ratio = _median_nees("ekf-measurements", CALIBRATION["rotation 1 deg"])
    assert ratio > HIGH, ratio


@pytest.mark.parametrize(  # kf in the default run; the others (1.5 s each idle) slow
    "observer", [o if o == "kf" else pytest.param(o, marks=pytest.mark.slow) for o in OBSERVERS]
)
def test_a_hundredfold_R_fails_the_band(observer):
    ratio = _median_nees(f"{observer}-measurements", CONDITIONS["0px"], r_scale=100.0)
    assert ratio < LOW, ratio


@pytest.mark.parametrize("bad", NOT_POSITIVE)
def test_r_scale_must_be_a_positive_number(make_env, bad):
    assert_r_scale_refused(make_env(ENV_ID, obs_mode="measurements"), OBSERVERS, bad)


def test_R_is_the_scatter_of_the_detections_under_pixel_noise(make_env):
    """The rule's R = sigma^2 J J^T (the geometry stage linearised) against the scatter of
    400 detections of one frame's pixels with Gaussian noise of 0.5 px added: R covers
    each variance and claims at most twice it (measured: the scatter is 67-82 % of R; the
    stage refuses 16 % of the noisy frames, its largest errors among them, because the
    noisy radius no longer fits the ball's distance)."""
    env = make_env(ENV_ID, obs_mode="measurements", measurement_noise_px=0.5)
    obs, info = env.reset(seed=3)
    for _ in range(10):
        obs, *_, info = env.step(np.array([0.04, -0.02], np.float32))
    frame = info["frames"][-1]
    K, T_world_cam = np.asarray(frame["K"]), np.asarray(frame["T_world_cam"])
    features = features_from_measurement(obs)
    detector = BallTableDetector()
    rule = BallTableNoiseRule(env.unwrapped.sensor_spec, False, detector, (0.0, 0.0), 0.0)
    R_tilt, R_ball = rule.detection_R(features, K, T_world_cam)
    rng = np.random.default_rng(0)
    found = []
    for _ in range(400):
        corners = features.corners_px + rng.normal(0.0, 0.5, (4, 2))
        ball = features.ball_px + rng.normal(0.0, 0.5, 3)
        noisy = BallTableFeatures(corners, ball, RED_TOP, source="measurement")
        detection = detector.detect(noisy, K, T_world_cam)
        if detection.table_found and detection.ball_found:
            found.append(np.concatenate([detection.tilt_rad, detection.ball_pos_table_m]))
    found = np.array(found)
    assert len(found) > 300  # the stage refuses some (a ball size that does not fit)
    scatter = np.var(found, axis=0)
    predicted = np.concatenate([np.diag(R_tilt), np.diag(R_ball)])
    ratio = scatter / predicted
    print(f"\nscatter / R: {ratio}")
    assert np.all((ratio > 0.5) & (ratio < 1.1)), ratio


def test_the_model_floors_cover_the_sim(make_env):
    """What the models leave out, measured on perfect pixels (0 px) over 3 episodes of the
    LQR on the truth with pushes at 0.5 Hz: the geometry stage's ball error and the tilt
    rate's departure from the lag model, each RMS at most 25 % above its floor and each
    floor at most 3x its RMS (measured RMS: 0.015 mm, 4-5 mrad/s);
    and the table corners' departure from ekf's model at the true tilt and the
    simulator's table centre, whose floor lies between their RMS and 99th percentile
    (measured 0.0010 and 0.0049 px; 0.052 px RMS from a table held at its home centre,
    the floor before ekf had the centre's translation)."""
    state_env = make_env(ENV_ID, obs_mode="state")
    env = make_env(ENV_ID, obs_mode="measurements", push_rate_hz=0.5)
    pipeline = VisionObserver(env, observer="kf").pipeline
    controller = make_controller("lqr", state_env)
    tilt_model = pipeline.tilt_model
    detector = BallTableDetector()
    corners_table = model_corners_table(RED_TOP)
    ball_err, rate_err, corner_err = [], [], []
    for seed in range(3):
        obs, info = env.reset(seed=seed)
        for _ in range(200):
            action, _ = controller.predict(np.asarray(info["state"], np.float32))
            obs, _, terminated, truncated, info = env.step(action)
            x = info["state"]
            rate_err.append(x[6:8] - tilt_model.rate(x[4:6], np.asarray(info["applied_action"])))
            if info["frames"]:
                frame = info["frames"][-1]
                K, T_world_cam = np.asarray(frame["K"]), np.asarray(frame["T_world_cam"])
                detection = detector.detect(features_from_measurement(obs), K, T_world_cam)
                if detection.ball_found:
                    ball_err.append(detection.ball_pos_table_m - x[:2])
                centre = env.unwrapped.scene.table_pose()[:3, 3] - TABLE_CENTRE_HOME_WORLD
                T = T_world_table(x[4:6], centre)
                modelled, _ = project(K, T_world_cam, corners_table @ T[:3, :3].T + T[:3, 3])
                corner_err.append(np.asarray(obs[CORNERS_PX]).reshape(4, 2) - modelled)
            if terminated or truncated:
                break
    for errors, floor in [
        (ball_err, PERFECT_PIXELS_BALL_STD_M),
        (rate_err, TILT_RATE_MODEL_STD_RADPS),
    ]:
        rms = float(np.sqrt(np.mean(np.square(errors))))
        print(f"\nRMS {rms:.3g}, floor {floor:.3g}")
        assert rms <= 1.25 * floor and floor <= 3.0 * rms
    corner_rms = float(np.sqrt(np.mean(np.square(corner_err))))
    corner_p99 = float(np.percentile(np.abs(corner_err), 99))
    print(f"\ncorners: RMS {corner_rms:.3g}, 99th pct {corner_p99:.3g} px")
    assert corner_rms <= MEASUREMENT_FLOOR_PX <= corner_p99


@pytest.mark.slow
@pytest.mark.parametrize("observer", OBSERVERS)
def test_from_rendered_frames_at_the_defaults(observer):
    """The rgb detector's measured errors in R (kf: 0.3 mm and 3.5 / 1.0 mrad; ekf: the
    image stage's pixel errors): measured medians 0.87 (kf, kf-latency: from rendered
    frames without the measured model error, which read 2.15 and left the LQR 1.2 mm off
    the centre at rest), 0.44 (ekf)."""
    ratio = median_nees(ENV_ID, observer, "lqr", EPISODES, 150, {})
    assert LOW <= ratio <= HIGH, ratio


@pytest.mark.parametrize("push_rate_hz", [0.0, 0.5])
def test_kf_model_error_variances_claim_the_sim(make_env, push_rate_hz):
    """kf's variance models of what its models leave out against the simulator, 3 episodes
    of 300 steps of the LQR on the truth: the rolling model's acceleration error (with
    kf's rotation heights) against KF_ACCEL_FLOOR_MPS2^2 + motion_accel_var, without
    pushes (a push is the push term's), and the tilt rate's departure from g (u - theta)
    against rate_model_var, with and without: mean(e^2) / mean(sigma^2) per axis within
    the band (measured: acceleration 0.99 and 0.46 on x and y; the rate 0.99 and 1.02
    with pushes, 0.98 and 1.02 without). Over 10 episodes, by window
    (``python benchmarks/ball_table_model_error.py``), the acceleration model claims 1.3
    and 0.8 of the error in the first 15 steps, 0.7 and 0.01 in steps 15-50, and far
    more than the calm error after (its floor is the error while the table settles;
    estimation/ball_table/noise.py); the rate's, whose floors are sized with pushes, 0.2
    of the calm error without them."""
    env = make_env(ENV_ID, obs_mode="state", push_rate_hz=push_rate_hz)
    cfg = env.unwrapped.config
    lag = TiltLagModel.from_arm(cfg.arm_position_gain, cfg.physics_dt_s, 0.0)
    Phi, Gamma, _ = lag.matrices(cfg.dt_s)
    controller = make_controller("lqr", env)
    dt_s = cfg.dt_s
    accel_err, accel_var, rate_err, rate_var = [], [], [], []
    for seed in range(3):
        _, info = env.reset(seed=seed)
        x, command = info["state"], np.zeros(2)
        lag_tilt = np.array(x[4:6], dtype=float)
        for _ in range(300):
            action, _ = controller.predict(np.asarray(x, np.float32))
            _, _, terminated, truncated, info = env.step(action)
            x_next, applied = info["state"], np.asarray(info["applied_action"], float)
            lag_next = Phi @ lag_tilt + Gamma @ applied
            rate0, rate1 = lag.rate(lag_tilt, command), lag.rate(lag_next, applied)
            mid_tilt = 0.5 * (x[4:6] + x_next[4:6])
            gravity = RollingBallModel.gravity_acceleration(up_in_table(*mid_tilt))
            turned = RollingBallModel.rotation_increment(
                rate0, rate1, lag_next - lag_tilt, dt_s, KF_ROTATION_HEIGHTS_M
            )
            accel_err.append((x_next[2:4] - x[2:4] - turned[2:4]) / dt_s - gravity)
            alpha = (rate1 - rate0) / dt_s
            accel_var.append(
                KF_ACCEL_FLOOR_MPS2**2 + motion_accel_var(alpha, 0.5 * (rate0 + rate1))
            )
            rate_err.append(x_next[6:8] - lag.rate(x_next[4:6], applied))
            rate_var.append(rate_model_var(rate1))
            x, command, lag_tilt = x_next, applied, lag_next
            if terminated or truncated:
                break
    pairs = [(rate_err, rate_var)] + ([(accel_err, accel_var)] if push_rate_hz == 0.0 else [])
    for errors, variances in pairs:
        ratio = np.mean(np.square(errors), axis=0) / np.mean(variances, axis=0)
        print(f"\nmean(e^2) / mean(sigma^2): {ratio}")
        assert np.all((LOW <= ratio) & (ratio <= HIGH)), ratio
