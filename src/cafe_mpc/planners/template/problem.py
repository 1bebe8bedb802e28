"""Template-MPC baseline: the HKD-MPC structure of paper Sec. VII-C (Fig. 12), planning over the SRB only.

The paper compares CAFE-MPC with the authors' Hybrid Kinodynamic MPC (HKD-MPC, their ref. [79]): single
rigid-body (SRB) dynamics over the whole horizon with the legs as kinematics only, the planned ground
reaction forces (GRFs) applied directly by the stance legs, and a separate swing-leg controller. This module
is the planning half of such a baseline, built from the same parts as CAFE-MPC:

* the SRB model (29), (30) with the SRB cost (28) (``ocp.knots.SRBKnot``) on *every* knot of the horizon;
  stance flags and footholds (stance-foot positions) from the same ``Reference`` as CAFE-MPC (Raibert
  footholds of the locomotion reference): foot placement is not optimised;
* relaxed-barrier GRF constraints (``ConstrainedSRBKnot``): the friction pyramid with unilateral normal
  force, and the stance legs' joint-torque limits through the leg kinematics (``tau = -J(q)' f`` at the
  configuration expected at each knot: inverse kinematics of the footholds about the warm start's base
  pose). The GRFs are applied as planned, so they must be admissible; the torque rows are the "kinematics"
  part of the kinodynamic model (without them the bound's plans asked the hind legs for 150-190 N per foot,
  twice what 17 Nm knees give at that posture);
* MS-iLQR, warm-started from the previous solution shifted by time, with the same iteration budget per
  update as CAFE-MPC; the result is a ``planners.template.plan.TemplatePlan`` (SRB states, GRFs, stance,
  reference feet) for ``planners.template.low_level``;
* delay compensation (``TemplateMpc.predict_start``): an update plans from the time its plan will take
  effect (its measurement time plus the fixed latency, or the recent updates' median wall time), from the
  SRB state the plan in effect until then predicts there. CAFE-MPC's real-time iteration prepares each
  update from its plan's prediction too (``planners.cafe.planner``). Measured (bound with MIT's timing, +1.5
  m/s push): without it the template recovered at 5 and 10 ms of fixed latency and fell at 15 and 20 ms;
  with it, it recovers at 15 and 20 ms (falls at 30 ms).

The SRB's mass and inertia are the planning model's own, without the rotor point masses of the CAFE tail
(``template_srb``: the plant has none). Its position is the robot's centre of mass: each update starts from
the measured centroidal state (``TemplateProblemBuilder.initial_state``: centre of mass, its velocity, and
the angular velocity of the centroidal angular momentum), which the GRFs act on whatever the legs do; the
reference's base poses are moved to the standing pose's centre of mass.

Reference height (``VerticalOscillation``). With flight phases the reference's constant height
contradicts its own GRF references (``support_factor * m g`` per stance foot): under them the body rises
in stance and falls in flight. The template adds that periodic motion to its SRB reference, so that the
terminal cost, wherever in the cycle the horizon ends, asks for a state of the gait rather than a hover
in mid-flight (the first plan of the paper's pronk crouched the centre of mass to 0.14 m with the constant
height, to 0.20 m with the oscillation; reference 0.24 m).

Knot grid (design choice). The authors' HKD-MPC plans 0.6 s at 0.01 s. Here: ``horizon`` 0.5 s (the CAFE
tail's Ts of S5) at ``dt`` 0.01 s, with the knots on the absolute time grid ``k * dt`` after the first one
(``t0``, the measurement time), so that knots persist between updates (the warm start maps them by time),
and an interval that a contact switch falls inside is split at the switch (``time_grid.grid_times``): the
paper's gaits switch on the grid, MIT's 26 ms segments do not. The first interval ``[t0, next grid time)``
is 1 ms to ``dt`` long; durations are rounded to 1 ms so the SRB dynamics objects (one per duration) stay
few. One update (50-60 knots, one MS-iLQR iteration) takes about 5-8 ms.

Weights: ``template_running_weights`` (the authors' HKD tracking weights with a heavier height, pitch and
roll and a lighter GRF regularisation) and ``terminal_weights`` (5 x the running ones); each deviation and
the measurement behind it is in its docstring.
"""

from __future__ import annotations

import bisect
import logging
import math
from dataclasses import dataclass, replace

import numpy as np
import pinocchio as pin
from numba import njit

