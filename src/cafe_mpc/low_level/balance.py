"""The balance controller: hold the stance the robot has, all feet down and the base level, with no plan.

The safe ladder's middle step (``control.plan_follower``: when no fresh plan arrives and the last one has
run out) and a standing controller by itself (``wbc: balance``). When it takes over (``engage``, at its
first ``compute`` after a ``reset``) it picks, from the measured state, a stance it can hold:

* the feet: each foot where it is in x-y; the feet in contact at their height, the others put down at the
  mean height of those (all of them when none is in contact);
* the base: level (roll = pitch = 0, yaw as measured), where it is in x-y, at the robot's standing height
  above the feet;
* the joint angles of that stance (``dynamics.leg_inverse_kinematics``) and its statics: the weight shared
  by the feet so that the centre of mass is balanced (the minimum-norm vertical forces, each at least
  ``min_normal_force`` of the weight), ``tau_s = S (g(q_s) - sum J_i' f_i)``.

Once, ``restance_after`` s after it engaged, the stance is picked again the same way at the first tick the
feet have landed (their heights within ``landed_spread`` of each other): engaged in flight, the first stance
put the feet in the air down where they were and levelled the base on the attitude of that instant.

Every tick: ``tau = tau_s + kp (q_s - q) - kd qd`` on the joints (with the feet on the ground, joint angles
at ``q_s`` put the base at its level pose). The foot forces this torque implies (quasi-statically, through
each leg's Jacobian at the stance) are kept inside the friction pyramid with at least the minimum normal
force, for the feet in contact; the torque is then clamped to the limits (``last_request``: before the
clamp). Nothing depends on the plan; it needs the joint encoders every tick and the IMU's attitude only
when it engages.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from cafe_mpc.config import DEFAULT_FRICTION, BalanceConfig
from cafe_mpc.core.controller import LowLevelController
from cafe_mpc.core.measurement import Measurement
from cafe_mpc.core.physics import GRAVITY
from cafe_mpc.core.plan import KnotPlan
from cafe_mpc.dynamics.leg_inverse_kinematics import JOINTS_PER_LEG, LegInverseKinematics
from cafe_mpc.reference.locomotion import quaternion_from_yaw, yaw_from_quaternion
from cafe_mpc.robots.robot import Robot

LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED

UNREACHABLE_STANCE = 0.1
"""m; a stance whose feet the legs miss by more than this cannot be held (``engage`` returns False)."""


class BalanceController(LowLevelController[KnotPlan]):
    """Holds the stance it finds when it engages (module docstring). The plan, if any, is ignored."""

    def __init__(
        self,
        robot: Robot,
        settings: BalanceConfig | None = None,
        torque_limits: np.ndarray | None = None,
        friction: float = DEFAULT_FRICTION,
    ) -> None:
        self.robot = robot
        self.settings = settings if settings is not None else BalanceConfig()
        self.kp, self.kd = float(self.settings.kp), float(self.settings.kd)
        self.friction = float(friction)
        self.limits = (robot.torque_limits if torque_limits is None else np.asarray(torque_limits)).copy()
        self.model = robot.model
        self.data = self.model.createData()
        self.inverse_kinematics = LegInverseKinematics(robot)
        n_feet, nu = robot.n_feet, robot.nu
        self.n_feet = n_feet
        self.weight = robot.total_mass * GRAVITY
        standing = robot.foot_positions(robot.q_standing) - robot.q_standing[:3]
        self._standing_offset = standing.mean(axis=0)
        """The feet's mean position relative to the base when standing (base frame, level): the base stands
        ``-offset[2]`` above the feet."""
        # the joints of leg i are JOINTS_PER_LEG i .. (the leg inverse kinematics' convention)
        self._leg_joints = [
            np.arange(JOINTS_PER_LEG * leg, JOINTS_PER_LEG * (leg + 1)) for leg in range(n_feet)
        ]
        self.target = robot.q_standing.copy()
        """The stance it holds: base pose and joint angles (planning coordinates)."""
        self.feet = np.zeros((n_feet, 3))
        """Where it holds the feet (world)."""
        self.static_forces = np.zeros((n_feet, 3))
        self.static_torques = np.zeros(nu)
        self._leg_jacobians = np.zeros((n_feet, 3, 3))
        self._leg_inverse_transposes = np.zeros((n_feet, 3, 3))
        self._torques = np.zeros(nu)
        self._force = np.zeros(3)
        self.last_request = np.zeros(nu)
        self.reset()

    def reset(self) -> None:
        self.engaged = False
        self.engaged_at = 0.0
        self.restance_pending = False
        self.restances = 0
        self.engagements = 0
        self.ticks = 0
        self.friction_clips = 0
        self.torque_clips = 0
        self.ik_error_max = 0.0
        self.last_request[:] = 0.0

    # ------------------------------------------------------------------------------------------ engage
    def engage(self, measurement: Measurement) -> bool:
        """Pick the stance to hold from ``measurement`` (module docstring); ``False`` when its feet are out
        of the legs' reach (then it holds the nearest posture the legs reach, and the caller may prefer the
        damped stance)."""
        robot, model, data = self.robot, self.model, self.data
        q = measurement.q
        pin.framesForwardKinematics(model, data, q)
        for foot, frame_id in enumerate(robot.foot_frame_ids):
            self.feet[foot] = data.oMf[frame_id].translation
        contacts = np.asarray(measurement.contacts, dtype=bool)
        down = contacts if contacts.any() else np.ones(self.n_feet, dtype=bool)
        ground = float(np.mean(self.feet[down, 2]))
        self.feet[~down, 2] = ground
        yaw = yaw_from_quaternion(q[3:7])
        target = self.target
        target[:2] = q[:2]
        target[2] = float(self.feet[:, 2].mean()) - self._standing_offset[2]
        target[3:7] = quaternion_from_yaw(yaw)
        joints, _, error = self.inverse_kinematics.solve(target[:7], self.feet, q[7:].copy())
        target[7:] = joints
        self.ik_error_max = max(self.ik_error_max, float(error))
        self._statics(target)
        self.engaged = True
        self.engaged_at = float(measurement.time)
        self.restance_pending = self.settings.restance_after is not None
        self.engagements += 1
        return bool(error <= UNREACHABLE_STANCE)

    def _restance(self, t: float, measurement: Measurement) -> None:
        """Pick the stance again once the feet have landed (module docstring); a stance out of the legs'
        reach is not taken (the first one is kept)."""
        if t - self.engaged_at < self.settings.restance_after:
            return
        pin.framesForwardKinematics(self.model, self.data, measurement.q)
        heights = [self.data.oMf[frame_id].translation[2] for frame_id in self.robot.foot_frame_ids]
        if max(heights) - min(heights) > self.settings.landed_spread:
            return
        kept = (self.target.copy(), self.feet.copy(), self.static_forces.copy(), self.static_torques.copy())
        kept_jacobians = (self._leg_jacobians.copy(), self._leg_inverse_transposes.copy())
        engagements = self.engagements
        if self.engage(measurement):
            self.restances += 1
        else:
            self.target[:], self.feet[:], self.static_forces[:], self.static_torques[:] = kept
            self._leg_jacobians[:], self._leg_inverse_transposes[:] = kept_jacobians
        self.engagements = engagements
        self.restance_pending = False

    def _statics(self, q: np.ndarray) -> None:
        """The vertical foot forces that balance the centre of mass over the feet (minimum norm, each at least
        ``min_normal_force`` of the weight), the joint torques that hold ``q`` with them, and each leg's
        Jacobian there."""
        robot, model, data = self.robot, self.model, self.data
        gravity = pin.computeGeneralizedGravity(model, data, q)
        com = pin.centerOfMass(model, data, q)
        pin.computeJointJacobians(model, data, q)
        pin.updateFramePlacements(model, data)
        relative = self.feet[:, :2] - com[:2]
        rows = np.vstack([np.ones(self.n_feet), relative.T])
        normal = rows.T @ np.linalg.lstsq(rows @ rows.T, np.array([self.weight, 0.0, 0.0]), rcond=None)[0]
        lowest = self.settings.min_normal_force * self.weight
        normal = np.maximum(normal, lowest)
        normal *= self.weight / normal.sum()
        self.static_forces[:] = 0.0
        self.static_forces[:, 2] = normal
        contact_term = np.zeros(model.nv)
        first_joint = model.nv - robot.nu
        for foot, frame_id in enumerate(robot.foot_frame_ids):
            jacobian = pin.getFrameJacobian(model, data, frame_id, LWA)[:3]
            contact_term += jacobian.T @ self.static_forces[foot]
            leg = jacobian[:, first_joint + self._leg_joints[foot]]
            self._leg_jacobians[foot] = leg
            try:
                self._leg_inverse_transposes[foot] = np.linalg.inv(leg.T)
            except np.linalg.LinAlgError:
                self._leg_inverse_transposes[foot] = np.nan  # a straight leg: no force check for it
        self.static_torques[:] = (gravity - contact_term)[first_joint:]

    # ----------------------------------------------------------------------------------------- compute
    def compute(self, t: float, measurement: Measurement, plan: KnotPlan | None = None) -> np.ndarray:
        if not self.engaged:
            self.engage(measurement)
        elif self.restance_pending:
            self._restance(t, measurement)
        robot = self.robot
        torques = self._torques
        joints_q = measurement.q[robot.nq - robot.nu :]
        joints_v = measurement.v[robot.nv - robot.nu :]
        np.subtract(self.target[7:], joints_q, out=torques)
        torques *= self.kp
        torques -= self.kd * joints_v
        torques += self.static_torques
        self._keep_forces_in_pyramid(torques, measurement.contacts)
        self.last_request[:] = torques
        if np.any(np.abs(torques) > self.limits):
            self.torque_clips += 1
            np.clip(torques, -self.limits, self.limits, out=torques)
        self.ticks += 1
        return torques

    def _keep_forces_in_pyramid(self, torques: np.ndarray, contacts: np.ndarray) -> None:
        """For each foot in contact: the foot force ``torques`` imply at the stance, ``f = f_s - J^-T (tau -
        tau_s)``, moved into the friction pyramid with at least the minimum normal force; the leg's torque
        then the one of the moved force (in place)."""
        lowest = self.settings.min_normal_force * self.weight
        mu = self.friction
        force = self._force
        clipped = False
        for foot in range(self.n_feet):
            if not contacts[foot]:
                continue
            inverse = self._leg_inverse_transposes[foot]
            if not np.isfinite(inverse[0, 0]):
                continue
            joints = self._leg_joints[foot]
            change = torques[joints] - self.static_torques[joints]
            np.subtract(self.static_forces[foot], inverse @ change, out=force)
            normal = max(force[2], lowest)
            tangential = mu * normal
            fx = min(max(force[0], -tangential), tangential)
            fy = min(max(force[1], -tangential), tangential)
            if fx != force[0] or fy != force[1] or normal != force[2]:
                clipped = True
                force[0], force[1], force[2] = fx, fy, normal
                torques[joints] = self.static_torques[joints] - self._leg_jacobians[foot].T @ (
                    force - self.static_forces[foot]
                )
        if clipped:
            self.friction_clips += 1

    def statistics(self) -> dict:
        """Engagements (and stances picked again) and ticks; ticks whose implied foot forces were moved into
        the friction pyramid and whose torque was clamped; the legs' largest miss of a stance's feet."""
        return {
            "engagements": self.engagements,
            "restances": self.restances,
            "ticks": self.ticks,
            "friction_clips": self.friction_clips,
            "torque_clips": self.torque_clips,
            "ik_error_max_m": self.ik_error_max,
        }
