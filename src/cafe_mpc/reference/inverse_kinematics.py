"""Joint references consistent with the foot references (leg inverse kinematics).

The whole-body cost (18) tracks joint angles as well as the base and the swing feet. If the joint reference
is the standing pose, the two fight: to lift a swing foot 6 cm it is cheaper to raise the whole body than to
fold the leg away from the standing angles, and a stance leg that must sweep backwards under a base moving
at 0.5 m/s is pulled forward by its joint cost. In closed loop that lifted the trotting base from 0.25 m to
0.28 m and halved the forward speed. The fix is the usual one: joint references from inverse kinematics of
the reference feet (stance feet at their footholds, swing feet on their Bezier curves) about the reference
base pose, and joint-rate references from the same Jacobians.

Each leg is a 3-joint chain, so per leg this is a 3 x 3 damped Newton iteration on Pinocchio's frame
Jacobians (any quadruped, no closed form per robot); warm-started from the previous knot it converges in
two or three iterations.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from cafe_mpc.robots.robot import Robot

LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED


class LegInverseKinematics:
    """Joint angles and rates that put the four feet at given world positions/velocities for a base pose."""

    def __init__(self, robot: Robot, iterations: int = 8, tolerance: float = 1e-5, damping: float = 1e-6):
        self.robot = robot
        self.model = robot.model
        self.data = robot.model.createData()
        self.frame_ids = robot.foot_frame_ids
        self.iterations = iterations
        self.tolerance = tolerance
        self.damping = damping
        self._damping_matrix = damping * np.eye(3)
        self.lower = robot.position_lower
        self.upper = robot.position_upper
        self._q = robot.q_standing.copy()

    def solve(
        self,
        base_configuration: np.ndarray,
        foot_positions: np.ndarray,
        joint_guess: np.ndarray | None = None,
        base_velocity: np.ndarray | None = None,
        foot_velocities: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray, float]:
        """Joint angles (12), joint rates (12) and the largest remaining foot-position error (m).

        ``base_configuration``: base position and quaternion (7); ``foot_positions``: world (4, 3);
        ``base_velocity``: base-frame linear and angular velocity (6); ``foot_velocities``: world (4, 3).
        Feet out of reach end as close as the joint limits allow (the error is returned, not raised).
        """
        model, data, q = self.model, self.data, self._q
        q[:7] = base_configuration
        q[7:] = self.robot.q_standing[7:] if joint_guess is None else joint_guess
        error_max = np.inf
        for _ in range(self.iterations):
            pin.forwardKinematics(model, data, q)
            error_max = 0.0
            pin.computeJointJacobians(model, data, q)
            for leg, frame_id in enumerate(self.frame_ids):
                position = pin.updateFramePlacement(model, data, frame_id).translation
                error = foot_positions[leg] - position
                error_max = max(error_max, float(np.max(np.abs(error))))
                columns = slice(6 + 3 * leg, 9 + 3 * leg)
                jacobian = pin.getFrameJacobian(model, data, frame_id, LWA)[:3, columns]
                step = np.linalg.solve(jacobian.T @ jacobian + self._damping_matrix, jacobian.T @ error)
                rows, limits = slice(7 + 3 * leg, 10 + 3 * leg), slice(3 * leg, 3 * leg + 3)
                q[rows] = np.clip(q[rows] + step, self.lower[limits], self.upper[limits])
            if error_max < self.tolerance:
                break
        joints = q[7:].copy()
        rates = np.zeros(self.robot.nu)
        if base_velocity is not None and foot_velocities is not None:
            pin.computeJointJacobians(model, data, q)
            for leg, frame_id in enumerate(self.frame_ids):
                jacobian = pin.getFrameJacobian(model, data, frame_id, LWA)[:3]
                columns = slice(6 + 3 * leg, 9 + 3 * leg)
                base_part = jacobian[:, :6] @ base_velocity
                leg_jacobian = jacobian[:, columns]
                rates[3 * leg : 3 * leg + 3] = np.linalg.solve(
                    leg_jacobian.T @ leg_jacobian + self._damping_matrix,
                    leg_jacobian.T @ (foot_velocities[leg] - base_part),
                )
        return joints, rates, error_max