from cafe_mpc.config import DEFAULT_FRICTION, TemplateSettings
from cafe_mpc.config.weights import SRBWeights
from cafe_mpc.core.interfaces import MultiPhaseProblem, Phase
from cafe_mpc.core.physics import GRAVITY
from cafe_mpc.dynamics.leg_inverse_kinematics import LegInverseKinematics
from cafe_mpc.dynamics.srb import (
    SRBDynamics,
    SRBParameters,
    SRBState,
    lumped_inertia,
    quaternion_to_rotation,
)
from cafe_mpc.dynamics.transition import whole_body_to_srb_state
from cafe_mpc.ocp.constraints import BarrierParameters
from cafe_mpc.ocp.contact_schedule import GaitCycle
from cafe_mpc.ocp.knots import SRBKnot, SRBKnotData, SRBReference
from cafe_mpc.planners.time_grid import TIME_QUANTUM, grid_times, quanta
from cafe_mpc.reference.base import Reference, ReferenceWindow
from cafe_mpc.robots.robot import Robot

logger = logging.getLogger(__name__)

LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED


# --------------------------------------------------------------------------------------------------
# GRF constraints: friction pyramid and joint-torque limits (relaxed barrier, Sec. III-B-2)
# --------------------------------------------------------------------------------------------------

FRICTION_ROWS = 5
TORQUE_ROWS = 6


@njit(cache=True, nogil=True)
def _force_barrier(
    u: np.ndarray,
    contacts: np.ndarray,
    rows: np.ndarray,
    offsets: np.ndarray,
    deltas: np.ndarray,
    weights: np.ndarray,
    scale: float,
    with_derivatives: bool,
    Lu: np.ndarray,
    Luu: np.ndarray,
) -> tuple[float, float]:
    """``scale * sum eps_r B_r(g)`` over the rows ``g = offsets[j, r] + rows[j, r] . f_j >= 0`` of each
    stance foot ``j`` (relaxed barrier ``B`` with per-row ``delta``, ``ocp.barrier``); adds the gradient and
    the Gauss-Newton Hessian to ``Lu``, ``Luu`` when ``with_derivatives``. Returns (cost, worst violation
    ``max(0, -g)``)."""
    cost = 0.0
    violation = 0.0
    for foot in range(contacts.shape[0]):
        if contacts[foot] < 0.5:
            continue
        base = 3 * foot
        for row in range(rows.shape[1]):
            a = rows[foot, row]
            delta, eps = deltas[row], weights[row]
            g = offsets[foot, row] + a[0] * u[base] + a[1] * u[base + 1] + a[2] * u[base + 2]
            if -g > violation:
                violation = -g
            if g > delta:
                b, db, ddb = -math.log(g), -1.0 / g, 1.0 / (g * g)
            else:
                z = (g - 2.0 * delta) / delta
                b, db, ddb = 0.5 * (z * z - 1.0) - math.log(delta), z / delta, 1.0 / (delta * delta)
            cost += eps * b
            if with_derivatives:
                for i in range(3):
                    Lu[base + i] += scale * eps * db * a[i]
                    for j in range(3):
                        Luu[base + i, base + j] += scale * eps * ddb * a[i] * a[j]
    return scale * cost, violation


