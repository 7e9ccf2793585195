"""The shipped URDFs agree with envs/ball_table/geometry.py, as PyBullet loads them."""

from __future__ import annotations

import os
from importlib import resources

import numpy as np
import pytest

import observer_gym.envs  # noqa: F401  (registers the envs)
from observer_gym.envs.ball_table import geometry as geo
from observer_gym.envs.sim import asset_path

ENV_ID = "observer_gym/BallTable-v0"
TOL = 1e-9
RED = (0.85, 0.05, 0.05)
AABB_MARGIN_M = 2e-3  # PyBullet pads AABBs with its collision margin (~1 mm for boxes)

# getVisualShapeData / getCollisionShapeData tuple fields
GEOM_TYPE, DIMENSIONS, LOCAL_POS, LOCAL_ORN = 2, 3, 5, 6
VISUAL_RGBA = 7


@pytest.fixture
def env(make_env):
    env = make_env(ENV_ID, obs_mode="state", occluder_rate_hz=1.0)
    env.reset(seed=0)
    return env


def _is_red(visual) -> bool:
    return np.allclose(visual[VISUAL_RGBA][:3], RED, atol=1e-6)


def _box_top_z(shape) -> float:
    return shape[LOCAL_POS][2] + shape[DIMENSIONS][2] / 2


def test_assets_are_found_through_importlib_resources():
    folder = resources.files("observer_gym.envs") / "assets"
    for name in ("table.urdf", "ball.urdf", "occluder.urdf"):
        path = asset_path(name)
        assert path == str(folder / name)
        assert os.path.isfile(path)
        assert path.endswith(os.path.join("assets", name))


def test_missing_asset_raises_file_not_found():
    with pytest.raises(FileNotFoundError, match=r"missing\.urdf"):
        asset_path("missing.urdf")


def test_table_top_is_a_red_square_of_side_l_with_its_surface_at_z_0(env):
    client, table = env.unwrapped.sim.client, env.unwrapped.scene.table
    visuals = client.getVisualShapeData(table)
    red = [v for v in visuals if _is_red(v)]
    assert len(red) == 1, visuals
    top = red[0]
    assert top[GEOM_TYPE] == client.GEOM_BOX
    np.testing.assert_allclose(top[DIMENSIONS][:2], [geo.TABLE_SIDE_M] * 2, atol=TOL)
    np.testing.assert_allclose(top[LOCAL_POS][:2], [0.0, 0.0], atol=TOL)
    assert abs(_box_top_z(top)) < TOL, "the red top's surface is not at z = 0 of the table frame"
    np.testing.assert_allclose(top[LOCAL_ORN], [0, 0, 0, 1], atol=TOL)

    # The collision box of the top matches its visual box.
    collisions = client.getCollisionShapeData(table, -1)
    tops = [c for c in collisions if np.allclose(c[DIMENSIONS][:2], [geo.TABLE_SIDE_M] * 2)]
    assert len(tops) == 1, collisions
    assert abs(_box_top_z(tops[0])) < TOL
    np.testing.assert_allclose(tops[0][LOCAL_POS][:2], [0.0, 0.0], atol=TOL)


def test_table_borders_match_the_geometry(env):
    client, table = env.unwrapped.sim.client, env.unwrapped.scene.table
    borders = [v for v in client.getVisualShapeData(table) if not _is_red(v)]
    collisions = client.getCollisionShapeData(table, -1)
    assert len(borders) == 4
    assert len(collisions) == 5  # the top and the four borders
    half = geo.TABLE_SIDE_M / 2
    sides = set()
    for shapes in (borders, [c for c in collisions if c[DIMENSIONS][2] > 0.02]):
        assert len(shapes) == 4
        for border in shapes:
            assert border[GEOM_TYPE] == client.GEOM_BOX
            assert abs(_box_top_z(border) - geo.BORDER_HEIGHT_M) < TOL
            pos, dims = np.asarray(border[LOCAL_POS]), np.asarray(border[DIMENSIONS])
            axis = int(np.argmax(np.abs(pos[:2])))  # the axis the border is across
            sign = np.sign(pos[axis])
            sides.add((axis, sign))
            inner_edge = sign * (pos[axis] - sign * dims[axis] / 2)
            assert abs(inner_edge - half) < TOL, "a border overlaps or leaves a gap to the top"
            assert abs(dims[axis] - geo.BORDER_WIDTH_M) < TOL
            assert abs(pos[1 - axis]) < TOL
            assert dims[1 - axis] >= geo.TABLE_SIDE_M - TOL  # spans the whole side
    assert sides == {(0, 1.0), (0, -1.0), (1, 1.0), (1, -1.0)}


