"""Low level of the template-MPC baseline (paper Sec. VII-C: "the GRFs are directly used for stance leg
control; a separate swing controller tracks swing trajectories that interpolate the foot placements").

Per control tick, with the plan interval containing ``t`` (``TemplatePlan.knot_at``, zero-order hold):

* stance legs (the plan's stance flags): the planned world GRFs mapped through the foot Jacobians,
  ``tau = g_J(q) - J_c(q)' F`` (the joint rows of the static equilibrium ``S' tau = g(q) - J_c' F`` of
  ``dynamics.statics``; ``g_J`` carries the legs' own weight);
* swing legs: joint PD toward the leg inverse kinematics (``dynamics.leg_inverse_kinematics``) of the
  reference swing-foot position and velocity at ``t`` (cubic Bezier swings of the locomotion reference,
  interpolated by ``TemplatePlan.feet_at``) about the *measured* base pose, plus the same leg-gravity term.

There is no whole-body feedback: the body is stabilised only through the GRFs that the MPC replans at every
update (the HKD-MPC structure), and no coordination of leg and body momentum (which is what the paper's
Fig. 12 shows failing in the barrel roll). Torques are clamped to the motor limits; ``last_request`` is the
torque before clamping.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from cafe_mpc.config import TemplateSettings
from cafe_mpc.core.controller import LowLevelController
from cafe_mpc.core.measurement import Measurement
from cafe_mpc.dynamics.leg_inverse_kinematics import LegInverseKinematics
from cafe_mpc.planners.template.plan import TemplatePlan
from cafe_mpc.robots.robot import Robot
from cafe_mpc.robots.scaling import IDENTITY, RobotScale

LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED


def leg_joint_indices(robot: Robot) -> list[np.ndarray]:
    """Indices (into the 12 actuated joints) of the joints that move each foot (leg order)."""
    model = robot.model
    data = model.createData()
    q = robot.q_standing
    pin.computeJointJacobians(model, data, q)
    pin.updateFramePlacements(model, data)
    legs = []
    for frame_id in robot.foot_frame_ids:
        jacobian = pin.getFrameJacobian(model, data, frame_id, LWA)[:3, 6:]
        legs.append(np.flatnonzero(np.any(np.abs(jacobian) > 1e-12, axis=0)))
    return legs


def stance_torques(
    robot: Robot,
    q: np.ndarray,
    forces: np.ndarray,
    stance: np.ndarray,
    leg_gravity: bool = True,
    model_data: pin.Data | None = None,
) -> np.ndarray:
    """Joint torques (nu) that make the stance feet push the ground with the world GRFs ``forces``
    (n_feet, 3; the force *on* the foot): ``g_J(q) - sum_stance J_foot(q)' F_foot`` (joint rows; legs not in
    stance get only ``g_J``). With all four feet in stance and ``forces`` the static balance, this is
    ``dynamics.statics.static_stance_torques``."""
    model = robot.model
    data = model.createData() if model_data is None else model_data
    pin.computeJointJacobians(model, data, q)
    pin.updateFramePlacements(model, data)
    torque = pin.computeGeneralizedGravity(model, data, q)[6:].copy() if leg_gravity else np.zeros(robot.nu)
    for foot, frame_id in enumerate(robot.foot_frame_ids):
        if stance[foot]:
            jacobian = pin.getFrameJacobian(model, data, frame_id, LWA)[:3, 6:]
            torque -= jacobian.T @ forces[foot]
    return torque


class TemplateLowLevelController(LowLevelController[TemplatePlan]):
    """Stance legs ``J' F`` from the planned GRFs (with the legs' own weight), swing legs joint PD on the
    Bezier swings (module docstring). Needs a ``TemplatePlan``. ``settings``: the ``template`` section, whose
    swing gains (the reference robot's) ``scale`` carries to the robot (``robots.scaling``: the torque scale,
    times the time scale for the damping). ``torque_limits``: the clamp (default the robot's plan limits; a
    run with ``torque_limits: motor`` passes the motor limits, as to the planner)."""

    def __init__(
        self,
        robot: Robot,
        settings: TemplateSettings | None = None,
        scale: RobotScale = IDENTITY,
        torque_limits: np.ndarray | None = None,
    ) -> None:
        self.robot = robot
        self.settings = settings or TemplateSettings()
        self.swing_kp = scale.stiffness(self.settings.swing_kp)
        self.swing_kd = scale.damping(self.settings.swing_kd)
        """Swing-leg joint PD gains (Nm/rad, Nm s/rad) of this robot."""
        self.model = robot.model
        self.data = robot.model.createData()
        self.limits = np.asarray(robot.torque_limits if torque_limits is None else torque_limits, dtype=float)
        if self.limits.shape != (robot.nu,) or np.any(self.limits <= 0):
            raise ValueError(f"template low level: {robot.nu} positive torque limits needed")
        self.legs = leg_joint_indices(robot)
        self.inverse_kinematics = LegInverseKinematics(robot)
        n_feet = robot.n_feet
        self._positions = np.zeros((1, n_feet, 3))
        self._velocities = np.zeros((1, n_feet, 3))
        self._base = np.zeros((1, 7))
        self._base_velocity = np.zeros((1, 6))
        self._ik_out = (np.zeros((1, robot.nu)), np.zeros((1, robot.nu)), np.zeros(1))
        self._torques = np.zeros(robot.nu)
        self.last_request = np.zeros(robot.nu)
        self.ticks = 0
        self.limit_violations = 0
        self.swing_ticks = 0
        self.swing_error_max = 0.0
        """Largest joint-space swing tracking error (rad) over the run."""
        self.planned_force_max = 0.0
        """Largest planned vertical GRF on a stance foot (N) over the run."""

    def reset(self) -> None:
        self.ticks = 0
        self.limit_violations = 0
        self.swing_ticks = 0
        self.swing_error_max = 0.0
        self.planned_force_max = 0.0
        self.last_request[:] = 0.0

    def compute(self, t: float, measurement: Measurement, plan: TemplatePlan | None) -> np.ndarray:
        if plan is None:
            raise RuntimeError("TemplateLowLevelController needs a TemplatePlan (planner: template)")
        robot = self.robot
        q, v = measurement.q, measurement.v
        k = plan.knot_at(t)
        stance = plan.contacts[k]
        if stance.any():
            self.planned_force_max = max(self.planned_force_max, float(np.max(plan.forces[k, stance, 2])))
        torques = stance_torques(robot, q, plan.forces[k], stance, model_data=self.data)
        if not np.all(stance):
            plan.feet_at(t, self._positions[0], self._velocities[0])
            self._base[0] = q[:7]
            self._base_velocity[0] = v[:6]
            joints, rates, _ = self.inverse_kinematics.solve_batch(
                self._base,
                self._positions,
                q[7:],
                self._base_velocity,
                self._velocities,
                out=self._ik_out,
            )
            kp, kd = self.swing_kp, self.swing_kd
            for foot, leg in enumerate(self.legs):
                if stance[foot]:
                    continue
                error = joints[0, leg] - q[7 + leg]
                torques[leg] += kp * error + kd * (rates[0, leg] - v[6 + leg])
                self.swing_error_max = max(self.swing_error_max, float(np.max(np.abs(error))))
            self.swing_ticks += 1
        self._torques[:] = torques
        self.last_request[:] = torques
        self.ticks += 1
        if np.any(np.abs(torques) > self.limits):
            self.limit_violations += 1
        np.clip(self._torques, -self.limits, self.limits, out=self._torques)
        return self._torques

    def statistics(self) -> dict:
        """``torque_limit_violations``: ticks whose requested torque exceeded a limit (then clamped);
        ``swing_error_max_rad``: largest swing-leg joint tracking error; ``planned_force_max_n``: largest
        planned vertical GRF on a stance foot (what the plan asked of one leg)."""
        return {
            "ticks": self.ticks,
            "torque_limit_violations": self.limit_violations,
            "swing_error_max_rad": self.swing_error_max,
            "planned_force_max_n": self.planned_force_max,
        }
