"""CAFE-MPC problem construction (paper Sec. IV-D) and the warm start between updates (Sec. VI-C, Fig. 5).

From the current time, the measured state, the contact schedule (through the reference) and a model
schedule ``(Tw, Ts, dt_w, dt_s)``:

* whole-body knots at ``t0 + k dt_w`` inside ``Tw``, grouped into phases at every contact change, each
  phase with its reset map (impact at touchdown, identity at take-off) and the touchdown switching
  constraint (25);
* one SRB phase with knots at ``t0 + Tw + j dt_s`` inside ``Ts``, the stance flags and footholds as
  per-knot parameters, joined by the transition map (31), (32); no SRB phase when ``Ts = 0`` (S0);
* the intermediate phases end with a cost-free terminal; the last phase has the terminal cost.

``WarmStart`` shifts the previous solution onto the new knots by time: knots that existed before keep
their state and control (shooting knots); appended whole-body knots copy the last whole-body state and
torque and stay shooting knots unless they belong to a newly appended phase entered through an impact, in
which case they become roll-out knots (the adaptive scheme of Fig. 5).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np

from cafe_mpc.core.contacts import touchdown_flags
from cafe_mpc.core.interfaces import MultiPhaseProblem, Phase
from cafe_mpc.dynamics.srb import SRBState
from cafe_mpc.dynamics.statics import static_stance_torques
from cafe_mpc.dynamics.transition import whole_body_to_srb_state
from cafe_mpc.ocp.costs import WholeBodyWeights
from cafe_mpc.ocp.knots import SRBModelFactory, WholeBodyModelFactory, WholeBodyReference
from cafe_mpc.reference.inverse_kinematics import LegInverseKinematics
from cafe_mpc.reference.locomotion import LocomotionReference
from cafe_mpc.solver.results import SolverResult

TIME_EPS = 1e-7

PAPER_SCHEDULES: dict[str, float] = {
    "S0": 0.0,
    "S1": 0.1,
    "S2": 0.2,
    "S3": 0.3,
    "S4": 0.4,
    "S5": 0.5,
    "S10": 1.0,
    "S15": 1.5,
    "S20": 2.0,
}
"""Table I: Ts of the paper's model schedules (Tw = 0.25 s for all)."""


@dataclass(frozen=True)
class ModelSchedule:
    """How the horizon is split: whole-body ``Tw`` at ``dt_w``, then SRB ``Ts`` at ``dt_s``."""

    whole_body_horizon: float = 0.25
    srb_horizon: float = 0.5
    whole_body_dt: float = 0.01
    srb_dt: float = 0.05

    def __post_init__(self) -> None:
        if not (self.whole_body_dt > 0 and self.srb_dt > 0):
            raise ValueError("model schedule time steps must be positive")
        if self.whole_body_horizon < self.whole_body_dt - TIME_EPS:
            raise ValueError(
                f"model schedule: Tw = {self.whole_body_horizon} s is shorter than one whole-body knot "
                f"({self.whole_body_dt} s)"
            )
        if self.srb_horizon < 0:
            raise ValueError(f"model schedule: Ts must be >= 0, got {self.srb_horizon}")
        if 0 < self.srb_horizon < self.srb_dt - TIME_EPS:
            raise ValueError(f"model schedule: Ts = {self.srb_horizon} s is shorter than one SRB knot")

    @classmethod
    def named(cls, name: str, whole_body_dt: float = 0.01, srb_dt: float = 0.05) -> ModelSchedule:
        """One of the paper's schedules S0..S20 (Table I)."""
        if name not in PAPER_SCHEDULES:
            raise ValueError(f"unknown model schedule {name!r}; known: {', '.join(PAPER_SCHEDULES)}")
        return cls(0.25, PAPER_SCHEDULES[name], whole_body_dt, srb_dt)

    @property
    def whole_body_knots(self) -> int:
        return max(1, round(self.whole_body_horizon / self.whole_body_dt))

    @property
    def srb_knots(self) -> int:
        return round(self.srb_horizon / self.srb_dt)


