"""A stored whole-body trajectory as a reference, sampled by time (paper Sec. VI-B, VII-C, Appendix).

The offline barrel-roll trajectory optimisation (``cafe_mpc.trajopt``) writes a ``WholeBodyTrajectory``:
states at knots ``t_k`` (post-impact at a touchdown), torques, stance flags and ground-reaction forces per
interval ``[t_k, t_k+1)``. The paper uses it "as a reference and an initial guess for the online CAFE-MPC"
(Appendix), which fine-tunes it online to the real robot (Sec. VI-B). ``TrajectoryReference`` answers the
``Reference`` interface of the CAFE problem builder from it:

* time: the trajectory's first knot plays at ``start`` (reference time); ``t - start`` is the trajectory's
  own time;
* configuration on the manifold: base position and joint angles interpolated linearly between the two
  surrounding knots, the base quaternion by spherical interpolation from ``q_k`` (its sign follows the
  stored quaternions, which carry the roll's sign continuously, so a 2 pi roll ends on ``-q``, not ``q``);
* velocities (base-frame twist, joint rates) interpolated linearly; torque and GRF references of the
  interval containing ``t`` (piecewise constant, as the stored controls);
* stance: the stored flags of the interval that starts at (contains) ``t``; the contact switches of the
  MPC's knots therefore happen at the first MPC knot at or after a stored switch;
* feet: world positions and velocities from forward kinematics of the stored knots, interpolated linearly
  (stance feet stay where the trajectory planted them; swing feet follow the stored legs); the SRB tail
  takes its footholds from these (Sec. IV-B: "foot positions come from the reference");
* before ``start`` and after the end it holds its first and last configuration at rest as a standing
  reference: zero velocity, the stance of the first / last interval, the static torques that carry the
  weight split over those feet, and that weight as GRF reference;
* weight sets: ``weight_set`` (e.g. ``"barrel_roll"``, the authors' barrel-roll costs) inside the
  trajectory, ``hold_weight_set`` during the holds.

``update`` does nothing: the stored trajectory is not re-anchored on the measured state (the paper tracks
the offline reference as it is and lets the MPC absorb the mismatch). To place it elsewhere in the world,
compose it (``reference.composition.ComposedReference``: x, y and yaw offsets).
"""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin

from cafe_mpc.core.physics import GRAVITY
from cafe_mpc.dynamics.statics import static_stance_torques
from cafe_mpc.reference.base import STANCE_TIME_EPS, Reference, ReferenceWindow, switches_inside
from cafe_mpc.reference.kernels import sample_trajectory
from cafe_mpc.reference.trajectory_file import WholeBodyTrajectory
from cafe_mpc.robots.robot import Robot

INDEX_TOLERANCE = 1e-6
"""Knot-index rounding tolerance in units of ``dt`` (a time a hair below a knot belongs to that knot)."""


def quaternion_slerp(q0: np.ndarray, q1: np.ndarray, alpha: float, out: np.ndarray) -> None:
    """Spherical interpolation from ``q0`` (x, y, z, w) toward ``q1`` by ``alpha`` in [0, 1], along the
    shorter arc between the rotations; the result stays on ``q0``'s side of the double cover (``q1`` is
    flipped if ``q0 . q1 < 0``), so a sign-continuous sequence of knots interpolates sign-continuously."""
    dot = float(np.dot(q0, q1))
    sign = 1.0 if dot >= 0.0 else -1.0
    dot = min(abs(dot), 1.0)
    if dot > 1.0 - 1e-9:
        out[:] = q0 + alpha * (sign * q1 - q0)
    else:
        angle = math.acos(dot)
        s = math.sin(angle)
        out[:] = (math.sin((1.0 - alpha) * angle) / s) * q0 + (sign * math.sin(alpha * angle) / s) * q1
    out /= np.linalg.norm(out)


