"""BallCatcher-v1: ballistic flight, no tunnelling, catches and misses, the camera rig's
timing, perfect measurements, the box's motion limits and configuration errors."""

from __future__ import annotations

import numpy as np
import pytest

from observer_gym.envs.ball_catcher import BallCatcherConfig, BallCatcherEnv
from observer_gym.envs.ball_catcher import geometry as geo
from observer_gym.envs.ball_catcher.throws import plane_crossing, sample_throw, throw_through
from observer_gym.envs.camera import project_points
from observer_gym.envs.robots.kuka_iiwa import KukaIiwa
from observer_gym.envs.sim import GRAVITY_MPS2, Simulation


@pytest.fixture(scope="module")
def state_env():
    env = BallCatcherEnv(obs_mode="state")
    yield env
    env.close()


def parabola(throw: dict, t_s: float) -> np.ndarray:
    p = throw["launch_pos_world"] + throw["launch_vel_world"] * t_s
    p[2] -= 0.5 * GRAVITY_MPS2 * t_s**2
    return p


def fly(env, throw, steps=200, action=None):
    """Reset with ``throw`` (launch position, velocity) and step until the end."""
    _, info = env.reset(seed=0, options={"throw": throw})
    infos = [info]
    for _ in range(steps):
        _, _, terminated, _, info = env.step(np.zeros(3, np.float32) if action is None else action)
        infos.append(info)
        if terminated:
            break
    return infos


def aimed(launch, target, flight_time_s):
    """The reset option of the drag-free throw from ``launch`` reaching ``target``."""
    throw = throw_through(launch, target, flight_time_s)
    return throw.launch_pos_world, throw.launch_vel_world


def fastest_default_throw_mps() -> float:
    rng = np.random.default_rng(0)
    cfg = BallCatcherConfig()
    return max(np.linalg.norm(sample_throw(cfg, rng).launch_vel_world) for _ in range(2000))


def test_workspace_corners_are_reachable_with_the_box_facing_the_thrower():
    sim = Simulation(0.001)
    try:
        arm = KukaIiwa(sim, geo.ARM_BASE_WORLD, geo.ARM_HOME_Q, 0.2)
        low, high = geo.WORKSPACE_LOW_WORLD, geo.WORKSPACE_HIGH_WORLD
        for corner in np.array(np.meshgrid(*zip(low, high, strict=True))).T.reshape(-1, 3):
            flange = corner - np.array([geo.FLANGE_TO_HOLE_M, 0.0, 0.0])
            arm.reset_joints(geo.ARM_HOME_Q)
            arm.settle_at_pose(flange, geo.FLANGE_QUAT_WORLD, rounds=8)
            pos, R = arm.ee_pose()
            assert np.linalg.norm(pos - flange) < 1e-3, corner
            assert np.linalg.norm(R[:, 2] - geo.NORMAL_WORLD) < 1e-3, corner
    finally:
        sim.close()


def test_the_box_holds_the_hole_at_home(state_env):
    infos = fly(state_env, (np.array([3.0, 2.0, 0.5]), np.array([0.0, 0.0, 0.0])), steps=30)
    np.testing.assert_allclose(infos[-1]["box_pos_world_m"], geo.HOLE_HOME_WORLD, atol=5e-4)


def test_the_flight_is_exactly_ballistic_without_drag(state_env):
    infos = fly(state_env, (np.array([3.0, 0.1, 0.5]), np.array([-6.0, 0.0, 2.0])), steps=30)
    throw = infos[0]["throw"]
    for info in infos[1:]:
        np.testing.assert_allclose(info["state"][:3], parabola(throw, info["time_s"]), atol=1e-9)


def test_air_drag_decelerates_as_the_quadratic_law_says():
    env = BallCatcherEnv(obs_mode="state", air_drag=True)
    try:
        v0 = np.array([-6.0, 0.0, 0.0])
        infos = fly(env, (np.array([3.0, 0.0, 1.5]), v0), steps=10)
        vx = [info["state"][3] for info in infos]
        accel_mps2 = (vx[-1] - vx[1]) / (infos[-1]["time_s"] - infos[1]["time_s"])
        area = np.pi * geo.BALL_RADIUS_M**2
        expected = 0.5 * 1.2 * 0.47 * area * 6.0**2 / 0.05  # rho Cd A v^2 / (2 m)
        assert accel_mps2 == pytest.approx(expected, rel=0.03)
    finally:
        env.close()


