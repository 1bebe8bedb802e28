"""How much support the motors give per commanded torque, relative to the controller's model, estimated
while the robot runs.

A payload makes the robot heavier than its model (mass factor ``k``), a weak motor delivers ``s`` times its
command. In stance the robot shows only their ratio: the legs' torques hold up ``k`` times the model's
weight with ``s`` times the commanded torque. For a factor on every body and every motor the ratio is also
all a controller needs: the motions of a robot ``k`` times heavier driven by ``tau`` are those of the model
driven by ``tau / k``, so sending ``tau / r`` with ``r = s / k`` makes the plant move as the model does,
and a command at the motors' limit delivers what a heavier model at its limit would (``r`` times the
limit). ``SupportRatioEstimator`` estimates ``r``; ``low_level.motor_strength`` applies it.

**The impulse balance.** Over a stretch of settled stance (the stance set unchanged for ``settle`` s), the
vertical momentum of the whole robot changes by what the ground gives minus gravity:
``k m (v_c(t1) - v_c(t0) + g T) = integral of sum_i F_i`` over the stance feet. A stance leg's force comes
from its joints' rows of the equations of motion (19), ``J_i' F_i = k (M qdd + h)_i - s tau_i`` (``J_i``
the foot's 3 x 3 world-frame Jacobian in its own joints; ``(M qdd + h)_i`` the leg joints' rows of the
model's inverse dynamics, Pinocchio's RNEA at the last tick's state with the acceleration the velocities
changed by since, gravity included), so with the model's ``m`` and the torques sent,

    r = s / k = (m (dv_c + g T) - int sum_i e_z' J_i^-T (M qdd + h)_i) / int sum_i (-e_z' J_i^-T tau_i).

The momentum change comes from the centre-of-mass velocity of the estimated state (Pinocchio, the model's
masses) at the stretch's ends; the legs' accelerations from the estimated velocities of consecutive ticks
(an impulse: their noise does not add up). Stretches are summed until
``window`` s of them make one estimate; an estimate needs its commanded support to be at least
``min_support`` of the weight, is clipped to ``[lower, upper]`` and enters a first-order filter over
``time_constant`` s of stance. The ratio is 1 until ``min_windows`` estimates were accepted; from then on
an estimate off the filtered one by more than ``outlier`` (a share) is left out unless ``outlier_windows``
in a row are: a take-off or a landing, where feet touch the ground before their flags say so and carry
support the balance does not count, gives a few such windows; a payload picked up gives them all along.

Stance feet are the measurement's contact flags (the plan's, gated by the estimator, or the detected ones).
The flags changing, a gap between ticks (the low level did not run: the safe ladder held the robot) or a
tick without a foot on the ground ends a stretch. A non-uniform factor (a payload on the trunk alone, one
weak motor) is met on average: the whole robot's ``r``.
"""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin

from cafe_mpc.config import OnlineCalibrationConfig
from cafe_mpc.core.measurement import Measurement
from cafe_mpc.core.physics import GRAVITY
from cafe_mpc.estimation.estimator import leg_velocity_indices
from cafe_mpc.estimation.kernels import leg_ground_forces
from cafe_mpc.robots.robot import Robot

LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED

MAX_GAP_TICKS = 1.5
"""Ticks between two observations beyond which the stretch ends (the low level skipped a tick)."""