class ConstrainedSRBKnot(SRBKnot):
    """``SRBKnot`` (dynamics (29), (30), cost (28)) plus, on each stance foot's GRF ``f``, relaxed-barrier
    costs (times the time step, like the whole-body knots' constraints (26), (27)) for

    * the friction pyramid with unilateral normal force ``[fz, mu fz -+ fx, mu fz -+ fy] >= 0`` (26);
    * the joint-torque limits of that leg, ``|tau_j| <= tau_max`` with ``tau = -J(q)' f`` (27a through the
      stance torque map of the low level): ``torque_map`` (n_feet, 3, 3), rows ``d tau_leg / d f``, is set
      per update (``set_torque_map``) from the leg kinematics at the knot's expected configuration; zero
      (no torque rows in effect beyond a constant) until set.

    Terminal knots (no forces) are plain ``SRBKnot`` s.
    """

    def __init__(
        self,
        dynamics: SRBDynamics,
        weights: SRBWeights,
        reference: SRBReference,
        friction_coefficient: float,
        friction_barrier: BarrierParameters,
        torque_limits: np.ndarray,
        torque_barrier: BarrierParameters,
    ) -> None:
        super().__init__(dynamics, weights, reference)
        if not friction_coefficient > 0:
            raise ValueError(f"friction coefficient must be positive, got {friction_coefficient}")
        mu = float(friction_coefficient)
        n_feet = len(reference.contacts)
        limits = np.asarray(torque_limits, dtype=float).reshape(n_feet, 3)
        self.friction_coefficient = mu
        self.rows = np.zeros((n_feet, FRICTION_ROWS + TORQUE_ROWS, 3))
        self.offsets = np.zeros((n_feet, FRICTION_ROWS + TORQUE_ROWS))
        pyramid = np.array([[0, 0, 1], [-1, 0, mu], [1, 0, mu], [0, -1, mu], [0, 1, mu]], dtype=float)
        self.rows[:, :FRICTION_ROWS] = pyramid
        self.offsets[:, FRICTION_ROWS : FRICTION_ROWS + 3] = limits
        self.offsets[:, FRICTION_ROWS + 3 :] = limits
        self.deltas = np.r_[
            np.full(FRICTION_ROWS, friction_barrier.delta), np.full(TORQUE_ROWS, torque_barrier.delta)
        ]
        self.barrier_weights = np.r_[
            np.full(FRICTION_ROWS, friction_barrier.eps), np.full(TORQUE_ROWS, torque_barrier.eps)
        ]

    def set_torque_map(self, torque_map: np.ndarray) -> None:
        """Rows ``d tau / d f`` (n_feet, 3 joints, 3 force components) of each leg at this knot: the torque
        rows become ``tau_max -+ torque_map f >= 0``."""
        self.rows[:, FRICTION_ROWS : FRICTION_ROWS + 3] = -torque_map
        self.rows[:, FRICTION_ROWS + 3 :] = torque_map

    def calc(self, data: SRBKnotData, x: np.ndarray, u: np.ndarray) -> None:
        super().calc(data, x, u)
        cost, violation = _force_barrier(
            u,
            self.reference.contacts,
            self.rows,
            self.offsets,
            self.deltas,
            self.barrier_weights,
            self.cost_scale,
            False,
            data.Lu,
            data.Luu,
        )
        data.cost += cost
        data.constraint_violation = violation

    def calc_diff(self, data: SRBKnotData, x: np.ndarray, u: np.ndarray) -> None:
        super().calc_diff(data, x, u)
        _force_barrier(
            u,
            self.reference.contacts,
            self.rows,
            self.offsets,
            self.deltas,
            self.barrier_weights,
            self.cost_scale,
            True,
            data.Lu,
            data.Luu,
        )


# --------------------------------------------------------------------------------------------------
# Settings and problem
# --------------------------------------------------------------------------------------------------


def hkd_running_weights(force: float = 1e-3) -> SRBWeights:
    """The authors' HKD-MPC tracking weights (public CAFE-MPC code, ``HKDMPC/HKD-TrajOpt/HKDCost.h``; base
    order here ``[x, y, z, yaw, pitch, roll]``): position (1, 1, 30), Euler angles (yaw 1, pitch 4, roll 4),
    linear velocity (1, 1, 1), body rates (yaw 0.2, pitch 0.5, roll 1.0); GRF regularisation ``force``
    (their 0.1; 1e-3 here, see ``template_running_weights``). The template's own set is
    ``template_running_weights``."""
    return SRBWeights(
        base_position=(1.0, 1.0, 30.0, 1.0, 4.0, 4.0),
        base_velocity=(1.0, 1.0, 1.0, 0.2, 0.5, 1.0),
        force=force,
    )


