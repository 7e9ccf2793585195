"""TargetFollower's observer families: raw, kf-latency / stkf-latency, the pixel EKF and
oracle-visible, against the truth and against the delivery-time VSE (kf / stkf)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from observer_gym.controllers import make_controller
from observer_gym.envs.target_follower import IMAGE, IMAGE_RATE, StateIndex
from observer_gym.envs.target_follower.geometry import image_state, target_image_velocity
from observer_gym.estimation import VisionObserver
from observer_gym.estimation.ekf import numerical_jacobian
from observer_gym.estimation.observer import default_pipeline
from observer_gym.estimation.target_follower import OBSERVERS
from observer_gym.estimation.target_follower.models import (
    image_state_transition,
    robot_jacobian,
)
from observer_gym.estimation.target_follower.target_projection import (
    back_project,
    image_state_and_rate,
    project,
)

ENV_ID = "observer_gym/TargetFollower-v0"
NEW = ("raw", "kf-latency", "stkf-latency", "ekf", "oracle-visible")
FILTERS_WITH_NIS = ("kf", "stkf", "kf-latency", "stkf-latency", "ekf")


def _run(make_env, names, steps, seed=0, drive=None, reset_options=None, **env_options):
    """Run the env once with a pipeline per name fed the same frames; the VTC acts on
    ``drive``'s estimate (default: the truth). Returns per step (info, {name: Estimate})
    and the pipelines."""
    env = make_env(ENV_ID, **env_options)
    pipelines = {name: default_pipeline(env, name) for name in names}
    controller = make_controller("vtc", env)
    obs, info = env.reset(seed=seed, options=reset_options)
    estimates = {n: p.observe(obs, info, None) for n, p in pipelines.items()}
    trace = [(info, estimates)]
    for _ in range(steps):
        state = info["state"] if drive is None else estimates[drive].mean
        action, _ = controller.predict(state.astype(np.float32))
        obs, _, terminated, _, info = env.step(action)
        applied = info["applied_action"]
        estimates = {n: p.observe(obs, info, applied) for n, p in pipelines.items()}
        trace.append((info, estimates))
        if terminated:
            break
    return trace, pipelines, env


def _centre_errors(trace, name, skip=0):
    return np.array(
        [
            np.hypot(*(e[name].mean[:2] - info["state"][:2]))
            for info, e in trace[skip:]
            if e[name].mean[StateIndex.TRACKING_VALID] == 1.0
        ]
    )


def _rms(values) -> float:
    return float(np.sqrt(np.mean(np.square(values))))


@pytest.mark.parametrize(
    "options",
    [
        {"obs_mode": "measurements", "measurement_noise_px": 3.0, "frame_drop_prob": 0.2},
        {
            "obs_mode": "measurements",
            "latency_s": 0.15,
            "latency_jitter_s": 0.05,
            "measurement_noise_px": 3.0,
        },
        {"obs_mode": "rgb", "latency_s": 0.1},
    ],
    ids=["drops", "latency-jitter", "rgb"],
)
def test_estimates_keep_the_state_layout(make_env, options):
    steps = 25 if options["obs_mode"] == "rgb" else 80
    trace, _, env = _run(
        make_env,
        NEW,
        steps,
        drive="kf-latency",
        reset_options={"occlusions_s": (1.0,)},
        occluder_hold_s=1.5,
        **options,
    )
    space = env.unwrapped.state_space
    for _, estimates in trace:
        for name, e in estimates.items():
            assert e.mean.shape == space.shape and e.covariance.shape == (15, 15), name
            assert np.all(np.isfinite(e.mean)) and np.all(np.isfinite(e.covariance)), name
            assert space.contains(e.mean.astype(space.dtype)), name
    valid = {n: sum(e[n].mean[StateIndex.TRACKING_VALID] for _, e in trace) for n in NEW}
    assert all(v > len(trace) / 3 for v in valid.values()), valid


def test_raw_is_the_detection_without_lag(make_env):
    """Its image state is the detection itself at every detected step (so its error is
    the detection's), held through misses, and its rate is the finite difference of two
    detections less the robot's part by (30)."""
    trace, pipelines, _ = _run(
        make_env,
        ["raw"],
        80,
        obs_mode="measurements",
        measurement_noise_px=3.0,
        reset_options={"occlusions_s": (1.0,)},
        occluder_hold_s=1.5,
    )
    params = pipelines["raw"].camera_params
    held = checked = 0
    for k in range(1, len(trace)):
        info, e = trace[k]
        raw = e["raw"]
        if raw.measurement is not None:
            np.testing.assert_array_equal(raw.mean[IMAGE], raw.measurement)
            assert raw.mean[StateIndex.TRACKING_VALID] == 1.0
            previous = trace[k - 1][1]["raw"]
            if previous.measurement is not None:  # consecutive detections, T apart
                B_i = robot_jacobian(previous.measurement, previous.mean[StateIndex.TILT], params)
                rate = (raw.measurement - previous.measurement) / 0.1 - B_i @ info["applied_action"]
                np.testing.assert_allclose(raw.mean[IMAGE_RATE], rate, rtol=1e-9, atol=1e-9)
                checked += 1
        else:
            np.testing.assert_array_equal(raw.mean[IMAGE], trace[k - 1][1]["raw"].mean[IMAGE])
            assert raw.mean[StateIndex.TRACKING_VALID] == 0.0
            held += 1
    assert checked > 40 and held > 5


@pytest.mark.parametrize("filter", ["kf", "stkf"])
def test_latency_aware_drive_equals_the_filter_at_zero_latency(make_env, filter):
    """Noise, dropped frames and a full occlusion long enough to restart the estimator."""
    trace, pipelines, _ = _run(
        make_env,
        [filter, f"{filter}-latency"],
        120,
        drive=filter,
        obs_mode="measurements",
        measurement_noise_px=3.0,
        frame_drop_prob=0.15,
        reset_options={"occlusions_s": (2.0,)},
        occluder_hold_s=4.0,
    )
    for _, e in trace:
        a, b = e[filter], e[f"{filter}-latency"]
        np.testing.assert_allclose(b.mean, a.mean, rtol=0.0, atol=1e-9)
        np.testing.assert_allclose(b.covariance, a.covariance, rtol=0.0, atol=1e-9)
        assert (a.measurement_used, a.nis, a.nis_dof) == (b.measurement_used, b.nis, b.nis_dof)
    assert pipelines[filter].vse.reinitialisations >= 1  # the restart was exercised
    assert pipelines[f"{filter}-latency"].fusion.rewinds == 0


def test_latency_aware_drive_is_the_one_step_prediction(make_env):
    """With a latency of one step, kf-latency's estimate at step k is the zero-latency
    filter's prediction x(k | k-1): the same world (same seed and actions), its frames one
    step late."""
    now = make_env(ENV_ID, obs_mode="measurements", measurement_noise_px=3.0)
    late = make_env(ENV_ID, obs_mode="measurements", measurement_noise_px=3.0, latency_s=0.1)
    a, b = default_pipeline(now, "kf-latency"), default_pipeline(late, "kf-latency")
    controller = make_controller("vtc", now)
    obs_a, info_a = now.reset(seed=1)
    obs_b, info_b = late.reset(seed=1)
    est_a, _ = a.observe(obs_a, info_a, None), b.observe(obs_b, info_b, None)
    compared = 0
    for _ in range(60):
        action, _ = controller.predict(est_a.mean.astype(np.float32))
        vse = a.fusion.core.vse
        x, tilt = (None, None) if not vse.initialised else (vse.x, est_a.mean[StateIndex.TILT])
        obs_a, *_, info_a = now.step(action)
        obs_b, *_, info_b = late.step(action)
        np.testing.assert_array_equal(info_a["state"], info_b["state"])
        u = info_a["applied_action"]
        est_a = a.observe(obs_a, info_a, u)
        est_b = b.observe(obs_b, info_b, u)
        if x is not None and est_b.mean[StateIndex.TRACKING_VALID] == 1.0:
            F, G = image_state_transition(0.1, robot_jacobian(x[:3], tilt, a.camera_params))
            np.testing.assert_allclose(est_b.mean[:6], F @ x + G @ u, rtol=0.0, atol=1e-9)
            compared += 1
    assert compared > 50 and b.fusion.rewinds > 50


def test_latency_aware_drive_beats_delivery_time_fusion_at_300_ms(make_env):
    """Latency 0.3 s (3 frames), the VTC on kf's estimate so both see the same world.
    Measured per seed (150 steps, after 20): kf-latency / kf centre RMSE 0.17, 0.25, 0.21
    (seeds 0-2), pooled 0.20 (with the spec's Table 1 noise: 0.68, 0.91, 0.80). With the
    truth driving the VTC (the image then barely moves) the stale detection is a good guess
    and the gain is smaller: pooled 0.86."""
    kf, latency_aware = [], []
    for seed in range(3):
        trace, *_ = _run(
            make_env,
            ["kf", "kf-latency"],
            150,
            seed=seed,
            drive="kf",
            obs_mode="measurements",
            latency_s=0.3,
        )
        kf.append(_centre_errors(trace, "kf", skip=20))
        latency_aware.append(_centre_errors(trace, "kf-latency", skip=20))
    ratio = _rms(np.concatenate(latency_aware)) / _rms(np.concatenate(kf))
    assert ratio < 0.9, ratio


def test_ekf_is_comparable_to_the_kf(make_env):
    """Noise 3 px, no latency, the truth driving: measured EKF / KF centre RMSE ~1.0
    (1.89 vs 1.91 px over 4 x 300 steps)."""
    trace, pipelines, _ = _run(
        make_env, ["kf", "ekf"], 150, obs_mode="measurements", measurement_noise_px=3.0
    )
    kf, ekf = _rms(_centre_errors(trace, "kf", 10)), _rms(_centre_errors(trace, "ekf", 10))
    assert ekf < 1.5 * kf, (ekf, kf)
    assert pipelines["ekf"].fusion.core.starts == 1


def test_oracle_visible_is_the_truth_when_detected_and_predicts_otherwise(make_env):
    trace, pipelines, _ = _run(
        make_env,
        ["oracle-visible"],
        60,
        obs_mode="measurements",
        reset_options={"occlusions_s": (1.0,)},
        occluder_hold_s=1.5,
    )
    params = pipelines["oracle-visible"].camera_params
    hidden = 0
    for k in range(1, len(trace)):
        info, e = trace[k]
        est, previous = e["oracle-visible"], trace[k - 1][1]["oracle-visible"]
        truth = info["state"]
        assert est.mean[StateIndex.TRACKING_VALID] == truth[StateIndex.TRACKING_VALID]
        if est.measurement is not None:
            np.testing.assert_array_equal(est.mean[:6], truth[:6])
            np.testing.assert_array_equal(est.covariance, np.zeros((15, 15)))
        else:  # (30) from the previous estimate, the rate held
            x = previous.mean[:6]
            B_i = robot_jacobian(x[:3], previous.mean[StateIndex.TILT], params)
            F, G = image_state_transition(0.1, B_i)
            np.testing.assert_allclose(est.mean[:6], F @ x + G @ info["applied_action"])
            assert np.all(np.diag(est.covariance)[:6] > 0.0)
            hidden += 1
    assert hidden >= 10


def test_filters_nis_is_plausible(make_env):
    """Uniform noise of +-3 px rounded (variance 3.08 px^2), which the noise rule declares:
    NIS per dof ~1 expected; measured 1.00 (kf, stkf and their latency-aware drive), 1.00
    (ekf). (The spec's R_0 = 5 px^2 gave 0.44, 0.24 and 0.61.) Over 150 steps the NIS per
    dof of a consistent filter lies within ~0.8-1.2."""
    names = (*FILTERS_WITH_NIS, "raw", "oracle-visible")
    trace, *_ = _run(make_env, names, 150, obs_mode="measurements", measurement_noise_px=3.0)
    for name in FILTERS_WITH_NIS:
        steps = [e[name] for _, e in trace if e[name].nis is not None]
        assert len(steps) > 100, name
        per_dof = sum(e.nis for e in steps) / sum(e.nis_dof for e in steps)
        assert 0.7 < per_dof < 1.4, (name, per_dof)
    for name in ("raw", "oracle-visible"):  # no innovation covariance
        assert all(e[name].nis is None and e[name].nis_dof == 0 for _, e in trace)


def test_every_observer_by_name(make_env):
    env = make_env(ENV_ID, obs_mode="measurements")
    for name in OBSERVERS:
        observed = VisionObserver(env, observer=name)
        obs, _ = observed.reset(seed=0)
        obs, *_ = observed.step(np.zeros(3, np.float32))
        assert observed.observation_space.contains(obs), name
    with pytest.raises(ValueError, match="allowed: stkf, kf, kf-latency, stkf-latency, raw"):
        VisionObserver(env, observer="ukf")


def test_history_covers_the_latency():
    """The capture-time observers keep the declared sensor's history (SensorSpec)."""
    env = gym.make(ENV_ID, obs_mode="measurements", latency_s=0.5, latency_jitter_s=0.1)
    try:
        spec = env.unwrapped.sensor_spec
        assert spec.history_s(0.1) >= 0.5 + 5 * 0.1
        for name in ("kf-latency", "stkf-latency", "ekf", "raw"):
            assert default_pipeline(env.unwrapped, name).history_s == spec.history_s(0.1), name
    finally:
        env.close()


def test_projection_jacobians_and_inverse():
    rng = np.random.default_rng(3)
    fx, fy, W = 393.4, 391.8, 0.12
    K = np.array([[fx, 0.0, 160.0], [0.0, fy, 120.0], [0.0, 0.0, 1.0]])
    for _ in range(20):
        angles = rng.uniform(-0.5, 0.5, 3)
        R = _rotation(*angles)
        T = np.eye(4)
        T[:3, :3] = R
        T[:3, 3] = rng.normal(size=3)
        p_w = T[:3, 3] + R @ np.array([*rng.uniform(-0.5, 0.5, 2), rng.uniform(0.8, 3.0)])
        v_w = rng.normal(scale=0.2, size=3)
        h, H, _ = project(p_w, T, fx, fy, W)
        np.testing.assert_allclose(h, image_state(K, T, p_w, W), rtol=1e-12)
        np.testing.assert_allclose(
            H, numerical_jacobian(lambda p, T=T: project(p, T, fx, fy, W)[0], p_w), atol=1e-5
        )
        x = np.concatenate([p_w, v_w])
        s, J, _ = image_state_and_rate(x, T, fx, fy, W)
        np.testing.assert_allclose(s[3:], target_image_velocity(K, T, p_w, v_w, W), rtol=1e-10)
        numeric = numerical_jacobian(lambda y, T=T: image_state_and_rate(y, T, fx, fy, W)[0], x)
        np.testing.assert_allclose(J, numeric, atol=1e-4)
        back, G = back_project(h, T, fx, fy, W)
        np.testing.assert_allclose(back, p_w, atol=1e-12)
        np.testing.assert_allclose(
            G, numerical_jacobian(lambda z, T=T: back_project(z, T, fx, fy, W)[0], h), atol=1e-7
        )


def _rotation(a: float, b: float, c: float) -> np.ndarray:
    ca, sa, cb, sb, cc, sc = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(c), np.sin(c)
    Rx = np.array([[1, 0, 0], [0, ca, -sa], [0, sa, ca]])
    Ry = np.array([[cb, 0, sb], [0, 1, 0], [-sb, 0, cb]])
    Rz = np.array([[cc, -sc, 0], [sc, cc, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx
