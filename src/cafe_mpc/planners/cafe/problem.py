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
from dataclasses import dataclass, field, replace

import numpy as np
from numba import njit

from cafe_mpc.config import SRB_DT, WHOLE_BODY_DT
from cafe_mpc.config.weights import WholeBodyWeights
from cafe_mpc.core.interfaces import MultiPhaseProblem, Phase
from cafe_mpc.core.physics import GRAVITY
from cafe_mpc.dynamics.srb import SRBState
from cafe_mpc.dynamics.statics import static_stance_torques
from cafe_mpc.dynamics.transition import whole_body_to_srb_state
from cafe_mpc.ocp.constraints import TouchdownFootHeight
from cafe_mpc.ocp.knots import (
    SRBKnot,
    SRBModelFactory,
    SRBReference,
    WholeBodyKnot,
    WholeBodyModelFactory,
    WholeBodyReference,
    weight_split_forces,
)
from cafe_mpc.planners.time_grid import TIME_QUANTUM, PiecewiseTrajectory, grid_times, quanta
from cafe_mpc.reference.base import Reference, ReferenceWindow
from cafe_mpc.solver.results import SolverResult

TIME_EPS = 1e-7

PHASE_CACHE_SIZE = 512
"""Phases (and problems) the builder keeps for reuse; past it the oldest is dropped."""

SPARE_SLOTS = 8
"""Whole-body knot slots beyond the schedule's ``n_wb + 1`` whose references are rows of the builder's
stacked storage (each contact switch inside the horizon adds a knot); a slot past them (many switches in
one horizon) has its own reference, written knot by knot."""

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

SURFACE_HEIGHT_RESOLUTION = 0.01
"""m; a touchdown's surface height (the reference's foot height at the touchdown less the foot radius) is
rounded to this: an optimised trajectory's feet touch a flat floor within 1 mm of it (the solver's
tolerance on Eq. (25)), and those stay on the floor at exactly 0, as a gait's footholds do."""


@dataclass(frozen=True)
class ModelSchedule:
    """How the horizon is split: whole-body ``Tw`` at ``dt_w``, then SRB ``Ts`` at ``dt_s``."""

    whole_body_horizon: float = 0.25
    srb_horizon: float = 0.5
    whole_body_dt: float = WHOLE_BODY_DT
    srb_dt: float = SRB_DT

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
    def named(cls, name: str, whole_body_dt: float = WHOLE_BODY_DT, srb_dt: float = SRB_DT) -> ModelSchedule:
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
    first_knot: int = 0
    """Index of the phase's first knot among the whole-body (or SRB) knots of the horizon."""
    fractions: np.ndarray | None = None
    """SRB phase: per knot and foot, the share of the knot's interval in stance (``CafeProblemBuilder``)."""


@dataclass
class BuiltProblem:
    problem: MultiPhaseProblem
    phases: list[PhaseInfo]
    start_time: float
    srb_forces: np.ndarray
    """GRF targets of the SRB knots (n_srb, 3 n_feet): also their warm-start guess. Like the knots'
    references, the builder's storage: valid until its next ``build``."""
    torque_reference: np.ndarray
    """Torque references of the whole-body knots (n_wb + 1, nu): the guess of appended knots (valid until
    the builder's next ``build``)."""

    @property
    def whole_body_phases(self) -> list[int]:
        return [i for i, info in enumerate(self.phases) if info.kind == "whole_body"]


