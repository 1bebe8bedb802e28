"""The base's attitude and angular velocity while the IMU is out, from the robot's model, its joint encoders
and torques, and the feet on the ground.

Holding the IMU's last sample is the worst guess there is for a robot in motion: a bound pitches at 2-5 rad/s
and reverses its pitch rate at every stance, so 0.1 s after the IMU goes out a held gyro is off by several
rad/s and the low level (and the balance controller when it engages) act on a base that is not there.
While the IMU is out, ``ImuOutageObserver`` integrates the base's motion instead:

1. **On the ground: dynamics** (the rigid-body model, Pinocchio): from the estimated state ``(q, v)``, the
   measured joint torques ``tau`` and the feet that stand on the ground (planned in stance and, by the legs'
   kinematics, at the ground's height), the constrained forward dynamics (the KKT system of contact
   dynamics) ``M a - J_c' f = S' tau - h``, ``J_c a = -Jdot_c v`` gives the base's acceleration; its angular
   part integrates the angular velocity (and the attitude), its linear part is the specific force the
   accelerometer would read (``a_lin + w x v_lin + R' g_up``, base frame), which the position filter
   integrates in place of the held sample.
2. **In flight: the angular momentum** about the centre of mass is conserved whatever the joints do, so the
   base's angular velocity is the one that keeps the momentum of the lift-off with the measured joint rates
   (Pinocchio's centroidal map ``A_G``); the accelerometer reads free fall.
3. **Kinematics of the feet on the ground**: three feet or more at rest, ``v_b + w x r_i + J_i qd_i = 0``
   (base frame), set the angular velocity by least squares (the integrated one as a weak prior,
   ``RATE_PRIOR``; with two feet the rotation about the line through them is free, the dynamics' alone);
   and the feet's heights (``z + e_z' R r_i`` equal for all, flat ground) pull roll and pitch towards the
   plane of the feet (two feet: the tilt of the line through them) with a time constant
   ``PLANE_TIME_CONSTANT``. Yaw is not observable.

The model is the controller's (no joint friction, which the plant has, and the rotors' masses are not in
it): over a bound's stance the integrated pitch rate drifts by about 0.5 rad/s per 0.1 s, its attitude by a
few hundredths of a radian; standing on four feet (the balance stance) the feet hold both.

The IMU's outage is detected late (a driver repeating its last sample is noticed only once the sample is
older than ``max_sample_age``): the observer keeps the joint readings of the last ``HISTORY`` ticks (copies,
nothing computed) and, when the IMU goes out, starts from the last good IMU sample at its own time stamp and
replays the ticks since. Nothing of it runs while the IMU is in but the copies.
"""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin

from cafe_mpc.core.sensors import SensorReadings, rotation_to_quaternion
from cafe_mpc.dynamics.srb_kernels import quaternion_to_rotation
from cafe_mpc.robots.robot import Robot

LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED

HISTORY = 64
"""Ticks of joint readings kept for the replay from the last good IMU sample (0.128 s at 500 Hz)."""
RATE_PRIOR = 0.01
"""m^2: weight of the integrated angular velocity against the feet's velocities (1 per foot axis, m/s) in the
least-squares fit of the base's rates: with a lever arm of 0.2 m a foot weighs 0.04 per rate axis, so three
feet or more set the rates, and the rotation about the line through two feet stays the dynamics'."""
PLANE_TIME_CONSTANT = 0.05
"""s; the roll and pitch the feet's plane gives are approached with this time constant (a foot on the ground
sinks in by a few millimetres, and a touchdown planned early stands above it for a tick or two)."""
CONTACT_TIME_CONSTANT = 0.01
"""s; a foot on the ground that moves (in the estimated state: a touchdown, the estimate's error) is brought
to rest with this time constant (Baumgarte stabilisation of the contact constraint: ``J a = -Jdot v - J v /
T``), which stands for the touchdown's impact the acceleration-level constraint does not see (replayed on a
bound's log: the pitch within 0.08 rad over 0.45 s; 0.004 s: 0.15 rad, none: 0.23 rad)."""
PLANE_PRIOR = 1e-4
"""m^2: weight keeping the plane fit's attitude correction small in the directions the feet do not see."""


