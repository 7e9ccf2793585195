"""The observer wrapper on BallTable-v0 against the simulator's ground truth."""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import observer_gym.envs  # noqa: F401  (registers the envs)
from observer_gym.estimation import VisionObserver

ENV_ID = "observer_gym/BallTable-v0"
DT_S = 0.02
# Documented bounds (measured values in the comments; `python benchmarks/quality_observer.py`).
POS_RMSE_BOUND_M = 0.0007  # measured 0.43-0.45 mm over 20 s from rgb (seeds 0-3)
VEL_RMSE_BOUND_MPS = 0.012  # measured 7.8-8.1 mm/s (the noise rule's Q)
TILT_RMSE_BOUND_RAD = 0.004  # measured ~2-3 mrad
RECOVERY_S = 0.3  # after a blind spell the position error is back under RECOVERED_ERR_M
RECOVERED_ERR_M = 0.005


def circle_tracking_action(time_s: float, estimate: np.ndarray, phase: float) -> np.ndarray:
    """Closed loop through the observer: a PD tilt law on the estimate makes the ball follow
    a 5 cm circle, so it keeps rolling without resting on a border (test scaffolding, not a
    controller: a = k_p (r - p) - k_d v, inverted through a = (5/7) g tilt, spec
    "Dynamics")."""
    omega_radps, radius_m, k_p, k_d = 0.8, 0.05, 4.0, 3.0
    angle = omega_radps * time_s + phase
    ref = radius_m * np.array([np.cos(angle), np.sin(angle)])
    accel = k_p * (ref - estimate[0:2]) - k_d * estimate[2:4]
    gain = 5.0 / 7.0 * 9.81
    return np.clip([-accel[1] / gain, accel[0] / gain], -0.1, 0.1).astype(np.float32)


def run_observed(seed: int, seconds: float, **env_kwargs):
    """Run the observer in closed loop; per-step truth, estimate, covariance, flags."""
    env = VisionObserver(gym.make(ENV_ID, max_episode_steps=int(seconds / DT_S) + 1, **env_kwargs))
    phase = np.random.default_rng(seed).uniform(0, 2 * np.pi)
    rows = []
    try:
        estimate, info = env.reset(seed=seed)
        for k in range(int(seconds / DT_S)):
            action = circle_tracking_action(k * DT_S, estimate, phase)
            estimate, _, terminated, truncated, info = env.step(action)
            est = info["estimate"]
            detection = est["measurement"]
            raw = (
                detection.ball_pos_table_m
                if detection is not None and detection.ball_found
                else np.full(2, np.nan)
            )
            rows.append(
                (info["state"], est["mean"], est["covariance"], est["measurement_used"], raw)
            )
            if terminated or truncated:
                break
    finally:
        env.close()
    truth, mean, cov, used, raw = (np.array(c) for c in zip(*rows, strict=True))
    return truth, mean, cov, used.astype(bool), raw


@pytest.mark.parametrize("obs_mode", ["rgb", "measurements"])
def test_observer_passes_check_env(obs_mode):
    env = VisionObserver(gym.make(ENV_ID, obs_mode=obs_mode))
    # check_env steps with actions sampled from the action space: seeded, the same ones
    # every run (unseeded, one run in a full default run on 2026-11-29 caught a warning
    # that six runs of this test alone did not)
    env.action_space.seed(0)
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            check_env(env, skip_render_check=True)
        # check_env says it is handed a wrapped env: the wrapper is what is checked here.
        messages = [str(w.message) for w in caught if "has a wrapper applied" not in str(w.message)]
        assert messages == []
        assert env.observation_space == env.unwrapped.state_space
    finally:
        env.close()


def test_observer_refuses_state_mode():
    with pytest.raises(ValueError, match="obs_mode"):
        VisionObserver(gym.make(ENV_ID, obs_mode="state"))


@pytest.mark.parametrize("seed", [0, 1])
# 20-s pixel episodes (28-38 s each at load 7); test_closed_loop.py's pixel loops stay
@pytest.mark.slow
def test_observer_tracks_the_ball_from_pixels_for_20_s(seed):
    truth, mean, cov, used, raw = run_observed(seed, 20.0, obs_mode="rgb")
    assert len(truth) == 1000 and used.mean() > 0.99
    skip = 25  # the first 0.5 s: the velocity estimate starts from zero
    pos_err = mean[skip:, 0:2] - truth[skip:, 0:2]
    vel_err = mean[skip:, 2:4] - truth[skip:, 2:4]
    pos_rmse = np.sqrt(np.mean(np.sum(pos_err**2, axis=1)))
    vel_rmse = np.sqrt(np.mean(np.sum(vel_err**2, axis=1)))
    raw_rmse = np.sqrt(np.nanmean(np.sum((raw[skip:] - truth[skip:, 0:2]) ** 2, axis=1)))
    raw_vel = (raw[skip + 1 :] - raw[skip:-1]) / DT_S  # velocity from differenced detections
    raw_vel_rmse = np.sqrt(np.nanmean(np.sum((raw_vel - truth[skip + 1 :, 2:4]) ** 2, axis=1)))
    tilt_rmse = np.sqrt(np.mean(np.sum((mean[skip:, 4:6] - truth[skip:, 4:6]) ** 2, axis=1)))
    err = np.concatenate([pos_err, vel_err], axis=1)
    nees = np.einsum("ki,kij,kj->k", err, np.linalg.inv(cov[skip:, 0:4, 0:4]), err)
    print(
        f"\nseed {seed}: position RMSE {pos_rmse * 1e3:.3f} mm (raw detections "
        f"{raw_rmse * 1e3:.3f} mm), velocity RMSE {vel_rmse * 1e3:.2f} mm/s (differenced "
        f"detections {raw_vel_rmse * 1e3:.2f} mm/s), tilt RMSE {tilt_rmse * 1e3:.2f} mrad, "
        f"average NEES {nees.mean():.2f}"
    )
    assert pos_rmse < POS_RMSE_BOUND_M
    assert vel_rmse < VEL_RMSE_BOUND_MPS
    assert tilt_rmse < TILT_RMSE_BOUND_RAD
    # Filtering beats the raw detections: a little in position (their error is mostly a
    # slowly varying bias no filter can remove), by far in velocity (measured 0.52x).
    assert pos_rmse < raw_rmse
    assert vel_rmse < 0.65 * raw_vel_rmse
    # Consistency: the time-averaged NEES/dof of (x, y, vx, vy) within issue 23's band
    # [1/3, 3]. R is the rgb detector's measured error and Q the noise rule's; nothing is
    # tuned to this run (measured 1.08 and 1.05, seeds 0 and 1).
    assert 1.0 / 3.0 < nees.mean() / 4.0 < 3.0, nees.mean() / 4.0