@dataclass
class PhaseInfo:
    """Bookkeeping of one built phase: kind, stance, knot times (``N + 1``: the last is the phase end)."""

    kind: str  # "whole_body" or "srb"
    stance: tuple[bool, bool, bool, bool] | None
    times: np.ndarray
    contacts: np.ndarray  # (N, 4) stance flags per running knot
    entered_by_impact: bool = False


@dataclass
class BuiltProblem:
    problem: MultiPhaseProblem
    phases: list[PhaseInfo]
    start_time: float
    srb_forces: np.ndarray = field(default_factory=lambda: np.zeros((0, 12)))
    """GRF targets of the SRB knots (n_srb, 12): also their warm-start guess."""

    @property
    def whole_body_phases(self) -> list[int]:
        return [i for i, info in enumerate(self.phases) if info.kind == "whole_body"]


class CafeProblemBuilder:
    """Builds the multi-phase CAFE problem of one MPC update (Sec. IV-D)."""

    def __init__(
        self,
        whole_body: WholeBodyModelFactory,
        srb: SRBModelFactory,
        schedule: ModelSchedule,
        joint_reference: Literal["inverse_kinematics", "standing"] = "inverse_kinematics",
    ) -> None:
        if joint_reference not in ("inverse_kinematics", "standing"):
            raise ValueError(
                f"joint_reference must be 'inverse_kinematics' or 'standing', got {joint_reference!r}"
            )
        self.joint_reference = joint_reference
        self.inverse_kinematics = LegInverseKinematics(whole_body.robot)
        self.whole_body = whole_body
        self.srb = srb
        self.schedule = schedule
        self.robot = whole_body.robot
        # Intermediate whole-body phases end with a cost-free terminal that keeps the state-only
        # constraints (joint limits and speeds, base height): without them the last torques of a phase
        # are free to whip the light legs (the end state is priced only by the phases after it).
        zero = WholeBodyWeights.zero()
        self.intermediate = WholeBodyModelFactory(
            whole_body.robot, replace(whole_body.settings, terminal_weights=zero)
        )
        self._stance_torques: dict[tuple[tuple[bool, ...], float | None], np.ndarray] = {}

    def stance_torque(
        self, stance: tuple[bool, ...] | None, support_factor: float | None = None
    ) -> np.ndarray:
        """Torques that hold the standing pose with ``support_factor * m g`` on each stance foot (default:
        the weight split over the stance feet); zero in flight.

        This is the torque regularisation target of every running knot: regularising toward zero biases
        the plan toward straight legs (less knee torque), which in closed loop lifted the trotting base from
        0.25 m to 0.32 m; regularising toward the static split biased bounding the same way (the stance legs
        of a gait with flight phases carry more than their share of the weight on average, see
        ``GaitCycle.support_factor``). It is also the torque guess of appended warm-start knots.
        """
        key = tuple(bool(s) for s in stance) if stance is not None else (False,) * 4
        factor = None if support_factor is None else round(float(support_factor), 6)
        if (key, factor) not in self._stance_torques:
            if any(key):
                force = None if factor is None else factor * self.robot.total_mass * 9.81
                torque = static_stance_torques(self.robot, self.robot.q_standing, key, force)
            else:
                torque = np.zeros(self.robot.nu)
            torque.setflags(write=False)
            self._stance_torques[(key, factor)] = torque
        return self._stance_torques[(key, factor)]

    def build(self, t0: float, x0: np.ndarray, reference: LocomotionReference) -> BuiltProblem:
        schedule = self.schedule
        n_wb = schedule.whole_body_knots
        wb_times = t0 + schedule.whole_body_dt * np.arange(n_wb + 1)
        stance_wb, feet_positions, feet_velocities = reference.feet(wb_times)
        # stance of a knot = the schedule at the knot's start (sampled a hair after to break ties)
        stance_wb = np.array([reference.stance_at(t + TIME_EPS) for t in wb_times], dtype=bool)
        groups: list[tuple[tuple[bool, ...], int, int]] = []  # (stance, first knot, last knot + 1)
        start = 0
        for k in range(1, n_wb + 1):
            if k == n_wb or tuple(stance_wb[k]) != tuple(stance_wb[start]):
                groups.append((tuple(bool(s) for s in stance_wb[start]), start, k))
                start = k
        states = self._whole_body_references(reference, wb_times, feet_positions, feet_velocities)
        has_srb = schedule.srb_knots > 0
        phases: list[Phase] = []
        infos: list[PhaseInfo] = []
        for index, (stance, first, last) in enumerate(groups):
            running = []
            for k in range(first, last):
                ref = WholeBodyReference(
                    states[k],
                    feet_positions[k],
                    feet_velocities[k],
                    self.stance_torque(stance, reference.support_factor(float(wb_times[k]))),
                )
                running.append(self.whole_body.running_knot(stance, ref, schedule.whole_body_dt))
            is_last = index == len(groups) - 1
            next_stance = groups[index + 1][0] if not is_last else tuple(bool(s) for s in stance_wb[n_wb])
            terminal_ref = WholeBodyReference(states[last], feet_positions[last], feet_velocities[last])
            if is_last:
                # the whole-body plan's terminal cost (also before the SRB tail, which drops the joints)
                terminal = self.whole_body.terminal_knot(stance, terminal_ref)
            else:
                terminal = self.intermediate.terminal_knot(stance, terminal_ref)
            if is_last and not has_srb:
                reset = None
                switching = None
            else:
                if is_last:
                    reset = self.whole_body.transition_to_srb(stance, next_stance, self.srb.state)
                else:
                    reset = self.whole_body.reset_map(stance, next_stance)
                switching = self.whole_body.touchdown_constraint(stance, next_stance)
            entered_by_impact = index > 0 and any(touchdown_flags(groups[index - 1][0], stance))
            phases.append(
                Phase(running, terminal, reset, switching, dt=schedule.whole_body_dt, name=f"wb{index}")
            )
            infos.append(
                PhaseInfo(
                    "whole_body",
                    stance,
                    wb_times[first : last + 1].copy(),
                    stance_wb[first:last].copy(),
                    entered_by_impact,
                )
            )
        if has_srb:
            n_srb = schedule.srb_knots
            srb_times = wb_times[-1] + schedule.srb_dt * np.arange(n_srb + 1)
            stance_srb = np.array([reference.stance_at(t + TIME_EPS) for t in srb_times], dtype=bool)
            _, srb_feet, _ = reference.feet(srb_times)
            running = []
            srb_forces = np.zeros((n_srb, 12))
            for j in range(n_srb):
                q_ref, v_ref = reference.base_state(srb_times[j])
                state = whole_body_to_srb_state(np.concatenate([q_ref, v_ref]))
                # GRF target (28): the gait's average stance force on each stance foot
                srb_forces[j].reshape(4, 3)[:, 2] = (
                    stance_srb[j] * reference.support_factor(float(srb_times[j])) * self.srb.weight
                )
                ref = self.srb.reference(state, srb_feet[j], tuple(bool(s) for s in stance_srb[j]))
                ref.set(forces=srb_forces[j])
                running.append(self.srb.running_knot(ref, schedule.srb_dt))
            q_ref, v_ref = reference.base_state(srb_times[-1])
            terminal_ref = self.srb.reference(
                whole_body_to_srb_state(np.concatenate([q_ref, v_ref])),
                srb_feet[-1],
                tuple(bool(s) for s in stance_srb[-1]),
            )
            phases.append(
                Phase(running, self.srb.terminal_knot(terminal_ref), dt=schedule.srb_dt, name="srb")
            )
            entered = any(touchdown_flags(groups[-1][0], tuple(bool(s) for s in stance_srb[0])))
            infos.append(PhaseInfo("srb", None, srb_times, stance_srb[:-1].copy(), entered))
        else:
            srb_forces = np.zeros((0, 12))
        problem = MultiPhaseProblem(np.asarray(x0, dtype=float), phases)
        return BuiltProblem(problem, infos, t0, srb_forces)

    def _whole_body_references(
        self,
        reference: LocomotionReference,
        times: np.ndarray,
        feet_positions: np.ndarray,
        feet_velocities: np.ndarray,
    ) -> np.ndarray:
        """Reference states ``[q, v]`` of the whole-body knots: base from the commands, joints and joint rates
        from leg inverse kinematics of the reference feet (or the standing pose)."""
        nq = self.robot.nq
        states = np.empty((len(times), nq + self.robot.nv))
        joints = None
        for k, t in enumerate(times):
            q_ref, v_ref = reference.base_state(float(t))
            if self.joint_reference == "inverse_kinematics":
                joints, rates, _ = self.inverse_kinematics.solve(
                    q_ref[:7], feet_positions[k], joints, v_ref[:6], feet_velocities[k]
                )
                q_ref[7:] = joints
                v_ref[6:] = rates
            states[k, :nq] = q_ref
            states[k, nq:] = v_ref
        return states