def template_running_weights() -> SRBWeights:
    """Running weights of the template's SRB cost (28): the HKD set (``hkd_running_weights``) with the height
    weight 1000 (HKD: 30) and the pitch and roll weights 40 (HKD: 4), GRF regularisation 1e-3.

    Each change measured in closed loop (fixed 20 ms latency, 5-10 s at 0.5 m/s; docs/settings.md):

    * GRF regularisation 1e-3 (HKD: 0.1) toward the reference's equal per-foot forces: 0.1 (and 0.01) kept
      the trotting body pitched by 0.3-0.45 rad, because equal forces do not balance the moments about the
      centre of mass and a heavy pull toward them wins over the pitch cost; 1e-4 fell (GRFs chattering
      between updates).
    * Height 1000: with 30, a lift priced in GRF regularisation cost as much as an 8 cm height error, and
      the pace (0.25 s a side) sank from 0.25 m to 0.11 m and fell at 2.7 s; with 100, 300 and 1000 it
      paced at a mean base height of 0.196, 0.220 and 0.238 m (reference 0.25 m). The ratio of the height
      weight to the GRF weight is then about that of MIT's convex MPC (Cheetah-Software: 50 / 4e-5).
    * Pitch and roll 40: pitch RMS 0.033 -> 0.008 rad trotting, 0.098 -> 0.073 rad pronking; of the sets
      tried (pitch and roll 20 or 40, horizontal-speed weights 1, 3 or 10) only this one recovered from
      the push test (bound, +1.5 m/s) at 20 ms latency.
    """
    return SRBWeights(
        base_position=(1.0, 1.0, 1000.0, 1.0, 40.0, 40.0),
        base_velocity=(1.0, 1.0, 1.0, 0.2, 0.5, 1.0),
        force=1e-3,
    )


TERMINAL_SCALE = 5.0
"""Terminal weights = this x the running state weights (``terminal_weights``)."""


def terminal_weights(running: SRBWeights | None = None) -> SRBWeights:
    """Terminal weights: ``TERMINAL_SCALE`` (5) x the running state weights, no force term. The HKD code's
    ``Qf = 20 diag(scale) Q`` (400 x the running height weight) made the plans aim only at the horizon's
    end: in a pronk the first plan let the body fall from 0.24 m to 0.02 m and launched it back to hit the
    terminal height. The CAFE tail's regular terminal set (base (0, 0, 1, 1, 1, 1), velocities 1) let the
    trotting body roll away slowly (1.2 rad at 6.2 s, then the fall); 1 x and 5 x the running weights both
    trot for 10 s (measured with fixed latency)."""
    running = running or template_running_weights()
    return SRBWeights(
        base_position=tuple(TERMINAL_SCALE * w for w in running.base_position),
        base_velocity=tuple(TERMINAL_SCALE * w for w in running.base_velocity),
        force=0.0,
    )


FRICTION_BARRIER = BarrierParameters(0.1, 0.01)
"""Relaxed barrier of the GRF pyramid rows (the authors' HKD-MPC ReB: delta 0.1, eps 0.01)."""

TORQUE_BARRIER = BarrierParameters(1.0, 0.01)
"""Relaxed barrier of the stance legs' torque rows ``-J' f`` (the whole-body knots' delta 1, eps 0.01)."""


def template_srb(robot: Robot) -> tuple[SRBParameters, np.ndarray]:
    """SRB mass, inertia (about the centre of mass, base frame) and centre of mass (base frame) of the
    template model: every body of the robot's model lumped at the standing pose, *without* the rotor point
    masses that ``dynamics.srb.srb_parameters`` adds for the CAFE tail (the simulated plant's mass is the
    model's: with the rotors the plan asked for 8 % more vertical force than the 8.25 kg Mini Cheetah needs
    and the trotting base rose by 2 cm). The SRB position is the centre of mass, not the base origin: the
    template plans with the SRB alone, and the 8 mm / 12 mm offset of the Mini Cheetah's centre of mass
    behind / below the base origin otherwise leaves a standing pitch error of 0.08 rad."""
    lumped = lumped_inertia(replace(robot, rotor_mass=0.0))
    inertia = np.asarray(lumped.inertia, dtype=float)
    inertia = 0.5 * (inertia + inertia.T)
    parameters = SRBParameters(
        float(lumped.mass), tuple(tuple(float(v) for v in row) for row in inertia), n_feet=robot.n_feet
    )
    return parameters, np.asarray(lumped.lever, dtype=float).copy()


