"""BallCatcher's re-acquisition in both filters: ``ekf`` (:class:`PixelEKFObserver`)
restarts after ``reacquire_after`` gated-out frames of one camera in a row exactly as
``kf`` (:class:`BallCatcherObserver`) does, and both hold at the env's heaviest image
noise (image_noise_std=64, rendered frames)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import observer_gym.envs  # noqa: F401  (registers the envs)
from observer_gym.controllers import make_controller
from observer_gym.envs.ball_catcher.layout import BALL_POS
from observer_gym.estimation import VisionObserver
from observer_gym.estimation.ball_catcher.observer import BallCatcherObserver
from observer_gym.estimation.ball_catcher.pixel_ekf import (
    PixelEKFCore,
    PixelEKFObserver,
    PixelMeasurement,
)

ENV_ID = "observer_gym/BallCatcher-v1"
OFFSET_PX = np.array([80.0, 0.0])  # a false detection far outside the gate
FROM_S = 0.2  # the corrupted frames are camera 0's first ones captured from here on
NEES_3_SIGMA = 14.16  # chi-square(3)'s 99.73 % quantile: an error within ~3 claimed std


def corrupted_flight(env, pipelines, k, seed=0, steps=60):
    """One flight with the box held still; camera 0's first ``k`` detections captured from
    FROM_S on are moved by OFFSET_PX. Every pipeline sees the same frames. Returns the
    throw, the steps [(info, frames seen, {name: (Estimate, reacquisitions)})] and the
    capture times of the corrupted frames."""
    obs, info = env.reset(seed=seed)
    for pipeline in pipelines.values():
        pipeline.reset()
        pipeline.observe(obs, info, None)
    throw, rows, corrupted_s = info["throw"], [], []
    for _ in range(steps):
        obs, _, terminated, _, info = env.step(np.zeros(3, np.float32))
        frames = []
        for frame in info["frames"]:
            if (
                frame["camera_id"] == 0
                and frame["uv_px"] is not None
                and frame["capture_time_s"] >= FROM_S
                and len(corrupted_s) < k
            ):
                frame = {**frame, "uv_px": frame["uv_px"] + OFFSET_PX}
                corrupted_s.append(frame["capture_time_s"])
            frames.append(frame)
        seen = {**info, "frames": frames}
        estimates = {
            name: (p.observe(obs, seen, np.zeros(3)), p.reacquisitions)
            for name, p in pipelines.items()
        }
        rows.append((info, frames, estimates))
        if terminated:
            break
    return throw, rows, corrupted_s


@pytest.mark.parametrize("reacquire_after", [1, 3])
def test_ekf_restarts_after_reacquire_after_rejections_as_kf_does(reacquire_after):
    """Camera 0 reports k = ``reacquire_after - 1`` far-off pixels in a row: neither
    filter restarts, and the EKF gates out exactly those (a clean flight's rejections plus
    k). One more: both restart at the step of the last of them, and the EKF's estimate
    there is a fresh filter's from the prior at time 0 fed every detection captured from
    the first rejected frame on (both cameras', in capture order), bit for bit. The
    restart fuses the false frames again, so a second restart follows from the good ones;
    from 0.1 s after the last false frame to the crossing each filter's error is below
    2 cm (measured: 2 restarts in each, at most 4.2 / 4.2 mm (kf / ekf) for
    reacquire_after 1, 6.0 / 3.9 mm for 3). Every detection is counted once as accepted
    or rejected."""
    env = gym.make(ENV_ID, obs_mode="measurements").unwrapped
    try:
        clean = PixelEKFObserver(env, reacquire_after=reacquire_after)
        corrupted_flight(env, {"ekf": clean}, 0)
        for k in (reacquire_after - 1, reacquire_after):
            pipelines = {
                "kf": BallCatcherObserver(env, reacquire_after=reacquire_after),
                "ekf": PixelEKFObserver(env, reacquire_after=reacquire_after),
            }
            ekf = pipelines["ekf"]
            throw, rows, corrupted_s = corrupted_flight(env, pipelines, k)
            assert len(corrupted_s) == k
            restarts = {n: [e[n][1] for _, _, e in rows] for n in pipelines}
            detections = sum(f["uv_px"] is not None for _, frames, _ in rows for f in frames)
            core = ekf.core.ekf
            assert core.accepted_count + core.rejected_count == detections
            if k < reacquire_after:
                assert restarts["kf"][-1] == restarts["ekf"][-1] == 0
                assert core.rejected_count == clean.core.ekf.rejected_count + k
                continue
            first = {n: next(i for i, r in enumerate(restarts[n]) if r) for n in pipelines}
            assert first["kf"] == first["ekf"]
            at_restart, _, _ = rows[first["ekf"]]
            assert at_restart["frames"][-1]["capture_time_s"] == corrupted_s[-1]
            assert restarts["ekf"][-1] >= 1 and restarts["kf"][-1] >= 1

            # restarted: the restart prior at 0, then every detection since corrupted_s[0]
            fresh = PixelEKFCore(
                ekf.x_lost,
                ekf.P_lost,
                ekf.flight,
                ekf.pixel_std_px,
                ekf.gate_p,
                0.0,
                ekf.iterations,
            )
            since = [
                f for _, frames, _ in rows[: first["ekf"] + 1] for f in frames
                if f["uv_px"] is not None and f["capture_time_s"] >= corrupted_s[0]
            ]  # fmt: skip
            for f in sorted(since, key=lambda f: f["capture_time_s"]):
                fresh.predict_to(f["capture_time_s"])
                fresh.update(PixelMeasurement(f["camera_id"], f["K"], f["T_world_cam"], f["uv_px"]))
            fresh.predict_to(at_restart["time_s"])
            estimate, _ = rows[first["ekf"]][2]["ekf"]
            np.testing.assert_array_equal(estimate.mean[BALL_POS], fresh.ekf.x[:3])
            np.testing.assert_array_equal(
                estimate.covariance[BALL_POS, BALL_POS], fresh.ekf.P[:3, :3]
            )

            for name in pipelines:
                after = [
                    np.linalg.norm(e[name][0].mean[BALL_POS] - info["state"][BALL_POS])
                    for info, _, e in rows
                    if corrupted_s[-1] + 0.1 <= info["time_s"] < throw["crossing_time_s"] - 0.01
                ]
                assert len(after) >= 10 and max(after) < 0.02, (name, max(after))
    finally:
        env.close()


@pytest.mark.parametrize("bad", [0, -1, 2.5, True, "3", None, np.float64(3.0)])
@pytest.mark.parametrize("pipeline_class", [BallCatcherObserver, PixelEKFObserver])
def test_reacquire_after_must_be_a_positive_integer(pipeline_class, bad):
    env = gym.make(ENV_ID, obs_mode="measurements").unwrapped
    try:
        expected = f"{pipeline_class.__name__}: reacquire_after = .*, must be an integer >= 1"
        with pytest.raises(ValueError, match=expected):
            pipeline_class(env, reacquire_after=bad)
        assert pipeline_class(env, reacquire_after=np.int64(2)).reacquire_after == 2
    finally:
        env.close()


# ---------------------------------------------------------------------------- heavy image noise


def closed_loop_at_heavy_image_noise(observer, seed):
    """One throw, rendered frames at image_noise_std=64 (the env's maximum), the intercept
    controller acting on ``observer``'s estimate. Returns the outcome, the restarts and,
    per step until 15 ms before the ball reaches the box's plane (then it can touch the
    box and leave the ballistic model), (time, position error (m), NEES of the position)."""
    env = VisionObserver(gym.make(ENV_ID, obs_mode="rgb", image_noise_std=64.0), observer=observer)
    try:
        controller = make_controller("intercept", env)
        obs, info = env.reset(seed=seed)
        controller.reset()
        controller.observe_info(info)
        rows, done = [], False
        while not done:
            obs, _, terminated, truncated, info = env.step(controller.predict(obs)[0])
            controller.observe_info(info)
            done = terminated or truncated
            if info["time_s"] < info["throw"]["crossing_time_s"] - 0.015:
                error = info["estimate"]["mean"][BALL_POS] - info["state"][BALL_POS]
                P = info["estimate"]["covariance"][BALL_POS, BALL_POS]
                rows.append(
                    (info["time_s"], np.linalg.norm(error), error @ np.linalg.solve(P, error))
                )
        return info["outcome"], env.pipeline.reacquisitions, rows
    finally:
        env.close()


# 1.5 s each (idle): kf in the default run, ekf slow
@pytest.mark.parametrize("observer", ["kf", pytest.param("ekf", marks=pytest.mark.slow)])
def test_both_filters_recover_and_stay_consistent_at_the_heaviest_image_noise(observer):
    """image_noise_std=64, seeds 0-1: the catch is made, and from FROM_S (0.2 s) on the
    error is below 1 cm and within ~3 claimed std (NEES <= 14.2), 15 ms before the plane
    below 3 mm. Measured (kf / ekf): one restart per flight; NEES above 14.2 only up to
    0.09 and 0.07 / 0.09 and 0.06 s; from 0.2 s the error at most 2.6 and 1.0 / 3.0 and
    1.3 mm with NEES at most 6.9 and 1.3 / 7.9 and 1.7; at the end 0.15 and 0.65 mm in
    both.

    Both changes are needed. The detector took a noise blob on the grey box for the ball
    in 23 % of the frames with the ball in view (90 of 395 over 10 throws); with it, even
    with the restart, the estimate was metres off (NEES up to 4e5) until 0.15-0.44 s and
    the ekf missed 1 of 10 throws. With the smoothing detector but without the ekf's
    restart (reacquire_after 10^6), its first frames' false detections held: seeds 0 and
    1 missed, 14 and 2.7 m off at the end."""
    for seed in (0, 1):
        outcome, restarts, rows = closed_loop_at_heavy_image_noise(observer, seed)
        late = [(t, e, nees) for t, e, nees in rows if t >= FROM_S]
        worst_nees = max(nees for *_, nees in late)
        worst_m = max(e for _, e, _ in late)
        print(
            f"{observer} seed {seed}: {outcome}, restarts {restarts}, from {FROM_S} s: "
            f"max NEES {worst_nees:.1f}, max error {worst_m * 1e3:.2f} mm, final "
            f"{rows[-1][1] * 1e3:.2f} mm"
        )
        assert outcome == "caught"
        assert len(late) >= 15
        assert worst_nees <= NEES_3_SIGMA, worst_nees
        assert worst_m < 0.01, worst_m
        assert rows[-1][1] < 0.003, rows[-1][1]
