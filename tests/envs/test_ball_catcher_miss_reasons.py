"""BallCatcher-v1's ``info["miss_reason"]``: why an episode missed, from the catch
judgement (the env docstring's Episode End), set on the step that ends a miss and None on
every other step and on a catch; checked against where the ball ended relative to the box
and against throws aimed by geometry."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from observer_gym.envs.ball_catcher import MISS_REASONS, BallCatcherEnv
from observer_gym.envs.ball_catcher import geometry as geo
from observer_gym.envs.ball_catcher.env import PASSED_MARGIN_M
from observer_gym.envs.ball_catcher.throws import throw_through

LAUNCH = np.array([3.0, 0.0, 0.55])
FLIGHT_S = 0.42


@pytest.fixture(scope="module")
def env():
    env = BallCatcherEnv(obs_mode="state")
    yield env
    env.close()


def ball_in_box(info) -> np.ndarray:
    """The ball's centre in the box's frame (z: out of the front face)."""
    T = info["T_world_box"]
    return T[:3, :3].T @ (info["state"][:3] - T[:3, 3])


def episode(env, seed, throw=None, chase=False):
    """Reset (with ``throw``, if given) and step to the end: the box held still or, with
    ``chase``, sent toward the drag-free crossing of its home plane (the throw's, known to
    the env: a ground-truth controller). Returns every step's info."""
    options = None if throw is None else {"throw": throw}
    _, info = env.reset(seed=seed, options=options)
    infos = [info]
    crossing = info["throw"]["crossing_pos_world"]
    v_max = env.config.profile.max_speed_mps
    for _ in range(200):
        action = np.zeros(3)
        if chase and crossing is not None:
            action[1:] = np.clip(20.0 * (crossing[1:] - info["box_pos_world_m"][1:]), -v_max, v_max)
        _, _, terminated, truncated, info = env.step(action.astype(np.float32))
        infos.append(info)
        if terminated or truncated:
            break
    return infos


def expected_side(reason: str | None, info) -> None:
    """Where a miss of ``reason`` ended, by the geometry: behind the front plane, on the
    face, after entering; in front of it, fallen below MISS_HEIGHT_M, or past the box
    after never entering."""
    p = ball_in_box(info)
    if reason in ("rim_touch", "outside_clean_radius"):
        assert p[2] < 0.0 and geo.on_front_face(p), p
    else:
        fell = info["state"][2] < geo.MISS_HEIGHT_M
        passed = p[2] < -geo.BOX_DEPTH_M - PASSED_MARGIN_M
        assert fell or passed, p


@pytest.mark.parametrize("seed", range(6))
def test_every_miss_has_a_reason_and_no_catch_or_flying_step_has_one(env, seed):
    for chase in (False, True):
        infos = episode(env, seed, chase=chase)
        *before, last = infos
        assert all(info["miss_reason"] is None for info in before)
        assert all(info["outcome"] == "flying" for info in before)
        if last["outcome"] == "caught":
            assert last["miss_reason"] is None
        else:
            assert last["outcome"] == "missed"
            assert last["miss_reason"] in MISS_REASONS
            expected_side(last["miss_reason"], last)


def test_a_throw_through_the_holes_centre_is_caught_without_a_reason(env):
    throw = throw_through(LAUNCH, geo.HOLE_HOME_WORLD, FLIGHT_S)
    infos = episode(env, 0, (throw.launch_pos_world, throw.launch_vel_world))
    assert infos[-1]["outcome"] == "caught"
    assert [info["miss_reason"] for info in infos] == [None] * len(infos)


def test_a_throw_beside_the_box_missed_it(env):
    # 0.3 m to the side at the box's plane: the ball's edge 0.3 - 0.025 m from the hole's
    # axis, far beyond the front face's half side (0.09 m): it never touches the box.
    target = geo.HOLE_HOME_WORLD + np.array([0.0, 0.3, 0.0])
    throw = throw_through(LAUNCH, target, FLIGHT_S)
    last = episode(env, 0, (throw.launch_pos_world, throw.launch_vel_world))[-1]
    assert (last["outcome"], last["miss_reason"]) == ("missed", "missed_box")
    expected_side("missed_box", last)


@pytest.mark.parametrize("offset_m", [(0.0, 0.05), (0.06, 0.0), (-0.045, -0.045)])
def test_a_throw_at_the_plate_bounced_off(env, offset_m):
    # 5-6.4 cm from the axis at the box's plane: the ball's centre line meets the plate
    # (the hole's radius is 3 cm, the face's half side 9 cm), so it touches and cannot enter.
    target = geo.HOLE_HOME_WORLD + np.array([0.0, *offset_m])
    throw = throw_through(LAUNCH + np.array([0.0, *offset_m]), target, FLIGHT_S)
    infos = episode(env, 0, (throw.launch_pos_world, throw.launch_vel_world))
    assert (infos[-1]["outcome"], infos[-1]["miss_reason"]) == ("missed", "bounced_off")
    assert not infos[-1]["ball_in_flight"]  # it touched the box
    assert min(ball_in_box(info)[2] for info in infos) > 0.0  # never behind the plane
    expected_side("bounced_off", infos[-1])


@pytest.mark.parametrize("offset_m", [0.007, 0.01, 0.013])
def test_a_throw_at_the_rim_is_a_rim_touch_or_bounced_off(env, offset_m):
    # Between the clean radius (5 mm) and the hole's radius (30 mm), below the axis: the
    # ball must touch the rim before its centre reaches the plane, so no catch; it then
    # rattles in (rim_touch, ending behind the plane) or bounces off (ending in front).
    radius = geo.clean_radius_m(geo.HOLE_DIAMETER_M)
    assert radius < offset_m < geo.HOLE_DIAMETER_M / 2
    target = geo.HOLE_HOME_WORLD - np.array([0.0, 0.0, offset_m])
    throw = throw_through(LAUNCH, target, FLIGHT_S)
    infos = episode(env, 0, (throw.launch_pos_world, throw.launch_vel_world))
    last = infos[-1]
    assert last["outcome"] == "missed"
    assert last["miss_reason"] in ("rim_touch", "bounced_off")
    assert not last["ball_in_flight"]
    expected_side(last["miss_reason"], last)


@pytest.mark.parametrize(
    ("outcome", "entered_clean", "entered_after_touch", "approach_clean", "reason"),
    [
        ("flying", None, False, None, None),
        ("caught", True, False, None, None),
        ("caught", True, True, True, None),
        ("missed", False, True, False, "rim_touch"),  # the line before the touch was out
        ("missed", False, True, True, "rim_touch"),  # the entry after the touch was out
        ("missed", False, False, None, "outside_clean_radius"),
        ("missed", False, False, False, "outside_clean_radius"),  # touched after entering
        ("missed", None, False, False, "bounced_off"),
        ("missed", None, False, True, "bounced_off"),
        ("missed", None, False, None, "missed_box"),
    ],
)
def test_the_reason_follows_the_judgements_record(
    outcome, entered_clean, entered_after_touch, approach_clean, reason
):
    record = SimpleNamespace(
        _outcome=outcome,
        _entered_clean=entered_clean,
        _entered_after_touch=entered_after_touch,
        _approach_clean=approach_clean,
    )
    assert BallCatcherEnv._miss_reason(record) == reason  # type: ignore[arg-type]