def test_aimed_throws_through_the_hole_are_caught_and_beside_it_missed(state_env):
    launch = np.array([3.0, 0.05, 0.55])
    caught = fly(state_env, aimed(launch, geo.HOLE_HOME_WORLD, 0.42))
    assert caught[-1]["outcome"] == "caught"
    beside = geo.HOLE_HOME_WORLD + np.array([0.0, 0.05, 0.0])  # onto the plate
    missed = fly(state_env, aimed(launch, beside, 0.42))
    assert missed[-1]["outcome"] == "missed"


@pytest.mark.parametrize("offset_m", [(0.05, 0.0), (0.0, 0.06), (-0.045, -0.045)])
def test_no_tunnelling_through_the_plate_at_one_and_a_half_times_the_fastest_throw(
    state_env, offset_m
):
    speed = 1.5 * fastest_default_throw_mps()  # about 10 m/s
    target = geo.HOLE_HOME_WORLD + np.array([0.0, *offset_m])
    launch = target + np.array([2.4, 0.0, 0.0])
    flight_s = 2.4 / speed  # nearly flat: the whole speed goes into the plate
    infos = fly(state_env, aimed(launch, target, flight_s))
    assert np.linalg.norm(infos[0]["throw"]["launch_vel_world"]) >= speed
    front_m = [info["state"][0] - geo.HOLE_HOME_WORLD[0] for info in infos]
    assert min(front_m) > -geo.WALL_M  # the ball's centre never got behind the plate
    assert infos[-1]["outcome"] == "missed"


def test_a_fast_throw_through_the_hole_stays_in_the_box(state_env):
    speed = 1.5 * fastest_default_throw_mps()
    launch = geo.HOLE_HOME_WORLD + np.array([2.4, 0.0, 0.0])
    infos = fly(
        state_env,
        aimed(launch, geo.HOLE_HOME_WORLD, 2.4 / speed),
        steps=40,
    )
    assert infos[-1]["outcome"] == "caught"
    # It cannot leave through the back wall: keep stepping the world after the catch.
    env = state_env
    for _ in range(30):
        _, _, _, _, info = env.step(np.zeros(3, np.float32))
    assert info["state"][0] > geo.HOLE_HOME_WORLD[0] - geo.BOX_DEPTH_M


@pytest.mark.parametrize(
    ("preset", "phases_s"),
    [("synchronised", (0.0, 0.0)), ("alternating", (0.0, 0.01))],
)
def test_camera_presets_capture_at_their_phases(preset, phases_s):
    env = BallCatcherEnv(obs_mode="state", camera_preset=preset, latency_s=0.015)
    try:
        env.reset(seed=0)
        frames = []
        for _ in range(40):
            frames += env.step(np.zeros(3, np.float32))[4]["frames"]
        for camera, phase in enumerate(phases_s):
            times = np.array([f["capture_time_s"] for f in frames if f["camera_id"] == camera])
            np.testing.assert_allclose(times, phase + 0.02 * np.arange(len(times)), atol=1e-12)
        delays = np.array([f["delivery_time_s"] - f["capture_time_s"] for f in frames])
        assert delays.min() >= 0.015 - 1e-12 and delays.max() < 0.015 + 0.01
    finally:
        env.close()


def test_random_offsets_deliver_frames_out_of_order_and_drops_lose_frames():
    env = BallCatcherEnv(obs_mode="state", camera_preset="random_offsets", frame_drop_prob=0.3)
    try:
        late = delivered = 0
        for seed in range(8):
            env.reset(seed=seed)
            newest = -1.0
            for _ in range(50):
                for frame in env.step(np.zeros(3, np.float32))[4]["frames"]:
                    delivered += 1
                    late += frame["capture_time_s"] < newest
                    newest = max(newest, frame["capture_time_s"])
        assert late > 0
        captured = 8 * 2 * 50 * 0.01 * 50  # cameras x steps x dt x rate, about
        assert 0.6 * captured < delivered < 0.8 * captured  # 70 % kept
    finally:
        env.close()