class CafeProblemBuilder:
    """Builds the multi-phase CAFE problem of each MPC update (Sec. IV-D) from persistent parts.

    Nothing heavy is rebuilt per update. The whole-body horizon has ``n_wb`` knot slots (slot ``k`` at
    ``t0 + k dt_w``) and the SRB tail ``n_srb``; each slot keeps one knot object per (stance, weight set) it
    has needed so far, each with its own mutable reference that the update overwrites in place; reset maps,
    WB -> SRB transitions and touchdown constraints are kept per switch. So the same knot objects come back
    every update and the solver reuses their data (Pinocchio ``Data`` included) and its workspace; what is
    re-made per update is only the list structure (``Phase`` objects holding existing knots), because the
    contact phases move through the fixed horizon.

    The references of all knots of a slot are views of one row of stacked arrays (``_KnotRows``; the SRB
    tail's likewise): an update writes the sampled window into the stack with one copy per field, and the
    SRB tail's states, footholds, stance fractions and force targets with a few whole-array operations,
    instead of writing every knot's reference on its own.

    ``weights``: the weight sets a reference may ask for by name (``Reference.weight_sets``), each a
    ``(WholeBodyModelFactory, SRBModelFactory)`` pair; the default set is the given ``whole_body``/``srb``.
    """

    def __init__(
        self,
        whole_body: WholeBodyModelFactory,
        srb: SRBModelFactory,
        schedule: ModelSchedule,
        weights: dict[str, tuple[WholeBodyModelFactory, SRBModelFactory]] | None = None,
        touchdown_on_reference: bool = False,
        touchdown_below_floor: bool = False,
    ) -> None:
        self.whole_body = whole_body
        self.touchdown_on_reference = touchdown_on_reference
        """Whether a touchdown's surface height is the reference's foothold height (``mpc.touchdown_surface``:
        reference) or the floor, z = 0."""
        self.touchdown_below_floor = touchdown_below_floor
        """With ``touchdown_on_reference``: the surface height is at most the floor's, z = 0
        (``mpc.touchdown_surface: lower``)."""
        self.srb = srb
        self.schedule = schedule
        self.robot = whole_body.robot
        self.weight_factories: dict[str, tuple[WholeBodyModelFactory, SRBModelFactory]] = {
            "regular": (whole_body, srb)
        }
        if weights:
            self.weight_factories.update(weights)
        # Intermediate whole-body phases end with a cost-free terminal that keeps the state-only
        # constraints (joint limits and speeds, base height): without them the last torques of a phase
        # are free to whip the light legs (the end state is priced only by the phases after it).
        zero = WholeBodyWeights.zero()
        self._intermediate = {
            name: WholeBodyModelFactory(factory.robot, replace(factory.settings, terminal_weights=zero))
            for name, (factory, _) in self.weight_factories.items()
        }
        robot = self.robot
        n_wb, n_srb = schedule.whole_body_knots, schedule.srb_knots
        self.window = ReferenceWindow(
            n_wb + 1 + (n_srb + 1 if n_srb else 0) + 16, robot.nq, robot.nv, robot.nu, robot.n_feet
        )
        self._rows = _KnotRows(n_wb + 1 + SPARE_SLOTS, robot.nq + robot.nv, robot.n_feet, robot.nu)
        self._srb_rows = _SRBRows(n_srb + 1 if n_srb else 0, robot.n_feet)
        self._srb_ratio: dict[str, float] = {}
        n_feet = robot.n_feet
        self._foot_bits = 1 << np.arange(n_feet, dtype=np.int64)
        self._stance_tuples = [
            tuple(bool(code >> foot & 1) for foot in range(n_feet)) for code in range(1 << n_feet)
        ]
        self._running: dict[tuple, WholeBodyKnot] = {}
        self._phases: dict[tuple, Phase] = {}
        self._problems: dict[tuple[int, ...], MultiPhaseProblem] = {}
        self._terminal: dict[tuple, WholeBodyKnot] = {}
        self._srb_running: dict[tuple, SRBKnot] = {}
        self._srb_terminal: dict[str, SRBKnot] = {}
        self._switches: dict[tuple, tuple] = {}
        self._names: tuple[str, ...] = ("regular",)
        self._total_weight = self.robot.total_mass * GRAVITY
        self._contact_frame = np.eye(3)
        """The ground's frame of every whole-body knot's friction pyramid (``Reference.contact_frame``,
        written by each ``build``; shared by the knots' references)."""

    def stance_torque(
        self, stance: tuple[bool, ...] | None, support_factor: float | None = None
    ) -> np.ndarray:
        """Torques that hold the standing pose with ``support_factor * m g`` on each stance foot (default: the
        weight split over the stance feet); zero in flight. The warm start's guess for appended knots."""
        key = tuple(bool(s) for s in stance) if stance is not None else (False,) * self.robot.n_feet
        if not any(key):
            return np.zeros(self.robot.nu)
        force = None if support_factor is None else support_factor * self.robot.total_mass * GRAVITY
        return static_stance_torques(self.robot, self.robot.q_standing, key, force)

    # ------------------------------------------------------------------------------------ persistent parts
    def _factories(self, weight_set: int) -> tuple[str, WholeBodyModelFactory, SRBModelFactory]:
        name = self._names[weight_set]
        if name not in self.weight_factories:
            raise ValueError(
                f"the reference asks for weight set {name!r}; known: {', '.join(self.weight_factories)}"
            )
        whole_body, srb = self.weight_factories[name]
        return name, whole_body, srb

    def _running_knot(
        self, slot: int, stance: tuple[bool, ...], weight_set: int, duration: int
    ) -> WholeBodyKnot:
        """The knot object of slot ``slot`` for this stance, weight set and duration (in ``TIME_QUANTUM``)."""
        key = (slot, stance, weight_set, duration)
        knot = self._running.get(key)
        if knot is None:
            _, factory, _ = self._factories(weight_set)
            knot = factory.running_knot(stance, self._slot_reference(slot, factory), duration * TIME_QUANTUM)
            self._running[key] = knot
        return knot

    def _slot_reference(
        self, slot: int, factory: WholeBodyModelFactory, torque: bool = True
    ) -> WholeBodyReference:
        """The reference of a new knot of slot ``slot``: the slot's rows of ``_KnotRows`` (the torque row
        only for a running knot: a terminal knot keeps its zero torque target), or its own arrays for a slot
        past the stack."""
        rows = self._rows
        if slot >= rows.capacity:
            reference = factory.default_reference()
            reference.contact_frame = self._contact_frame
            return reference
        return WholeBodyReference.of_rows(
            rows.state[slot],
            rows.foot_positions[slot],
            rows.foot_velocities[slot],
            rows.torque[slot] if torque else np.zeros(self.robot.nu),
            self._contact_frame,
        )

    def _terminal_knot(
        self, slot: int, stance: tuple[bool, ...], weight_set: int, last: bool
    ) -> WholeBodyKnot:
        key = (slot, stance, weight_set, last)
        knot = self._terminal.get(key)
        if knot is None:
            name, factory, _ = self._factories(weight_set)
            source = factory if last else self._intermediate[name]
            knot = source.terminal_knot(stance, self._slot_reference(slot, source, torque=False))
            self._terminal[key] = knot
        return knot

    def _switch(self, index: int, before: tuple[bool, ...], after: tuple[bool, ...], to_srb: bool):
        """(reset map, touchdown constraint) of the switch at the end of whole-body phase ``index``, made
        once; one touchdown constraint per phase index, as its surface heights are written each update
        (``_write_surface_heights``)."""
        key = (index, before, after, to_srb)
        parts = self._switches.get(key)
        if parts is None:
            factory = self.whole_body
            reset = (
                factory.transition_to_srb(before, after, self.srb.state)
                if to_srb
                else factory.reset_map(before, after)
            )
            parts = (reset, factory.touchdown_constraint(before, after))
            self._switches[key] = parts
        return parts

    def _srb_knot(self, slot: int, weight_set: int, duration: int) -> SRBKnot:
        key = (slot, weight_set, duration)
        knot = self._srb_running.get(key)
        if knot is None:
            _, _, srb = self._factories(weight_set)
            rows = self._srb_rows
            reference = SRBReference.of_rows(
                rows.state[slot],
                rows.foot_positions[slot],
                rows.contacts[slot],
                rows.forces[slot],
                srb.weight,
            )
            knot = srb.running_knot(reference, duration * TIME_QUANTUM)
            self._srb_running[key] = knot
        return knot

    def _srb_terminal_knot(self, weight_set: int) -> SRBKnot:
        """The SRB terminal knot of a weight set: the last row of the SRB stack (its own force target, the
        weight split over four stance feet: the terminal cost has no force term)."""
        knot = self._srb_terminal.get(weight_set)
        if knot is None:
            _, _, srb = self._factories(weight_set)
            rows, last = self._srb_rows, self._srb_rows.capacity - 1
            forces = weight_split_forces(np.ones(self.robot.n_feet), srb.weight)
            reference = SRBReference.of_rows(
                rows.state[last], rows.foot_positions[last], rows.contacts[last], forces, srb.weight
            )
            knot = srb.terminal_knot(reference)
            self._srb_terminal[weight_set] = knot
        return knot

    def _phase(
        self,
        index: int,
        running: list,
        terminal: WholeBodyKnot | SRBKnot,
        reset: object | None,
        switching: object | None,
    ) -> Phase:
        """The ``Phase`` of whole-body phase ``index`` (``-1``: the SRB tail) with these knots, reset map and
        touchdown constraint: made (and validated) once, then the same object whenever the same knots come
        back (a gait's phases do, at every cycle)."""
        key = (index, terminal, reset, switching, *running)
        phase = self._phases.get(key)
        if phase is None:
            schedule = self.schedule
            if index < 0:
                phase = Phase(running, terminal, dt=schedule.srb_dt, name="srb")
            else:
                dt, name = schedule.whole_body_dt, f"wb{index}"
                phase = Phase(running, terminal, reset, switching, dt=dt, name=name)
            if len(self._phases) >= PHASE_CACHE_SIZE:
                del self._phases[next(iter(self._phases))]
            self._phases[key] = phase
        return phase

    def _problem(self, phases: list[Phase], x0: np.ndarray) -> MultiPhaseProblem:
        """The ``MultiPhaseProblem`` of these phases from ``x0``: made (and validated) once per sequence of
        phase objects; one that comes back gets a new array ``x0`` (an array taken from it before is left as
        it was). The solver's workspace then recognises it at once (``Workspace.setup``)."""
        key = tuple(id(phase) for phase in phases)  # phases compare by value; the cached problem holds them
        problem = self._problems.get(key)
        if problem is None:
            problem = MultiPhaseProblem(np.asarray(x0, dtype=float), list(phases))
            if len(self._problems) >= PHASE_CACHE_SIZE:
                del self._problems[next(iter(self._problems))]
            self._problems[key] = problem
        else:
            problem.x0 = np.array(x0, dtype=float)
        return problem

    def _srb_weight_ratio(self, weight_set: int) -> float:
        """The SRB model's weight over the robot's (scales the reference's forces to the SRB tail)."""
        name = self._names[weight_set]
        ratio = self._srb_ratio.get(name)
        if ratio is None:
            ratio = self._factories(weight_set)[2].weight / self._total_weight
            self._srb_ratio[name] = ratio
        return ratio

    # ------------------------------------------------------------------------------------------- build
    def _window_for(self, rows: int) -> ReferenceWindow:
        """The reference window, grown (rarely: many switches in one horizon) to hold ``rows`` times."""
        if rows > self.window.capacity:
            robot = self.robot
            self.window = ReferenceWindow(rows + 8, robot.nq, robot.nv, robot.nu, robot.n_feet)
        return self.window

    def knot_times(self, t0: float, reference: Reference) -> tuple[np.ndarray, np.ndarray, list[float]]:
        """Whole-body and SRB knot times of an update at ``t0`` and the contact switches of the SRB tail.

        Whole-body knots on the absolute ``dt_w`` grid after a fractional first knot, split at every contact
        switch (``time_grid.grid_times``); the SRB tail from the whole-body end on the absolute ``dt_s``
        grid, its first knot between half and one and a half ``dt_s`` long; no SRB times for ``Ts = 0``.
        """
        schedule = self.schedule
        n_wb, n_srb = schedule.whole_body_knots, schedule.srb_knots
        dt_w, dt_s = schedule.whole_body_dt, schedule.srb_dt
        horizon = (n_wb + 1) * dt_w + ((n_srb + 1) * dt_s if n_srb else 0.0)
        switches = reference.switch_times(t0, t0 + horizon)
        wb_times = grid_times(t0, n_wb, dt_w, switches)
        if not n_srb:
            return wb_times, np.zeros(0), []
        srb_times = grid_times(float(wb_times[-1]), n_srb, dt_s, first_min=0.5 * dt_s)
        tail = [s for s in switches if srb_times[0] < s < srb_times[-1]]
        return wb_times, srb_times, tail

    def build(self, t0: float, x0: np.ndarray, reference: Reference) -> BuiltProblem:
        """The problem of an MPC update at ``t0`` from the measured ``x0`` (references written in place).

        Knots at ``knot_times``: every touchdown and lift-off at the reference's own time, whatever ``t0``.
        An SRB knot whose interval a switch falls inside gets per-foot stance fractions (the share of the
        interval each foot stands: the SRB's impulse over the interval is then that of the schedule) and,
        for a foot that lands inside it, the foothold it lands on.

        Like the knots, the returned problem's objects are the builder's: a problem stays valid until the
        next ``build`` (whose problem may be the very same object, with its own ``x0``).
        """
        wb_times, srb_times, tail_switches = self.knot_times(t0, reference)
        n_w, n_s = len(wb_times) - 1, max(len(srb_times) - 1, 0)
        has_srb = n_s > 0
        window = self._window_for(len(wb_times) + len(srb_times) + len(tail_switches))
        times = np.concatenate([wb_times, srb_times, np.asarray(tail_switches, dtype=float)])
        window.set_times(times, joint_rows=n_w + 1)  # the SRB tail reads only the base of its rows
        self._names = tuple(reference.weight_sets)
        reference.sample(window)
        window.check_finite(type(reference).__name__)
        frame = reference.contact_frame()
        self._contact_frame[:] = _WORLD_AXES if frame is None else frame
        state, torque = window.state, window.torque
        positions, velocities = window.foot_positions, window.foot_velocities
        # every whole-body slot's reference at once (knots past the stack are written below, one by one)
        rows = self._rows
        n_rows = n_w + 1
        stacked = min(n_rows, rows.capacity)
        rows.state[:stacked] = state[:stacked]
        rows.foot_positions[:stacked] = positions[:stacked]
        rows.foot_velocities[:stacked] = velocities[:stacked]
        rows.torque[:stacked] = torque[:stacked]
        # the stance flags of every row as the builder's one tuple per stance (keys of its knot caches)
        stance_of = self._stance_tuples
        stance_rows = [stance_of[code] for code in window.stance.dot(self._foot_bits).tolist()]
        weight_set = window.weight_set.tolist()
        steps = np.maximum(np.rint(np.diff(wb_times) / TIME_QUANTUM), 1.0).astype(np.int64).tolist()
        groups: list[tuple[tuple[bool, ...], int, int]] = []  # (stance, first knot, last knot + 1)
        start = 0
        for k in range(1, n_w + 1):
            if k == n_w or stance_rows[k] != stance_rows[start]:
                groups.append((stance_rows[start], start, k))
                start = k
        phases: list[Phase] = []
        infos: list[PhaseInfo] = []
        stance_array = window.stance[:n_rows]
        for index, (stance, first, last) in enumerate(groups):
            running = [self._running_knot(k, stance, weight_set[k], steps[k]) for k in range(first, last)]
            for k in range(max(first, stacked), last):
                ref = running[k - first].reference
                ref.state[:] = state[k]
                ref.foot_positions[:] = positions[k]
                ref.foot_velocities[:] = velocities[k]
                ref.torque[:] = torque[k]
            is_last = index == len(groups) - 1
            next_stance = groups[index + 1][0] if not is_last else stance_rows[n_w + 1 if has_srb else n_w]
            terminal = self._terminal_knot(last, stance, weight_set[last], is_last)
            if last >= stacked:
                ref = terminal.reference
                ref.state[:] = state[last]
                ref.foot_positions[:] = positions[last]
                ref.foot_velocities[:] = velocities[last]
            if is_last and not has_srb:
                reset, switching = None, None
            else:
                reset, switching = self._switch(index, stance, next_stance, to_srb=is_last)
                if switching is not None and self.touchdown_on_reference:
                    next_row = last if not is_last else n_w + 1
                    self._write_surface_heights(switching, positions[next_row])
            entered_by_impact = index > 0 and _touches_down(groups[index - 1][0], stance)
            phases.append(self._phase(index, running, terminal, reset, switching))
            infos.append(
                PhaseInfo(
                    "whole_body",
                    stance,
                    wb_times[first : last + 1].copy(),
                    stance_array[first:last].copy(),
                    entered_by_impact,
                    first,
                )
            )
        if has_srb:
            srb_forces, fractions = self._write_srb_tail(
                window, srb_times, tail_switches, n_rows, stance_rows
            )
            offset = n_rows
            running = [
                self._srb_knot(j, weight_set[offset + j], int(quanta(float(srb_times[j + 1] - srb_times[j]))))
                for j in range(n_s)
            ]
            terminal = self._srb_terminal_knot(weight_set[offset + n_s])
            phases.append(self._phase(-1, running, terminal, None, None))
            entered = _touches_down(groups[-1][0], stance_rows[offset])
            srb_stance = window.stance[offset : offset + n_s]
            infos.append(
                PhaseInfo("srb", None, np.array(srb_times), srb_stance.copy(), entered, 0, fractions)
            )
        else:
            srb_forces = np.zeros((0, 3 * self.robot.n_feet))
        problem = self._problem(phases, x0)
        torque_reference = rows.torque[:n_rows] if n_rows <= rows.capacity else torque[:n_rows].copy()
        return BuiltProblem(problem, infos, t0, srb_forces, torque_reference)

    def _write_surface_heights(self, switching: TouchdownFootHeight, feet: np.ndarray) -> None:
        """The touchdown constraint's (25) surface heights, in place: the touching-down feet's reference
        heights ``feet[leg, 2]`` at the touchdown (their footholds) less the foot radius, rounded to
        ``SURFACE_HEIGHT_RESOLUTION`` (a box top in a stored trajectory; 0 on a flat floor); with
        ``touchdown_below_floor`` at most 0, the floor's."""
        heights = feet[list(switching.legs), 2] - self.robot.foot_radius
        rounded = np.round(heights / SURFACE_HEIGHT_RESOLUTION) * SURFACE_HEIGHT_RESOLUTION
        if self.touchdown_below_floor:
            np.minimum(rounded, 0.0, out=rounded)
        switching.surface_heights[:] = rounded + 0.0  # + 0.0: a flat floor gives +0.0, never -0.0

    def _write_srb_tail(
        self,
        window: ReferenceWindow,
        srb_times: np.ndarray,
        tail_switches: list[float],
        offset: int,
        stance_rows: list[tuple[bool, ...]],
    ) -> tuple[np.ndarray, np.ndarray]:
        """The SRB tail's rows (``_SRBRows``) from the window rows ``offset ...``: states (projection (32)),
        per-foot stance fractions and the footholds and GRF targets (28) of the rows they come from
        (``_stance_fractions``); the terminal row takes its own row's feet and stance. Returns the running
        knots' GRF targets (n_s, 3 n_feet), rows of the stack, and the stance fractions."""
        n_s = len(srb_times) - 1
        srb = self._srb_rows
        if n_s + 1 != srb.capacity:
            raise RuntimeError(f"the SRB tail has {n_s} knots, the schedule {srb.capacity - 1}")
        switch_rows = {float(s): offset + n_s + 1 + i for i, s in enumerate(tail_switches)}
        fractions, sample_rows = self._stance_fractions(
            srb_times, offset, switch_rows, window.stance, stance_rows
        )
        nq = self.robot.nq
        _srb_states_into(
            window.state[offset : offset + n_s + 1], nq, srb.rotations, srb.velocities, srb.state
        )
        feet = srb.feet_index
        srb.foot_positions[:n_s] = window.foot_positions[sample_rows, feet]
        srb.foot_positions[n_s] = window.foot_positions[offset + n_s]
        srb.contacts[:n_s] = fractions
        srb.contacts[n_s] = window.stance[offset + n_s]
        ratios = srb.ratios
        for j, weight_set in enumerate(window.weight_set[offset : offset + n_s].tolist()):
            ratios[j] = self._srb_weight_ratio(weight_set)
        # GRF target (28): the reference's stance force of the foot, for the SRB's own weight
        np.multiply(window.forces[sample_rows, feet], ratios[:n_s, None, None], out=srb.force_rows[:n_s])
        return srb.forces[:n_s], fractions

    def _stance_fractions(
        self,
        srb_times: np.ndarray,
        offset: int,
        switch_rows: dict[float, int],
        stance: np.ndarray,
        stance_rows: list[tuple[bool, ...]],
    ) -> tuple[np.ndarray, np.ndarray]:
        """Per SRB knot and foot: the share of the knot's interval in stance, and the window row whose foot
        position and force the knot uses (the knot's own row, or the row of the switch at which the foot's
        first stance inside the interval starts). A knot without a switch inside its interval stands as its
        own row does over all of it (fraction 0 or 1); the others are summed piece by piece (``stance_rows``:
        the window's stance flags as tuples). The result is a new fractions array (kept by the phase's
        ``PhaseInfo``) and the stack's row indices."""
        n_s = len(srb_times) - 1
        n_feet = self.robot.n_feet
        fractions = stance[offset : offset + n_s].astype(float)
        rows = self._srb_rows.sample_rows[:n_s]
        rows[:] = self._srb_rows.own_rows[:n_s] + offset
        if not switch_rows:
            return fractions, rows
        switch_times = sorted(switch_rows)
        intervals = np.searchsorted(srb_times, switch_times, side="left") - 1
        for j in sorted(set(intervals.tolist())):
            if not 0 <= j < n_s:
                continue
            a, b = float(srb_times[j]), float(srb_times[j + 1])
            inside = [(s, switch_rows[s]) for s in switch_times if a < s < b]
            if not inside:
                continue
            starts = [(a, offset + j), *inside]
            shares, sample = [0.0] * n_feet, [-1] * n_feet
            for index, (start, row) in enumerate(starts):
                end = starts[index + 1][0] if index + 1 < len(starts) else b
                share = (end - start) / (b - a)
                for foot, flag in enumerate(stance_rows[row]):
                    if flag:
                        shares[foot] += share
                        if sample[foot] < 0:
                            sample[foot] = row
            # round-off of the interval sums (the other rows are whole 0s and 1s)
            fractions[j] = [0.0 if x < 1e-9 else 1.0 if x > 1.0 - 1e-9 else x for x in shares]
            for foot, row in enumerate(sample):
                if row >= 0:
                    rows[j, foot] = row
        return fractions, rows