class VerticalOscillation:
    """The periodic height and vertical speed a gait's GRF references imply (added to the SRB reference).

    The locomotion reference holds the body at a constant height, and its GRF reference puts
    ``support_factor * m g`` on every stance foot (``GaitCycle.support_factor``). With flight phases the two
    disagree: under those forces the SRB accelerates upward by ``g (n_stance * support_factor - 1)`` in
    stance and falls at ``g`` in flight. This is that motion's periodic solution: piecewise parabolas with
    zero mean height and zero mean vertical speed over the cycle. Zero for gaits without flight phases
    whose stance count is constant (trot, pace, stand).
    """

    def __init__(self, gait: GaitCycle, gravity: float = GRAVITY) -> None:
        self.period = gait.period
        factor = gait.support_factor
        self.starts: list[float] = []
        self.accelerations: list[float] = []
        velocity = position = elapsed = 0.0
        velocities, positions = [], []
        mean_velocity = mean_position = 0.0
        for flags, duration in gait.cycle:
            acceleration = gravity * (sum(flags) * factor - 1.0)
            self.starts.append(elapsed)
            self.accelerations.append(acceleration)
            velocities.append(velocity)
            positions.append(position)
            mean_velocity += velocity * duration + 0.5 * acceleration * duration**2
            mean_position += (
                position * duration + 0.5 * velocity * duration**2 + acceleration * duration**3 / 6.0
            )
            position += velocity * duration + 0.5 * acceleration * duration**2
            velocity += acceleration * duration
            elapsed += duration
        # shift the initial speed so that the mean speed is zero, then the height so that its mean is zero
        v0 = -mean_velocity / self.period
        self.velocities = [v + v0 for v in velocities]
        shifted = [z + v0 * t for z, t in zip(positions, self.starts, strict=True)]
        mean_shifted = mean_position + v0 * 0.5 * self.period**2
        self.positions = [z - mean_shifted / self.period for z in shifted]

    def at(self, tau: float) -> tuple[float, float]:
        """Height offset and vertical speed at ``tau`` seconds into the cycle."""
        tau = tau % self.period
        index = max(bisect.bisect_right(self.starts, tau) - 1, 0)
        s = tau - self.starts[index]
        a, v, z = self.accelerations[index], self.velocities[index], self.positions[index]
        return z + v * s + 0.5 * a * s * s, v + a * s


@dataclass
class TemplateProblem:
    """One update's problem and what the plan needs besides the solution."""

    problem: MultiPhaseProblem
    times: np.ndarray  # (n + 1,) knot times
    contacts: np.ndarray  # (n, n_feet) bool
    foot_positions: np.ndarray  # (n + 1, n_feet, 3)
    foot_velocities: np.ndarray  # (n + 1, n_feet, 3)
    force_targets: np.ndarray  # (n, 3 n_feet) GRF regularisation targets (also the guess of new knots)
    reference_states: np.ndarray  # (n + 1, SRBState.nx) SRB reference states
    knots: list[ConstrainedSRBKnot]  # the running knots (their torque maps are set per update)


