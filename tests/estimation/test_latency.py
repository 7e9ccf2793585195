"""Capture-time fusion (estimation/latency.py) against an offline filter that knows every
capture time: on a linear model, rewind-and-replay must give exactly the estimate of
fusing each delivered measurement at its capture time, in capture order."""

from __future__ import annotations

import numpy as np
import pytest

from observer_gym.estimation.filters import KalmanFilter
from observer_gym.estimation.latency import CaptureTimeFusion, TimedMeasurement

Q_INTENSITY = 0.3  # white acceleration, (m/s^2)^2 s
R_M2 = 0.01**2


class ConstantVelocityCore:
    """x = [position, velocity], input: acceleration held over each interval."""

    def __init__(self) -> None:
        self.kf = KalmanFilter(np.zeros(2), np.diag([1.0, 1.0]))
        self.time_s = 0.0
        self.C = np.array([[1.0, 0.0]])
        self.R = np.array([[R_M2]])

    def predict_to(self, time_s, action):
        dt = time_s - self.time_s
        if dt <= 0.0:
            return
        Phi = np.array([[1.0, dt], [0.0, 1.0]])
        Gamma = np.array([[0.5 * dt * dt], [dt]])
        Q = Q_INTENSITY * np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]])
        u = np.zeros(1) if action is None else np.asarray(action, dtype=float)
        self.kf.predict(Phi, Q, Gamma, u)
        self.time_s = time_s

    def update(self, z):
        return self.kf.update(np.array([z]), self.C, self.R).accepted

    def snapshot(self):
        return (self.kf.x, self.kf.P, self.time_s)

    def restore(self, snap):
        self.kf.x, self.kf.P, self.time_s = snap[0], snap[1], snap[2]


def scenario(latency_s, jitter_s, seed=0, steps=60, dt_s=0.02, frame_dt_s=0.03):
    """Step times, the action held over each step, and the frames: (capture, delivery, z)."""
    rng = np.random.default_rng(seed)
    step_times = dt_s * np.arange(1, steps + 1)
    actions = rng.normal(size=(steps, 1))
    captures = np.arange(0.0, step_times[-1], frame_dt_s)[1:]
    delays = latency_s + rng.uniform(0.0, jitter_s, size=captures.size)
    # a frame is delivered at the first step at or after capture + delay
    delivery_step = np.searchsorted(step_times, captures + delays - 1e-12)
    z = np.sin(captures) + rng.normal(scale=0.01, size=captures.size)
    frames = zip(captures, delivery_step, z, strict=True)
    return step_times, actions, [(c, int(k), float(v)) for c, k, v in frames if k < steps]


def offline_estimate(step_times, actions, frames, k):
    """A filter that fuses every frame delivered by step k at its capture time, in capture
    order, predicted to step k's time."""
    core = ConstantVelocityCore()
    known = sorted((c, z) for c, d, z in frames if d <= k)
    events = [(t, "step", None) for t in step_times[: k + 1]] + [(c, "frame", z) for c, z in known]
    events.sort(key=lambda e: (e[0], e[1] == "step"))
    for t, kind, z in events:
        j = int(np.searchsorted(step_times, t - 1e-12))  # the interval (t_{j-1}, t_j] holds t
        core.predict_to(t, actions[j])
        if kind == "frame":
            core.update(z)
    return core.kf.x, core.kf.P


def drive(step_times, actions, frames, latency_aware):
    fusion = CaptureTimeFusion(ConstantVelocityCore(), latency_aware=latency_aware)
    out = []
    for k, t in enumerate(step_times):
        delivered = [TimedMeasurement(c, z) for c, d, z in frames if d == k]
        fusion.step(t, actions[k], delivered)
        out.append((fusion.core.kf.x.copy(), fusion.core.kf.P.copy()))
    return fusion, out


@pytest.mark.parametrize("latency_s, jitter_s", [(0.05, 0.0), (0.033, 0.0), (0.06, 0.05)])
def test_late_frames_are_fused_at_their_capture_time(latency_s, jitter_s):
    step_times, actions, frames = scenario(latency_s, jitter_s)
    fusion, out = drive(step_times, actions, frames, latency_aware=True)
    assert fusion.rewinds > 10
    for k in range(len(step_times)):
        x, P = offline_estimate(step_times, actions, frames, k)
        np.testing.assert_allclose(out[k][0], x, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(out[k][1], P, rtol=1e-9, atol=1e-15)


def test_jitter_delivers_out_of_order_and_is_still_exact():
    step_times, actions, frames = scenario(0.0, 0.12, seed=3)
    order = [c for c, d, z in sorted(frames, key=lambda f: (f[1], f[0]))]
    assert order != sorted(order)  # some frame arrives after a later capture
    _, out = drive(step_times, actions, frames, latency_aware=True)
    x, P = offline_estimate(step_times, actions, frames, len(step_times) - 1)
    np.testing.assert_allclose(out[-1][0], x, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(out[-1][1], P, rtol=1e-9, atol=1e-15)


def test_at_zero_latency_the_aware_drive_is_the_plain_drive_bit_for_bit():
    step_times, actions, frames = scenario(0.0, 0.0, frame_dt_s=0.02)
    frames = [(step_times[d], d, z) for c, d, z in frames]  # captured at the step time
    aware, out_aware = drive(step_times, actions, frames, latency_aware=True)
    _, out_plain = drive(step_times, actions, frames, latency_aware=False)
    assert aware.rewinds == 0
    for (xa, Pa), (xp, Pp) in zip(out_aware, out_plain, strict=True):
        assert np.array_equal(xa, xp) and np.array_equal(Pa, Pp)


def test_the_plain_drive_fuses_at_delivery():
    step_times, actions, frames = scenario(0.05, 0.0)
    _, out = drive(step_times, actions, frames, latency_aware=False)
    core = ConstantVelocityCore()
    for k, t in enumerate(step_times):
        core.predict_to(t, actions[k])
        for _capture, d, z in frames:
            if d == k:
                core.update(z)
        assert np.array_equal(core.kf.x, out[k][0])


def test_history_must_be_positive():
    with pytest.raises(ValueError, match="history_s"):
        CaptureTimeFusion(ConstantVelocityCore(), True, history_s=0.0)
