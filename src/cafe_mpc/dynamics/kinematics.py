"""Foot kinematics for costs and constraints: world positions/velocities and their tangent Jacobians.

Feet are points at the foot frames (the foot-sphere centres). Jacobians are w.r.t. the whole-body tangent
``[dq (nv), dv (nv)]`` of ``MultibodyState`` and come from Pinocchio (``LOCAL_WORLD_ALIGNED`` frame
Jacobians and ``getPointVelocityDerivatives``; ``getFrameVelocityDerivatives`` in ``LOCAL_WORLD_ALIGNED``
is not the derivative of the world-frame foot velocity: it omits the frame's rotation with ``q``); the
position Jacobian does not depend on ``v`` and the
velocity's ``v``-Jacobian equals the position Jacobian.

This uses its own Pinocchio ``Data``, separate from the dynamics' one, so that evaluating costs never
disturbs what ``computeConstraintDynamicsDerivatives`` needs from the forward pass.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pinocchio as pin

from cafe_mpc.robots.robot import Robot

LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED


class FootKinematicsData:
    """Workspace of ``FootKinematics`` (arrays indexed by leg; only the requested legs are written)."""

    def __init__(self, kinematics: FootKinematics) -> None:
        nv, n_feet = kinematics.model.nv, len(kinematics.frame_ids)
        self.pinocchio = kinematics.model.createData()
        self.positions = np.zeros((n_feet, 3))
        self.velocities = np.zeros((n_feet, 3))
        self.position_jacobians = np.zeros((n_feet, 3, nv))
        self.velocity_dq = np.zeros((n_feet, 3, nv))
        self._zero_acceleration = np.zeros(nv)


class FootKinematics:
    """World positions of ``position_legs`` and world velocities of ``velocity_legs`` (leg indices)."""

    def __init__(
        self, robot: Robot, position_legs: Sequence[int] = (), velocity_legs: Sequence[int] = ()
    ) -> None:
        for leg in (*position_legs, *velocity_legs):
            if leg not in range(robot.n_feet):
                raise ValueError(f"leg index must be in 0..{robot.n_feet - 1}, got {leg}")
        self.model = robot.model
        self.frame_ids = robot.foot_frame_ids
        # Velocity Jacobians need the position Jacobians too (dv_foot/dv = J).
        self.position_legs = tuple(sorted(set(position_legs) | set(velocity_legs)))
        self.velocity_legs = tuple(sorted(set(velocity_legs)))
        self._position_only_legs = tuple(leg for leg in self.position_legs if leg not in self.velocity_legs)
        frames = [robot.model.frames[frame_id] for frame_id in self.frame_ids]
        self._parent_joints = tuple(frame.parentJoint for frame in frames)
        self._placements = tuple(frame.placement.copy() for frame in frames)

    @property
    def empty(self) -> bool:
        return not self.position_legs

    def create_data(self) -> FootKinematicsData:
        return FootKinematicsData(self)

    def calc(self, data: FootKinematicsData, q: np.ndarray, v: np.ndarray) -> None:
        """Foot positions (and velocities) at ``(q, v)``."""
        if not self.position_legs:
            return
        pd = data.pinocchio
        if self.velocity_legs:
            pin.forwardKinematics(self.model, pd, q, v)
        else:
            pin.forwardKinematics(self.model, pd, q)
        for leg in self.position_legs:
            data.positions[leg] = pin.updateFramePlacement(self.model, pd, self.frame_ids[leg]).translation
        for leg in self.velocity_legs:
            data.velocities[leg] = pin.getFrameVelocity(self.model, pd, self.frame_ids[leg], LWA).linear

    def calc_diff(self, data: FootKinematicsData, q: np.ndarray, v: np.ndarray) -> None:
        """Position Jacobians ``d p / d dq`` and velocity Jacobians ``d pdot / d dq`` (``d pdot / d v`` is the
        position Jacobian)."""
        if not self.position_legs:
            return
        pd = data.pinocchio
        if self.velocity_legs:
            pin.computeForwardKinematicsDerivatives(self.model, pd, q, v, data._zero_acceleration)
        else:
            pin.computeJointJacobians(self.model, pd, q)
        model = self.model
        for leg in self.velocity_legs:
            # Derivatives of the point's world velocity; d pdot / dv is the position Jacobian.
            dv_dq, dv_dv = pin.getPointVelocityDerivatives(
                model, pd, self._parent_joints[leg], self._placements[leg], LWA
            )
            data.velocity_dq[leg] = dv_dq
            data.position_jacobians[leg] = dv_dv
        for leg in self._position_only_legs:
            data.position_jacobians[leg] = pin.getFrameJacobian(model, pd, self.frame_ids[leg], LWA)[:3]
