"""An agent with its own camera meets the same angles as every other entry: the
benchmark's levels and the pixel-valued options of compare, run and sweep times its
camera's scale (train/experiments/camera_scale.py), and TargetFollower's pixel metrics in
the default camera's pixels (train/core/tasks/target_follower.py)."""

from __future__ import annotations

import json
import math

import gymnasium as gym
import numpy as np
import pytest

from observer_gym.train.core.tasks import target_follower as follower_task
from observer_gym.train.experiments.benchmark.run import check_benchmark
from observer_gym.train.experiments.benchmark.suite import load_suite
from observer_gym.train.experiments.camera_scale import (
    camera_scale,
    options_in_entry_pixels,
)
from observer_gym.train.experiments.request import resolve_request

BT, TF = "observer_gym/BallTable-v0", "observer_gym/TargetFollower-v0"
# the shipped TargetFollower rgb agent's camera: 84 x 63, focal lengths times 84 / 320
TF_AGENT = "ppo:target_follower-rgb"
BT_AGENT = "ppo:ball_table-rgb"  # 84 x 84 at the default 90-degree field of view
SMALL = 84.0 / 320.0


def test_the_scale_is_the_ratio_of_the_focal_lengths():
    # BallTable: f = (w / 2) / tan(hfov / 2), so at a fixed field of view f scales with w
    small = {"image_width_px": 84, "image_height_px": 84}
    assert camera_scale(BT, small) == pytest.approx(SMALL, rel=1e-12)
    # a camera with the default focal lengths is not scaled, whatever its image size
    assert camera_scale(BT, {}) == 1.0
    assert camera_scale(TF, {"image_width_px": 84, "image_height_px": 63}) == 1.0


def test_a_camera_not_scaled_as_a_whole_is_refused():
    with pytest.raises(ValueError, match=r"scaled as a whole.*one factor for x and y"):
        camera_scale(TF, {"fx_px": 200.0})


def test_only_the_pixel_valued_options_are_scaled():
    lab = load_suite("TargetFollower-v0").levels[1].env_options
    scaled = options_in_entry_pixels(lab, 0.5)
    assert scaled["measurement_noise_px"] == 0.5 * lab["measurement_noise_px"]
    assert scaled["calib_principal_point_error_px"] == 0.5 * lab["calib_principal_point_error_px"]
    unchanged = {k: v for k, v in lab.items() if not k.endswith("_px")}
    assert {k: scaled[k] for k in unchanged} == unchanged
    assert options_in_entry_pixels(lab, 1.0) == lab


@pytest.mark.parametrize("agent", [TF_AGENT, BT_AGENT])
def test_an_rgb_agents_request_carries_its_scale_into_episodes_and_identity(agent):
    env = "TargetFollower-v0" if agent == TF_AGENT else "BallTable-v0"
    request = check_benchmark(env, "pixels", agent, episodes=1)
    assert request.camera_scale == pytest.approx(SMALL, rel=1e-9)
    assert request.identity()["camera_scale"] == request.camera_scale
    lab = request.suite.levels[1]
    (spec,) = request.specs(lab)
    assert spec.env_kwargs["calib_principal_point_error_px"] == pytest.approx(
        lab.env_options["calib_principal_point_error_px"] * SMALL
    )
    assert spec.env_kwargs["image_width_px"] == 84  # the agent's own option is kept


def test_a_classical_entry_is_not_scaled():
    request = check_benchmark("TargetFollower-v0", "stkf-measurements", "vtc", episodes=1)
    assert request.camera_scale == 1.0
    assert "camera_scale" not in request.identity()


def _principal_point_angle_rad(env_kwargs: dict, seed: int) -> tuple[float, float]:
    """The true camera's principal-point offset drawn at reset, as angles (dx/fx, dy/fy)."""
    env = gym.make(TF, **env_kwargs)
    try:
        env.reset(seed=seed)
        rig = env.unwrapped.rig
        (nominal,), (true,) = rig.nominal, [camera.intrinsics for camera in rig.cameras]
        return (
            (true.cx_px - nominal.cx_px) / nominal.fx_px,
            (true.cy_px - nominal.cy_px) / nominal.fy_px,
        )
    finally:
        env.close()


def test_the_agent_meets_the_same_angles_of_view_as_every_other_entry():
    """At ``lab``, the principal point the agent's camera is off by, seen as an angle, is
    the default camera's, episode by episode (before the scaling it was 1 / SMALL = 3.8x)."""
    request = check_benchmark("TargetFollower-v0", "pixels", TF_AGENT, episodes=2)
    lab = request.suite.levels[1]
    for spec in request.specs(lab):
        agent = _principal_point_angle_rad(spec.env_kwargs, spec.seed)
        suite = _principal_point_angle_rad(lab.env_options, spec.seed)
        assert math.hypot(*suite) > 1e-3  # lab's 2 px at f = 393 px: 5 mrad
        assert agent == pytest.approx(suite, rel=1e-9)