@dataclass
class InitialGuess:
    xs: list[np.ndarray]
    us: list[np.ndarray]
    rollout: list[np.ndarray]
    multipliers: list[np.ndarray | None] = field(default_factory=list)
    penalties: list[float | None] = field(default_factory=list)
    """Augmented-Lagrangian parameters of each phase's touchdown constraint, carried over from the previous
    solve of the same switch (authors' warm start, docs/settings.md: "keep barrier and AL parameters");
    ``None``: start afresh."""


@dataclass
class WarmStart:
    """Maps a previous solution onto a new problem by knot time (Sec. VI-C, Fig. 5)."""

    srb_state: SRBState = field(default_factory=SRBState)

    def guess(
        self,
        built: BuiltProblem,
        previous: BuiltProblem | None,
        solution: SolverResult | None,
        stance_torque: Callable[[tuple[bool, ...]], np.ndarray],
        srb_force_guess: np.ndarray,
    ) -> InitialGuess:
        """Initial states, controls and roll-out masks for ``built`` from the previous solution.

        ``stance_torque(stance)`` gives the torque guess of appended knots (the static torques that carry
        the weight on that phase's stance feet): copying the last planned torque into a phase with other
        stance feet would swing the now-unloaded legs violently.
        """
        x0 = built.problem.x0
        xs, us, rollout = [], [], []
        previous_wb: list[tuple[float, np.ndarray, np.ndarray | None, bool]] = []
        previous_srb: list[tuple[float, np.ndarray, np.ndarray | None]] = []
        if previous is not None and solution is not None:
            for info, phase in zip(previous.phases, solution.phases, strict=True):
                for k, t in enumerate(info.times):
                    control = phase.us[k] if k < len(phase.us) else None
                    if info.kind == "whole_body":
                        previous_wb.append((float(t), phase.xs[k], control, k == 0))
                    else:
                        previous_srb.append((float(t), phase.xs[k], control))
        last_wb_state = previous_wb[-1][1] if previous_wb else x0
        previous_end = previous_wb[-1][0] if previous_wb else -math.inf
        for info in built.phases:
            n = len(info.times) - 1
            if info.kind == "whole_body":
                appended_torque = stance_torque(info.stance)
                phase_x = np.empty((n + 1, len(x0)))
                phase_u = np.empty((n, appended_torque.size))
                phase_rollout = np.zeros(n + 1, dtype=bool)
                new_phase_after_impact = info.entered_by_impact and info.times[0] > previous_end - TIME_EPS
                for k, t in enumerate(info.times):
                    match = _lookup_whole_body(previous_wb, float(t), prefer_phase_start=(k == 0))
                    if match is not None:
                        phase_x[k] = match[0]
                        if k < n:
                            phase_u[k] = match[1] if match[1] is not None else appended_torque
                    else:
                        phase_x[k] = last_wb_state
                        if k < n:
                            phase_u[k] = appended_torque
                        phase_rollout[k] = new_phase_after_impact and k > 0
                xs.append(phase_x)
                us.append(phase_u)
                rollout.append(phase_rollout)
            else:
                phase_x = np.empty((n + 1, 13))
                phase_u = np.empty((n, 12))
                wb_end = xs[-1][-1] if xs else x0
                for j, t in enumerate(info.times):
                    match = _nearest_srb(previous_srb, float(t))
                    if match is not None:
                        phase_x[j] = match[0]
                        if j < n:
                            phase_u[j] = match[1] if match[1] is not None else srb_force_guess[j]
                    else:
                        phase_x[j] = whole_body_to_srb_state(wb_end)
                        if j < n:
                            phase_u[j] = srb_force_guess[j]
                xs.append(phase_x)
                us.append(phase_u)
                rollout.append(np.zeros(n + 1, dtype=bool))
        multipliers, penalties = _augmented_lagrangian_guess(built, previous, solution)
        return InitialGuess(xs, us, rollout, multipliers, penalties)