def _touches_down(before: tuple[bool, ...], after: tuple[bool, ...]) -> bool:
    """Whether a foot in swing in ``before`` is in stance in ``after`` (``touchdown_flags`` of validated
    flags, without validating them again)."""
    return any(a and not b for b, a in zip(before, after, strict=True))


def _srb_states_into(
    states: np.ndarray, nq: int, rotations: np.ndarray, velocities: np.ndarray, out: np.ndarray
) -> None:
    """``whole_body_to_srb_state`` (32) of every row of ``states`` into ``out``: the rotation matrices by
    the element formulas of ``pin.Quaternion.toRotationMatrix`` (``_rotation_matrices``) and the world
    velocities by one stacked ``matmul`` (the products of the one-row function, so the same bits)."""
    n = len(states)
    rotation, velocity = rotations[:n], velocities[:n]
    _rotation_matrices(states, rotation)
    velocity[:, :, 0] = states[:, nq : nq + 3]
    out[:n, 0:7] = states[:, 0:7]
    np.matmul(rotation, velocity, out=out[:n, 7:10, None])
    out[:n, 10:13] = states[:, nq + 3 : nq + 6]


@njit(cache=True, nogil=True)
def _rotation_matrices(states: np.ndarray, out: np.ndarray) -> None:
    """The rotation matrix of each row's base quaternion ``states[i, 3:7]`` (x, y, z, w) into ``out[i]``:
    the element formulas and operation order of Eigen's ``Quaternion::toRotationMatrix`` (no fused
    multiply-adds: the same bits as ``pin.Quaternion(q).toRotationMatrix()``)."""
    for i in range(states.shape[0]):
        x, y, z, w = states[i, 3], states[i, 4], states[i, 5], states[i, 6]
        tx, ty, tz = 2.0 * x, 2.0 * y, 2.0 * z
        twx, twy, twz = tx * w, ty * w, tz * w
        txx, txy, txz = tx * x, ty * x, tz * x
        tyy, tyz, tzz = ty * y, tz * y, tz * z
        out[i, 0, 0] = 1.0 - (tyy + tzz)
        out[i, 0, 1] = txy - twz
        out[i, 0, 2] = txz + twy
        out[i, 1, 0] = txy + twz
        out[i, 1, 1] = 1.0 - (txx + tzz)
        out[i, 1, 2] = tyz - twx
        out[i, 2, 0] = txz - twy
        out[i, 2, 1] = tyz + twx
        out[i, 2, 2] = 1.0 - (txx + tyy)


