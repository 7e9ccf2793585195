"""BallCatcher's shipped variance scale in use (estimation/learned/variance_scale.py):
``learned`` reports the network's variance times the report's scale for measurements and
none for frames, and ``learned-kf`` fuses the network's position with the scaled
variance as R."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest

from observer_gym.envs.ball_catcher.layout import BALL, BALL_POS
from observer_gym.estimation import VisionObserver
from observer_gym.estimation.ball_catcher.learned import WEIGHTS
from observer_gym.estimation.learned.variance_scale import AgeVarianceScale, load_variance_scale

pytest.importorskip("torch")


def _shipped() -> AgeVarianceScale:
    report = json.loads(WEIGHTS.with_suffix(".json").read_text())
    return load_variance_scale(report, "measurements", 6)


def _shipped_scale() -> np.ndarray:
    """The scale where the frames are young (held at the constant up to 0.05 s)."""
    return _shipped().at(0.0)


def test_the_shipped_scale_is_fitted_and_says_how():
    report = json.loads(WEIGHTS.with_suffix(".json").read_text())
    scale = _shipped_scale()
    assert scale.shape == (6,) and np.all(scale > 0) and not np.allclose(scale, 1.0)
    command = report["variance_scale"]["commands"]["measurements"]
    assert "--ranges study" in command and "--hold-to 0.05" in command


def test_the_shipped_scale_is_the_constant_up_to_0_05_s_and_grows_along_the_throw_after():
    """Held at the constant scale fitted across every condition where the frames are
    young (so pixel noise and drops keep it), larger for the position along the throw (x)
    and in height (z) at 0.2 s, where the network errs 248 and 90 mm."""
    scale = _shipped()
    assert np.array_equal(scale.at(0.0), scale.at(0.05))
    assert np.array_equal(scale.at(0.0), scale.at(0.03))
    grown = scale.at(0.2) / scale.at(0.0)
    assert grown[0] > 2.0 and grown[2] > 2.0, grown


def test_learned_scales_by_the_newest_kept_frames_age():
    """Long after the last frame (no frame delivered for 0.2 s), the reported variance is
    the network's times the scale at that age, not at the young frames'."""
    env = VisionObserver(
        gym.make("observer_gym/BallCatcher-v1", obs_mode="measurements"), observer="learned"
    )
    try:
        info = _first_step_with_the_ball(env)
        observer = env.pipeline  # the LearnedObserver
        later_s = observer.features.newest_capture_s() + 0.2
        _, reported = observer.predict(later_s)
        _, raw = observer.net.predict(observer.features.vector(later_s))
        assert np.allclose(np.diag(reported), np.diag(raw) * _shipped().at(0.2))
        assert not np.allclose(np.diag(reported), np.diag(raw) * _shipped_scale())
        assert float(info["time_s"]) - observer.features.newest_capture_s() < 0.05
    finally:
        env.close()


def _first_step_with_the_ball(env):
    env.reset(seed=3)
    for _ in range(40):
        _, _, _, _, info = env.step(np.zeros(env.action_space.shape, dtype=np.float32))
        if info["estimate"]["measurement_used"]:
            return info
    raise AssertionError("no frame showed the ball in 40 steps")


def test_learned_reports_the_networks_variance_times_the_shipped_scale():
    env = VisionObserver(
        gym.make("observer_gym/BallCatcher-v1", obs_mode="measurements"), observer="learned"
    )
    try:
        info = _first_step_with_the_ball(env)
        observer = env.pipeline  # the LearnedObserver
        _, raw = observer.net.predict(observer.features.vector(float(info["time_s"])))
        reported = np.diag(info["estimate"]["covariance"][BALL, BALL])
        assert np.allclose(reported, np.diag(raw) * _shipped_scale())
    finally:
        env.close()


def test_learned_kf_fuses_the_scaled_variance_as_r(monkeypatch):
    from observer_gym.estimation.ball_catcher.filters import ViewlineKalmanFilter

    seen = []
    real = ViewlineKalmanFilter.add_position

    def spy(self, time_s, position_m, R_m2):
        seen.append(np.array(R_m2))
        return real(self, time_s, position_m, R_m2)

    monkeypatch.setattr(ViewlineKalmanFilter, "add_position", spy)
    env = VisionObserver(
        gym.make("observer_gym/BallCatcher-v1", obs_mode="measurements"), observer="learned-kf"
    )
    try:
        info = _first_step_with_the_ball(env)
        assert len(seen) == 1  # the first output showing the ball is fused
        observer = env.pipeline  # the LearnedKFObserver
        features = observer.learned.features.vector(float(info["time_s"]))
        _, raw = observer.learned.net.predict(features)
        expected = raw[BALL_POS, BALL_POS] * _shipped_scale()[BALL_POS]
        assert np.allclose(seen[0], expected)
        assert not np.allclose(seen[0], raw[BALL_POS, BALL_POS])
    finally:
        env.close()