@pytest.mark.slow  # renders and fits frames (30 s at load 7)
def test_check_derives_the_scale_and_finds_a_changed_one(tmp_path):
    from observer_gym.train.cli import main
    from observer_gym.train.experiments.benchmark.check import FolderCheckError, check_folder

    out = tmp_path / "run"
    argv = ["benchmark", "--env", "TargetFollower-v0", "--policy", TF_AGENT,
            "--episodes", "1", "--workers", "1", "--no-progress", "--out", str(out)]  # fmt: skip
    assert main(argv) == 0
    scores = json.loads((out / "scores.json").read_text())
    assert scores["camera_scale"] == pytest.approx(SMALL, rel=1e-9)
    assert "default camera's pixels" in (out / "table.md").read_text()
    assert "OK" in check_folder(out)
    scores["camera_scale"] = 1.0
    (out / "scores.json").write_text(json.dumps(scores))
    with pytest.raises(FolderCheckError, match="camera_scale"):
        check_folder(out)


def test_compare_gives_an_agent_the_same_angles_and_leaves_its_camera_alone():
    options = {"measurement_noise_px": 2.0, "desired_width_px": 40.0, "push_rate_hz": 0.5}
    classical = resolve_request(TF, "stkf", ["vtc"], [0], env_kwargs=options)
    assert classical.env_kwargs_for(classical.controllers[0]) == options
    assert classical.agent_camera_scales() == {}
    request = resolve_request(TF, "pixels", [TF_AGENT], [0], env_kwargs=options)
    (agent,) = request.controllers
    kwargs = request.env_kwargs_for(agent)
    assert kwargs["measurement_noise_px"] == pytest.approx(2.0 * SMALL)
    assert kwargs["desired_width_px"] == pytest.approx(40.0 * SMALL)
    assert kwargs["push_rate_hz"] == 0.5 and kwargs["image_width_px"] == 84
    assert request.agent_camera_scales() == {TF_AGENT: pytest.approx(SMALL)}
    # a sweep's varied pixel option is scaled too; the camera's own geometry never is
    point = {"measurement_noise_px": 4.0, "image_height_px": 63}
    kwargs = request.env_kwargs_for(agent, point)
    assert kwargs["measurement_noise_px"] == pytest.approx(4.0 * SMALL)
    assert kwargs["image_height_px"] == 63
    # no pixel-valued option, nothing to scale (and no env is built to find the scale)
    plain = resolve_request(TF, "pixels", [TF_AGENT], [0], env_kwargs={"push_rate_hz": 0.5})
    assert plain.env_kwargs_for(plain.controllers[0])["push_rate_hz"] == 0.5
    assert plain.agent_camera_scales() == {}


def test_a_target_follower_pixel_metric_is_in_the_default_cameras_pixels():
    """The same angles in a camera of a quarter of the default focal lengths: a quarter of
    the pixels in the state, the same metric."""
    default = follower_task.TargetFollowerConfig()
    desired = 60.0

    def record(factor: float) -> dict:
        state = np.zeros((3, follower_task.StateIndex.TARGET_VISIBLE + 1))
        state[:, follower_task.StateIndex.TRACKING_VALID] = 1.0
        state[:, follower_task.StateIndex.X_I] = 30.0 * factor
        state[:, follower_task.StateIndex.Y_I] = 40.0 * factor
        state[:, follower_task.StateIndex.D_X] = (desired + 8.0) * factor
        config = {
            "fx_px": default.fx_px * factor,
            "fy_px": default.fy_px * factor,
            "image_width_px": 320 * factor,
            "image_height_px": 240 * factor,
            "desired_width_px": desired * factor,
        }
        return {
            "state": state, "time_s": [0.0, 0.1, 0.2], "env_config": config,
            "actions": [0, 0, 0], "rewards": [0, 0, 0], "terminated": False, "estimate": None,
        }  # fmt: skip

    full, quarter = (follower_task.episode_metrics(record(f)) for f in (1.0, 0.25))
    assert full["centre_error_px"] == pytest.approx(50.0)  # hypot(30, 40)
    assert full["width_error_px"] == pytest.approx(8.0)
    assert quarter["centre_error_px"] == pytest.approx(50.0)
    assert quarter["width_error_px"] == pytest.approx(8.0)
