"""The MPC side of CAFE-MPC (paper Sec. IV, VI-C): receding-horizon updates, measured state -> Plan.

Two schemes (``MpcSettings.scheme``):

* **one-phase** (``update(t, q, v)``): re-anchor the reference on the measurement, write the persistent
  CAFE problem's references in place (``CafeProblemBuilder``), warm-start MS-iLQR from the previous solution
  by time (Fig. 5), iterate, and turn the whole-body part of the solution into a ``Plan`` (the message to
  the low-level controller: knots with states, torques, gains and the Q-function pieces of Eqs. (6)-(8),
  forces, contacts). Everything happens after the measurement: the robot waits for all of it.
* **real-time iteration** (``prepare`` then ``feedback``; Diehl's scheme, which the paper's Sec. VIII names
  as the next step; acados' preparation/feedback phases): ``prepare(t, q, v)`` does all of the above for
  the *next* update time ``t`` from the state the current plan predicts there (``predict``), while that
  plan still drives the robot; ``feedback(t, q, v)``, when the measurement of time ``t`` arrives, only
  embeds the measured initial state through the prepared policy (``MSiLQRSolver.feedback``: a linear
  forward pass, well under a millisecond) and publishes the plan. The latency the robot sees is the
  feedback phase.

Delay compensation (``problem_start``, ``carry``): with a known transport delay the loop asks where the
problem of an update starts (the last whole-body knot time at or before its plan takes effect) and has the
measured state carried there along the plans in effect meanwhile (``planners.cafe.prediction``).

This object knows nothing about time passing: the policy side (``cafe_mpc.control``) decides when updates
happen and when their plans take effect (fixed or measured latency in simulated time, or a separate
process against the wall clock). It is what the MPC process of the real-time mode runs (OCS2's MPC/MRT
split).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable

import numpy as np

from cafe_mpc.config import MpcSettings
from cafe_mpc.core.progress import stage
from cafe_mpc.planners import collector
from cafe_mpc.planners.base import (
    PLANNER_ERRORS,
    UPDATE_LINE_SEARCH_MIN_STEP,
    MpcStatistics,
    RecedingHorizonPlanner,
    prepare_solve_options,
)
from cafe_mpc.planners.cafe.plan import Plan, PlanBuffers
from cafe_mpc.planners.cafe.prediction import DelayPredictor
from cafe_mpc.planners.cafe.problem import BuiltProblem, CafeProblemBuilder, WarmStart
from cafe_mpc.planners.time_grid import TIME_QUANTUM, PiecewiseTrajectory
from cafe_mpc.reference.base import Reference
from cafe_mpc.robots.robot import Robot
from cafe_mpc.solver import MSiLQRSolver, SolverResult
from cafe_mpc.solver.workspace import Workspace

__all__ = [
    "UPDATE_LINE_SEARCH_MIN_STEP",
    "MpcSettings",
    "MpcStatistics",
    "RecedingHorizonMpc",
    "plan_from_solution",
]

logger = logging.getLogger(__name__)

GRID_TOLERANCE = 1e-6
"""Fraction of a knot below which a time counts as on the knot grid."""


class RecedingHorizonMpc(RecedingHorizonPlanner[Plan]):
    """CAFE-MPC updates: persistent problem, warm start by time, MS-iLQR, Plan; one-phase or real-time
    iteration (see the module docstring)."""

    name = "MPC"

    def __init__(
        self,
        robot: Robot,
        reference: Reference,
        builder: CafeProblemBuilder,
        settings: MpcSettings | None = None,
    ) -> None:
        super().__init__(robot, reference, builder, settings)
        self.prepare_solver = MSiLQRSolver(prepare_solve_options(self.settings))
        # one workspace and data pool for the cold solve and the updates (the updates reuse its data)
        workspace = Workspace()
        self.solver.workspace = self.first_solver.workspace = self.prepare_solver.workspace = workspace
        self.warm_start = WarmStart()
        self.previous: tuple[BuiltProblem, SolverResult] | None = None
        self.prepared: tuple[float, BuiltProblem, SolverResult, Plan] | None = None
        """The preparation waiting for its measurement: (update time, problem, prepared solution, the plan
        of the prepared solution, whose gains and Q-function blocks the feedback keeps)."""
        self._projections: dict[tuple[bool, ...], tuple] = {}
        self.plan_buffers = PlanBuffers()
        """The arrays of the plans this MPC publishes, reused once no plan made of them is in use."""
        self._predictor: DelayPredictor | None = None

    @property
    def supports_rti(self) -> bool:
        return True

    @property
    def prepared_time(self) -> float | None:
        return self.prepared[0] if self.prepared is not None else None

    def problem_start(self, t: float, delay: float) -> float:
        """Where the problem of the update measured at ``t`` starts: ``t`` without a delay; with one, the last
        whole-body knot time at or before the plan takes effect (``t + delay``), not before ``t``: the plan's
        first knot is then a whole one and holds the time the plan takes effect."""
        if delay <= 0:
            return t
        grid = self.builder.schedule.whole_body_dt
        on_grid = math.floor((t + delay) / grid + GRID_TOLERANCE) * grid
        return max(t, on_grid)

    def carry(
        self, q: np.ndarray, v: np.ndarray, t: float, until: float, plan_at: Callable[[float], Plan | None]
    ) -> np.ndarray:
        """The state measured at ``t`` carried to ``until`` along the plans in effect
        (``DelayPredictor.carry``: the planning model under each plan's Riccati law)."""
        if self._predictor is None:
            self._predictor = DelayPredictor(self.robot, self.builder.whole_body)
        return self._predictor.carry(q, v, t, until, plan_at)

    @collector.paused
    def prepare(self, t: float, q: np.ndarray, v: np.ndarray) -> bool:
        """The preparation phase of a real-time iteration for the update at ``t``, from the state ``q, v``
        predicted for ``t`` (``predict``): reference, problem, warm start, linearisation, backward sweep
        (and the line search, ``MpcSettings.rti_line_search``). ``False`` (counted and logged) if it failed:
        the update at ``t`` then falls back to a one-phase update. Needs a first (cold) solve."""
        if self.previous is None:
            raise RuntimeError(f"{self.name}: prepare needs a first solve (call update once)")
        self.prepared = None
        cpu_start = time.thread_time()
        outcome = self._solve_at(t, q, v, self.prepare_solver)
        cpu = time.thread_time() - cpu_start
        if outcome is None:
            return False
        built, result = outcome
        try:
            template = self._plan(built, result)
        except PLANNER_ERRORS as error:
            self._failed(t, f"its plan could not be made ({error})")
            return False
        self.statistics.prepare_times.append(self.statistics.update_times[-1])
        self.statistics.prepare_cpu_times.append(cpu)
        self.prepared = (t, built, result, template)
        return True

    @collector.paused
    def feedback(self, t: float, q: np.ndarray, v: np.ndarray) -> Plan | None:
        """The feedback phase of the update at ``t``: the state measured at ``t`` embedded through the
        prepared policy (``MSiLQRSolver.feedback``), the plan made; ``None`` (counted and logged) when no
        preparation for ``t`` is waiting or the embedding failed (the previous plan stays)."""
        prepared, self.prepared = self.prepared, None
        if prepared is None or abs(prepared[0] - t) > 1e-9:
            self._failed(t, "no preparation for this time")
            return None
        _, built, result, template = prepared
        robot = self.robot
        start = time.perf_counter()
        x = self._x
        x[: robot.nq] = q
        x[robot.nq :] = v
        settings = self.settings
        try:
            self._contact_consistent(x, built.phases[0].stance)
            embedded = self.prepare_solver.feedback(
                result, x, 0.0 if settings.rti_line_search else 1.0, settings.rti_feedback
            )
            built.problem.x0[:] = x
            # the template's arrays are this update's alone (``PlanBuffers``): the trajectory goes into them
            Qu = None if settings.rti_line_search else template.Qu
            write_whole_body_trajectory(built, embedded, template.xs, template.us, Qu)
            plan = template.with_trajectory(template.xs, template.us, Qu)
        except PLANNER_ERRORS as error:
            self._failed(t, f"its feedback failed ({error})")
            return None
        elapsed = time.perf_counter() - start
        statistics = self.statistics
        statistics.feedback_times.append(elapsed)
        statistics.update_times[-1] += elapsed
        self.previous = (built, embedded)
        return plan

    def predict(self, t: float) -> np.ndarray | None:
        """The whole-body state ``[q, v]`` the newest solution predicts at ``t`` (``None`` without one, or
        past its whole-body horizon): interpolated between the knots around ``t``; at a contact switch the
        state after it (the phase starting at ``t``)."""
        if self.previous is None:
            return None
        built, result = self.previous
        tolerance = 0.5 * TIME_QUANTUM
        candidates = [
            (info, phase, problem_phase)
            for info, phase, problem_phase in zip(
                built.phases, result.phases, built.problem.phases, strict=True
            )
            if info.kind == "whole_body" and info.times[0] - tolerance <= t <= info.times[-1] + tolerance
        ]
        if not candidates:
            return None
        info, phase, problem_phase = candidates[-1]  # the phase that starts at a switch time ``t``
        manifold = problem_phase.state
        return PiecewiseTrajectory(
            info.times, phase.xs, phase.us, manifold.difference, manifold.integrate
        ).state_at(t)

    def _prepare_problem(self, built: BuiltProblem) -> None:
        """The measured state's stance feet brought to rest (``_contact_consistent``) before the solve."""
        self._contact_consistent(built.problem.x0, built.phases[0].stance)

    def _contact_consistent(self, x: np.ndarray, stance: tuple[bool, ...] | None) -> None:
        """Bring the feet the plan's first phase stands on to rest in ``x`` (in place): the impact map (22)
        onto that stance. A measurement taken at a touchdown's planned time has the landing feet still
        moving (or not yet landed) while the plan's state there is the post-impact one; projected, the
        measurement differs from the prediction by the touchdown's timing error, not by the whole impact."""
        if stance is None or not any(stance):
            return
        reset, data = self._projection(stance)
        reset.calc(data, x)
        x[:] = data.x_next

    def _projection(self, stance: tuple[bool, ...]) -> tuple:
        """The impact map onto ``stance`` from a flight and its data (``_contact_consistent``), made at the
        first call for a stance (the warm-up's, for every stance a phase of its problems has)."""
        key = tuple(bool(s) for s in stance)
        entry = self._projections.get(key)
        if entry is None:
            reset = self.builder.whole_body.reset_map((False,) * len(key), key)
            entry = (reset, reset.create_data())
            self._projections[key] = entry
        return entry

    def _compile_kernels(self) -> None:
        """The real-time iteration's feedback (``MSiLQRSolver.feedback``) run once on the first solve, its
        result dropped: the first solve is a one-phase solve, so without this the first feedback of the run
        compiled its kernels after the clock started (0.3 s on the PD fallback in a first run's trot)."""
        if self.settings.scheme != "rti" or self.previous is None:
            return
        _, result = self.previous
        settings = self.settings
        self.prepare_solver.feedback(
            result,
            result.phases[0].xs[0].copy(),
            0.0 if settings.rti_line_search else 1.0,
            settings.rti_feedback,
        )

    def _warm_up(self, t0: float) -> None:
        """Create and evaluate the solver data of every knot object the updates of ``settings.warm_up``
        seconds after ``t0`` will use (``MpcSettings.warm_up``): the problems of updates one period apart,
        from each start an update can have (``problem_start``), are built and served by the solver's
        workspace, and each new data object is evaluated once (``_evaluate_new_data``); nothing is solved,
        and the next update rewrites every reference. An update then creates no data and maps no new
        memory (``tests/test_warm_up.py``)."""
        start = time.perf_counter()
        period = self.settings.period
        steps = math.ceil(self.settings.warm_up / period)
        stage(f"warm-up: solver data for the first {self.settings.warm_up:g} s of updates")
        workspace = self.solver.workspace
        grid = getattr(getattr(self.builder, "schedule", None), "whole_body_dt", period)
        assert self.previous is not None
        _, first_result = self.previous
        points = {  # a state and control of each state space, from the first solve
            (phase.xs[0].shape[0], phase.us[0].shape[0] if len(phase.us) else 0): (phase.xs[0], phase.us[0])
            for phase in first_result.phases
        }
        evaluated: dict[int, object] = {  # the data the first solve evaluated, kept alive with their ids
            id(data): data for work in workspace.phases for _, data in _knot_data(work)
        }
        evaluated.update((id(work.state), work.state) for work in workspace.phases)
        nx = self.robot.nq + self.robot.nv
        whole_body_point = next((x for (n, _), (x, _) in points.items() if n == nx), None)
        built_starts: set[float] = set()
        for step in range(1, steps + 1):
            t = t0 + step * period
            # without delay compensation an update's problem starts at its measurement, anywhere on the
            # control ticks: vary the start's offset from the knot grid so that the knot objects of the
            # first knot's durations get their data too; with it, on the knot grid at or after the
            # measurement (``problem_start``): every grid point of the period
            on_grid = math.floor(t / grid + GRID_TOLERANCE) * grid
            starts = {round(s, 9) for s in (t + (step * 3 * TIME_QUANTUM) % grid, on_grid, on_grid + grid)}
            for start_time in sorted(starts - built_starts):  # a start shared with the last step: built once
                built_starts.add(start_time)
                built = self._build(start_time)
                workspace.setup(built.problem)
                _evaluate_new_data(workspace, points, evaluated)
                for info in built.phases:  # the impact maps an update's state is projected with
                    if info.stance is not None and any(info.stance) and info.stance not in self._projections:
                        reset, data = self._projection(info.stance)
                        if whole_body_point is not None:
                            reset.calc(data, whole_body_point.copy())
        self.statistics.warm_up_time = time.perf_counter() - start

    def _build(self, t: float):
        return self.builder.build(t, self._x.copy(), self.reference)

    def _solve(self, built, solver: MSiLQRSolver, budget_start: float | None = None) -> SolverResult:
        previous_built, previous_solution = self.previous if self.previous else (None, None)
        guess = self.warm_start.guess(built, previous_built, previous_solution)
        return solver.solve(
            built.problem,
            guess.xs,
            guess.us,
            guess.rollout,
            initial_multipliers=guess.multipliers,
            initial_penalties=guess.penalties,
            budget_start=budget_start,
        )

    def _plan(self, built, result: SolverResult) -> Plan:
        return plan_from_solution(built, result, self.plan_buffers)


def write_whole_body_trajectory(
    built: BuiltProblem, result: SolverResult, xs: np.ndarray, us: np.ndarray, Qu: np.ndarray | None = None
) -> None:
    """Write the states (the knots' and the last one), torques and (unless ``Qu`` is ``None``) ``Qu`` of the
    whole-body phases of a solution, each stacked over its knots, into ``xs``, ``us`` and ``Qu``: what a
    ``Plan`` carries of the trajectory."""
    phases = [result.phases[i] for i in built.whole_body_phases]
    np.concatenate([phase.xs[:-1] for phase in phases] + [phases[-1].xs[-1:]], out=xs)
    np.concatenate([phase.us for phase in phases], out=us)
    if Qu is not None:
        np.concatenate([phase.Qu for phase in phases], out=Qu)


def plan_from_solution(built: BuiltProblem, result: SolverResult, buffers: PlanBuffers | None = None) -> Plan:
    """The whole-body part of a solution as the low-level controller's ``Plan`` (knot times, states, torques,
    gains, Q-function pieces, contacts, planned GRFs), written into arrays from ``buffers`` (none: new
    arrays)."""
    indices = built.whole_body_phases
    phases = [result.phases[i] for i in indices]
    infos = [built.phases[i] for i in indices]
    first = phases[0]
    n = sum(len(info.times) - 1 for info in infos)
    _, nu, ndx = first.K.shape
    arrays = (buffers or PlanBuffers(capacity=0)).take(n, first.xs.shape[1], nu, ndx, len(infos[0].stance))
    write_whole_body_trajectory(built, result, arrays["xs"], arrays["us"], arrays["Qu"])
    for name in ("K", "Quu", "Qux", "forces"):
        np.concatenate([getattr(phase, name) for phase in phases], out=arrays[name])
    times, dt, contacts = arrays["times"], arrays["dt"], arrays["contacts"]
    row = 0
    for info in infos:
        knots = len(info.times) - 1
        times[row : row + knots] = info.times[:-1]
        np.subtract(info.times[1:], info.times[:-1], out=dt[row : row + knots])
        contacts[row : row + knots] = info.stance
        row += knots
    return Plan(**arrays)


def _knot_data(work) -> list[tuple[object, object]]:
    """The knot objects of a phase's workspace with the data the solver uses for them: the running and
    terminal models, the reset map and the switching constraint."""
    pairs = [*zip(work.models, work.running_data, strict=True), (work.terminal_model, work.terminal_data)]
    if work.reset_map is not None and work.reset_data is not None:
        pairs.append((work.reset_map, work.reset_data))
    if work.constraint is not None and work.constraint_data is not None:
        pairs.append((work.constraint, work.constraint_data))
    return pairs


def _evaluate_new_data(workspace, points: dict, evaluated: dict[int, object]) -> None:
    """Evaluate, with derivatives, every data object of the problem ``workspace`` serves that was not
    evaluated yet (``evaluated``: by id, the objects kept so that an id is not reused), at the first
    solve's point of its state space (``points``). Before the clock starts, this runs the compiled kernels
    of a knot the first solve did not have (a swing foot's costs in a gait that starts standing, a flight
    phase, a landing's reset map: ``core.compilation``), makes the views a data object keeps of Pinocchio's
    results, and writes every page of the data's arrays, which the OS otherwise maps at their first write:
    inside an update, a few hundred page faults for the knots that come into the horizon with a take-off.
    The values are dropped: an update evaluates every knot at its own nominal before it reads one."""
    for work in workspace.phases:
        state = work.state
        if id(state) not in evaluated:
            evaluated[id(state)] = state
            x = next((x for (n, _), (x, _) in points.items() if n == state.nx), None)
            if x is not None:
                _exercise_state(state, x)
        for model, data in _knot_data(work):
            if id(data) in evaluated:
                continue
            evaluated[id(data)] = data
            nx = model.state.nx
            nu = getattr(model, "nu", None)
            if nu is None:  # a reset map or a switching constraint: a state only
                x = next((x for (n, _), (x, _) in points.items() if n == nx), None)
                if x is not None:
                    model.calc(data, x.copy())
                    model.calc_diff(data, x.copy())
                continue
            point = points.get((nx, nu))
            if point is None:
                point = next(((x, np.zeros(nu)) for (n, _), (x, _) in points.items() if n == nx), None)
            if point is not None:
                x, u = point
                model.calc(data, x.copy(), u.copy())
                model.calc_diff(data, x.copy(), u.copy())


def _exercise_state(state, x: np.ndarray) -> None:
    """Call once each operation of ``state`` the solver calls (``core.interfaces.StateManifold``), at
    ``x`` and a point near it (the operations skip their work between equal points); results dropped. A
    phase after a flight or a second whole-body phase first appears after the first solve."""
    ndx = state.ndx
    dx = np.full(ndx, 1e-3)
    y = state.integrate(x, dx)
    state.difference(x, y)
    state.jacobian_difference(x, y)
    state.jacobian_integrate(x, dx)
    state.integrate_into(x, dx, np.empty_like(x))
    state.difference_into(x, y, np.empty(ndx))
    state.integrate_rows_into(np.stack([x, y]), np.stack([dx, dx]), np.empty((2, x.shape[0])))
    state.difference_jacobian_product(x, y, np.eye(ndx), np.empty((ndx, ndx)))
    state.difference_jacobian_product_stacked(x, y, np.eye(ndx), np.eye(ndx, 2), np.empty((ndx, ndx + 2)))