def test_measurements_are_the_projected_centre_at_capture_time():
    env = BallCatcherEnv(obs_mode="measurements", measurement_noise_px=0.0)
    try:
        obs, info = env.reset(seed=4)
        throw = info["throw"]
        checked = 0
        for _ in range(30):
            obs, _, _, _, info = env.step(np.zeros(3, np.float32))
            for frame in info["frames"]:
                p = parabola(throw, frame["capture_time_s"])
                uv, _ = project_points(frame["K"], frame["T_world_cam"], p[None])
                if frame["uv_px"] is not None:
                    np.testing.assert_allclose(frame["uv_px"], uv[0], atol=1e-6)
                    checked += 1
            c = info["frames"][-1]["camera_id"] if info["frames"] else None
            if c is not None and info["frames"][-1]["uv_px"] is not None:
                np.testing.assert_allclose(
                    obs["uv_px"][2 * c : 2 * c + 2], info["frames"][-1]["uv_px"], atol=1e-4
                )
        assert checked >= 25
    finally:
        env.close()


@pytest.mark.parametrize("profile", ["paper", "fast"])
def test_box_motion_respects_the_robot_profile(profile):
    env = BallCatcherEnv(obs_mode="state", robot_profile=profile)
    try:
        limits, dt_s = env.config.profile, env.config.control_dt_s
        env.reset(seed=0, options={"throw": (np.array([3.0, 2.0, 0.5]), np.zeros(3))})
        targets, positions = [], []
        for k in range(40):  # full speed up and left, then reversed, then into a face
            command = np.array([0.0, 1.0, -1.0]) if k < 8 else np.array([0.0, -1.0, 1.0])
            positions.append(env.step(5.0 * command)[4]["box_pos_world_m"])
            targets.append(env.unwrapped.scene.hole_target_world.copy())
        # The commanded motion keeps the profile exactly ...
        velocity = np.diff(np.array(targets), axis=0) / dt_s
        speed = np.linalg.norm(velocity, axis=1)
        accel = np.linalg.norm(np.diff(velocity, axis=0), axis=1) / dt_s
        assert speed.max() <= limits.max_speed_mps + 1e-9
        assert speed.max() >= 0.99 * limits.max_speed_mps
        inside = np.array(targets)
        assert np.all(inside >= geo.WORKSPACE_LOW_WORLD - 1e-12)
        assert np.all(inside <= geo.WORKSPACE_HIGH_WORLD + 1e-12)
        on_face = np.any(
            (inside <= geo.WORKSPACE_LOW_WORLD + 1e-9)
            | (inside >= geo.WORKSPACE_HIGH_WORLD - 1e-9),
            axis=1,
        )
        free = ~(on_face[:-2] | on_face[1:-1] | on_face[2:])  # the velocity stops at a face
        assert free.sum() >= 10
        assert accel[free].max() <= limits.max_accel_mps2 + 1e-6
        # ... and the box follows it through the arm's lag (a few ms), overshooting a little.
        box_speed = np.linalg.norm(np.diff(np.array(positions), axis=0), axis=1) / dt_s
        assert box_speed.max() <= 1.25 * limits.max_speed_mps
        np.testing.assert_allclose(positions[-1], targets[-1], atol=2e-3)
    finally:
        env.close()


@pytest.mark.parametrize(
    ("options", "match"),
    [
        ({"camera_preset": "single", "num_cameras": 2}, "num_cameras"),
        ({"control_dt_s": 0.01, "physics_dt_s": 0.003}, "multiple"),
        ({"flight_time_min_s": 0.6, "flight_time_max_s": 0.5}, "flight_time_min_s"),
        ({"robot_profile": "slow"}, "robot_profile"),
        ({"num_cameras": 5}, "num_cameras"),
    ],
)
def test_bad_configuration_raises_at_construction(options, match):
    with pytest.raises(ValueError, match=match):
        BallCatcherEnv(**options)