def _augmented_lagrangian_guess(
    built: BuiltProblem, previous: BuiltProblem | None, solution: SolverResult | None
) -> tuple[list[np.ndarray | None], list[float | None]]:
    """Multiplier and penalty of every touchdown constraint whose switch (phase end time, stance before and
    after) was already in the previous problem. Without this each update restarts the AL at ``sigma = 20``,
    ``lambda = 0`` and, with one AL update per solve, the touchdown constraint (25) is never enforced: the
    plan then lands its feet centimetres above the ground."""
    multipliers: list[np.ndarray | None] = [None] * len(built.phases)
    penalties: list[float | None] = [None] * len(built.phases)
    if previous is None or solution is None:
        return multipliers, penalties
    for index, info in enumerate(built.phases):
        if info.kind != "whole_body":
            continue
        end, after = float(info.times[-1]), _stance_after(built, index)
        for old_index, old in enumerate(previous.phases):
            if (
                old.kind == "whole_body"
                and abs(float(old.times[-1]) - end) <= 1e-6
                and old.stance == info.stance
                and _stance_after(previous, old_index) == after
            ):
                phase = solution.phases[old_index]
                if phase.multiplier is not None and after is not None:
                    multipliers[index] = phase.multiplier.copy()
                    penalties[index] = phase.penalty
                break
    return multipliers, penalties


