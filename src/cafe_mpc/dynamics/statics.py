"""Static equilibrium: joint torques that hold a configuration with given vertical foot forces."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from cafe_mpc.core.physics import GRAVITY
from cafe_mpc.robots.robot import Robot


def static_stance_torques(
    robot: Robot, q: np.ndarray, stance: np.ndarray | None = None, force_per_foot: float | None = None
) -> np.ndarray:
    """Joint torques that hold configuration ``q`` with a vertical force on each stance foot (leg gravity
    included): by default the weight split over the stance feet (static balance); gaits with flight phases
    pass their average stance force (``force_per_foot``, N).

    The joint rows of the static equilibrium ``S' tau = g(q) - Jc' F``.
    """
    n_feet = robot.n_feet
    stance = np.ones(n_feet, dtype=bool) if stance is None else np.asarray(stance, dtype=bool)
    if stance.shape != (n_feet,) or not stance.any():
        raise ValueError(
            f"static_stance_torques needs {n_feet} stance flags with at least one foot on the ground"
        )
    model = robot.model
    data = model.createData()
    gravity = pin.computeGeneralizedGravity(model, data, q)
    pin.computeJointJacobians(model, data, q)
    pin.updateFramePlacements(model, data)
    weight = robot.total_mass * GRAVITY / stance.sum() if force_per_foot is None else float(force_per_foot)
    contact_term = np.zeros(model.nv)
    for foot, frame_id in enumerate(robot.foot_frame_ids):
        if stance[foot]:
            jacobian = pin.getFrameJacobian(model, data, frame_id, pin.LOCAL_WORLD_ALIGNED)[:3]
            contact_term += jacobian.T @ np.array([0.0, 0.0, weight])
    return (gravity - contact_term)[model.nv - robot.nu :]