def test_bad_reset_throw_raises(state_env):
    with pytest.raises(ValueError, match="throw"):
        state_env.reset(seed=0, options={"throw": (np.zeros(3), np.array([np.nan, 0, 0]))})
    with pytest.raises(ValueError, match="throw"):
        state_env.reset(seed=0, options={"throw": (np.zeros(2), np.zeros(3))})


def test_a_throw_that_never_reaches_the_box_has_no_crossing(state_env):
    """A ball dropped (or thrown away from the box) never crosses the box's plane: its
    info says None, not NaN, so two equal resets compare equal (Gymnasium's
    data_equivalence, as the fuzz suite checks determinism; NaN != NaN failed it)."""
    from gymnasium.utils.env_checker import data_equivalence

    other = BallCatcherEnv(obs_mode="state")
    try:
        for velocity in ([0.0, 0.0, 0.0], [2.0, 0.0, 1.0]):
            throw = ([0.0, 0.0, 0.5], velocity)
            first = state_env.reset(seed=3, options={"throw": throw})
            second = other.reset(seed=3, options={"throw": throw})
            assert first[1]["throw"]["crossing_time_s"] is None
            assert first[1]["throw"]["crossing_pos_world"] is None
            assert data_equivalence(first, second)
    finally:
        other.close()


@pytest.mark.parametrize(
    ("offset_m", "outcome"), [(0.0, "caught"), (0.02, "missed"), (0.03, "missed"), (0.05, "missed")]
)
def test_shaping_is_potential_based_and_the_catch_adds_one(offset_m, outcome):
    """Each reward is w (m_prev - m) + [caught], m the predicted miss: where the ball,
    drag-free, crosses the box's front plane, relative to the hole (from the ground
    truth; kept once the ball stops approaching, and from its first touch of the box on,
    seen here as the first step whose velocity change is not gravity's). The sum
    telescopes."""
    weight = 3.0
    env = BallCatcherEnv(obs_mode="state", shaping_weight=weight)
    dv_gravity = np.array([0.0, 0.0, -GRAVITY_MPS2 * env.config.control_dt_s])
    touched = []

    def predicted_miss_m(state, previous_m, previous_state=None):
        if previous_state is not None and not touched:
            dv = state[3:6] - previous_state[3:6] - dv_gravity
            if np.linalg.norm(dv) > 1e-3:  # a contact's impulse, not free flight
                touched.append(True)
        crossing = plane_crossing(state[0:3], state[3:6], state[6])
        if crossing is None or touched:
            return previous_m
        return float(np.linalg.norm(crossing[1][1:] - state[7:9]))

    try:
        launch = np.array([3.0, 0.05, 0.55])
        target = geo.HOLE_HOME_WORLD + np.array([0.0, offset_m, 0.0])
        _, info = env.reset(seed=0, options={"throw": aimed(launch, target, 0.42)})
        miss_m = first_m = predicted_miss_m(info["state"], 0.0)
        assert first_m == pytest.approx(offset_m, abs=3e-3)  # aimed offset_m off (+-2 mm)
        rewards = []
        # The box drifts sideways (2 mm by the crossing, inside the hole's clean 5 mm; at
        # 0.02 m/s the ball met the rim 8 mm off, no catch by the geometric rule): the
        # predicted miss changes.
        for _ in range(200):
            state = info["state"]
            _, reward, terminated, _, info = env.step(np.array([0.0, 0.005, 0.0], np.float32))
            previous_m, miss_m = miss_m, predicted_miss_m(info["state"], miss_m, state)
            expected = weight * (previous_m - miss_m) + (info["outcome"] == "caught")
            assert reward == pytest.approx(expected, abs=1e-9)
            rewards.append(reward)
            if terminated:
                break
        assert info["outcome"] == outcome
        if outcome == "missed":
            assert touched  # it struck the plate and bounced: the shaping stopped there
        assert np.sum(rewards) == pytest.approx(
            weight * (first_m - miss_m) + (outcome == "caught"), abs=1e-9
        )
    finally:
        env.close()
