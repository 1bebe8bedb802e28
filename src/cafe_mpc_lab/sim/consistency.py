"""Checks that the MuJoCo plant and the Pinocchio planning model describe the same robot.

They must agree on total mass, forward kinematics of the feet and the joint-space mass matrix, with the
plant's armature set to the planning model's (the model carries the rotor inertia when the robot file says
``rotor_inertia_in_model``; otherwise both are compared without it).
MuJoCo's free-joint velocity is ``[world linear, body angular]`` and Pinocchio's ``[body linear, body
angular]``, so the mass matrices are compared after the change of velocity coordinates
``v_mujoco = T v_pinocchio`` with ``T = blockdiag(R, I, I)``: ``M_pinocchio = T' M_mujoco T``.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pinocchio as pin

from cafe_mpc.robots.robot import Robot
from cafe_mpc_lab.sim.mujoco_plant import MujocoPlant


def random_configurations(robot: Robot, count: int, seed: int = 0) -> list[np.ndarray]:
    """Random configurations with joint angles inside their limits and a random base pose."""
    rng = np.random.default_rng(seed)
    configurations = []
    for _ in range(count):
        q = pin.neutral(robot.model)
        q[:3] = rng.uniform(-0.5, 0.5, 3) + np.array([0.0, 0.0, 0.5])
        quaternion = rng.normal(size=4)
        q[3:7] = quaternion / np.linalg.norm(quaternion)
        low = np.maximum(robot.position_lower, -3.0)
        high = np.minimum(robot.position_upper, 3.0)
        q[7:] = rng.uniform(low, high)
        configurations.append(q)
    return configurations


def check_consistency(robot: Robot, samples: int = 5, seed: int = 0) -> dict:
    """Compare Pinocchio and MuJoCo; returns the largest differences and a ``passed`` flag."""
    plant = MujocoPlant(robot)
    mj_model, mj_data = plant.model, plant.data
    # compare like with like: the planning model's armature (the joints' rotors; a model file may also put
    # armature on its free joint, which both models then read)
    mj_model.dof_armature[:] = robot.model.armature
    data = robot.model.createData()
    foot_sites = [mj_model.site(f"{name}_site").id for name in robot.foot_frame_names]
    mass_pinocchio = robot.total_mass
    mass_mujoco = float(np.sum(mj_model.body_mass))
    foot_error, mass_matrix_error = 0.0, 0.0
    mass_matrix_mujoco = np.zeros((mj_model.nv, mj_model.nv))
    for q in random_configurations(robot, samples, seed):
        plant.reset(q)
        pin.framesForwardKinematics(robot.model, data, q)
        feet_pinocchio = np.array([data.oMf[i].translation for i in robot.foot_frame_ids])
        feet_mujoco = np.array([mj_data.site_xpos[s] for s in foot_sites])
        foot_error = max(foot_error, float(np.max(np.abs(feet_pinocchio - feet_mujoco))))
        mass_matrix = pin.crba(robot.model, data, q)
        mass_matrix = np.triu(mass_matrix) + np.triu(mass_matrix, 1).T
        mujoco.mj_fullM(mj_model, mj_data, mass_matrix_mujoco)
        transform = np.eye(robot.nv)
        transform[:3, :3] = pin.Quaternion(q[3:7]).toRotationMatrix()
        converted = transform.T @ mass_matrix_mujoco @ transform
        mass_matrix_error = max(mass_matrix_error, float(np.max(np.abs(converted - mass_matrix))))
    tolerances = {"total_mass": 1e-9, "foot_position_m": 1e-9, "mass_matrix": 1e-8}
    if robot.source == "urdf":  # MuJoCo's URDF reading is written back with 6 significant digits
        tolerances = {
            "total_mass": 1e-5 * mass_pinocchio,
            "foot_position_m": 1e-6,
            "mass_matrix": 1e-5 * max(1.0, float(np.max(np.abs(mass_matrix_mujoco)))),
        }
    result = {
        "total_mass_pinocchio": mass_pinocchio,
        "total_mass_mujoco": mass_mujoco,
        "total_mass_difference": abs(mass_pinocchio - mass_mujoco),
        "foot_position_max_error_m": foot_error,
        "mass_matrix_max_error": mass_matrix_error,
        "samples": samples,
        "tolerances": tolerances,
    }
    result["passed"] = bool(
        result["total_mass_difference"] <= tolerances["total_mass"]
        and foot_error <= tolerances["foot_position_m"]
        and mass_matrix_error <= tolerances["mass_matrix"]
    )
    return result