def base_to_com(state: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """Move an SRB state of the base frame (``[c, quat, c_dot, omega]``, ``dynamics.transition``) to the
    centre of mass at ``offset`` in the base frame (in place): ``c += R offset``, ``c_dot += R (omega x
    offset)``."""
    rotation = quaternion_to_rotation(state[3:7])
    state[0:3] += rotation @ offset
    state[7:10] += rotation @ np.cross(state[10:13], offset)
    return state


class TemplateProblemBuilder:
    """Builds the SRB-only problem of each update from persistent knots (references written in place).

    Knot slot ``k`` keeps one knot per interval duration it has needed (in ms), so the same knot objects,
    and the solver's data for them, come back every update.
    """

    def __init__(
        self,
        robot: Robot,
        settings: TemplateSettings | None = None,
        friction: float = DEFAULT_FRICTION,
        torque_limits: np.ndarray | None = None,
    ) -> None:
        self.robot = robot
        self.settings = settings or TemplateSettings()
        if not friction > 0:
            raise ValueError(f"friction coefficient must be positive, got {friction}")
        self.friction = float(friction)
        """Friction coefficient of the GRF pyramid (a run's ``ContactModel.friction``)."""
        self.parameters, self.com_offset = template_srb(robot)
        """The SRB's mass and inertia, and its position: the centre of mass in the base frame."""
        self.running_weights = template_running_weights()
        self.weight = self.parameters.mass * self.parameters.gravity
        n = self.settings.knots
        # the grid's n + 1 times and up to one split per knot interval at the contact switches
        self.window = ReferenceWindow(2 * n + 1, robot.nq, robot.nv, robot.nu, robot.n_feet)
        self._dynamics: dict[int, SRBDynamics] = {}
        self._running: dict[tuple[int, int], ConstrainedSRBKnot] = {}
        limits = robot.torque_limits if torque_limits is None else torque_limits
        self.torque_limits = np.asarray(limits, dtype=float)
        """The leg torque bound of the stance legs' ``-J' f`` (``settings.leg_torque_limits``)."""
        if self.torque_limits.shape != (robot.nu,) or np.any(self.torque_limits <= 0):
            raise ValueError(f"template torque limits need {robot.nu} positive values")
        self.inverse_kinematics = LegInverseKinematics(robot)
        self._data = robot.model.createData()
        self._oscillations: dict[str, VerticalOscillation] = {}
        self._inertia_inverse = np.linalg.inv(np.asarray(self.parameters.inertia, dtype=float))
        self._terminal = SRBKnot(
            None,
            terminal_weights(self.running_weights),
            SRBReference(SRBState().zero(), np.zeros((robot.n_feet, 3)), (True,) * robot.n_feet, self.weight),
        )

    def knot_times(self, t0: float, reference: Reference | None = None) -> np.ndarray:
        """``t0``, then the absolute grid ``k * dt`` after it, with the intervals that a contact switch of
        ``reference`` falls inside split at the switch (``time_grid.grid_times``): a gait whose phases are
        not whole multiples of ``dt`` (MIT's 26 ms segments) still switches at its own times."""
        n, dt = self.settings.knots, self.settings.dt
        switches = () if reference is None else reference.switch_times(t0, t0 + (n + 1) * dt)
        return grid_times(t0, n, dt, switches)

    def dynamics(self, milliseconds: int) -> SRBDynamics:
        """The SRB dynamics (29), (30) over ``milliseconds`` (one object per duration, shared by knots)."""
        dynamics = self._dynamics.get(milliseconds)
        if dynamics is None:
            dynamics = SRBDynamics(self.parameters, milliseconds * TIME_QUANTUM)
            self._dynamics[milliseconds] = dynamics
        return dynamics

    def _knot(self, slot: int, milliseconds: int) -> ConstrainedSRBKnot:
        key = (slot, milliseconds)
        knot = self._running.get(key)
        if knot is None:
            dynamics = self.dynamics(milliseconds)
            feet = self.robot.n_feet
            knot = ConstrainedSRBKnot(
                dynamics,
                self.running_weights,
                SRBReference(SRBState().zero(), np.zeros((feet, 3)), (True,) * feet, self.weight),
                self.friction,
                FRICTION_BARRIER,
                self.torque_limits,
                TORQUE_BARRIER,
            )
            self._running[key] = knot
        return knot

    def build(
        self, t0: float, x0: np.ndarray, reference: Reference, start: np.ndarray | None = None
    ) -> TemplateProblem:
        """The problem of an update at ``t0`` from the measured whole-body state ``x0 = [q, v]``; ``start``:
        the SRB state at ``t0`` when it is not ``initial_state(x0)`` (a prediction)."""
        robot = self.robot
        times = self.knot_times(t0, reference)
        n = len(times) - 1
        window = self.window
        window.set_times(times)
        reference.sample(window)
        window.check_finite(type(reference).__name__)
        durations = [quanta(float(d)) for d in np.diff(times)]
        contacts = np.asarray(window.stance[:n], dtype=bool).copy()
        # GRF targets (28): the reference's stance forces scaled to the SRB's own weight
        force_targets = window.forces[:n].reshape(n, -1) * (self.weight / (robot.total_mass * GRAVITY))
        reference_states = np.empty((n + 1, SRBState.nx))
        for k in range(n + 1):
            whole_body_to_srb_state(window.state[k], robot.nq, reference_states[k])
            base_to_com(reference_states[k], self.com_offset)
        self._add_vertical_oscillation(reference, times, reference_states)
        running = []
        for k in range(n):
            knot = self._knot(k, int(durations[k]))
            ref = knot.reference
            ref.state[:] = reference_states[k]
            ref.foot_positions[:] = window.foot_positions[k]
            ref.contacts[:] = contacts[k]
            ref.forces[:] = force_targets[k]
            running.append(knot)
        terminal = self._terminal
        terminal.reference.state[:] = reference_states[n]
        terminal.reference.foot_positions[:] = window.foot_positions[n]
        terminal.reference.contacts[:] = window.stance[n]
        srb_x0 = self.initial_state(np.asarray(x0, dtype=float)) if start is None else start
        phase = Phase(running, terminal, dt=self.settings.dt, name="template")
        return TemplateProblem(
            MultiPhaseProblem(srb_x0, [phase]),
            times.copy(),
            contacts,
            window.foot_positions.copy(),
            window.foot_velocities.copy(),
            force_targets,
            reference_states,
            running,
        )

    def initial_state(self, x0: np.ndarray) -> np.ndarray:
        """The SRB state an update starts from, for the measured whole-body state ``x0 = [q, v]``.

        With ``settings.centroidal_state`` (default): the base orientation with the robot's centre of mass,
        its velocity, and the angular velocity whose SRB momentum ``R I omega`` is the robot's centroidal
        angular momentum ``h_G`` (Pinocchio, legs included): the quantities the GRFs change, ``m c_ddot =
        sum f - m g`` and ``h_G_dot = sum (p - c) x f`` exactly, whatever the legs do. Otherwise the base's
        pose and velocities moved to the standing-pose centre of mass (``base_to_com``). The legs are 60 % of
        the Mini Cheetah's mass. Measured with the base state (fixed 20 ms latency): both paces (0.25 and
        0.13 s a side) rolled over within 0.7 s and the bound fell after the push test's push, where all
        three run 10 s with this state; with the HKD weights a pace of 0.13 s a side rolled to 0.58 rad in
        10 s, the plan's roll moment cancelled by a true centre of mass 4 mm to the side of the SRB's.
        """
        robot = self.robot
        state = whole_body_to_srb_state(x0, robot.nq)
        if not self.settings.centroidal_state:
            return base_to_com(state, self.com_offset)
        q, v = x0[: robot.nq], x0[robot.nq :]
        model, data = robot.model, self._data
        state[0:3] = pin.centerOfMass(model, data, q, v)
        state[7:10] = data.vcom[0]
        momentum = pin.computeCentroidalMomentum(model, data, q, v).angular
        state[10:13] = self._inertia_inverse @ (quaternion_to_rotation(state[3:7]).T @ momentum)
        return state

    def _add_vertical_oscillation(self, reference: Reference, times: np.ndarray, states: np.ndarray) -> None:
        """Add the gait's ``VerticalOscillation`` to the reference height and vertical speed (a
        ``LocomotionReference``'s gait, from its first cycle on, faded in over one period)."""
        if not self.settings.vertical_reference:
            return
        gait = getattr(reference, "gait", None)
        if not isinstance(gait, GaitCycle):
            return
        oscillation = self._oscillations.get(gait.name)
        if oscillation is None:
            oscillation = VerticalOscillation(gait, self.parameters.gravity)
            self._oscillations[gait.name] = oscillation
        start = float(getattr(reference, "cycle_start", 0.0))
        for k, t in enumerate(times):
            fade = min(max((float(t) - start) / oscillation.period, 0.0), 1.0)
            if fade > 0.0:
                dz, dvz = oscillation.at(float(t) - start)
                states[k, 2] += fade * dz
                states[k, 9] += fade * dvz

    def update_torque_maps(self, built: TemplateProblem, states: np.ndarray) -> None:
        """Set each running knot's torque map ``d tau / d f = -J_leg(q)'`` (world-frame foot Jacobian of each
        leg) at the configuration expected at that knot: the base pose of ``states`` (SRB states of the warm
        start, centre of mass moved back to the base origin) with the legs solved by inverse kinematics for
        the knot's foot positions (footholds for stance feet)."""
        robot = self.robot
        n = len(built.knots)
        base = np.empty((n, 7))
        for k in range(n):
            rotation = quaternion_to_rotation(states[k, 3:7])
            base[k, :3] = states[k, :3] - rotation @ self.com_offset
            base[k, 3:7] = states[k, 3:7]
        joints, _, _ = self.inverse_kinematics.solve_batch(base, built.foot_positions[:n])
        model, data = robot.model, self._data
        q = np.empty(robot.nq)
        torque_map = np.zeros((robot.n_feet, 3, 3))
        for k, knot in enumerate(built.knots):
            stance = built.contacts[k]
            if not stance.any():
                continue
            q[:7] = base[k]
            q[7:] = joints[k]
            pin.computeJointJacobians(model, data, q)
            pin.updateFramePlacements(model, data)
            for foot, frame_id in enumerate(robot.foot_frame_ids):
                if stance[foot]:
                    jacobian = pin.getFrameJacobian(model, data, frame_id, LWA)
                    torque_map[foot] = -jacobian[:3, 6 + 3 * foot : 9 + 3 * foot].T
            knot.set_torque_map(torque_map)
