"""The KUKA LBR iiwa 7 arm from pybullet_data, position-controlled through IK.

The joints run PyBullet's position motors at the physics rate. With proportional gain
k_p a joint closes the fraction k_p of its error every physics step, so it follows a
step command as a discrete first-order lag with pole (1 - k_p) per physics step
(time constant about dt_physics / k_p): that lag is part of the plant the controllers see.
"""

from __future__ import annotations

import numpy as np

from observer_gym.envs.bullet import pybullet
from observer_gym.envs.sim import Simulation
from observer_gym.envs.transforms import rotation_from_quaternion

URDF = "kuka_iiwa/model.urdf"
NUM_JOINTS = 7
EE_LINK = 6  # lbr_iiwa_link_7; its URDF frame is the flange frame used for IK


class KukaIiwa:
    """The arm, fixed at ``base_pos_world``, with its joints at ``home_q``.

    Args:
        sim: the world it lives in.
        base_pos_world: position of its base.
        home_q: joint angles (rad) of the home configuration.
        position_gain: k_p of the joint position motors, in (0, 1].
        max_torque_nm: torque limit of every joint motor.
        ik_iterations: damped-least-squares iterations per IK solve.
        ik_joint_damping: the IK's damping per joint; None keeps PyBullet's default (0.1),
            which converges slowly: a 5 cm move is solved to 23 mm in 20 iterations, while
            1e-3 solves it to 1 um (BallCatcher uses 1e-3; BallTable's tilts are small).
    """

    def __init__(
        self,
        sim: Simulation,
        base_pos_world,
        home_q,
        position_gain: float,
        max_torque_nm: float = 300.0,
        ik_iterations: int = 20,
        ik_joint_damping: float | None = None,
    ) -> None:
        self.sim = sim
        client = sim.client
        self.body = client.loadURDF(URDF, base_pos_world, useFixedBase=True)
        self.joints = list(range(NUM_JOINTS))
        info = [client.getJointInfo(self.body, j) for j in self.joints]
        self.lower_q = np.array([i[8] for i in info])
        self.upper_q = np.array([i[9] for i in info])
        self.home_q = np.asarray(home_q, dtype=float)
        self._gains = [float(position_gain)] * NUM_JOINTS
        self._torques = [float(max_torque_nm)] * NUM_JOINTS
        self._ik_iterations = int(ik_iterations)
        self._ik_options = (
            {}
            if ik_joint_damping is None
            else {"jointDamping": [float(ik_joint_damping)] * NUM_JOINTS}
        )
        # PyBullet places a link's constraint frame at its centre of mass.
        self._ee_com_in_link = np.array(client.getDynamicsInfo(self.body, EE_LINK)[3])
        self.reset_joints(self.home_q)

    def reset_joints(self, q) -> None:
        """Teleport the joints to ``q`` at rest and hold them there."""
        for j, angle in zip(self.joints, q, strict=True):
            self.sim.client.resetJointState(self.body, j, float(angle), 0.0)
        self.command_joints(q)

    def command_joints(self, q) -> None:
        """Set the joint position motors' targets."""
        self.sim.client.setJointMotorControlArray(
            self.body,
            self.joints,
            pybullet.POSITION_CONTROL,
            targetPositions=q.tolist() if isinstance(q, np.ndarray) else list(q),
            forces=self._torques,
            positionGains=self._gains,
        )

    def joint_positions(self) -> np.ndarray:
        return np.array([s[0] for s in self.sim.client.getJointStates(self.body, self.joints)])

    def ee_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """World position and rotation matrix of the flange frame."""
        state = self.sim.client.getLinkState(self.body, EE_LINK, computeForwardKinematics=True)
        return np.array(state[4]), rotation_from_quaternion(state[5])

    def solve_ik(self, ee_pos_world, ee_quat_world, iterations: int | None = None) -> np.ndarray:
        """Joint angles that put the flange at the given pose, found by damped least
        squares starting from the current joint state (PyBullet's IK; its
        ``currentPositions`` argument does not iterate, so the current state is used)."""
        q = self.sim.client.calculateInverseKinematics(
            self.body,
            EE_LINK,
            ee_pos_world.tolist() if isinstance(ee_pos_world, np.ndarray) else list(ee_pos_world),
            list(ee_quat_world),
            maxNumIterations=iterations or self._ik_iterations,
            residualThreshold=1e-10,
            **self._ik_options,
        )
        return np.asarray(q)

    def settle_at_pose(self, ee_pos_world, ee_quat_world, rounds: int = 5) -> np.ndarray:
        """Solve the IK exactly by teleporting to each solution and solving again; used
        at construction to make the home configuration exact."""
        q = self.home_q
        for _ in range(rounds):
            self.reset_joints(q)
            q = self.solve_ik(ee_pos_world, ee_quat_world, iterations=200)
        self.reset_joints(q)
        self.home_q = q
        return q

    def attach(self, body: int, body_pos_in_ee) -> int:
        """Weld ``body`` (its base frame) to the flange at ``body_pos_in_ee`` (flange
        frame), with no rotation between them, and stop the two (all links of both) from
        colliding."""
        client = self.sim.client
        body_links = [-1, *range(client.getNumJoints(body))]
        for link in [-1, *self.joints]:
            for body_link in body_links:
                client.setCollisionFilterPair(self.body, body, link, body_link, 0)
        constraint = client.createConstraint(
            self.body,
            EE_LINK,
            body,
            -1,
            pybullet.JOINT_FIXED,
            jointAxis=[0, 0, 0],
            parentFramePosition=list(np.asarray(body_pos_in_ee) - self._ee_com_in_link),
            childFramePosition=[0, 0, 0],
        )
        client.changeConstraint(constraint, maxForce=1e4)
        return constraint
