"""The BallCatcher world: a KUKA iiwa carrying the box with the hole, and the ball.

The box is one rigid body built from boxes (PyBullet has no primitive plate with a hole):
a square front plate of WALL_M thickness whose round hole's rim is a ring of
HOLE_SEGMENTS boxes tangent to the hole's circle (their inner faces form a regular
polygon circumscribing it: the widest gap exceeds the hole's radius by
r (1 / cos(pi / N) - 1), 0.26 mm at N = 24), four side walls and a back wall. The box's
frame has its origin at the hole's centre on the front face's outer plane, z along the
outward normal; its centre of mass is put there too, so PyBullet's base pose and velocity
are the hole's.

Tunnelling: PyBullet's collision test is discrete, so a fast ball can step past the 1 cm
front plate or be pushed sideways through the rim when it is first found deep inside it
(measured: at a 1 ms step, throws from 20 m/s aimed 1.4 cm off the hole's axis went
through the rim; at 5 ms, from 5 m/s). A swept-sphere radius (PyBullet's
ccdSweptSphereRadius, with or without contactProcessingThreshold=0) did not stop it. So
:meth:`BallCatcherScene.step` splits a physics step into substeps while the ball is within
reach of the box and moves more than MAX_SUBSTEP_MOTION_M (the wall's 1 cm) relative to it
per step: enough that it moves at most SUBSTEP_MOTION_M (5 mm) per substep, so it is found
at most 5 mm into a wall and pushed back out the way it came (with 1 cm substeps a 92 m/s
ball still squeezed 4 mm into the rim). The default throws (under 7 m/s at 1 ms) never
need a substep. tests/envs/test_ball_catcher_tunnelling.py throws at the rim, the plate and
the hole from 5 m/s up to the fastest throw the configuration allows (91.7 m/s), at the
smallest and largest physics steps.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from observer_gym.envs.ball_catcher import geometry as geo
from observer_gym.envs.ball_catcher.layout import STATE_DIM, StateIndex
from observer_gym.envs.bullet import pybullet
from observer_gym.envs.robots.kuka_iiwa import KukaIiwa
from observer_gym.envs.sim import GRAVITY_MPS2, Simulation, asset_path
from observer_gym.envs.transforms import norm

BOX_MASS_KG = 0.5
MAX_SHAPES_PER_LINK = 16  # PyBullet's limit on the shapes of one link
BOX_RGBA = (0.85, 0.85, 0.8, 1.0)
RESTITUTION = 0.4
IK_JOINT_DAMPING = 1e-3  # exact IK in 20 iterations (see KukaIiwa)
# Near the box, a physics step in which the ball moves more than MAX_SUBSTEP_MOTION_M
# relative to it is split into substeps of at most SUBSTEP_MOTION_M.
MAX_SUBSTEP_MOTION_M = geo.WALL_M
SUBSTEP_MOTION_M = geo.WALL_M / 2
# The radius of the sphere around the box's centre that holds the box.
BOX_BOUND_RADIUS_M = float(np.hypot(np.sqrt(2.0) * geo.BOX_OUTER_SIDE_M / 2, geo.BOX_DEPTH_M / 2))
_BOX_CENTRE_BOX = np.array([0.0, 0.0, -geo.BOX_DEPTH_M / 2])  # the box's centre, box frame
# ground_truth writes the state as ball position, ball velocity, box position, box velocity.
_STATE_STARTS = (StateIndex.BALL_X, StateIndex.BALL_VX, StateIndex.BOX_X, StateIndex.BOX_VX)
assert _STATE_STARTS == (0, 3, 6, 9) and STATE_DIM == 12
# may_reach_box: room for gravity's bend over a step (g t^2 / 2 = 0.5 mm at 10 ms) and more.
REACH_MARGIN_M = 0.05
# Quadratic drag (optional): F = -1/2 rho C_d A |v| v, air at 20 C, smooth sphere.
AIR_DENSITY_KGPM3 = 1.2
DRAG_COEFFICIENT = 0.47


def _box_parts(hole_radius_m: float) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """(half extents, centre, rotation about z in rad) of every part, box frame."""
    r, s, w, d = hole_radius_m, geo.BOX_OUTER_SIDE_M / 2, geo.WALL_M, geo.BOX_DEPTH_M
    n = geo.HOLE_SEGMENTS
    z_front = -w / 2
    # The plate leaves a square of half-side h0 open around the hole; the ring fills it.
    h0 = r + 0.01
    ring_outer = h0 * np.sqrt(2.0) / np.cos(np.pi / n) + 0.002  # covers the square's corners
    half_len = ring_outer * np.tan(np.pi / n)
    radial_half = (ring_outer - r) / 2
    parts = []
    for i in range(n):
        a = 2.0 * np.pi * i / n
        centre = (r + radial_half) * np.array([np.cos(a), np.sin(a), 0.0])
        centre[2] = z_front
        parts.append((np.array([radial_half, half_len, w / 2]), centre, a))
    # Front plate around the open square: top and bottom full width, left and right between.
    parts.append((np.array([s, (s - h0) / 2, w / 2]), np.array([0.0, (s + h0) / 2, z_front]), 0.0))
    parts.append((np.array([s, (s - h0) / 2, w / 2]), np.array([0.0, -(s + h0) / 2, z_front]), 0.0))
    parts.append((np.array([(s - h0) / 2, h0, w / 2]), np.array([(s + h0) / 2, 0.0, z_front]), 0.0))
    parts.append(
        (np.array([(s - h0) / 2, h0, w / 2]), np.array([-(s + h0) / 2, 0.0, z_front]), 0.0)
    )
    # Side walls and the back wall.
    z_mid = -(w + d) / 2
    side_half = (d - w) / 2
    parts.append((np.array([s, w / 2, side_half]), np.array([0.0, s - w / 2, z_mid]), 0.0))
    parts.append((np.array([s, w / 2, side_half]), np.array([0.0, -s + w / 2, z_mid]), 0.0))
    parts.append((np.array([w / 2, s - w, side_half]), np.array([s - w / 2, 0.0, z_mid]), 0.0))
    parts.append((np.array([w / 2, s - w, side_half]), np.array([-s + w / 2, 0.0, z_mid]), 0.0))
    parts.append((np.array([s, s, w / 2]), np.array([0.0, 0.0, -d + w / 2]), 0.0))
    return parts


@dataclass
class GroundTruth:
    state: np.ndarray  # STATE_NAMES layout
    T_world_box: np.ndarray  # 4x4, origin at the hole's centre


def _readonly(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False
    return a


class WorldNow:
    """The ball and the box at one version of the world (``Simulation.version``): PyBullet's
    answers, and what the scene derives from them, each computed on first use, so a tick's
    ground truth is asked for once however many of the scene's methods need it (the
    arrays are read-only: they are shared)."""

    __slots__ = (
        "R_raw",
        "_arrays",
        "_ball_in_box",
        "_box_centre_distance",
        "_speed",
        "ball_pos",
        "ball_vel",
        "box_pos",
        "box_vel",
        "version",
    )

    def __init__(self, version: int, ball_pos, ball_vel, box_pos, box_vel, R_raw) -> None:
        self.version = version
        # PyBullet's tuples: positions, linear velocities, R_world_box row by row.
        self.ball_pos, self.ball_vel = ball_pos, ball_vel
        self.box_pos, self.box_vel = box_pos, box_vel
        self.R_raw = R_raw
        self._arrays: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None
        self._ball_in_box: tuple[np.ndarray, np.ndarray] | None = None
        self._box_centre_distance: float | None = None
        self._speed: float | None = None

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(ball centre, box origin, R_world_box, ball velocity relative to the box)."""
        if self._arrays is None:
            self._arrays = (
                _readonly(np.array(self.ball_pos)),
                _readonly(np.array(self.box_pos)),
                _readonly(np.array(self.R_raw).reshape(3, 3)),
                _readonly(np.subtract(self.ball_vel, self.box_vel)),
            )
        return self._arrays


