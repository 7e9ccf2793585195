"""The BallTable world: a KUKA iiwa holding the table, the ball, and an optional occluder.

The env builds a new scene in a cleared world at every reset (about 20 ms): PyBullet's
``restoreState`` leaves constraint warm-starts and renderer caches behind, and a restored
world stepped and rendered measurably differently from a new one. tests/envs/test_envs.py
checks that a reset after use equals a fresh one, pixels included.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from observer_gym.envs.ball_table import geometry as geo
from observer_gym.envs.ball_table.layout import STATE_DIM, StateIndex
from observer_gym.envs.robots.kuka_iiwa import KukaIiwa
from observer_gym.envs.sim import Simulation, asset_path
from observer_gym.envs.transforms import cross3

BALL_FRICTION = 0.8  # ample to roll without slipping: needs > (2/7) tan(tilt)
TABLE_FRICTION = 0.8
OCCLUDER_PARKED_WORLD = np.array([0.0, 0.0, -10.0])  # out of every camera's view


def tilt_quaternion(tilt_x: float, tilt_y: float) -> list[float]:
    """Quaternion (x, y, z, w) of R_x(tilt_x) @ R_y(tilt_y), in closed form."""
    sx, cx = np.sin(tilt_x / 2), np.cos(tilt_x / 2)
    sy, cy = np.sin(tilt_y / 2), np.cos(tilt_y / 2)
    return [sx * cy, cx * sy, sx * sy, cx * cy]


# ground_truth writes the state in this order.
assert tuple(StateIndex) == tuple(range(STATE_DIM)) and [i.name for i in StateIndex] == [
    "BALL_X",
    "BALL_Y",
    "BALL_VX",
    "BALL_VY",
    "TILT_X",
    "TILT_Y",
    "TILT_RATE_X",
    "TILT_RATE_Y",
]


@dataclass
class GroundTruth:
    """Everything the simulator knows after a step."""

    state: np.ndarray  # STATE_NAMES layout
    T_world_table: np.ndarray  # 4x4
    ball_pos_world: np.ndarray  # (3,)
    ball_pos_table: np.ndarray  # (3,), z = r when the ball rests on the top


class BallTableScene:
    """Builds and drives the BallTable world.

    Args:
        sim: the (empty) world to build in.
        arm_position_gain: the arm's joint motor gain (see KukaIiwa).
        with_occluder: load the occluder slab.
        arm_home_q: the exact home joint angles from an earlier build; when None they
            are refined by IK from ``geometry.ARM_HOME_Q``.
    """

    def __init__(
        self,
        sim: Simulation,
        arm_position_gain: float,
        with_occluder: bool,
        arm_home_q=None,
    ) -> None:
        self.sim = sim
        client = sim.client
        home_q = geo.ARM_HOME_Q if arm_home_q is None else arm_home_q
        self.arm = KukaIiwa(sim, geo.ARM_BASE_WORLD, home_q, arm_position_gain)
        self._table_centre_home = geo.TABLE_CENTRE_HOME_WORLD
        flange_offset = np.array([0.0, 0.0, geo.FLANGE_TO_TABLE_M])
        self._flange_offset = flange_offset
        if arm_home_q is None:
            self.arm.settle_at_pose(self._table_centre_home - flange_offset, [0, 0, 0, 1])
        self.table = client.loadURDF(asset_path("table.urdf"), list(self._table_centre_home))
        self.arm.attach(self.table, flange_offset)
        self.ball = client.loadURDF(
            asset_path("ball.urdf"),
            list(self._table_centre_home + np.array([0.0, 0.0, geo.BALL_RADIUS_M])),
            useMaximalCoordinates=True,
        )
        self.ball_mass_kg = client.getDynamicsInfo(self.ball, -1)[0]
        for body, friction in ((self.ball, BALL_FRICTION), (self.table, TABLE_FRICTION)):
            client.changeDynamics(
                body, -1, lateralFriction=friction, rollingFriction=0.0, spinningFriction=0.0
            )
        self.occluder: int | None = None
        if with_occluder:
            self.occluder = client.loadURDF(
                asset_path("occluder.urdf"), list(OCCLUDER_PARKED_WORLD), useFixedBase=True
            )
        self.occluder_pose_world: tuple[np.ndarray, np.ndarray] | None = None  # while in view

    # --- commands ---------------------------------------------------------------------
    def place_ball(self, ball_pos_table, ball_vel_table) -> None:
        """Put the ball on the table at a TRF position (x, y), rolling without slipping
        at a TRF velocity (vx, vy)."""
        T = self.table_pose()
        R = T[:3, :3]
        p_table = np.array([ball_pos_table[0], ball_pos_table[1], geo.BALL_RADIUS_M])
        v_world = R @ np.array([ball_vel_table[0], ball_vel_table[1], 0.0])
        normal = R[:, 2]
        omega_world = cross3(normal, v_world) / geo.BALL_RADIUS_M  # rolling: v = w x (r n)
        client = self.sim.client
        client.resetBasePositionAndOrientation(
            self.ball, list(T[:3, :3] @ p_table + T[:3, 3]), [0, 0, 0, 1]
        )
        client.resetBaseVelocity(self.ball, list(v_world), list(omega_world))

    def command_tilt(self, tilt_x: float, tilt_y: float) -> None:
        """Send the arm the joint targets that tilt the table about its fixed centre."""
        R = geo.tilt_rotation(tilt_x, tilt_y)
        flange_pos = self._table_centre_home - R @ self._flange_offset
        self.arm.command_joints(self.arm.solve_ik(flange_pos, tilt_quaternion(tilt_x, tilt_y)))

    def push_ball(self, impulse_world) -> None:
        """An impulse through the ball's centre (a push): its velocity jumps by J/m."""
        client = self.sim.client
        v, w = client.getBaseVelocity(self.ball)
        client.resetBaseVelocity(
            self.ball, list(np.add(v, np.asarray(impulse_world) / self.ball_mass_kg)), w
        )

    def place_occluder(self, pos_world) -> None:
        self.sim.client.resetBasePositionAndOrientation(
            self.occluder, list(pos_world), [0, 0, 0, 1]
        )
        self.occluder_pose_world = (np.asarray(pos_world, dtype=float), np.eye(3))

    def park_occluder(self) -> None:
        if self.occluder is not None:
            self.place_occluder(OCCLUDER_PARKED_WORLD)
        self.occluder_pose_world = None

    # --- ground truth -----------------------------------------------------------------
    def table_pose(self) -> np.ndarray:
        client = self.sim.client
        (x, y, z), quat = client.getBasePositionAndOrientation(self.table)
        R = client.getMatrixFromQuaternion(quat)  # row by row
        # pose_matrix(rotation_from_quaternion(quat), pos) in one array.
        return np.array(
            [
                [R[0], R[1], R[2], x],
                [R[3], R[4], R[5], y],
                [R[6], R[7], R[8], z],
                [0.0, 0.0, 0.0, 1.0],
            ]
        )

    def ground_truth(self) -> GroundTruth:
        client = self.sim.client
        T = self.table_pose()
        R, o = T[:3, :3], T[:3, 3]
        v_o, w_world = client.getBaseVelocity(self.table)
        p_ball, _ = client.getBasePositionAndOrientation(self.ball)
        v_ball, _ = client.getBaseVelocity(self.ball)
        p_ball = np.array(p_ball)
        rel = p_ball - o
        ball_pos_table = R.T @ rel
        # Velocity of the ball as seen from the (moving, rotating) table frame.
        ball_vel_table = R.T @ (np.subtract(v_ball, v_o) - cross3(w_world, rel))
        tilt_x, tilt_y = geo.tilt_angles(R)  # TRF is parallel to the world at home
        rate_x, rate_y = geo.tilt_rates(R.T @ np.array(w_world), tilt_y)
        x, y, _ = ball_pos_table.tolist()
        vx, vy, _ = ball_vel_table.tolist()
        state = np.array([x, y, vx, vy, tilt_x, tilt_y, rate_x, rate_y])  # STATE_NAMES
        return GroundTruth(state, T, p_ball, ball_pos_table)