class SupportRatioEstimator:
    """``r`` = delivered support / commanded support relative to the model (module docstring), estimated
        from ``observe(t, measurement)`` before the low level's torques of a tick and ``command(torques)``
        after them (the torques the motors are sent, in the model's units). ``ratio``: the value to apply;
        ``history``: ``(time, window estimate, filtered)`` of every window with enough support (an outlier
    leaves the filtered value as it was)."""

    def __init__(self, robot: Robot, settings: OnlineCalibrationConfig, control_period: float) -> None:
        if not (math.isfinite(control_period) and control_period > 0.0):
            raise ValueError(f"control period must be a positive number of seconds, got {control_period}")
        self.settings = settings
        self.model = robot.model
        self.data = self.model.createData()
        self.mass = robot.total_mass  # the whole-body model's bodies (rotors sit in them on the plant)
        self.frame_ids = tuple(robot.foot_frame_ids)
        leg_v = leg_velocity_indices(robot)
        self.leg_v = leg_v
        self.leg_joints = (leg_v - 6).reshape(-1)  # joint (torque) index of each leg's joints, root to foot
        n_feet = len(self.frame_ids)
        self.max_gap = MAX_GAP_TICKS * float(control_period)
        self._jacobians = np.zeros((n_feet, 3, 3))
        self._leg_torques = np.zeros(3 * n_feet)
        self._forces = np.zeros((n_feet, 3))
        self._dynamics_forces = np.zeros((n_feet, 3))
        self._last_q = np.zeros(robot.nq)
        self._last_v = np.zeros(robot.nv)
        self._acceleration = np.zeros(robot.nv)
        self._contacts = np.zeros(n_feet, dtype=bool)
        self.reset()

    def reset(self) -> None:
        """Forget the run: the ratio back to 1."""
        self.ratio = 1.0
        self.filtered = 1.0
        self.windows = 0
        self.rejected = 0
        self.history: list[tuple[float, float, float]] = []
        self._outliers = 0  # windows in a row off the applied estimate by more than ``outlier``
        self._last_time = -math.inf
        self._changed_at = -math.inf
        self._contacts[:] = False
        self._usable = False  # this tick's measurement is inside a settled stance
        self._in_stretch = False
        self._stretch_start = 0.0
        self._stretch_velocity = 0.0
        self._last_velocity = 0.0
        self._commanded_rate = 0.0  # N: sum of -e_z' J^-T tau over the stance feet at the last command
        self._commanded = 0.0  # N s over the stretch so far
        self._dynamics = 0.0  # N s: the legs' own dynamics, sum of e_z' J^-T (M qdd + h) over the stretch
        self._window_demand = 0.0  # N s: m (dv_c + g T) of the window's finished stretches
        self._window_commanded = 0.0
        self._window_dynamics = 0.0
        self._window_time = 0.0

    # ------------------------------------------------------------------------------------------ per tick
    def observe(self, t: float, measurement: Measurement) -> None:
        """The state at ``t``: closes the interval since the last tick (its torques, held, against the
        momentum now) and says whether this tick's command will count."""
        contacts = measurement.contacts
        gap = t - self._last_time > self.max_gap
        changed = bool(np.any(contacts != self._contacts))
        if changed or gap:
            self._changed_at = t
            np.copyto(self._contacts, contacts)
        settled = t - self._changed_at >= self.settings.settle - 1e-9 and bool(np.any(contacts))
        model, data = self.model, self.data
        velocity = self._last_velocity
        if settled or self._in_stretch:
            pin.centerOfMass(model, data, measurement.q, measurement.v)
            velocity = float(data.vcom[0][2])
        if self._in_stretch and settled and not gap and not changed:
            dt = t - self._last_time
            self._commanded += self._commanded_rate * dt
            self._dynamics += self._leg_dynamics(measurement.v, dt) * dt
            self._last_velocity = velocity
        elif self._in_stretch:
            self._close_stretch()
        if settled and not self._in_stretch:
            self._open_stretch(t, velocity)
        self._last_time = t
        self._usable = settled
        if settled:
            pin.computeJointJacobians(model, data, measurement.q)
            pin.updateFramePlacements(model, data)
            for leg, frame_id in enumerate(self.frame_ids):
                full = pin.getFrameJacobian(model, data, frame_id, LWA)
                self._jacobians[leg] = full[:3, self.leg_v[leg]]
            np.copyto(self._last_q, measurement.q)
            np.copyto(self._last_v, measurement.v)
            if self._in_stretch and self._window_time + (t - self._stretch_start) >= self.settings.window:
                self._close_stretch()
                self._close_window(t)
                self._open_stretch(t, velocity)

    def command(self, torques: np.ndarray) -> None:
        """The joint torques sent at this tick (the model's units: what the model's motors would deliver),
        held until the next ``observe``."""
        if not self._usable:
            self._commanded_rate = 0.0
            return
        np.take(torques, self.leg_joints, out=self._leg_torques)
        leg_ground_forces(self._jacobians, self._leg_torques, 3, self._forces)
        self._commanded_rate = self._stance_vertical(self._forces)

    def _leg_dynamics(self, velocity: np.ndarray, dt: float) -> float:
        """N: the stance legs' vertical ``e_z' J^-T (M qdd + h)`` over the last interval (RNEA at the last
        tick's state, ``qdd`` from its velocity to ``velocity``; the last tick's Jacobians)."""
        np.subtract(velocity, self._last_v, out=self._acceleration)
        self._acceleration /= dt
        inverse = pin.rnea(self.model, self.data, self._last_q, self._last_v, self._acceleration)
        np.negative(inverse[self.leg_v.reshape(-1)], out=self._leg_torques)
        leg_ground_forces(self._jacobians, self._leg_torques, 3, self._dynamics_forces)
        return self._stance_vertical(self._dynamics_forces)

    def _stance_vertical(self, forces: np.ndarray) -> float:
        total = 0.0
        for leg in range(len(self.frame_ids)):
            if self._contacts[leg]:
                total += forces[leg, 2]
        return total

    # ------------------------------------------------------------------------------------------ windows
    def _open_stretch(self, t: float, velocity: float) -> None:
        self._in_stretch = True
        self._stretch_start = t
        self._stretch_velocity = velocity
        self._last_velocity = velocity
        self._commanded = 0.0
        self._dynamics = 0.0

    def _close_stretch(self) -> None:
        duration = self._last_time - self._stretch_start
        self._in_stretch = False
        if duration <= 0.0:
            return
        self._window_demand += self.mass * (self._last_velocity - self._stretch_velocity + GRAVITY * duration)
        self._window_commanded += self._commanded
        self._window_dynamics += self._dynamics
        self._window_time += duration

    def _close_window(self, t: float) -> None:
        settings = self.settings
        duration, commanded = self._window_time, self._window_commanded
        demand = self._window_demand - self._window_dynamics
        self._window_demand = self._window_commanded = self._window_dynamics = self._window_time = 0.0
        weight_impulse = self.mass * GRAVITY * duration
        if not (commanded >= settings.min_support * weight_impulse and demand > 0.0):  # NaN fails too
            self.rejected += 1
            return
        estimate = demand / commanded
        if not math.isfinite(estimate):
            self.rejected += 1
            return
        estimate = min(max(estimate, settings.lower), settings.upper)
        if (
            self.windows >= settings.min_windows
            and abs(estimate - self.filtered) > settings.outlier * self.filtered
        ):
            self._outliers += 1
            if self._outliers < settings.outlier_windows:
                self.rejected += 1
                self.history.append((round(t, 4), round(float(estimate), 4), round(float(self.filtered), 4)))
                return
        self._outliers = 0
        if self.windows == 0:
            self.filtered = estimate
        else:
            weight = duration / (duration + settings.time_constant)
            self.filtered += weight * (estimate - self.filtered)
        self.windows += 1
        if self.windows >= settings.min_windows:
            self.ratio = self.filtered
        self.history.append((round(t, 4), round(float(estimate), 4), round(float(self.filtered), 4)))

    def statistics(self) -> dict:
        """The ratio applied at the end, the windows accepted and rejected, and every accepted window."""
        return {
            "ratio": round(float(self.ratio), 4),
            "windows": self.windows,
            "rejected_windows": self.rejected,
            "history": [list(entry) for entry in self.history],
        }
