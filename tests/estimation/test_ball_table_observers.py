"""BallTable's observer family (estimation/ball_table: ``kf``, ``kf-latency``, ``ekf``,
``raw``, ``oracle-visible``) against the simulator's ground truth and against each other.

Every pipeline of a run watches the same episode: the actions come from test_observer.py's
PD law that makes the ball circle, here on the true state, so the observers do not steer
the ball and their errors are comparable step by step.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from test_observer import circle_tracking_action

import observer_gym.envs  # noqa: F401  (registers the envs)
from observer_gym.envs.ball_table import STATE_DIM
from observer_gym.envs.ball_table import geometry as geo
from observer_gym.envs.ball_table.layout import BALL_PX, CORNERS_PX, DETECTED
from observer_gym.envs.camera import sphere_image
from observer_gym.estimation import VisionObserver, default_pipeline
from observer_gym.estimation.ball_table import OBSERVERS
from observer_gym.estimation.ball_table.frames import detected_parts
from observer_gym.estimation.ball_table.noise import BallTableNoiseRule, ball_process_params
from observer_gym.estimation.ball_table.observer import (
    RGB_BALL_STD_M,
    BallTableObserverParams,
    Fused,
    TiltBallDetection,
    TiltBallFilters,
)
from observer_gym.estimation.ball_table.pixel_ekf import (
    PixelMeasurement,
    ball_pixel,
    corner_pixels,
    gravity_jacobian,
    project,
)
from observer_gym.estimation.ekf import numerical_jacobian

ENV_ID = "observer_gym/BallTable-v0"
DT_S = 0.02
SKIP = 25  # the first 0.5 s: velocities start from zero


def watch(names, steps, seed=0, change=None, **env_kwargs):
    """Run one episode; every observer in ``names`` watches it. Returns the truth (T, 8),
    the estimates {name: [Estimate]} and the per-step infos. ``change(k, obs)`` may alter
    the observation the observers get at step k."""
    env = gym.make(ENV_ID, **env_kwargs).unwrapped
    try:
        pipelines = {name: default_pipeline(env, name) for name in names}
        obs, info = env.reset(seed=seed)
        estimates = {name: [p.observe(obs, info, None)] for name, p in pipelines.items()}
        truth, infos = [info["state"]], [info]
        for k in range(steps):
            action = circle_tracking_action(k * DT_S, info["state"], phase=0.5)
            obs, _, terminated, _, info = env.step(action)
            seen = obs if change is None else change(k, obs)
            for name, pipeline in pipelines.items():
                estimates[name].append(pipeline.observe(seen, info, info["applied_action"]))
            truth.append(info["state"])
            infos.append(info)
            assert not terminated
    finally:
        env.close()
    return np.array(truth), estimates, infos


def rmse(estimates, truth, part) -> float:
    mean = np.array([e.mean for e in estimates])
    return float(np.sqrt(np.mean(np.sum((mean[SKIP:, part] - truth[SKIP:, part]) ** 2, axis=1))))


# --- every observer -------------------------------------------------------------------
# (the learned observers, the network centimetres off at a 30 % drop rate, have their own
# tests: tests/estimation/test_learned_ball_table.py, test_learned_frames.py)
@pytest.mark.parametrize("obs_mode", ["measurements", "rgb"])
@pytest.mark.parametrize("name", [name for name in OBSERVERS if not name.startswith("learned")])
def test_every_observer_gives_the_state_layout(name, obs_mode):
    env = VisionObserver(gym.make(ENV_ID, obs_mode=obs_mode, frame_drop_prob=0.3), observer=name)
    try:
        assert env.observation_space == env.unwrapped.state_space
        estimate, info = env.reset(seed=1)
        for _ in range(8):
            estimate, *_, info = env.step(np.full(2, 0.02, np.float32))
            assert estimate in env.observation_space
            mean, cov = info["estimate"]["mean"], info["estimate"]["covariance"]
            assert mean.shape == (STATE_DIM,) and cov.shape == (STATE_DIM, STATE_DIM)
            assert np.all(np.isfinite(mean)) and np.allclose(cov, cov.T)
            assert np.all(np.linalg.eigvalsh(cov) >= -1e-12)
            assert np.linalg.norm(mean[0:2] - info["state"][0:2]) < 0.01
    finally:
        env.close()


def test_an_unknown_observer_is_refused_naming_the_allowed():
    env = gym.make(ENV_ID, obs_mode="measurements")
    try:
        with pytest.raises(ValueError, match="allowed: kf, kf-latency, ekf, raw, oracle-visible"):
            VisionObserver(env, observer="ukf")
    finally:
        env.close()


@pytest.mark.parametrize("bad", [np.nan, np.inf, 1e308])
@pytest.mark.parametrize("name", list(OBSERVERS))
def test_non_finite_pixels_are_no_detection_for_every_observer(name, bad):
    def corrupt(k, obs):
        if k not in (3, 4, 5):
            return obs
        corners, ball = (np.array(obs[key], dtype=float) for key in (CORNERS_PX, BALL_PX))
        corners[k % 8], ball[k % 3] = bad, bad
        return {**obs, CORNERS_PX: corners, BALL_PX: ball}

    _, estimates, _ = watch([name], 10, obs_mode="measurements", change=corrupt)
    for e in estimates[name]:
        assert np.all(np.isfinite(e.mean)) and np.all(np.isfinite(e.covariance))


def test_an_old_frame_delivered_again_is_not_fused_twice():
    """With latency jitter a step can deliver only a frame older than the newest one seen;
    the observation is then the newest again, which the filter has already fused."""
    env = gym.make(ENV_ID, obs_mode="measurements").unwrapped
    try:
        pipeline, reference = default_pipeline(env, "kf"), default_pipeline(env, "kf")
        obs, info = env.reset(seed=0)
        pipeline.observe(obs, info, None), reference.observe(obs, info, None)
        zero = np.zeros(2, np.float32)
        obs, *_, info = env.step(zero)
        pipeline.observe(obs, info, zero), reference.observe(obs, info, zero)
        obs, *_, info = env.step(zero)
        stale = {**info, "frames": [{**info["frames"][0], "capture_time_s": 0.01}]}
        got = pipeline.observe(obs, stale, zero)
        want = reference.observe(obs, {**info, "frames": []}, zero)
        assert not got.measurement_used and got.measurement is None
        np.testing.assert_array_equal(got.mean, want.mean)
    finally:
        env.close()


# --- raw ------------------------------------------------------------------------------
def test_raw_is_the_detection_itself_with_differenced_velocities():
    """No filter lag: raw's position and tilt are the detection's (so its error is the
    detection's error), its velocity the difference of the last two detections."""
    truth, estimates, infos = watch(["raw", "kf"], 60, obs_mode="measurements", frame_drop_prob=0.2)
    raw, previous, errors = estimates["raw"], None, []
    for k, e in enumerate(raw):
        tilt, ball = detected_parts(e.measurement)
        if ball is None:  # a dropped frame: the last detection held
            assert k > 0 and np.array_equal(e.mean, raw[k - 1].mean)
            continue
        errors.append(ball - truth[k, 0:2])
        np.testing.assert_array_equal(e.mean[0:2], ball)
        np.testing.assert_array_equal(e.mean[4:6], tilt)
        capture_s = infos[k]["frames"][-1]["capture_time_s"]
        if previous is not None:
            (last_ball, last_tilt, last_s) = previous
            np.testing.assert_allclose(e.mean[2:4], (ball - last_ball) / (capture_s - last_s))
            np.testing.assert_allclose(e.mean[6:8], (tilt - last_tilt) / (capture_s - last_s))
        previous = (ball, tilt, capture_s)
    # Perfect features: the detection is exact to 0.2 mm (geometry stage), so is raw when
    # it has one; held through a drop, it lags by the ball's travel (~0.8 mm per frame).
    assert len(errors) > 40 and np.abs(errors).max() < 2e-4
    assert 2e-4 < rmse(raw, truth, slice(0, 2)) < 1e-3


# --- kf-latency -----------------------------------------------------------------------
@pytest.mark.parametrize(
    ("obs_mode", "steps", "options"),
    [
        ("measurements", 200, {}),
        (
            "measurements",
            200,
            {"frame_drop_prob": 0.2, "occluder_rate_hz": 0.5, "measurement_noise_px": 1.0},
        ),
        ("rgb", 60, {"frame_drop_prob": 0.2}),
    ],
)
def test_kf_latency_is_kf_at_zero_latency_bit_for_bit(obs_mode, steps, options):
    _, estimates, _ = watch(["kf", "kf-latency"], steps, obs_mode=obs_mode, **options)
    for a, b in zip(estimates["kf"], estimates["kf-latency"], strict=True):
        assert np.array_equal(a.mean, b.mean) and np.array_equal(a.covariance, b.covariance)
        assert a.measurement_used == b.measurement_used and a.nis == b.nis


def offline_kf_latency(pipeline, infos, measurements, k):
    """The estimate at step k of a filter that fuses every measurement delivered by step k
    at its capture time, in capture order, from the start: ``kf``'s filters driven by
    hand, for comparison with the rewind-and-replay of ``kf-latency``."""
    first = measurements[0]
    core = TiltBallFilters(
        pipeline.params,
        pipeline.ball_model,
        pipeline.tilt_model,
        infos[0]["time_s"],
        *(first[:2] if first is not None else (None, None)),
        start_R=first[2:] if first is not None else (None, None),
    )
    step_times = [info["time_s"] for info in infos[: k + 1]]
    events = [(t, 1, j, None) for j, t in enumerate(step_times[1:], start=1)]
    for j in range(1, k + 1):
        if measurements[j] is not None:
            capture_s = infos[j]["frames"][-1]["capture_time_s"]
            events.append((capture_s, 0, j, measurements[j]))
    events.sort(key=lambda e: (e[0], e[1]))
    for time_s, _, _, value in events:
        interval = int(np.searchsorted(step_times, time_s - 1e-9))  # (t_{i-1}, t_i] holds it
        if interval > 0:
            core.predict_to(time_s, infos[interval]["applied_action"])
        if value is not None:
            core.update(Fused(value))
    core.predict_to(step_times[-1], None)
    return core.mean(), core.covariance()


@pytest.mark.parametrize(("latency_s", "jitter_s"), [(0.06, 0.0), (0.05, 0.02)])
def test_kf_latency_fuses_each_frame_at_its_capture_time(latency_s, jitter_s, monkeypatch):
    options = {"latency_s": latency_s, "latency_jitter_s": jitter_s, "frame_drop_prob": 0.1}
    # the R the noise rule gave each of kf-latency's frames (its rule has no timing term)
    given_R = []
    detection_R = BallTableNoiseRule.detection_R

    def recording(rule, *args):
        R = detection_R(rule, *args)
        if rule.age_sq_s2 == 0.0:
            given_R.append(R)
        return R

    monkeypatch.setattr(BallTableNoiseRule, "detection_R", recording)
    _, estimates, infos = watch(["kf", "kf-latency"], 150, obs_mode="measurements", **options)
    env = gym.make(ENV_ID, obs_mode="measurements", **options).unwrapped
    pipeline = default_pipeline(env, "kf-latency")
    env.close()
    frames_R = iter(given_R)
    measurements = [
        None
        if e.measurement is None
        else TiltBallDetection(*detected_parts(e.measurement), *next(frames_R))
        for e in estimates["kf-latency"]
    ]
    for k in range(0, 151, 10):
        mean, cov = offline_kf_latency(pipeline, infos, measurements, k)
        aware = estimates["kf-latency"][k]
        np.testing.assert_allclose(aware.mean, mean, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(aware.covariance, cov, rtol=1e-9, atol=1e-15)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_with_latency_the_capture_time_filters_are_far_better(seed):
    """80 ms of latency, perfect features: kf's position error is the ball's travel over the
    latency (it circles at ~4 cm/s: measured 2.3-4.5 mm, as raw's), kf-latency's and ekf's
    their filters' own (measured 0.009-0.013 and 0.016-0.045 mm over seeds 0-2)."""
    names = ["kf", "kf-latency", "ekf", "raw"]
    truth, estimates, _ = watch(names, 100, seed=seed, obs_mode="measurements", latency_s=0.08)
    error = {name: rmse(estimates[name], truth, slice(0, 2)) for name in names}
    print(f"\nseed {seed}: " + ", ".join(f"{n} {e * 1e3:.3f} mm" for n, e in error.items()))
    assert error["kf"] > 2e-3 and error["raw"] > 2e-3
    assert error["kf-latency"] < 0.02 * error["kf"]
    assert error["ekf"] < 0.05 * error["kf"]


# --- ekf ------------------------------------------------------------------------------
def _frame_measurement(seed=0):
    env = gym.make(ENV_ID, obs_mode="measurements").unwrapped
    try:
        env.reset(seed=seed)
        obs, *_, info = env.step(np.array([0.05, -0.03], np.float32))
        for _ in range(20):
            obs, *_, info = env.step(np.array([0.05, -0.03], np.float32))
    finally:
        env.close()
    return obs, info


def test_the_pixel_model_is_the_envs_projection():
    obs, info = _frame_measurement()
    frame, state = info["frames"][-1], info["state"]
    K, T_world_cam = frame["K"], frame["T_world_cam"]
    # The table's pose from the tilt and the centre's offset from home (the arm holds the
    # centre to 0.02 mm, settled).
    T_table = info["T_world_table"]
    np.testing.assert_allclose(T_table[:3, 3], geo.TABLE_CENTRE_HOME_WORLD, atol=3e-5)
    centre = T_table[:3, 3] - geo.TABLE_CENTRE_HOME_WORLD
    x = np.concatenate([state[0:4], np.zeros(2), state[4:6], centre, np.zeros(3)])
    m = PixelMeasurement(
        K, T_world_cam, geo.TABLE_CORNERS_TABLE, np.zeros((4, 2)), np.ones(4), None, 1.0
    )
    h_corners, _ = corner_pixels(x, m)
    np.testing.assert_allclose(h_corners, obs[CORNERS_PX], atol=0.01)
    h_ball, _ = ball_pixel(x, m)
    np.testing.assert_allclose(h_ball, obs[BALL_PX][:2], atol=0.01)
    # The ellipse centre in closed form is sphere_image's, exactly.
    centre = T_table[:3, :3] @ np.array([0.05, -0.04, geo.BALL_RADIUS_M]) + T_table[:3, 3]
    uv, _ = project(K, T_world_cam, centre[None], geo.BALL_RADIUS_M)
    np.testing.assert_allclose(uv[0], sphere_image(K, T_world_cam, centre, geo.BALL_RADIUS_M)[0])


def test_the_pixel_models_jacobians_are_its_derivatives():
    _, info = _frame_measurement()
    frame = info["frames"][-1]
    m = PixelMeasurement(
        frame["K"],
        frame["T_world_cam"],
        geo.TABLE_CORNERS_TABLE,
        np.zeros((4, 2)),
        np.ones(4),
        None,
        1.0,
    )
    ball, tilt, centre = [0.04, -0.06, 0.1, 0.2, 0.0, 0.0], [0.07, -0.05], [0.003, -0.002, 0.004]
    x = np.array(ball + tilt + centre + [1e-4, 0.0, -2e-4])
    for model in (corner_pixels, ball_pixel):
        _, H = model(x, m)
        numeric = numerical_jacobian(lambda v, model=model: model(v, m)[0], x, 1e-7)
        np.testing.assert_allclose(H, numeric, rtol=1e-6, atol=1e-4)  # px per unit of state
    from observer_gym.estimation.ball_table.models import RollingBallModel

    def accel(t):
        return RollingBallModel.gravity_acceleration(geo.up_in_table(*t))

    tilt = np.array([0.07, -0.05])
    np.testing.assert_allclose(
        gravity_jacobian(*tilt), numerical_jacobian(accel, tilt, 1e-7), rtol=1e-7, atol=1e-9
    )


def test_ekf_predicts_as_kf_does():
    """The same process model: with nothing measured, the EKF's mean follows the
    prediction of kf with kf's measured model errors (``measured_model_error``: the
    tilt_y axis's extra height, which ekf has too since issue 45; the rest of it sets
    only kf's covariance) (tilt through the arm's lag, the ball with the trapezoid's
    gravity and the table's angular acceleration)."""
    env = gym.make(ENV_ID, obs_mode="measurements").unwrapped
    try:
        params = BallTableObserverParams(
            ball=ball_process_params(env.config, RGB_BALL_STD_M), measured_model_error=True
        )
        kf = default_pipeline(env, "kf", params=params)
        ekf = default_pipeline(env, "ekf")
        obs, info = env.reset(seed=0)
        kf.observe(obs, info, None), ekf.observe(obs, info, None)
        ekf.core.ekf.x = np.concatenate([kf.core.ball_kf.x, kf.core.tilt_kf.x, np.zeros(6)])
        ekf.core._lag_tilt = kf.core._lag_tilt.copy()  # the rotation term's command-driven tilt
        rng = np.random.default_rng(0)
        for k in range(1, 40):
            blind = {"time_s": k * DT_S, "frames": []}
            action = rng.uniform(-0.1, 0.1, 2)
            a, b = kf.observe(None, blind, action), ekf.observe(None, blind, action)
            np.testing.assert_allclose(b.mean, a.mean, rtol=1e-12, atol=1e-15)
    finally:
        env.close()


def test_ekf_from_perfect_pixels_is_nearly_exact():
    truth, estimates, _ = watch(["ekf"], 250, obs_mode="measurements")
    ekf = estimates["ekf"]
    assert all(e.measurement_used for e in ekf)
    assert rmse(ekf, truth, slice(0, 2)) < 1e-4  # measured 0.02 mm
    assert rmse(ekf, truth, slice(4, 6)) < 5e-4  # measured 0.14 mrad


def test_ekf_drops_the_corners_it_does_not_see():
    """A NaN corner leaves the others: 3 corners and the ball still update the filter."""

    def hide_a_corner(k, obs):
        corners = np.array(obs[CORNERS_PX])
        corners[2 * (k % 4)] = np.nan
        return {**obs, CORNERS_PX: corners}

    truth, estimates, _ = watch(["ekf"], 100, obs_mode="measurements", change=hide_a_corner)
    ekf = estimates["ekf"]
    assert [e.nis_dof for e in ekf[1:]] == [8] * 100  # 3 corners (6) and the ball (2)
    assert rmse(ekf, truth, slice(4, 6)) < 5e-4


def test_ekf_keeps_the_ball_when_the_table_is_hidden():
    """No table corners: kf (PnP) has no ball position; the EKF still fuses the ball's
    pixel with the predicted tilt."""

    def hide_the_table(k, obs):
        if not 40 <= k < 90:
            return obs
        return {**obs, DETECTED: np.array([0, obs[DETECTED][1]], np.int8)}

    truth, estimates, _ = watch(["kf", "ekf"], 120, obs_mode="measurements", change=hide_the_table)
    during = slice(41, 91)
    kf_used = [e.measurement_used for e in estimates["kf"][during]]
    ekf_dof = [e.nis_dof for e in estimates["ekf"][during]]
    assert not any(kf_used) and ekf_dof == [2] * 50
    errors = {
        name: np.linalg.norm([e.mean[0:2] for e in est[during]] - truth[during, 0:2], axis=1)
        for name, est in estimates.items()
    }
    # kf predicts from the commanded tilt alone meanwhile (measured max 0.09 mm, the EKF's
    # 0.06 mm)
    assert errors["ekf"].max() < 5e-4 and errors["kf"].max() > errors["ekf"].max()


# long pixel episodes (4.4 s idle): slow; the pixel EKF's closed loop on frames stays in the
# default run (tests/controllers/test_closed_loop.py)
@pytest.mark.slow
def test_ekf_from_pixels_beats_the_pnp_pipeline_on_position():
    """From rendered frames (6 s): the EKF's position and tilt errors are below kf's (no
    PnP of a square seen nearly head-on), its velocity error like kf's, far below raw's;
    both filters' NIS per dimension is plausible (kf's tilt noise is set cautiously).
    From rendered frames kf keeps sigma_w = 0.5 m/s^2 at every step (its measured model
    error is for measurements only: estimation/ball_table/observer.py)."""
    truth, estimates, _ = watch(["kf", "ekf", "raw"], 300, obs_mode="rgb")
    pos = {name: rmse(est, truth, slice(0, 2)) for name, est in estimates.items()}
    vel = {name: rmse(est, truth, slice(2, 4)) for name, est in estimates.items()}
    tilt = {name: rmse(est, truth, slice(4, 6)) for name, est in estimates.items()}
    err = np.array([e.mean[0:4] for e in estimates["ekf"]]) - truth[:, 0:4]
    cov = np.array([e.covariance[0:4, 0:4] for e in estimates["ekf"]])
    nees = np.einsum("ki,kij,kj->k", err[SKIP:], np.linalg.inv(cov[SKIP:]), err[SKIP:])
    print(
        "\n"
        + "\n".join(
            f"{n:4s} position {pos[n] * 1e3:.3f} mm, velocity {vel[n] * 1e3:.2f} mm/s, "
            f"tilt {tilt[n] * 1e3:.2f} mrad"
            for n in pos
        )
        + f"\nekf average NEES (4 dof) {nees.mean():.2f}"
        + "".join(f", {n} NIS per dof {nis_per_dof(estimates[n]):.2f}" for n in ("kf", "ekf"))
    )
    assert pos["ekf"] < 0.5 * pos["kf"]  # measured 0.17 against 0.42 mm
    assert tilt["ekf"] < tilt["kf"]  # measured 1.8 against 2.3 mrad
    # measured 7.0 against 5.3 and 11.0 mm/s (the measured pixel errors in R: the EKF
    # follows the ball's pixel more closely than kf's 0.3 mm on the table)
    assert vel["ekf"] < 1.5 * vel["kf"] and vel["ekf"] < 0.7 * vel["raw"]
    assert 0.3 < nees.mean() < 4.0
    assert 0.05 < nis_per_dof(estimates["kf"]) < 2.0  # measured 0.13
    assert 0.3 < nis_per_dof(estimates["ekf"]) < 2.0  # measured 0.65


def nis_per_dof(estimates) -> float:
    """The run's NIS over its measurement dimensions (the steps that fused something)."""
    fused = [e for e in estimates if e.nis is not None]
    return sum(e.nis for e in fused) / sum(e.nis_dof for e in fused)


# --- oracle-visible -------------------------------------------------------------------
def test_oracle_visible_is_the_truth_while_the_ball_is_seen_and_predicts_it_otherwise():
    def hide_the_ball(k, obs):
        if not 30 <= k < 60:
            return obs
        return {**obs, DETECTED: np.array([obs[DETECTED][0], 0], np.int8)}

    truth, estimates, _ = watch(
        ["oracle-visible"], 80, obs_mode="measurements", change=hide_the_ball
    )
    oracle = estimates["oracle-visible"]
    blind = range(31, 61)
    for k, e in enumerate(oracle):
        if k in blind:
            assert not e.measurement_used
        else:
            assert e.measurement_used and np.array_equal(e.mean, truth[k])
            assert not e.covariance.any()
    errors = [np.linalg.norm(oracle[k].mean[0:2] - truth[k, 0:2]) for k in blind]
    variances = [oracle[k].covariance[0, 0] for k in blind]
    # 0.6 s on the models alone: 3.0 mm at most, measured with the rotation term driven
    # by the lag model's open-loop tilt (below 2 mm without the term)
    assert max(errors) < 4e-3
    assert np.all(np.diff(variances) > 0)