_WORLD_AXES = np.eye(3)
"""The contact frame of flat ground: the friction pyramid (26) about world z."""


class _KnotRows:
    """Stacked references of the whole-body knot slots: row ``k`` is the reference of every knot object of
    slot ``k`` (``WholeBodyReference.of_rows``)."""

    def __init__(self, capacity: int, nx: int, n_feet: int, nu: int) -> None:
        self.capacity = capacity
        self.state = np.zeros((capacity, nx))
        self.foot_positions = np.zeros((capacity, n_feet, 3))
        self.foot_velocities = np.zeros((capacity, n_feet, 3))
        self.torque = np.zeros((capacity, nu))


class _SRBRows:
    """Stacked references of the SRB tail's knots (row ``j``: running knot ``j``; the last row: the
    terminal knot) and the workspace of writing them."""

    def __init__(self, capacity: int, n_feet: int) -> None:
        self.capacity = capacity
        self.state = np.zeros((capacity, 13))
        self.foot_positions = np.zeros((capacity, n_feet, 3))
        self.contacts = np.zeros((capacity, n_feet))
        self.forces = np.zeros((capacity, 3 * n_feet))
        self.force_rows = self.forces.reshape(capacity, n_feet, 3)
        self.ratios = np.zeros(capacity)
        self.rotations = np.zeros((capacity, 3, 3))
        self.velocities = np.zeros((capacity, 3, 1))
        self.sample_rows = np.zeros((capacity, n_feet), dtype=np.int64)
        self.own_rows = np.repeat(np.arange(capacity, dtype=np.int64)[:, None], n_feet, axis=1)
        self.feet_index = np.arange(n_feet)