def _stance_after(built: BuiltProblem, index: int) -> tuple[bool, ...] | None:
    """Stance flags right after phase ``index`` ends (the next whole-body phase's or the SRB tail's first
    knot's); ``None`` at the end of the horizon."""
    if index + 1 >= len(built.phases):
        return None
    following = built.phases[index + 1]
    if following.kind == "whole_body":
        return following.stance
    return tuple(bool(s) for s in following.contacts[0])


def _lookup_whole_body(
    records: list[tuple[float, np.ndarray, np.ndarray | None, bool]], t: float, prefer_phase_start: bool
) -> tuple[np.ndarray, np.ndarray | None] | None:
    """State/control of the previous whole-body knot at time ``t`` (post-reset copy for phase starts)."""
    found = None
    for time, state, control, is_start in records:
        if abs(time - t) < 1e-6 and (found is None or is_start == prefer_phase_start):
            found = (state, control)
    return found


def _nearest_srb(
    records: list[tuple[float, np.ndarray, np.ndarray | None]], t: float
) -> tuple[np.ndarray, np.ndarray | None] | None:
    if not records:
        return None
    times = np.array([r[0] for r in records])
    index = int(np.argmin(np.abs(times - t)))
    if abs(times[index] - t) > 0.5 * 0.05 + 1e-6 and t > times[-1]:
        index = len(records) - 1
    return records[index][1], records[index][2]