@pytest.mark.slow  # a long pixel episode (20 s at load 4)
def test_observer_rides_out_dropped_frames_and_an_occluded_ball():
    truth, mean, cov, used, _raw = run_observed(
        3, 12.0, obs_mode="rgb", frame_drop_prob=0.1, occluder_rate_hz=0.3, occluder_pass_s=3.5
    )
    assert np.all(np.isfinite(mean)) and np.all(np.isfinite(cov))
    # Blind spells: consecutive steps without a ball measurement.
    blind = ~used
    assert 0.05 < blind.mean() < 0.5
    spells, start = [], None
    for k, b in enumerate(blind):
        if b and start is None:
            start = k
        if not b and start is not None:
            spells.append((start, k))
            start = None
    longest = max(spells, key=lambda s: s[1] - s[0])
    assert (longest[1] - longest[0]) * DT_S >= 0.5  # the occluder hid the ball for >= 0.5 s
    pos_var = cov[:, 0, 0] + cov[:, 1, 1]
    a, b = longest
    assert np.all(np.diff(pos_var[a:b]) > 0)  # the covariance grows while blind
    recovery_steps = round(RECOVERY_S / DT_S)
    pos_err = np.linalg.norm(mean[:, 0:2] - truth[:, 0:2], axis=1)
    print(
        f"\nblind {blind.mean():.1%} of steps; longest spell {(b - a) * DT_S:.2f} s, position "
        f"std {np.sqrt(pos_var[a]) * 1e3:.2f} -> {np.sqrt(pos_var[b - 1]) * 1e3:.2f} mm, "
        f"error at its end {pos_err[b - 1] * 1e3:.2f} mm, {RECOVERY_S} s later "
        f"{pos_err[b + recovery_steps] * 1e3:.2f} mm"
    )
    assert pos_err[b + recovery_steps] < RECOVERED_ERR_M  # recovered within 0.3 s
    # and stays recovered: small, or (a later blind spell: measured 49 mm after 1.2 s with
    # a claimed std of 109 mm) within 3 of its claimed std
    later = slice(b + recovery_steps, None)
    small = pos_err[later] < 5 * RECOVERED_ERR_M
    assert np.all(small | (pos_err[later] < 3.0 * np.sqrt(pos_var[later])))


def _observed_ball_table(obs_mode: str = "rgb"):
    """Module-level env factory, so spawned workers can unpickle it."""

    return VisionObserver(gym.make(ENV_ID, obs_mode=obs_mode))


@pytest.mark.slow  # spawned workers (17 s at load 7); test_vector_envs.py's spawn test stays
def test_observer_runs_in_spawned_subprocess_vec_env():
    from stable_baselines3.common.vec_env import SubprocVecEnv

    vec_env = SubprocVecEnv([_observed_ball_table, _observed_ball_table], start_method="spawn")
    try:
        vec_env.seed(5)
        obs = vec_env.reset()
        for _ in range(10):
            obs, _, _, infos = vec_env.step(np.zeros((2, 2), np.float32))
        assert obs.shape == (2, 8) and np.all(np.isfinite(obs))
        for worker_obs, info in zip(obs, infos, strict=True):
            # Each worker's observation is its own estimate, close to its own ground truth.
            np.testing.assert_allclose(worker_obs, info["estimate"]["mean"], atol=1e-6)
            assert np.linalg.norm(worker_obs[0:2] - info["state"][0:2]) < 0.002
        assert not np.allclose(obs[0], obs[1])  # different seeds, different episodes
    finally:
        vec_env.close()


def test_observer_on_perfect_measurements_is_nearly_exact():
    """The measurements obs_mode feeds the same geometry and filters without pixels; with
    perfect features the remaining error is the filter's own."""
    truth, mean, _cov, used, raw = run_observed(4, 6.0, obs_mode="measurements")
    skip = 25
    assert used[skip:].all()
    assert np.abs(raw[skip:] - truth[skip:, 0:2]).max() < 2e-4  # geometry stage: 0.2 mm
    assert np.sqrt(np.mean(np.sum((mean[skip:, 0:2] - truth[skip:, 0:2]) ** 2, axis=1))) < 3e-4
    assert np.sqrt(np.mean(np.sum((mean[skip:, 4:6] - truth[skip:, 4:6]) ** 2, axis=1))) < 1e-3