def test_table_aabb_top_is_border_height_above_the_table_frame(env):
    client, table = env.unwrapped.sim.client, env.unwrapped.scene.table
    (pos, quat) = client.getBasePositionAndOrientation(table)
    # Level at reset: the table frame is parallel to the world's.
    np.testing.assert_allclose(client.getEulerFromQuaternion(quat), [0, 0, 0], atol=1e-4)
    np.testing.assert_allclose(pos, geo.TABLE_CENTRE_HOME_WORLD, atol=1e-4)
    aabb_min, aabb_max = client.getAABB(table)
    assert abs(aabb_max[2] - pos[2] - geo.BORDER_HEIGHT_M) < AABB_MARGIN_M
    half_outer = geo.TABLE_SIDE_M / 2 + geo.BORDER_WIDTH_M
    np.testing.assert_allclose(np.subtract(aabb_max[:2], pos[:2]), [half_outer] * 2, atol=2e-3)
    np.testing.assert_allclose(np.subtract(pos[:2], aabb_min[:2]), [half_outer] * 2, atol=2e-3)


def test_ball_radius_and_solid_sphere_inertia(env):
    client, ball = env.unwrapped.sim.client, env.unwrapped.scene.ball
    (visual,) = client.getVisualShapeData(ball)
    assert visual[GEOM_TYPE] == client.GEOM_SPHERE
    assert abs(visual[DIMENSIONS][0] - geo.BALL_RADIUS_M) < TOL
    # The env loads the ball with maximal coordinates; its AABB is the bare sphere's.
    aabb_min, aabb_max = client.getAABB(ball)
    np.testing.assert_allclose(
        np.subtract(aabb_max, aabb_min), [2 * geo.BALL_RADIUS_M] * 3, atol=TOL
    )
    # getCollisionShapeData does not answer for maximal-coordinate bodies: load a probe.
    probe = client.loadURDF(asset_path("ball.urdf"), [5.0, 5.0, -10.0])
    ((_, _, geom, dims, *_),) = client.getCollisionShapeData(probe, -1)
    assert geom == client.GEOM_SPHERE
    assert abs(dims[0] - geo.BALL_RADIUS_M) < TOL

    mass, _, inertia = client.getDynamicsInfo(ball, -1)[:3]
    assert mass > 0
    solid_sphere = 2.0 / 5.0 * mass * geo.BALL_RADIUS_M**2
    np.testing.assert_allclose(inertia, [solid_sphere] * 3, rtol=0, atol=TOL)
    # TOL is loose next to 1.25e-5; also require the relative agreement PyBullet gives.
    np.testing.assert_allclose(inertia, [solid_sphere] * 3, rtol=1e-9)
    assert mass == env.unwrapped.scene.ball_mass_kg


def test_occluder_half_extents_match_the_geometry(env):
    scene = env.unwrapped.scene
    client = env.unwrapped.sim.client
    assert scene.occluder is not None
    (visual,) = client.getVisualShapeData(scene.occluder)
    assert visual[GEOM_TYPE] == client.GEOM_BOX
    np.testing.assert_allclose(
        np.asarray(visual[DIMENSIONS]) / 2, geo.OCCLUDER_HALF_EXTENTS_M, atol=TOL
    )
    np.testing.assert_allclose(visual[LOCAL_POS], [0, 0, 0], atol=TOL)
    # It only hides things from the camera: no collision shape that could hit the ball.
    assert client.getCollisionShapeData(scene.occluder, -1) == ()


def test_no_occluder_is_loaded_by_default(make_env):
    env = make_env(ENV_ID, obs_mode="state")
    env.reset(seed=0)
    assert env.unwrapped.scene.occluder is None
