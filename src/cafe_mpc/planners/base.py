"""What an MPC loop needs from a planner, the update machinery the planners share, and their registry.

A planner turns measured (or predicted) states into plans of its own type for the low-level controller. The
loops (``control.inline`` in simulated time, ``control.process`` in its own process against the wall clock)
see only the ``Planner[PlanT]`` protocol (OCS2's MPC side of its MPC/MRT split):

* ``update(t, q, v)``: a one-phase update (the first one is the cold solve) -> plan or ``None``;
* ``prepare(t, q, v)`` / ``feedback(t, q, v)``: the two phases of a real-time iteration, when
  ``supports_rti``; ``predict(t)``: the state the newest solution predicts at ``t`` (what ``prepare`` starts
  from); ``prepared_time``: the update time a waiting preparation is for;
* delay compensation, the planner's own prediction: ``problem_start(t, delay)``, where the problem of an
  update measured at ``t`` starts when its plan takes effect ``delay`` later, and ``carry(q, v, t, until,
  plan_at)``, the measured state carried there under the plans in effect meanwhile;
* ``settings`` (``config.MpcSettings``; the run config's ``mpc`` section is one), ``statistics``
  (``MpcStatistics``), ``reference``, ``started``, ``reset``.

``RecedingHorizonPlanner`` is the shared part: the one-phase update (reference re-anchored, problem built,
solver run, plan made; failures counted and logged and the previous plan kept) over three hooks, ``_build``,
``_solve`` and ``_plan``. ``planners.cafe.planner.RecedingHorizonMpc`` (CAFE-MPC, with the real-time
iteration and its delay compensation) and ``planners.template.planner.TemplateMpc`` (the SRB-only baseline)
implement them.

A planner is a vertical slice, one folder under ``planners/``: its problem, planner, plan type, its own low
level if its plan needs one, and a ``PlannerSlice`` that says how a run config builds them (from the
``ResolvedRun`` the assembly resolves once: ``planners.resolved``). ``planners.registry`` maps the config's
``planner`` key to the slices (``Registry``: an unknown name is one ``ConfigError`` line naming the key).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from typing import Generic, Protocol, TypeVar

import numpy as np

from cafe_mpc.config import ConfigError, MpcSettings
from cafe_mpc.core.controller import LowLevelController
from cafe_mpc.core.plan import PlanFormat, PlanT
from cafe_mpc.planners import collector
from cafe_mpc.planners.resolved import ResolvedRun
from cafe_mpc.reference.base import Reference
from cafe_mpc.robots.robot import Robot
from cafe_mpc.solver import MSiLQRSolver, SolverOptions, SolverResult, SolveStatus

logger = logging.getLogger(__name__)

UPDATE_LINE_SEARCH_MIN_STEP = 0.125
"""Smallest line-search step of an in-loop update (steps 1, 1/2, 1/4, 1/8; the offline solver goes down to
1e-3). Every trial is a full roll-out of the horizon: a search that fails on all ten steps of the offline
setting made 20 roll-outs (hybrid and nonlinear per step), and at the running barrel roll's touchdown that
update took 229 ms instead of ~50 ms (measured). A failed search keeps the previous plan and its policy."""


def first_solve_options() -> SolverOptions:
    """Solver settings of the first (cold) solve: the paper's, with a tighter tolerance, since it seeds
    every later warm start. It runs before the clock starts (the robot stands while the first plan is
    computed)."""
    return replace(
        SolverOptions.paper_first_solve(),
        max_iterations=30,
        max_al_iterations=3,
        cost_change_tolerance=1e-4,
        expected_decrease_tolerance=1e-5,
        defect_tolerance=1e-6,
        regularization_initial=1e-6,
        regularization_min=1e-6,
    )


def update_solve_options(settings: MpcSettings) -> SolverOptions:
    """In-loop solver settings (the paper's: ``max_iterations`` iterations, one AL update, the budget)."""
    options = replace(
        SolverOptions.paper_mpc(settings.budget),
        max_iterations=settings.max_iterations,
        regularization_initial=1e-6,
        regularization_min=1e-6,
        line_search_min_step=UPDATE_LINE_SEARCH_MIN_STEP,
        final_policy=settings.final_policy,
        threads=settings.threads,
        keep_value_function=False,  # the plan carries the policy and the Q-function pieces only
        copy_policy=False,  # the plan copies them; the feedback reads them before the next preparation
        lend_results=True,  # the trajectories written into lent buffers, reused once no result holds them
    )
    if settings.touchdown_max_penalty is not None:
        options = replace(options, al_max_penalty=settings.touchdown_max_penalty)
    return options


def prepare_solve_options(settings: MpcSettings) -> SolverOptions:
    """Solver settings of a real-time iteration's preparation: the in-loop ones, or (without the
    preparation's line search) no iteration: linearisation and backward sweep only."""
    if settings.rti_line_search:
        return update_solve_options(settings)
    return replace(update_solve_options(settings), max_iterations=0)


@dataclass
class MpcStatistics:
    """Per-update records of an MPC run (times in seconds)."""

    solves: int = 0
    failures: int = 0
    start_times: list[float] = field(default_factory=list)
    """Simulated (or run) time of each update's measurement."""
    iterations: list[int] = field(default_factory=list)
    iteration_times: list[float] = field(default_factory=list)
    update_times: list[float] = field(default_factory=list)
    """Problem update + solve + plan extraction, wall clock."""
    problem_times: list[float] = field(default_factory=list)
    """Reference sampling, writing the problem's references, warm start."""
    solve_times: list[float] = field(default_factory=list)
    linearize_times: list[float] = field(default_factory=list)
    backward_times: list[float] = field(default_factory=list)
    line_search_times: list[float] = field(default_factory=list)
    latencies: list[float] = field(default_factory=list)
    """Time from each update's measurement to its plan taking effect (simulated or wall clock)."""
    line_search_steps: list[int] = field(default_factory=list)
    costs: list[float] = field(default_factory=list)
    defects: list[float] = field(default_factory=list)
    statuses: list[SolveStatus] = field(default_factory=list)
    prepare_times: list[float] = field(default_factory=list)
    """Real-time iteration: wall time of each preparation (reference, problem, warm start, linearisation,
    backward sweep and, with ``rti_line_search``, the line search)."""
    prepare_cpu_times: list[float] = field(default_factory=list)
    """Real-time iteration: the thread CPU time of each preparation. Below its wall time by what the machine
    took away (another process, the hypervisor): it tells a slow update from a slow computer."""
    feedback_times: list[float] = field(default_factory=list)
    """Real-time iteration: wall time of each feedback phase (embedding the measurement, the plan)."""
    first_solve_time: float | None = None
    warm_up_time: float | None = None
    """Wall time of the warm-up after the first solve (``MpcSettings.warm_up``), before the clock starts."""
    fallback_ticks: int = 0
    stale_plans: int = 0
    """Plans received more than ``recovery.stale_after`` after their measurement, not followed (the MPC in
    its own process: ``control.process``)."""

    def record(self, t: float, result: SolverResult, update_time: float, problem_time: float) -> None:
        stats = result.statistics
        self.solves += 1
        self.start_times.append(t)
        self.iterations.append(stats.iterations)
        self.iteration_times.extend(stats.iteration_times)
        self.update_times.append(update_time)
        self.problem_times.append(problem_time)
        self.solve_times.append(stats.solve_time)
        self.linearize_times.append(stats.linearize_time)
        self.backward_times.append(stats.backward_time)
        self.line_search_times.append(stats.line_search_time)
        self.line_search_steps.append(int(sum(stats.line_search_steps)))
        self.costs.append(result.cost)
        self.defects.append(result.defect_max)
        self.statuses.append(result.status)

    def arrays(self) -> dict[str, np.ndarray]:
        """The per-update records as arrays, one entry per solve (times in milliseconds; ``status`` the
        solver's stop reason): what a run's log keeps so that the timing of every update, not only its
        median and p99, can be read back. ``prepare_ms`` and ``feedback_ms`` have one entry per real-time
        preparation and feedback (none for the first, cold solve), ``prepare_cpu_ms`` its thread CPU time."""
        ms = 1e3
        return {
            "start_time": np.asarray(self.start_times, dtype=float),
            "update_ms": np.asarray(self.update_times, dtype=float) * ms,
            "problem_ms": np.asarray(self.problem_times, dtype=float) * ms,
            "linearize_ms": np.asarray(self.linearize_times, dtype=float) * ms,
            "backward_ms": np.asarray(self.backward_times, dtype=float) * ms,
            "line_search_ms": np.asarray(self.line_search_times, dtype=float) * ms,
            "iterations": np.asarray(self.iterations, dtype=int),
            "line_search_steps": np.asarray(self.line_search_steps, dtype=int),
            "status": np.asarray([str(status) for status in self.statuses], dtype=str),
            "prepare_ms": np.asarray(self.prepare_times, dtype=float) * ms,
            "prepare_cpu_ms": np.asarray(self.prepare_cpu_times, dtype=float) * ms,
            "feedback_ms": np.asarray(self.feedback_times, dtype=float) * ms,
        }

    def summary(self, skip_first: bool = True) -> dict:
        """Medians and p99 in milliseconds. ``skip_first``: leave out the first (cold) solve, which runs
        before the clock starts."""
        start = 1 if skip_first and self.solves > 1 else 0

        def every_ms(values: list[float], percentile: float) -> float | None:
            return float(np.percentile(values, percentile)) * 1e3 if len(values) else None

        def ms(values: list[float], percentile: float) -> float | None:
            """``every_ms`` of a per-solve record without the cold solve."""
            return every_ms(values[start:] if len(values) == self.solves else values, percentile)

        iterations = self.iterations[start:]
        return {
            "solves": self.solves,
            "failures": self.failures,
            "iterations_mean": float(np.mean(iterations)) if iterations else None,
            "iteration_time_ms_median": every_ms(self.iteration_times, 50),
            "iteration_time_ms_p99": every_ms(self.iteration_times, 99),
            "update_ms_median": ms(self.update_times, 50),
            "update_ms_p99": ms(self.update_times, 99),
            "problem_update_ms_median": ms(self.problem_times, 50),
            "solve_time_ms_median": ms(self.solve_times, 50),
            "solve_time_ms_p99": ms(self.solve_times, 99),
            "linearize_ms_median": ms(self.linearize_times, 50),
            "backward_ms_median": ms(self.backward_times, 50),
            "line_search_ms_median": ms(self.line_search_times, 50),
            "latency_ms_median": every_ms(self.latencies, 50),
            "latency_ms_p99": every_ms(self.latencies, 99),
            "first_solve_ms": self.first_solve_time * 1e3 if self.first_solve_time is not None else None,
            "line_search_steps_mean": float(np.mean(self.line_search_steps[start:]))
            if self.line_search_steps[start:]
            else None,
            "defect_max_median": float(np.median(self.defects)) if self.defects else None,
            "time_budget_stops": sum(status == SolveStatus.TIME_BUDGET for status in self.statuses),
            "pd_fallback_ticks": self.fallback_ticks,
            "stale_plans": self.stale_plans,
            "prepare_ms_median": every_ms(self.prepare_times, 50),
            "prepare_ms_p99": every_ms(self.prepare_times, 99),
            "prepare_cpu_ms_median": every_ms(self.prepare_cpu_times, 50),
            "prepare_cpu_ms_p99": every_ms(self.prepare_cpu_times, 99),
            "feedback_ms_median": every_ms(self.feedback_times, 50),
            "feedback_ms_p99": every_ms(self.feedback_times, 99),
        }


class Planner(Protocol[PlanT]):
    """What the MPC loops call (module docstring)."""

    name: str
    settings: MpcSettings
    statistics: MpcStatistics
    reference: Reference

    @property
    def started(self) -> bool: ...

    @property
    def supports_rti(self) -> bool: ...

    @property
    def prepared_time(self) -> float | None: ...

    def reset(self) -> None: ...

    def update(self, t: float, q: np.ndarray, v: np.ndarray) -> PlanT | None: ...

    def prepare(self, t: float, q: np.ndarray, v: np.ndarray) -> bool: ...

    def feedback(self, t: float, q: np.ndarray, v: np.ndarray) -> PlanT | None: ...

    def predict(self, t: float) -> np.ndarray | None: ...

    def problem_start(self, t: float, delay: float) -> float: ...

    def carry(
        self, q: np.ndarray, v: np.ndarray, t: float, until: float, plan_at: Callable[[float], PlanT | None]
    ) -> np.ndarray: ...


def forget_warm_start(planner: Planner) -> None:
    """Drop ``planner``'s warm start and any waiting preparation, its records kept: its next update is a cold
    solve from its measurement (an MPC that was away: a stalled process that resumes, ``control.process``,
    or plans withheld, ``control.inline``)."""
    statistics = planner.statistics
    planner.reset()
    planner.statistics = statistics


PLANNER_ERRORS = (ValueError, FloatingPointError, np.linalg.LinAlgError, RuntimeError)
"""What a failed update raises inside (a singular system, a non-finite value, a bad reference): caught,
counted and logged; the previous plan stays."""


class RecedingHorizonPlanner(Generic[PlanT]):
    """The one-phase update shared by the planners (module docstring). Subclasses implement ``_build(t)``
    (the problem of an update at ``t`` from ``self._x``, references written in place), ``_solve(built,
    solver)`` (warm start and MS-iLQR) and ``_plan(built, result)`` (the message to the low level), and
    may add the real-time iteration (``prepare``, ``feedback``, ``predict``, ``prepared_time``) and its delay
    compensation (``problem_start``, ``carry``)."""

    name = "MPC"
    """How log messages name this planner."""

    def __init__(
        self, robot: Robot, reference: Reference, builder, settings: MpcSettings | None = None
    ) -> None:
        self.robot = robot
        self.reference = reference
        self.builder = builder
        self.settings = settings or MpcSettings()
        self.first_solver = MSiLQRSolver(first_solve_options())
        self.solver = MSiLQRSolver(update_solve_options(self.settings))
        self.statistics = MpcStatistics()
        self.previous: tuple | None = None
        """The newest (problem, solution) the plan in effect came from."""
        self._collected = False
        """Whether the objects of a first solve were frozen out of the collector's reach (``update``)."""
        self.prepared: tuple | None = None
        self._x = np.zeros(robot.nq + robot.nv)

    def reset(self) -> None:
        self.previous = None
        self.prepared = None
        self.statistics = MpcStatistics()

    @property
    def started(self) -> bool:
        """Whether a first (cold) solve has succeeded."""
        return self.previous is not None

    @property
    def supports_rti(self) -> bool:
        """Whether this planner has the real-time iteration's two phases."""
        return False

    @property
    def prepared_time(self) -> float | None:
        """The update time the waiting preparation is for (None without one)."""
        return None

    @collector.paused
    def update(self, t: float, q: np.ndarray, v: np.ndarray) -> PlanT | None:
        """One one-phase update from the state measured at ``t``; ``None`` (counted and logged) if it
        failed. The first update of a run is the cold solve (``first_solve_options``); after it (and the
        warm-up) the objects alive are frozen out of the garbage collector's reach
        (``planners.collector``). A later cold solve (after ``reset``: a resumed or restarted MPC) leaves
        them frozen: collecting everything again took 60-130 ms while the robot waited for the plan."""
        first = self.previous is None
        self.prepared = None
        collect = first and not self._collected
        if collect:
            collector.thaw()
        start = time.perf_counter()
        outcome = self._solve_at(t, q, v, self.first_solver if first else self.solver)
        if outcome is None:
            return None
        built, result = outcome
        try:
            plan = self._plan(built, result)
        except PLANNER_ERRORS as error:
            self._failed(t, f"its plan could not be made ({error})")
            return None
        if first:
            self.statistics.first_solve_time = time.perf_counter() - start
        self.previous = (built, result)
        if first:
            self._compile_kernels()
        if first and self.settings.warm_up > 0.0:
            self._warm_up(t)
        if collect:
            collector.freeze_live_objects()  # before the clock starts
            self._collected = True
        return plan

    def prepare(self, t: float, q: np.ndarray, v: np.ndarray) -> bool:
        raise NotImplementedError(f"{self.name} has no real-time iteration (one-phase updates only)")

    def feedback(self, t: float, q: np.ndarray, v: np.ndarray) -> PlanT | None:
        raise NotImplementedError(f"{self.name} has no real-time iteration (one-phase updates only)")

    def predict(self, t: float) -> np.ndarray | None:
        return None

    def problem_start(self, t: float, delay: float) -> float:
        """Where the problem of the update measured at ``t`` starts when its plan takes effect ``delay``
        later (default: at ``t``; a planner that compensates the delay in the loop overrides it)."""
        return t

    def carry(
        self, q: np.ndarray, v: np.ndarray, t: float, until: float, plan_at: Callable[[float], PlanT | None]
    ) -> np.ndarray:
        """The state ``[q, v]`` measured at ``t`` carried to ``until`` under ``plan_at(s)``, the plan in
        effect at each time ``s`` (the loop's delay compensation; a planner with ``problem_start`` overrides
        it)."""
        raise NotImplementedError(f"{self.name} has no delay prediction")

    def _solve_at(self, t: float, q: np.ndarray, v: np.ndarray, solver: MSiLQRSolver) -> tuple | None:
        """Reference update, problem, ``solver`` from the state ``q, v`` at ``t``; records the update's
        statistics; ``None`` (counted and logged) on failure."""
        robot = self.robot
        self._x[: robot.nq] = q
        self._x[robot.nq :] = v
        start = time.perf_counter()
        try:
            self.reference.update(t, q, v)
            built = self._build(t)
            self._prepare_problem(built)
            problem_time = time.perf_counter() - start
            result = self._solve(built, solver, budget_start=start)
        except PLANNER_ERRORS as error:
            self._failed(t, f"it failed ({error})")
            return None
        elapsed = time.perf_counter() - start
        self.statistics.record(t, result, elapsed, problem_time)
        if result.status == SolveStatus.NON_FINITE or not result.policy_valid:
            self._failed(t, f"it returned {result.status}")
            return None
        return built, result

    def _failed(self, t: float, why: str) -> None:
        self.statistics.failures += 1
        logger.warning("%s update at t = %.3f s: %s; keeping the previous plan", self.name, t, why)

    def _prepare_problem(self, built) -> None:
        """A last touch of a built problem before it is solved (default: nothing)."""

    def _compile_kernels(self) -> None:
        """After the first solve, before the clock starts: run once what later updates run and the first
        solve did not, so that no kernel compiles after the clock starts (``core.compilation``; default:
        nothing)."""

    def _warm_up(self, t0: float) -> None:
        """Make the solver data of the next updates before the clock starts (default: nothing)."""

    def _build(self, t: float):
        raise NotImplementedError

    def _solve(self, built, solver: MSiLQRSolver, budget_start: float | None = None) -> SolverResult:
        raise NotImplementedError

    def _plan(self, built, result: SolverResult):
        raise NotImplementedError


# ------------------------------------------------------------------------------------------- registry
@dataclass(frozen=True)
class PlannerSlice(Generic[PlanT]):
    """A planner as a run config builds it (module docstring), from the run resolved once
    (``planners.resolved.ResolvedRun``).

    ``build(run, reference)``: the planner tracking ``reference``; ``plan_format(run)``: how its plans travel
    as arrays (the MPC process's plan channel); ``low_level(run)``: the low level of its own plan type, or
    None when the config's ``wbc`` names it (``low_level.registry``); ``plan_type``: the type of its plans,
    which a low level it is paired with must follow."""

    plan_type: type[PlanT]
    build: Callable[[ResolvedRun, Reference], Planner[PlanT]]
    plan_format: Callable[[ResolvedRun], PlanFormat[PlanT]]
    low_level: Callable[[ResolvedRun], LowLevelController[PlanT]] | None = None


EntryT = TypeVar("EntryT")


class Registry(Generic[EntryT]):
    """Names of a config key -> what they build (``planners.registry.PLANNERS``, ``low_level.registry``).

    ``get(name)`` raises ``ConfigError`` (one line naming the key and the known names) for an unknown name;
    ``register`` adds an entry (a test's toy planner; ``unregister`` takes it out again)."""

    def __init__(self, key: str, what: str, entries: Mapping[str, EntryT]) -> None:
        self.key = key
        self.what = what
        self._entries: dict[str, EntryT] = dict(entries)

    def get(self, name: str) -> EntryT:
        entry = self._entries.get(name)
        if entry is None:
            raise ConfigError(f"{self.key}: unknown {self.what} {name!r}; known: {', '.join(self.names)}")
        return entry

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(self._entries)

    def register(self, name: str, entry: EntryT) -> None:
        if name in self._entries:
            raise ValueError(f"{self.key}: {name!r} is registered already")
        self._entries[name] = entry

    def unregister(self, name: str) -> None:
        del self._entries[name]