class ImuOutageObserver:
    """The base's attitude, angular velocity and specific force without the IMU (module docstring).

    ``remember`` every tick the IMU is in (copies the joint readings); ``start`` when it goes out (from the
    last good IMU sample, replaying the remembered ticks after its time stamp), ``step`` every tick it stays
    out, ``write`` the estimate into a reading; ``stop`` when it is back. ``contact_height``: m above the
    ground at which a foot planned in stance counts as not on it (the estimator's
    ``contact_height_threshold``; None: planned stance only).
    """

    def __init__(self, robot: Robot, contact_height: float | None = 0.03) -> None:
        self.model = robot.model
        self.data = self.model.createData()
        self.frame_ids = tuple(robot.foot_frame_ids)
        self.n_feet = len(self.frame_ids)
        self.nj = robot.nu
        self.foot_height = float(robot.foot_radius)
        self.contact_height = contact_height
        nv = self.model.nv
        self.q = pin.neutral(self.model)
        self.v = np.zeros(nv)
        self.rotation = np.eye(3)
        """Base to world, while active."""
        self.angular_velocity = np.zeros(3)
        """Base frame, rad/s."""
        self.specific_force = np.zeros(3)
        """What the accelerometer would read (base frame, m/s^2)."""
        self.velocity_change = np.zeros(3)
        """World, m/s: the model's specific force against the held samples over the replay's flight."""
        self.position_change = np.zeros(3)
        """World, m: the same in position."""
        self.on_ground = np.zeros(self.n_feet, dtype=bool)
        """The feet the last step took as standing on the ground."""
        self.active = False
        self.ticks = 0
        """Ticks estimated without the IMU so far (all outages)."""
        self._time = 0.0
        self._momentum: np.ndarray | None = None
        """World-frame angular momentum about the centre of mass at lift-off (None: on the ground)."""
        self._previous_q = self.q.copy()
        self._previous_v = np.zeros(nv)
        self._has_previous = False
        self._tau = np.zeros(nv)
        self._gravity_up = np.array([0.0, 0.0, -float(self.model.gravity.linear[2])])
        self._history_time = np.full(HISTORY, -math.inf)
        self._history_q = np.zeros((HISTORY, self.nj))
        self._history_qd = np.zeros((HISTORY, self.nj))
        self._history_tau = np.zeros((HISTORY, self.nj))
        self._history_flags = np.zeros((HISTORY, self.n_feet), dtype=bool)
        self._history_orientation = np.zeros((HISTORY, 4))
        self._history_force = np.zeros((HISTORY, 3))
        """The IMU's samples the position filter integrated (base frame, with their attitude)."""
        self._held_rotation = np.eye(3)
        self._next = 0
        self.readings = SensorReadings.zeros(self.nj)
        """The reading ``write`` fills (the input's values, the IMU's replaced)."""

    def reset(self) -> None:
        self.active = False
        self.ticks = 0
        self._history_time[:] = -math.inf
        self._next = 0

    # ------------------------------------------------------------------------------------ IMU in: copies
    def remember(self, readings: SensorReadings, planned: np.ndarray) -> None:
        """Keep this tick's joint readings and planned stance (ring of ``HISTORY`` ticks)."""
        row = self._next
        self._history_time[row] = readings.time
        self._history_q[row] = readings.joint_positions
        self._history_qd[row] = readings.joint_velocities
        self._history_tau[row] = readings.joint_torques
        self._history_flags[row] = planned
        self._history_orientation[row] = readings.orientation
        self._history_force[row] = readings.accelerometer
        self._next = (row + 1) % HISTORY

    def stop(self) -> None:
        """The IMU is back."""
        self.active = False

    # ----------------------------------------------------------------------------------- IMU out: model
    def start(
        self,
        sample_time: float,
        orientation: np.ndarray,
        gyro: np.ndarray,
        velocity: np.ndarray,
        height: float,
    ) -> None:
        """The IMU went out; its last good sample (``orientation``, ``gyro``) was taken at ``sample_time``
        (NaN: this tick). The remembered ticks after it are replayed with the base's world-frame ``velocity``
        and ``height`` (the position filter's). The position filter integrated the samples the driver
        repeated over those ticks (remembered, with their attitude); over the ticks in flight (no leg
        corrected it) ``velocity_change`` and ``position_change`` (world) say what the model's specific
        force changes in its velocity and position since."""
        quaternion_to_rotation(orientation, self.rotation)
        self.velocity_change[:] = 0.0
        self.position_change[:] = 0.0
        self.angular_velocity[:] = gyro
        self.active = True
        self._momentum = None
        self._time = math.nan
        self._has_previous = False
        if math.isnan(sample_time):
            return
        order = [(self._next + offset) % HISTORY for offset in range(HISTORY)]  # oldest first
        times = self._history_time[order]
        at_sample = np.flatnonzero(times <= sample_time + 1e-9)
        if len(at_sample) == 0:  # older than the history: from the oldest tick kept
            self._time = float(sample_time)
            first = 0
        else:  # the tick of the sample itself sets the state (no time passes)
            first = int(at_sample[-1])
        for row in order[first:]:
            t = self._history_time[row]
            if np.isfinite(t):
                before = self._time
                self._advance(
                    t,
                    self._history_q[row],
                    self._history_qd[row],
                    self._history_tau[row],
                    self._history_flags[row],
                    velocity,
                    height,
                )
                dt = 0.0 if math.isnan(before) else t - before
                if dt > 0.0:
                    self.position_change += self.velocity_change * dt
                    if not self.on_ground.any():  # in flight: the filter ran on the held sample alone
                        quaternion_to_rotation(self._history_orientation[row], self._held_rotation)
                        difference = self.rotation @ self.specific_force
                        difference -= self._held_rotation @ self._history_force[row]
                        self.position_change += 0.5 * dt * dt * difference
                        self.velocity_change += dt * difference

    def step(
        self, readings: SensorReadings, planned: np.ndarray, velocity: np.ndarray, height: float
    ) -> None:
        """Advance to ``readings.time`` with its joint readings and the feet planned in stance."""
        self._advance(
            float(readings.time),
            readings.joint_positions,
            readings.joint_velocities,
            readings.joint_torques,
            planned,
            velocity,
            height,
        )
        self.ticks += 1

    def write(self, readings: SensorReadings) -> SensorReadings:
        """``readings`` with the IMU's values replaced by the estimate (this object's reading)."""
        out = self.readings
        out.copy_from(readings)
        out.orientation[:] = rotation_to_quaternion(self.rotation)
        out.gyro[:] = self.angular_velocity
        out.accelerometer[:] = self.specific_force
        return out

    def _advance(
        self,
        t: float,
        joint_positions: np.ndarray,
        joint_velocities: np.ndarray,
        joint_torques: np.ndarray,
        planned: np.ndarray,
        velocity: np.ndarray,
        height: float,
    ) -> None:
        dt = 0.0 if math.isnan(self._time) else t - self._time
        self._time = t
        model, data, q, v = self.model, self.data, self.q, self.v
        rotation, w = self.rotation, self.angular_velocity
        q[:2] = 0.0
        q[2] = height
        q[3:7] = rotation_to_quaternion(rotation)
        q[7:] = joint_positions
        v[:3] = rotation.T @ velocity
        v[3:6] = w
        v[6:] = joint_velocities
        pin.forwardKinematics(model, data, q, v, np.zeros(model.nv))
        pin.computeJointJacobians(model, data, q)
        pin.updateFramePlacements(model, data)
        on_ground = self.on_ground
        for foot, frame_id in enumerate(self.frame_ids):
            clearance = data.oMf[frame_id].translation[2] - self.foot_height
            on_ground[foot] = planned[foot] and (
                self.contact_height is None or clearance <= self.contact_height
            )
        if dt > 0.0:
            if on_ground.any():
                self._momentum = None
                self._dynamics(dt, joint_torques)
                self._feet(dt, velocity)
            else:
                self._flight()
            rotation[:] = rotation @ pin.exp3(w * dt)
        self._previous_q[:] = q
        self._previous_v[:] = v
        self._previous_v[3:6] = w
        self._has_previous = True

    def _flight(self) -> None:
        """No foot on the ground: the angular momentum about the centre of mass is conserved whatever the
        joints do (their torques are internal), so the base's angular velocity is the one that, with the
        measured joint rates, keeps the momentum it had at lift-off (``A_G v``, Pinocchio's centroidal map:
        no joint friction or torque error enters); the accelerometer reads free fall."""
        model, data, v = self.model, self.data, self.v
        if self._momentum is None:  # lift-off: the momentum of the last tick on the ground
            previous_q, previous_v = (
                (self._previous_q, self._previous_v) if self._has_previous else (self.q, v)
            )
            self._momentum = pin.computeCentroidalMap(model, data, previous_q)[3:6] @ previous_v
        angular = pin.computeCentroidalMap(model, data, self.q)[3:6]
        self.angular_velocity[:] = np.linalg.solve(angular[:, 3:6], self._momentum - angular[:, 6:] @ v[6:])
        self.specific_force[:] = 0.0

    def _dynamics(self, dt: float, joint_torques: np.ndarray) -> None:
        """The base's acceleration from the constrained dynamics; its angular velocity integrated, the
        specific force kept. Torques not measured (NaN): the angular velocity is held."""
        if not np.all(np.isfinite(joint_torques)):
            self.specific_force[:] = self.rotation.T @ self._gravity_up
            return
        model, data, q, v = self.model, self.data, self.q, self.v
        mass_matrix = pin.crba(model, data, q)
        mass_matrix = np.triu(mass_matrix) + np.triu(mass_matrix, 1).T
        bias = pin.nonLinearEffects(model, data, q, v)
        tau = self._tau
        tau[6:] = joint_torques
        feet = [foot for foot in range(self.n_feet) if self.on_ground[foot]]
        if feet:
            n_rows = 3 * len(feet)
            jacobian = np.zeros((n_rows, model.nv))
            drift = np.zeros(n_rows)
            pin.forwardKinematics(model, data, q, v, np.zeros(model.nv))
            for row, foot in enumerate(feet):
                self._contact_point(foot, jacobian[3 * row : 3 * row + 3], drift[3 * row : 3 * row + 3])
            drift += (jacobian @ v) / max(CONTACT_TIME_CONSTANT, dt)
            system = np.zeros((model.nv + n_rows, model.nv + n_rows))
            system[: model.nv, : model.nv] = mass_matrix
            system[: model.nv, model.nv :] = -jacobian.T
            system[model.nv :, : model.nv] = jacobian
            right = np.concatenate([tau - bias, -drift])
            acceleration = np.linalg.lstsq(system, right, rcond=None)[0][: model.nv]
        else:
            acceleration = np.linalg.solve(mass_matrix, tau - bias)
        w, linear = v[3:6], v[:3]
        self.specific_force[:] = acceleration[:3] + np.cross(w, linear) + self.rotation.T @ self._gravity_up
        self.angular_velocity += dt * acceleration[3:6]

    def _contact_point(self, foot: int, jacobian: np.ndarray, drift: np.ndarray | None = None) -> np.ndarray:
        """The centre of ``foot``'s sphere, taken as at rest on the ground: its world-frame Jacobian into
        ``jacobian`` (3 x nv) and, given ``drift``, its acceleration at zero generalised acceleration
        (``forwardKinematics`` with ``v`` and zero ``a`` done); returns its position. (The point that touches
        the ground, which a rolling foot holds at rest, did worse: replayed on a bound's log the pitch rate
        drifted 1.2 rad/s in 0.25 s against 0.8 for the centre; MuJoCo's soft contact neither rolls nor holds
        the sphere's centre exactly.)"""
        model, data = self.model, self.data
        frame_id = self.frame_ids[foot]
        jacobian[:] = pin.getFrameJacobian(model, data, frame_id, LWA)[:3]
        if drift is not None:
            drift[:] = pin.getFrameClassicalAcceleration(model, data, frame_id, LWA).linear
        return data.oMf[frame_id].translation

    def _feet(self, dt: float, velocity: np.ndarray) -> None:
        """Correct the angular velocity with the feet on the ground at rest, and roll and pitch towards their
        plane (module docstring)."""
        feet = [foot for foot in range(self.n_feet) if self.on_ground[foot]]
        if len(feet) < 2:
            return
        data = self.data
        base = data.oMi[1]
        relative = [
            base.rotation.T @ (data.oMf[self.frame_ids[foot]].translation - base.translation) for foot in feet
        ]
        if len(feet) >= 3:
            self._rates(feet, velocity)
        self._plane(dt, relative)

    def _rates(self, feet: list[int], velocity: np.ndarray) -> None:
        """The least-squares ``(v_b, w)`` of three feet or more whose contact points are at rest, the
        integrated ones as the prior."""
        base = self.data.oMi[1]
        rows, right = [], []
        jacobian = np.zeros((3, self.model.nv))
        for foot in feet:
            r = base.rotation.T @ (self._contact_point(foot, jacobian) - base.translation)
            joints_part = base.rotation.T @ (jacobian[:, 6:] @ self.v[6:])
            rows.append(np.hstack([np.eye(3), -pin.skew(r)]))
            right.append(-joints_part)
        a = np.vstack(rows)
        b = np.concatenate(right)
        normal = a.T @ a
        normal[3:, 3:] += RATE_PRIOR * np.eye(3)
        normal[:3, :3] += RATE_PRIOR * np.eye(3)
        rhs = a.T @ b
        rhs[3:] += RATE_PRIOR * self.angular_velocity
        rhs[:3] += RATE_PRIOR * (self.rotation.T @ velocity)
        self.angular_velocity[:] = np.linalg.solve(normal, rhs)[3:]

    def _plane(self, dt: float, relative: list[np.ndarray]) -> None:
        """Roll and pitch towards the plane of the feet on the ground (flat ground), by ``dt`` over
        ``PLANE_TIME_CONSTANT``; with two feet only the tilt of the line through them."""
        # e_z' R (r_i + d x r_i) + z = h for every foot on the ground (flat ground); unknowns the small
        # rotation d (base frame) and the height z
        up = self.rotation.T @ np.array([0.0, 0.0, 1.0])
        plane_rows = np.zeros((len(relative), 4))
        plane_right = np.zeros(len(relative))
        for row, r in enumerate(relative):
            plane_rows[row, :3] = np.cross(r, up)  # e_z' R (d x r) = up . (d x r) = d . (r x up)
            plane_rows[row, 3] = 1.0
            plane_right[row] = self.foot_height - float(up @ r)
        normal = plane_rows.T @ plane_rows
        normal[:3, :3] += PLANE_PRIOR * np.eye(3)
        correction = np.linalg.solve(normal, plane_rows.T @ plane_right)[:3]
        correction -= (correction @ up) * up  # no yaw
        gain = min(1.0, dt / PLANE_TIME_CONSTANT)
        self.rotation[:] = self.rotation @ pin.exp3(gain * correction)