def foot_states(robot: Robot, xs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World positions and velocities (N, n_feet, 3) of the foot points at the states ``xs`` (N, nq + nv)."""
    model = robot.model
    data = model.createData()
    nq = model.nq
    positions = np.zeros((len(xs), robot.n_feet, 3))
    velocities = np.zeros((len(xs), robot.n_feet, 3))
    world = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
    for row, x in enumerate(xs):
        pin.forwardKinematics(model, data, x[:nq], x[nq:])
        pin.updateFramePlacements(model, data)
        for foot, frame_id in enumerate(robot.foot_frame_ids):
            positions[row, foot] = data.oMf[frame_id].translation
            velocities[row, foot] = pin.getFrameVelocity(model, data, frame_id, world).linear
    return positions, velocities


class TrajectoryReference(Reference):
    """A ``WholeBodyTrajectory`` sampled by time (see the module docstring).

    Args:
        robot: the robot the trajectory was made for (checked against the trajectory's dimensions).
        trajectory: the stored trajectory (``reference.trajectory_file.load_trajectory``).
        start: reference time at which the trajectory's first knot plays (s, >= 0).
        weight_set: weight set of the knots inside the trajectory.
        hold_weight_set: weight set of the knots before ``start`` and after the end.
        touchdown_events: ``(on_time, window, height)`` or None: at each ``update`` a foot in a planned
            flight or swing whose sole is within ``height`` of its planned touchdown height, with that
            touchdown ``window`` s ahead or less and more than ``on_time`` away, advances the trajectory's
            clock to that touchdown (``advance``), so that the plans stand on the feet that landed early
            (the gaits' ``touchdown_events``, ``LocomotionReference``); None: the clock is fixed.
    """

    def __init__(
        self,
        robot: Robot,
        trajectory: WholeBodyTrajectory,
        start: float = 0.0,
        weight_set: str = "barrel_roll",
        hold_weight_set: str = "barrel_roll",
        touchdown_events: tuple[float, float, float] | None = None,
    ) -> None:
        if not (math.isfinite(start) and start >= 0.0):
            raise ValueError(f"trajectory reference: start must be >= 0 s, got {start}")
        trajectory.validate(robot.nq, robot.nv, robot.nu, trajectory.name)
        contacts = np.asarray(trajectory.contacts, dtype=bool)
        for label, flags in (("first", contacts[0]), ("last", contacts[-1])):
            if not flags.any():
                raise ValueError(
                    f"trajectory {trajectory.name!r}: its {label} interval is a flight phase; a trajectory "
                    "reference holds its first and last states as a stand and needs feet on the ground there"
                )
        self.robot = robot
        self.trajectory = trajectory
        self.start = float(start)
        self.dt = float(trajectory.dt)
        self.duration = float(trajectory.times[-1] - trajectory.times[0])
        self.n_intervals = trajectory.n_knots
        nq = robot.nq
        self._q = np.ascontiguousarray(trajectory.xs[:, :nq])
        self._v = np.ascontiguousarray(trajectory.xs[:, nq:])
        self._us = np.asarray(trajectory.us, dtype=float)
        self._forces = np.asarray(trajectory.forces, dtype=float)
        self._contacts = contacts
        self._feet, self._feet_velocity = foot_states(robot, trajectory.xs)
        names = [weight_set] if weight_set == hold_weight_set else [weight_set, hold_weight_set]
        self.weight_sets = tuple(names)
        self._inside = 0
        self._hold = names.index(hold_weight_set)
        # the two holds: configuration at rest, stance of the first / last interval, static torques
        self._holds = []
        for index, stance in ((0, contacts[0]), (-1, contacts[-1])):
            q = self._q[index].copy()
            torque = static_stance_torques(robot, q, stance)
            forces = np.zeros((robot.n_feet, 3))
            forces[stance, 2] = robot.total_mass * GRAVITY / stance.sum()
            self._holds.append((q, tuple(bool(s) for s in stance), torque, forces, self._feet[index].copy()))
        self._quaternion = np.zeros(4)
        # the same as arrays for the compiled sampling (``reference.kernels.sample_trajectory``)
        self._timing = np.array([self.start, self.dt, INDEX_TOLERANCE, STANCE_TIME_EPS])
        self._weight_set_array = np.array([self._inside, self._hold], dtype=np.int64)
        self._hold_arrays = tuple(
            np.ascontiguousarray(np.array([hold[field] for hold in self._holds])) for field in (0, 1, 2, 3, 4)
        )
        self._knot_arrays = tuple(
            np.ascontiguousarray(array, dtype=float)
            for array in (self._q, self._v, self._feet, self._feet_velocity, self._us, self._forces)
        )
        self._contact_array = np.ascontiguousarray(contacts)
        # compile (or load from numba's cache) the sampling kernel now, not in the first MPC update
        window = ReferenceWindow(1, robot.nq, robot.nv, robot.nu, robot.n_feet)
        window.set_times(np.array([self.start]))
        self.sample(window)
        changes = np.flatnonzero(np.any(contacts[1:] != contacts[:-1], axis=1)) + 1
        self._switches = [self.start + float(k) * self.dt for k in changes]
        self.touchdown_events = touchdown_events
        self._data = robot.model.createData() if touchdown_events is not None else None
        self.advances = 0
        self.advance_total = 0.0

    # ------------------------------------------------------------------------------------------- times
    @property
    def end_time(self) -> float:
        """Reference time of the last knot; after it the reference holds the last state."""
        return self.start + self.duration

    def _locate(self, t: float) -> tuple[int, float]:
        """``(-1, 0)`` before the start, ``(N, 0)`` after the end, else (interval k, fraction in it)."""
        s = (t - self.start) / self.dt
        if s < -INDEX_TOLERANCE:
            return -1, 0.0
        k = math.floor(s + INDEX_TOLERANCE)
        if k >= self.n_intervals:
            if s <= self.n_intervals + INDEX_TOLERANCE:
                return self.n_intervals - 1, 1.0  # the last knot itself (the hold starts after it)
            return self.n_intervals, 0.0
        return k, min(max(s - k, 0.0), 1.0)

    def switch_times(self, t0: float, t1: float) -> list[float]:
        """Contact switches in ``(t0, t1)``: the stored knot times where the stance flags change (the holds
        keep the first and last intervals' flags)."""
        return switches_inside(self._switches, t0, t1)

    def stance_at(self, t: float) -> tuple[bool, ...]:
        """Stored stance flags of the interval containing ``t`` (the holds' stance outside)."""
        k, _ = self._locate(t)
        if k < 0:
            return self._holds[0][1]
        if k >= self.n_intervals:
            return self._holds[1][1]
        return tuple(bool(flag) for flag in self._contacts[k])

    # ------------------------------------------------------------------------------------------ events
    def update(self, t: float, q: np.ndarray, v: np.ndarray) -> None:
        """With ``touchdown_events``: advance the clock when a foot landed early (see the class)."""
        if self.touchdown_events is None:
            return
        on_time, window, height = self.touchdown_events
        k, _ = self._locate(t)
        if k < 0 or k >= self.n_intervals:
            return  # the holds: no touchdown ahead
        assert self._data is not None
        model, data, robot = self.robot.model, self._data, self.robot
        pin.framesForwardKinematics(model, data, q)
        last = min(self.n_intervals - 1, k + math.ceil(window / self.dt))
        lead = None
        for foot, frame_id in enumerate(robot.foot_frame_ids):
            if self._contacts[k, foot]:
                continue
            # the first interval ahead in which the foot is planned in stance: its touchdown knot
            ahead = np.flatnonzero(self._contacts[k + 1 : last + 1, foot])
            if len(ahead) == 0:
                continue
            knot = k + 1 + int(ahead[0])
            touchdown = self.start + knot * self.dt
            if not (on_time < touchdown - t <= window):
                continue
            planned_sole = self._feet[knot, foot, 2] - robot.foot_radius
            sole = float(data.oMf[frame_id].translation[2]) - robot.foot_radius
            if sole - planned_sole <= height:
                lead = touchdown - t if lead is None else min(lead, touchdown - t)
        if lead is not None:
            self.advance(lead)

    def advance(self, lead: float) -> None:
        """From now on the trajectory plays ``lead`` seconds ahead: what was planned for ``t + lead`` happens
        at ``t`` (its end comes ``lead`` earlier and its last state is held from there)."""
        self.start -= lead
        self._timing[0] = self.start
        self._switches = [switch - lead for switch in self._switches]
        self.advances += 1
        self.advance_total += lead

    # ------------------------------------------------------------------------------------------ sample
    def sample(self, window: ReferenceWindow) -> None:
        """Fill ``window`` at its times (see the module docstring for each field): one compiled call
        (``reference.kernels.sample_trajectory``, the arithmetic of ``sample_python``)."""
        q, v, feet, feet_velocity, us, forces = self._knot_arrays
        hold_q, hold_stance, hold_torque, hold_forces, hold_feet = self._hold_arrays
        sample_trajectory(
            window.times,
            self._timing,
            self.n_intervals,
            q,
            v,
            feet,
            feet_velocity,
            us,
            forces,
            self._contact_array,
            hold_q,
            hold_stance,
            hold_torque,
            hold_forces,
            hold_feet,
            self._weight_set_array,
            window.state,
            window.stance,
            window.torque,
            window.forces,
            window.foot_positions,
            window.foot_velocities,
            window.weight_set,
        )

    def sample_python(self, window: ReferenceWindow) -> None:
        """``sample`` knot by knot in Python (the straightforward version the tests compare with)."""
        nq = self.robot.nq
        quaternion = self._quaternion
        for i, t in enumerate(window.times):
            t = float(t)
            k, alpha = self._locate(t)
            state = window.state[i]
            if k < 0 or k >= self.n_intervals:
                q, stance, torque, forces, feet = self._holds[0 if k < 0 else 1]
                state[:nq] = q
                state[nq:] = 0.0
                window.stance[i] = stance
                window.torque[i] = torque
                window.forces[i] = forces
                window.foot_positions[i] = feet
                window.foot_velocities[i] = 0.0
                window.weight_set[i] = self._hold
                continue
            q0, q1 = self._q[k], self._q[k + 1]
            state[:3] = q0[:3] + alpha * (q1[:3] - q0[:3])
            quaternion_slerp(q0[3:7], q1[3:7], alpha, quaternion)
            state[3:7] = quaternion
            state[7:nq] = q0[7:] + alpha * (q1[7:] - q0[7:])
            state[nq:] = self._v[k] + alpha * (self._v[k + 1] - self._v[k])
            window.foot_positions[i] = self._feet[k] + alpha * (self._feet[k + 1] - self._feet[k])
            window.foot_velocities[i] = self._feet_velocity[k] + alpha * (
                self._feet_velocity[k + 1] - self._feet_velocity[k]
            )
            # controls, forces and stance of the interval that starts at (contains) t
            interval = k
            if alpha > 1.0 - STANCE_TIME_EPS / self.dt:
                interval = min(k + 1, self.n_intervals - 1)
            window.stance[i] = self._contacts[interval]
            window.torque[i] = self._us[interval]
            window.forces[i] = self._forces[interval]
            window.weight_set[i] = self._inside