@dataclass
class InitialGuess:
    xs: list[np.ndarray]
    us: list[np.ndarray]
    rollout: list[np.ndarray]
    multipliers: list[np.ndarray | None] = field(default_factory=list)
    penalties: list[float | None] = field(default_factory=list)
    """Augmented-Lagrangian parameters of each phase's touchdown constraint, carried over from the previous
    solve of the same switch (facts: "keep barrier and AL parameters"); ``None``: start afresh."""


@dataclass
class WarmStart:
    """Maps a previous solution onto a new problem by time (Sec. VI-C, Fig. 5; ``time_grid``).

    The arrays of a guess are this object's buffers (one per phase position and kind, grown when a phase
    is longer): valid until its next ``guess``. The solver copies them into its workspace.
    """

    srb_state: SRBState = field(default_factory=SRBState)
    _buffers: dict[tuple, np.ndarray] = field(default_factory=dict, init=False, repr=False, compare=False)

    def _rows(self, key: tuple, rows: int, width: int | None, dtype: type = float) -> np.ndarray:
        """The first ``rows`` rows of buffer ``key`` (``width`` columns; a vector for ``None``)."""
        columns = () if width is None else (width,)
        buffer = self._buffers.get(key)
        if buffer is None or buffer.shape[0] < rows or buffer.shape[1:] != columns:
            buffer = np.empty((max(rows, 8), *columns), dtype=dtype)
            self._buffers[key] = buffer
        return buffer[:rows]

    def guess(
        self, built: BuiltProblem, previous: BuiltProblem | None, solution: SolverResult | None
    ) -> InitialGuess:
        """Initial states, controls and roll-out masks for ``built`` from the previous solution.

        A whole-body knot inside the time span of a previous phase with the same stance takes that
        phase's solution at its time (``PiecewiseTrajectory``: the knot's own state where the times agree,
        the interpolation between the two knots around it otherwise; the control of the previous interval
        containing it); at a phase's start the post-reset state, at its end the pre-reset one (contact
        switches sit at the same absolute times in every update). Shooting knots. Whole-body knots past
        the previous whole-body horizon copy its last state and take the knot's torque reference (the
        static torques carrying that phase's stance load: copying the last planned torque into a phase
        with other stance feet would swing the now-unloaded legs violently); they are roll-out knots when
        they belong to a newly appended phase entered through an impact (the adaptive scheme of Fig. 5),
        shooting knots otherwise. SRB knots take the previous SRB tail at their time (its last state past
        its end).
        """
        x0 = built.problem.x0
        xs, us, rollout = [], [], []
        previous_wb: list[tuple[tuple[bool, ...] | None, PiecewiseTrajectory]] = []
        previous_srb: PiecewiseTrajectory | None = None
        last_wb_state, previous_end = x0, -math.inf
        if previous is not None and solution is not None:
            for info, phase, problem_phase in zip(
                previous.phases, solution.phases, previous.problem.phases, strict=True
            ):
                manifold = problem_phase.state
                trajectory = PiecewiseTrajectory(
                    info.times, phase.xs, phase.us, manifold.difference, manifold.integrate
                )
                if info.kind == "whole_body":
                    previous_wb.append((info.stance, trajectory))
                    last_wb_state, previous_end = phase.xs[-1], float(info.times[-1])
                else:
                    previous_srb = trajectory
        tolerance = 0.5 * TIME_QUANTUM
        torque_reference = built.torque_reference
        for info in built.phases:
            n = len(info.times) - 1
            if info.kind == "whole_body":
                position = len(xs)
                phase_x = self._rows(("x", position), n + 1, len(x0))
                phase_u = self._rows(("u", position), n, torque_reference.shape[1])
                phase_rollout = self._rows(("rollout", position), n + 1, None, bool)
                phase_rollout[:] = False
                new_phase_after_impact = info.entered_by_impact and info.times[0] > previous_end - tolerance
                same_stance = [trajectory for stance, trajectory in previous_wb if stance == info.stance]
                for k, t in enumerate(info.times.tolist()):
                    source = _covering(same_stance, t, k, n)
                    if source is not None:
                        source.state_into(t, phase_x[k])
                        control = source.control_at(t) if k < n else None
                        if k < n:
                            phase_u[k] = torque_reference[info.first_knot + k] if control is None else control
                    else:
                        phase_x[k] = last_wb_state
                        if k < n:
                            phase_u[k] = torque_reference[info.first_knot + k]
                        phase_rollout[k] = new_phase_after_impact and k > 0
                xs.append(phase_x)
                us.append(phase_u)
                rollout.append(phase_rollout)
            else:
                position = len(xs)
                phase_x = self._rows(("srb x", position), n + 1, self.srb_state.nx)
                phase_u = self._rows(("srb u", position), n, built.srb_forces.shape[1])
                wb_end = xs[-1][-1] if xs else x0
                for j, t in enumerate(info.times.tolist()):
                    if previous_srb is not None:
                        previous_srb.state_into(t, phase_x[j])
                        control = previous_srb.control_at(t) if j < n else None
                        if j < n:
                            phase_u[j] = control if control is not None else built.srb_forces[j]
                    else:
                        phase_x[j] = whole_body_to_srb_state(wb_end)
                        if j < n:
                            phase_u[j] = built.srb_forces[j]
                xs.append(phase_x)
                us.append(phase_u)
                srb_rollout = self._rows(("srb rollout", position), n + 1, None, bool)
                srb_rollout[:] = False
                rollout.append(srb_rollout)
        multipliers, penalties = _augmented_lagrangian_guess(built, previous, solution)
        return InitialGuess(xs, us, rollout, multipliers, penalties)


def _covering(
    trajectories: list[PiecewiseTrajectory], t: float, k: int, n: int
) -> PiecewiseTrajectory | None:
    """The previous phase (same stance) a new knot ``k`` of ``n`` at time ``t`` takes its guess from: one
    that starts at ``t`` for a phase start (post-reset state), one that ends at ``t`` for a phase end
    (pre-reset state), else one whose span contains ``t``."""
    tolerance = 0.5 * TIME_QUANTUM
    if k == 0:
        for trajectory in trajectories:
            if abs(trajectory.start - t) <= tolerance:
                return trajectory
    if k == n:
        for trajectory in trajectories:
            if abs(trajectory.end - t) <= tolerance:
                return trajectory
    for trajectory in trajectories:
        if trajectory.start - tolerance <= t <= trajectory.end + tolerance:
            return trajectory
    return None


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