class BallCatcherScene:
    """Builds and drives the BallCatcher world.

    Args:
        sim: the (empty) world to build in.
        hole_diameter_m: the hole's diameter.
        arm_position_gain: the arm's joint motor gain.
        arm_home_q: exact home joint angles from an earlier build (None: refine by IK).
    """

    def __init__(
        self,
        sim: Simulation,
        hole_diameter_m: float,
        arm_position_gain: float,
        arm_home_q=None,
    ) -> None:
        self.sim = sim
        client = sim.client
        home_q = geo.ARM_HOME_Q if arm_home_q is None else arm_home_q
        self.arm = KukaIiwa(
            sim, geo.ARM_BASE_WORLD, home_q, arm_position_gain, ik_joint_damping=IK_JOINT_DAMPING
        )
        self._flange_offset = np.array([geo.FLANGE_TO_HOLE_M, 0.0, 0.0])  # world, flange to hole
        if arm_home_q is None:
            self.arm.settle_at_pose(self.flange_target(geo.HOLE_HOME_WORLD), geo.FLANGE_QUAT_WORLD)
        self.box = self._build_box(hole_diameter_m / 2)
        self.arm.attach(self.box, [0.0, 0.0, geo.FLANGE_TO_HOLE_M])
        self.ball = client.loadURDF(
            asset_path("ball.urdf"), [0.0, 0.0, -5.0], useMaximalCoordinates=True
        )
        # PyBullet damps every body's velocity by default (linear damping 0.04 1/s, a
        # 2 cm error over a 0.45 s throw): off, so the flight is ballistic (19)-(20).
        client.changeDynamics(
            self.ball, -1, restitution=RESTITUTION, linearDamping=0.0, angularDamping=0.0
        )
        self.ball_mass_kg = client.getDynamicsInfo(self.ball, -1)[0]
        self.hole_target_world = geo.HOLE_HOME_WORLD.copy()
        self.air_drag = False
        self._now: WorldNow | None = None  # the ground truth of the world's latest version

    def _build_box(self, hole_radius_m: float) -> int:
        """The box as one multibody: PyBullet keeps at most 16 shapes per link, so the
        parts are spread over the base and fixed links that share its frame."""
        client = self.sim.client
        parts = _box_parts(hole_radius_m)
        groups = [
            parts[i : i + MAX_SHAPES_PER_LINK] for i in range(0, len(parts), MAX_SHAPES_PER_LINK)
        ]
        collisions, visuals = [], []
        for group in groups:
            half_extents = [list(h) for h, _, _ in group]
            centres = [list(c) for _, c, _ in group]
            quats = [list(pybullet.getQuaternionFromEuler([0.0, 0.0, a])) for _, _, a in group]
            box_types = [pybullet.GEOM_BOX] * len(group)
            collisions.append(
                client.createCollisionShapeArray(
                    box_types,
                    halfExtents=half_extents,
                    collisionFramePositions=centres,
                    collisionFrameOrientations=quats,
                )
            )
            # (rgbaColors here crashes PyBullet 3.2.7; the colour is set below.)
            visuals.append(
                client.createVisualShapeArray(
                    box_types,
                    halfExtents=half_extents,
                    visualFramePositions=centres,
                    visualFrameOrientations=quats,
                )
            )
        links = len(groups) - 1
        link_mass = BOX_MASS_KG / len(groups)
        zeros, identity = [[0.0, 0.0, 0.0]] * links, [[0.0, 0.0, 0.0, 1.0]] * links
        body = client.createMultiBody(
            baseMass=link_mass,
            baseCollisionShapeIndex=collisions[0],
            baseVisualShapeIndex=visuals[0],
            basePosition=list(geo.HOLE_HOME_WORLD),
            baseOrientation=list(geo.FLANGE_QUAT_WORLD),
            linkMasses=[link_mass] * links,
            linkCollisionShapeIndices=collisions[1:],
            linkVisualShapeIndices=visuals[1:],
            linkPositions=zeros,
            linkOrientations=identity,
            linkInertialFramePositions=zeros,
            linkInertialFrameOrientations=identity,
            linkParentIndices=[0] * links,
            linkJointTypes=[pybullet.JOINT_FIXED] * links,
            linkJointAxis=[[0.0, 0.0, 1.0]] * links,
        )
        for link in range(-1, links):
            client.changeVisualShape(body, link, rgbaColor=list(BOX_RGBA))
            client.changeDynamics(body, link, restitution=RESTITUTION)
        return body

    # --- commands ---------------------------------------------------------------------
    def flange_target(self, hole_pos_world) -> np.ndarray:
        return np.asarray(hole_pos_world, dtype=float) - self._flange_offset

    def launch_ball(self, pos_world, vel_world) -> None:
        """Put the ball at ``pos_world`` flying at ``vel_world``.

        PyBullet integrates semi-implicitly (v += a dt, then x += v dt), which puts the
        ball g dt t / 2 below the parabola at time t (0.2 mm at 0.45 s and 1 kHz); starting
        with v_z + g dt / 2 makes every physics step land exactly on it.
        """
        client = self.sim.client
        vel = np.array(vel_world, dtype=float)
        vel[2] += 0.5 * GRAVITY_MPS2 * self.sim.physics_dt_s
        client.resetBasePositionAndOrientation(self.ball, list(pos_world), [0, 0, 0, 1])
        client.resetBaseVelocity(self.ball, list(vel), [0.0, 0.0, 0.0])
        self.sim.touch()

    def command_hole(self, hole_pos_world) -> None:
        """Send the arm the joint targets that put the hole at ``hole_pos_world``."""
        self.hole_target_world = np.asarray(hole_pos_world, dtype=float).copy()
        q = self.arm.solve_ik(self.flange_target(hole_pos_world), geo.FLANGE_QUAT_WORLD)
        self.arm.command_joints(q)

    def substeps(self) -> int:
        """How many substeps the next physics step needs: 1 unless the ball would move
        more than MAX_SUBSTEP_MOTION_M relative to the box within reach of it (its centre
        nearer the box's centre than BOX_BOUND_RADIUS_M, the ball's radius and one step's
        motion); then enough that it moves at most SUBSTEP_MOTION_M per substep."""
        now = self.world_now()
        motion_m = self._relative_speed(now) * self.sim.physics_dt_s
        if motion_m <= MAX_SUBSTEP_MOTION_M:
            return 1
        reach_m = BOX_BOUND_RADIUS_M + geo.BALL_RADIUS_M + motion_m
        if self._distance_to_box_centre(now) > reach_m:
            return 1
        return int(np.ceil(motion_m / SUBSTEP_MOTION_M))

    def may_reach_box(self, horizon_s: float) -> bool:
        """Whether the ball, moving at its velocity relative to the box, could come within
        reach of the box (BOX_BOUND_RADIUS_M of its centre, plus the ball's radius and a
        margin for gravity's bend) within ``horizon_s``."""
        now = self.world_now()
        reach_m = (
            BOX_BOUND_RADIUS_M
            + geo.BALL_RADIUS_M
            + self._relative_speed(now) * horizon_s
            + REACH_MARGIN_M
        )
        return self._distance_to_box_centre(now) <= reach_m

    def _ball_and_box(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(ball centre, box origin (the hole's centre), R_world_box, ball velocity relative
        to the box), world frame (read-only arrays)."""
        return self.world_now().arrays()

    def world_now(self) -> WorldNow:
        """The ball and the box now: PyBullet is asked once per version of the world (the
        world changes only by the scene's and the Simulation's steps and teleports, and
        each of them moves ``sim.version`` on)."""
        now, version = self._now, self.sim.version
        if now is not None and now.version == version:
            return now
        client = self.sim.client
        ball_pos, _ = client.getBasePositionAndOrientation(self.ball)
        box_pos, box_quat = client.getBasePositionAndOrientation(self.box)
        self._now = now = WorldNow(
            version,
            ball_pos,
            client.getBaseVelocity(self.ball)[0],
            box_pos,
            client.getBaseVelocity(self.box)[0],
            client.getMatrixFromQuaternion(box_quat),
        )
        return now

    @staticmethod
    def _relative_speed(now: WorldNow) -> float:
        """The ball's speed relative to the box."""
        if now._speed is None:
            now._speed = norm(now.arrays()[3])
        return now._speed

    @staticmethod
    def _distance_to_box_centre(now: WorldNow) -> float:
        """The ball's centre's distance from the box's centre."""
        if now._box_centre_distance is None:
            ball_pos, box_pos, R, _ = now.arrays()
            now._box_centre_distance = norm(ball_pos - (box_pos + R @ _BOX_CENTRE_BOX))
        return now._box_centre_distance

    def step(self, air_drag: bool, after_substep: Callable[[], None]) -> None:
        """One physics step of ``sim.physics_dt_s``, in :meth:`substeps` equal substeps
        (PyBullet's time step is set for them and restored), with the ball's air drag
        (optional) and ``after_substep()`` after each."""
        client = self.sim.client
        dt_s = self.sim.physics_dt_s
        n = self.substeps()
        if n > 1:
            client.setTimeStep(dt_s / n)
        try:
            for _ in range(n):
                if air_drag:
                    self.apply_drag()
                client.stepSimulation()
                self.sim.touch()
                after_substep()
        finally:
            if n > 1:
                client.setTimeStep(dt_s)

    def apply_drag(self) -> None:
        """Quadratic air drag on the ball for the next physics step (forces are cleared
        after every step)."""
        client = self.sim.client
        v = np.asarray(client.getBaseVelocity(self.ball)[0])
        area = np.pi * geo.BALL_RADIUS_M**2
        force = -0.5 * AIR_DENSITY_KGPM3 * DRAG_COEFFICIENT * area * np.linalg.norm(v) * v
        pos, _ = client.getBasePositionAndOrientation(self.ball)
        client.applyExternalForce(self.ball, -1, list(force), list(pos), pybullet.WORLD_FRAME)

    # --- ground truth -----------------------------------------------------------------
    def ball_pos_world(self) -> np.ndarray:
        return np.array(self.world_now().ball_pos)

    def ball_in_box(self, now: WorldNow | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The ball's centre and its velocity relative to the box, box frame (read-only
        arrays), now or at ``now`` (an earlier :meth:`world_now`)."""
        if now is None:
            now = self.world_now()
        if now._ball_in_box is None:
            ball_pos, box_pos, R, v_rel = now.arrays()
            now._ball_in_box = (_readonly(R.T @ (ball_pos - box_pos)), _readonly(R.T @ v_rel))
        return now._ball_in_box

    def ball_touches_box(self) -> bool:
        """Whether the last physics step pushed the ball off the box (a contact with a
        normal force)."""
        contacts = self.sim.client.getContactPoints(self.ball, self.box)
        return any(contact[9] > 0.0 for contact in contacts)

    def ground_truth(self) -> GroundTruth:
        now = self.world_now()
        # The STATE_NAMES layout: ball position and velocity, box position and velocity.
        state = np.array(now.ball_pos + now.ball_vel + now.box_pos + now.box_vel)
        R, (x, y, z) = now.R_raw, now.box_pos
        T = np.array(
            [
                [R[0], R[1], R[2], x],
                [R[3], R[4], R[5], y],
                [R[6], R[7], R[8], z],
                [0.0, 0.0, 0.0, 1.0],
            ]
        )
        return GroundTruth(state, T)
