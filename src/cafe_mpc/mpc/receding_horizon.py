"""The MPC side of CAFE-MPC (paper Sec. IV, VI-C): one receding-horizon update, measured state -> Plan.

``RecedingHorizonMpc.update(t, q, v)`` re-anchors the reference, writes the persistent CAFE problem's
references in place (``CafeProblemBuilder``), warm-starts MS-iLQR from the shifted previous solution
(Fig. 5) and turns the whole-body part of the solution into a ``Plan`` (the message to the low-level
controller: knots with states, torques, gains and the Q-function pieces of Eqs. (6)-(8), forces, contacts).

This object knows nothing about time passing: the policy side (``cafe_mpc.control``) decides when an update
starts and when its plan takes effect (fixed or measured latency in simulated time, or a separate process
against the wall clock). It is what the MPC process of the real-time mode runs (OCS2's MPC/MRT split).
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np

from cafe_mpc.core.plan import Plan
from cafe_mpc.mpc.problem import BuiltProblem, CafeProblemBuilder, WarmStart
from cafe_mpc.reference.base import Reference
from cafe_mpc.robots.robot import Robot
from cafe_mpc.solver import MSiLQRSolver, SolverOptions, SolverResult
from cafe_mpc.solver.workspace import Workspace

logger = logging.getLogger(__name__)

LatencyMode = Literal["fixed", "measured"]

UPDATE_LINE_SEARCH_MIN_STEP = 0.125
"""Smallest line-search step of an in-loop update (steps 1, 1/2, 1/4, 1/8; the offline solver goes down to
1e-3). Every trial is a full roll-out of the horizon: a search that fails on all ten steps of the offline
setting made 20 roll-outs (hybrid and nonlinear per step), and at the running barrel roll's touchdown that
update took 229 ms instead of ~50 ms (measured). A failed search keeps the previous plan and its policy."""


@dataclass
class MpcSettings:
    """Receding-horizon settings (docs/settings.md: "MPC loop" and "Solver (MS-iLQR)").

    ``latency``: ``"measured"`` (default): a plan takes effect once its real wall-clock update time has
    passed in simulated time, and the next update starts from the newest measurement when the worker is
    free; ``"fixed"``: the same with a constant ``fixed_latency`` (deterministic, for tests and for the
    paper's C++ budget). ``time_budget``: wall-clock cap of one solve (the paper's 0.9 x period), applied in
    measured mode only so that fixed-latency runs do not depend on the machine's load. ``max_iterations``:
    MS-iLQR iterations per update: 1, the real-time iteration scheme (the paper uses 4 with ~5 ms C++
    iterations; in Python, with measured latency, 4 iterations made 20-32 ms updates and the pace and bound
    presets fell, while 1 iteration keeps the latency near 12 ms and all five gaits stay up: BENCHMARKS.md).
    ``touchdown_max_penalty``: cap of the augmented-Lagrangian penalty of the touchdown constraint (25)
    (``SolverOptions.al_max_penalty``; ``None``: the authors' 1e4). The penalty starts at 20 and grows x5 per
    update while a planned foot misses the floor by more than 5 mm (the AL parameters carry over between
    updates); the barrel-roll preset caps it at 20 (docs/settings.md).
    ``final_policy``: the policy an update returns (``SolverOptions.final_policy``): ``"relinearize"``
    (default) linearises and sweeps again at the new plan; ``"shift"`` keeps the sweep the step was taken
    from, moved to the new plan to first order (the real-time iteration's policy: one linearisation and one
    sweep less, a fifth to a quarter of an update; but the bound fell with it at fixed 40 and 50 ms latency,
    where it stands with ``"relinearize"``: BENCHMARKS.md).
    ``warm_up``: seconds of future updates whose solver data (one per knot object: Pinocchio ``Data``,
    kinematics, buffers) are created right after the cold first solve, before the clock starts, instead of
    inside the first update that meets each knot object (which took 25-60 ms extra at the start of a gait
    and when the barrel roll entered the horizon). 0: no warm-up.
    """

    period: float = 0.02
    latency: LatencyMode = "measured"
    fixed_latency: float = 0.02
    time_budget: float | None = None
    max_iterations: int = 1
    touchdown_max_penalty: float | None = None
    final_policy: Literal["relinearize", "shift"] = "relinearize"
    warm_up: float = 1.0
    # The paper's first-solve settings with a tighter tolerance: the first (cold) solve seeds every later
    # warm start. It runs before the clock starts (the robot stands while the first plan is computed).
    first_solve: SolverOptions = field(
        default_factory=lambda: replace(
            SolverOptions.paper_first_solve(),
            max_iterations=30,
            max_al_iterations=3,
            cost_change_tolerance=1e-4,
            expected_decrease_tolerance=1e-5,
            defect_tolerance=1e-6,
            regularization_initial=1e-6,
            regularization_min=1e-6,
        )
    )

    def __post_init__(self) -> None:
        if not self.period > 0:
            raise ValueError(f"MPC period must be positive, got {self.period}")
        if self.latency not in ("fixed", "measured"):
            raise ValueError(f"MPC latency must be 'fixed' or 'measured', got {self.latency!r}")
        if self.fixed_latency < 0:
            raise ValueError("MPC latency must be >= 0")
        if self.time_budget is not None and not self.time_budget > 0:
            raise ValueError("MPC time budget must be positive (or null)")
        if self.max_iterations < 1:
            raise ValueError("MPC max_iterations must be >= 1")
        if self.touchdown_max_penalty is not None and not self.touchdown_max_penalty > 0:
            raise ValueError("MPC touchdown_max_penalty must be positive (or null)")

    @property
    def budget(self) -> float | None:
        """The wall-clock cap of an update's solve: ``time_budget`` or 0.9 x period in measured mode."""
        if self.latency != "measured":
            return None
        return self.time_budget if self.time_budget is not None else 0.9 * self.period

    @property
    def update_solve(self) -> SolverOptions:
        """In-loop solver settings (the paper's: ``max_iterations`` iterations, one AL update, the budget)."""
        options = replace(
            SolverOptions.paper_mpc(self.period),
            max_iterations=self.max_iterations,
            time_budget=self.budget,
            regularization_initial=1e-6,
            regularization_min=1e-6,
            line_search_min_step=UPDATE_LINE_SEARCH_MIN_STEP,
            final_policy=self.final_policy,
        )
        if self.touchdown_max_penalty is not None:
            options = replace(options, al_max_penalty=self.touchdown_max_penalty)
        return options


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
    statuses: list[str] = field(default_factory=list)
    first_solve_time: float | None = None
    warm_up_time: float | None = None
    """Wall time of the warm-up after the first solve (``MpcSettings.warm_up``), before the clock starts."""
    fallback_ticks: int = 0

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

    def summary(self, skip_first: bool = True) -> dict:
        """Medians and p99 in milliseconds. ``skip_first``: leave out the first (cold) solve, which runs
        before the clock starts."""
        start = 1 if skip_first and self.solves > 1 else 0

        def ms(values: list[float], percentile: float) -> float | None:
            values = values[start:] if len(values) == self.solves else values
            return float(np.percentile(values, percentile)) * 1e3 if len(values) else None

        iterations = self.iterations[start:]
        return {
            "solves": self.solves,
            "failures": self.failures,
            "iterations_mean": float(np.mean(iterations)) if iterations else None,
            "iteration_time_ms_median": float(np.median(self.iteration_times)) * 1e3
            if self.iteration_times
            else None,
            "iteration_time_ms_p99": float(np.percentile(self.iteration_times, 99)) * 1e3
            if self.iteration_times
            else None,
            "update_ms_median": ms(self.update_times, 50),
            "update_ms_p99": ms(self.update_times, 99),
            "problem_update_ms_median": ms(self.problem_times, 50),
            "solve_time_ms_median": ms(self.solve_times, 50),
            "solve_time_ms_p99": ms(self.solve_times, 99),
            "linearize_ms_median": ms(self.linearize_times, 50),
            "backward_ms_median": ms(self.backward_times, 50),
            "line_search_ms_median": ms(self.line_search_times, 50),
            "latency_ms_median": float(np.median(self.latencies)) * 1e3 if self.latencies else None,
            "latency_ms_p99": float(np.percentile(self.latencies, 99)) * 1e3 if self.latencies else None,
            "first_solve_ms": self.first_solve_time * 1e3 if self.first_solve_time is not None else None,
            "line_search_steps_mean": float(np.mean(self.line_search_steps[start:]))
            if self.line_search_steps[start:]
            else None,
            "defect_max_median": float(np.median(self.defects)) if self.defects else None,
            "time_budget_stops": sum(status == "time_budget" for status in self.statuses),
            "pd_fallback_ticks": self.fallback_ticks,
        }


class RecedingHorizonMpc:
    """CAFE-MPC updates: persistent problem, warm start, MS-iLQR, Plan (see the module docstring)."""

    def __init__(
        self,
        robot: Robot,
        reference: Reference,
        builder: CafeProblemBuilder,
        settings: MpcSettings | None = None,
    ) -> None:
        self.robot = robot
        self.reference = reference
        self.builder = builder
        self.settings = settings or MpcSettings()
        self.first_solver = MSiLQRSolver(self.settings.first_solve)
        self.solver = MSiLQRSolver(self.settings.update_solve)
        # one workspace and data pool for the cold solve and the updates (the updates reuse its data)
        self.solver.workspace = self.first_solver.workspace = Workspace()
        self.warm_start = WarmStart()
        self.statistics = MpcStatistics()
        self.previous: tuple[BuiltProblem, SolverResult] | None = None
        self._x = np.zeros(robot.nq + robot.nv)

    def reset(self) -> None:
        self.previous = None
        self.statistics = MpcStatistics()

    @property
    def started(self) -> bool:
        """Whether a first (cold) solve has succeeded."""
        return self.previous is not None

    def update(self, t: float, q: np.ndarray, v: np.ndarray) -> Plan | None:
        """One MPC update from the state measured at ``t``; ``None`` (counted and logged) if it failed.

        The steps are ``_build`` (reference update + problem with references written in place), ``_solve``
        (warm start + MS-iLQR) and ``_plan`` (the message to the low level); another planner over the same
        loop (the template baseline, ``mpc/template.py``) overrides them."""
        robot = self.robot
        self._x[: robot.nq] = q
        self._x[robot.nq :] = v
        first = self.previous is None
        start = time.perf_counter()
        try:
            self.reference.update(t, q, v)
            built = self._build(t)
            problem_time = time.perf_counter() - start
            result = self._solve(built, self.first_solver if first else self.solver)
            plan = self._plan(built, result)
        except (ValueError, FloatingPointError, np.linalg.LinAlgError, RuntimeError) as error:
            self.statistics.failures += 1
            logger.warning(
                "%s update at t = %.3f s failed (%s); keeping the previous plan", self.name, t, error
            )
            return None
        elapsed = time.perf_counter() - start
        self.statistics.record(t, result, elapsed, problem_time)
        if first:
            self.statistics.first_solve_time = elapsed
        if result.status == "non_finite" or not result.policy_valid:
            self.statistics.failures += 1
            logger.warning(
                "%s update at t = %.3f s returned %s; keeping the previous plan", self.name, t, result.status
            )
            return None
        self.previous = (built, result)
        if first and self.settings.warm_up > 0.0:
            self._warm_up(t)
        return plan

    def _warm_up(self, t0: float) -> None:
        """Create the solver data of every knot object the updates of ``settings.warm_up`` seconds after
        ``t0`` will use (``MpcSettings.warm_up``): the problems of updates one period apart are built and
        served by the solver's workspace, nothing is solved; the next update rewrites every reference."""
        start = time.perf_counter()
        period = self.settings.period
        steps = math.ceil(self.settings.warm_up / period)
        workspace = self.solver.workspace
        for step in range(1, steps + 1):
            built = self._build(t0 + step * period)
            if not isinstance(built, BuiltProblem):  # another planner's problem (the template's): no warm-up
                return
            workspace.setup(built.problem)
        self.statistics.warm_up_time = time.perf_counter() - start

    name = "MPC"
    """How log messages name this planner."""

    def _build(self, t: float):
        return self.builder.build(t, self._x.copy(), self.reference)

    def _solve(self, built, solver: MSiLQRSolver) -> SolverResult:
        previous_built, previous_solution = self.previous if self.previous else (None, None)
        guess = self.warm_start.guess(built, previous_built, previous_solution)
        return solver.solve(
            built.problem,
            guess.xs,
            guess.us,
            guess.rollout,
            initial_multipliers=guess.multipliers,
            initial_penalties=guess.penalties,
        )

    def _plan(self, built, result: SolverResult) -> Plan:
        return plan_from_solution(built, result)


def plan_from_solution(built: BuiltProblem, result: SolverResult) -> Plan:
    """The whole-body part of a solution as the low-level controller's ``Plan`` (knot times, states, torques,
    gains, Q-function pieces, contacts, planned GRFs)."""
    indices = built.whole_body_phases
    phases = [result.phases[i] for i in indices]
    infos = [built.phases[i] for i in indices]
    times = np.concatenate([info.times[:-1] for info in infos])
    dts = np.concatenate([np.diff(info.times) for info in infos])
    contacts = np.concatenate(
        [np.tile(np.asarray(info.stance, dtype=bool), (len(info.times) - 1, 1)) for info in infos]
    )
    xs = np.concatenate([phase.xs[:-1] for phase in phases] + [phases[-1].xs[-1:]])
    return Plan(
        times=times,
        xs=xs,
        us=np.concatenate([phase.us for phase in phases]),
        K=np.concatenate([phase.K for phase in phases]),
        Qu=np.concatenate([phase.Qu for phase in phases]),
        Quu=np.concatenate([phase.Quu for phase in phases]),
        Qux=np.concatenate([phase.Qux for phase in phases]),
        contacts=contacts,
        forces=np.concatenate([phase.forces for phase in phases]),
        dt=dts,
    )
