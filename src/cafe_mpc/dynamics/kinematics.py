"""Foot kinematics for costs and constraints: world positions/velocities and their tangent Jacobians.

Feet are points at the foot frames (the foot-sphere centres). Jacobians are w.r.t. the whole-body tangent
``[dq (nv), dv (nv)]`` of ``MultibodyState``: compiled passes over Pinocchio's WORLD joint Jacobian
(``computeJointJacobians``) give the feet's world velocities and position Jacobians
(``kernels.foot_point_velocities``, in ``calc``) and the ``q``-Jacobians of their world velocities
(``kernels.foot_velocity_q_jacobians``, in ``calc_diff``), equal to ``getPointVelocityDerivatives`` in
``LOCAL_WORLD_ALIGNED`` without its forward-kinematics derivatives pass (``getFrameVelocityDerivatives`` in
``LOCAL_WORLD_ALIGNED`` is not the derivative of the world-frame foot velocity: it omits the frame's rotation
with ``q``); the position Jacobian does not depend on ``v`` and the velocity's ``v``-Jacobian equals the
position Jacobian.

This uses its own Pinocchio ``Data``, separate from the dynamics' one, so that evaluating costs never
disturbs what ``computeConstraintDynamicsDerivatives`` needs from the forward pass.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pinocchio as pin

from cafe_mpc.dynamics.kernels import foot_point_velocities, foot_velocity_q_jacobians
from cafe_mpc.robots.robot import Robot

LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED


class FootKinematicsData:
    """Workspace of ``FootKinematics`` (arrays indexed by leg; only the requested legs are written; the
    position Jacobians are made by ``calc``, which the velocities need anyway)."""

    def __init__(self, kinematics: FootKinematics) -> None:
        nv, n_feet = kinematics.model.nv, len(kinematics.frame_ids)
        self.pinocchio = kinematics.model.createData()
        self.positions = np.zeros((n_feet, 3))
        self.velocities = np.zeros((n_feet, 3))
        self.position_jacobians = np.zeros((n_feet, 3, nv))
        self.velocity_dq = np.zeros((n_feet, 3, nv))
        self._joint_jacobian = self.pinocchio.J
        """Pinocchio's WORLD joint Jacobian (a view of ``data.J``, filled by ``computeJointJacobians``)."""


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
        self._legs = np.array(self.position_legs, dtype=np.int64)
        self._velocity_legs = np.array(self.velocity_legs, dtype=np.int64)
        self._columns, self._joint_starts, self._n_columns = _chain_columns(robot)

    @property
    def empty(self) -> bool:
        return not self.position_legs

    def create_data(self) -> FootKinematicsData:
        return FootKinematicsData(self)

    def calc(self, data: FootKinematicsData, q: np.ndarray, v: np.ndarray) -> None:
        """Foot positions and velocities (and the position Jacobians, which the velocities are made of) at
        ``(q, v)``."""
        if not self.position_legs:
            return
        model, pd = self.model, data.pinocchio
        pin.computeJointJacobians(model, pd, q)  # joint placements and the WORLD joint Jacobian
        positions, frame_ids = data.positions, self.frame_ids
        for leg in self.position_legs:
            positions[leg] = pin.updateFramePlacement(model, pd, frame_ids[leg]).translation
        foot_point_velocities(
            data._joint_jacobian,
            v,
            positions,
            self._legs,
            self._columns,
            self._n_columns,
            data.position_jacobians,
            data.velocities,
        )

    def calc_diff(self, data: FootKinematicsData, q: np.ndarray, v: np.ndarray) -> None:
        """Position Jacobians ``d p / d dq`` and velocity Jacobians ``d pdot / d dq`` (``d pdot / d v`` is the
        position Jacobian). Assumes ``calc(data, q, v)`` ran last on ``data``."""
        if not self.velocity_legs:
            return
        foot_velocity_q_jacobians(
            data._joint_jacobian,
            v,
            self._velocity_legs,
            self._columns,
            self._joint_starts,
            self._n_columns,
            data.position_jacobians,
            data.velocities,
            data.velocity_dq,
        )


def _chain_columns(robot: Robot) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per foot, the velocity columns of its kinematic chain (root joint first), which of them start a
    joint, and how many there are (rows padded with -1)."""
    model = robot.model
    chains = []
    for frame_id in robot.foot_frame_ids:
        columns, starts = [], []
        for joint_id in list(model.supports[model.frames[frame_id].parentJoint])[1:]:  # without the universe
            joint = model.joints[joint_id]
            for k in range(joint.nv):
                columns.append(joint.idx_v + k)
                starts.append(k == 0)
        chains.append((columns, starts))
    width = max(len(columns) for columns, _ in chains)
    column_table = np.full((len(chains), width), -1, dtype=np.int64)
    start_table = np.zeros((len(chains), width), dtype=bool)
    for leg, (columns, starts) in enumerate(chains):
        column_table[leg, : len(columns)] = columns
        start_table[leg, : len(starts)] = starts
    return column_table, start_table, np.array([len(columns) for columns, _ in chains], dtype=np.int64)
