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

This object knows nothing about time passing: the policy side (``cafe_mpc.control``) decides when updates
happen and when their plans take effect (fixed or measured latency in simulated time, or a separate
process against the wall clock). It is what the MPC process of the real-time mode runs (OCS2's MPC/MRT
split).
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np

from cafe_mpc.core.plan import Plan
from cafe_mpc.mpc import collector
from cafe_mpc.mpc.problem import BuiltProblem, CafeProblemBuilder, WarmStart
from cafe_mpc.mpc.time_grid import TIME_QUANTUM, PiecewiseTrajectory
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
    ``final_policy``: the policy an update returns (``SolverOptions.final_policy``): ``"shift"`` (default)
    keeps the sweep the step was taken from, moved to the new plan to first order (the real-time iteration's
    policy: one linearisation and one backward sweep per update); ``"relinearize"`` linearises and sweeps
    again at the new plan (a third more work per preparation; with the real-time iteration both track the
    gaits alike at fixed 20-60 ms latency, and the running barrel roll succeeds at 10-40 ms with either,
    at 50 ms only with ``"relinearize"``: BENCHMARKS.md).
    ``warm_up``: seconds of future updates whose solver data (one per knot object: Pinocchio ``Data``,
    kinematics, buffers) are created right after the cold first solve, before the clock starts, instead of
    inside the first update that meets each knot object (which took 25-60 ms extra at the start of a gait
    and when the barrel roll entered the horizon). 0: no warm-up.
    ``scheme``: ``"rti"`` (default; real-time iteration: ``prepare`` before the measurement, ``feedback``
    after it, see the module docstring) or ``"one_phase"`` (the whole update after the measurement).
    ``rti_line_search``: the preparation takes its MS-iLQR iteration(s) on the predicted state, line search
    included (``max_iterations`` of them), and the feedback only embeds the measured state (``True``,
    default); or the preparation stops after the backward sweep and the feedback takes the full Newton step
    (the classical real-time iteration, no globalisation).
    ``rti_feedback``: how the feedback carries the measured initial state through the plan: ``"linear"``
    (the tangential predictor through the prepared ``A``, ``B``) or ``"nonlinear"`` (the dynamics rolled out
    under the prepared policy).
    ``compute_scale``: measured mode only: every measured wall time (update, preparation, feedback) is
    multiplied by it before it is applied in simulated time, to show the controller as it would run on a
    computer ``compute_scale`` times slower.
    ``threads``: threads that linearise the knots of an update (``SolverOptions.threads``; 1: none).
    """

    period: float = 0.02
    latency: LatencyMode = "measured"
    fixed_latency: float = 0.02
    time_budget: float | None = None
    max_iterations: int = 1
    touchdown_max_penalty: float | None = None
    final_policy: Literal["relinearize", "shift"] = "shift"
    warm_up: float = 1.0
    scheme: Literal["one_phase", "rti"] = "rti"
    rti_line_search: bool = True
    rti_feedback: Literal["linear", "nonlinear"] = "linear"
    compute_scale: float = 1.0
    threads: int = 1
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
        if self.scheme not in ("one_phase", "rti"):
            raise ValueError(f"MPC scheme must be 'one_phase' or 'rti', got {self.scheme!r}")
        if self.rti_feedback not in ("linear", "nonlinear"):
            raise ValueError(f"MPC rti_feedback must be 'linear' or 'nonlinear', got {self.rti_feedback!r}")
        if not (math.isfinite(self.compute_scale) and self.compute_scale > 0):
            raise ValueError(f"MPC compute_scale must be positive, got {self.compute_scale}")
        if self.threads < 1:
            raise ValueError(f"MPC threads must be >= 1, got {self.threads}")

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
            threads=self.threads,
        )
        if self.touchdown_max_penalty is not None:
            options = replace(options, al_max_penalty=self.touchdown_max_penalty)
        return options

    @property
    def prepare_solve(self) -> SolverOptions:
        """Solver settings of a real-time iteration's preparation: the in-loop ones, or (without the
        preparation's line search) no iteration: linearisation and backward sweep only."""
        if self.rti_line_search:
            return self.update_solve
        return replace(self.update_solve, max_iterations=0)


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
    prepare_times: list[float] = field(default_factory=list)
    """Real-time iteration: wall time of each preparation (reference, problem, warm start, linearisation,
    backward sweep and, with ``rti_line_search``, the line search)."""
    feedback_times: list[float] = field(default_factory=list)
    """Real-time iteration: wall time of each feedback phase (embedding the measurement, the plan)."""
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
            "prepare_ms_median": float(np.median(self.prepare_times)) * 1e3 if self.prepare_times else None,
            "prepare_ms_p99": float(np.percentile(self.prepare_times, 99)) * 1e3
            if self.prepare_times
            else None,
            "feedback_ms_median": float(np.median(self.feedback_times)) * 1e3
            if self.feedback_times
            else None,
            "feedback_ms_p99": float(np.percentile(self.feedback_times, 99)) * 1e3
            if self.feedback_times
            else None,
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
        self.prepare_solver = MSiLQRSolver(self.settings.prepare_solve)
        # one workspace and data pool for the cold solve and the updates (the updates reuse its data)
        workspace = Workspace()
        self.solver.workspace = self.first_solver.workspace = self.prepare_solver.workspace = workspace
        self.warm_start = WarmStart()
        self.statistics = MpcStatistics()
        self.previous: tuple[BuiltProblem, SolverResult] | None = None
        self.prepared: tuple[float, BuiltProblem, SolverResult] | None = None
        """The preparation waiting for its measurement: (update time, problem, prepared solution)."""
        self._x = np.zeros(robot.nq + robot.nv)
        self._projections: dict[tuple[bool, ...], tuple] = {}

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
        """Whether this planner has the real-time iteration's two phases (the template baseline has not)."""
        return True

    @collector.paused
    def update(self, t: float, q: np.ndarray, v: np.ndarray) -> Plan | None:
        """One one-phase MPC update from the state measured at ``t``; ``None`` (counted and logged) if it
        failed. The first update of a run is the cold solve (``settings.first_solve``).

        The steps are ``_build`` (reference update + problem with references written in place), ``_solve``
        (warm start + MS-iLQR) and ``_plan`` (the message to the low level); another planner over the same
        loop (the template baseline, ``mpc/template.py``) overrides them."""
        first = self.previous is None
        self.prepared = None
        if first:
            collector.thaw()
        start = time.perf_counter()
        outcome = self._solve_at(t, q, v, self.first_solver if first else self.solver)
        if outcome is None:
            return None
        built, result = outcome
        try:
            plan = self._plan(built, result)
        except (ValueError, FloatingPointError, np.linalg.LinAlgError, RuntimeError) as error:
            self._failed(t, f"its plan could not be made ({error})")
            return None
        if first:
            self.statistics.first_solve_time = time.perf_counter() - start
        self.previous = (built, result)
        if first and self.settings.warm_up > 0.0:
            self._warm_up(t)
        if first:
            collector.freeze_live_objects()  # before the clock starts (collector module)
        return plan

    @collector.paused
    def prepare(self, t: float, q: np.ndarray, v: np.ndarray) -> bool:
        """The preparation phase of a real-time iteration for the update at ``t``, from the state ``q, v``
        predicted for ``t`` (``predict``): reference, problem, warm start, linearisation, backward sweep
        (and the line search, ``MpcSettings.rti_line_search``). ``False`` (counted and logged) if it failed:
        the update at ``t`` then falls back to a one-phase update. Needs a first (cold) solve."""
        if self.previous is None:
            raise RuntimeError(f"{self.name}: prepare needs a first solve (call update once)")
        self.prepared = None
        outcome = self._solve_at(t, q, v, self.prepare_solver)
        if outcome is None:
            return False
        built, result = outcome
        self.statistics.prepare_times.append(self.statistics.update_times[-1])
        self.prepared = (t, built, result)
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
        _, built, result = prepared
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
            plan = self._plan(built, embedded)
        except (ValueError, FloatingPointError, np.linalg.LinAlgError, RuntimeError) as error:
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

    def _solve_at(
        self, t: float, q: np.ndarray, v: np.ndarray, solver: MSiLQRSolver
    ) -> tuple[BuiltProblem, SolverResult] | None:
        """Reference update, problem, warm start and ``solver`` from the state ``q, v`` at ``t``; records the
        update's statistics; ``None`` (counted and logged) on failure."""
        robot = self.robot
        self._x[: robot.nq] = q
        self._x[robot.nq :] = v
        start = time.perf_counter()
        try:
            self.reference.update(t, q, v)
            built = self._build(t)
            if isinstance(built, BuiltProblem):
                self._contact_consistent(built.problem.x0, built.phases[0].stance)
            problem_time = time.perf_counter() - start
            result = self._solve(built, solver)
        except (ValueError, FloatingPointError, np.linalg.LinAlgError, RuntimeError) as error:
            self._failed(t, f"it failed ({error})")
            return None
        elapsed = time.perf_counter() - start
        self.statistics.record(t, result, elapsed, problem_time)
        if result.status == "non_finite" or not result.policy_valid:
            self._failed(t, f"it returned {result.status}")
            return None
        return built, result

    def _contact_consistent(self, x: np.ndarray, stance: tuple[bool, ...] | None) -> None:
        """Bring the feet the plan's first phase stands on to rest in ``x`` (in place): the impact map (22)
        onto that stance. A measurement taken at a touchdown's planned time has the landing feet still
        moving (or not yet landed) while the plan's state there is the post-impact one; projected, the
        measurement differs from the prediction by the touchdown's timing error, not by the whole impact."""
        if stance is None or not any(stance):
            return
        key = tuple(bool(s) for s in stance)
        entry = self._projections.get(key)
        if entry is None:
            reset = self.builder.whole_body.reset_map((False,) * len(key), key)
            entry = (reset, reset.create_data())
            self._projections[key] = entry
        reset, data = entry
        reset.calc(data, x)
        x[:] = data.x_next

    def _failed(self, t: float, why: str) -> None:
        self.statistics.failures += 1
        logger.warning("%s update at t = %.3f s: %s; keeping the previous plan", self.name, t, why)

    def _warm_up(self, t0: float) -> None:
        """Create the solver data of every knot object the updates of ``settings.warm_up`` seconds after
        ``t0`` will use (``MpcSettings.warm_up``): the problems of updates one period apart are built and
        served by the solver's workspace, nothing is solved; the next update rewrites every reference."""
        start = time.perf_counter()
        period = self.settings.period
        steps = math.ceil(self.settings.warm_up / period)
        workspace = self.solver.workspace
        grid = getattr(getattr(self.builder, "schedule", None), "whole_body_dt", period)
        for step in range(1, steps + 1):
            # updates start anywhere on the control ticks: vary the start's offset from the knot grid so
            # that the knot objects of the first knot's durations get their data too
            offset = (step * 3 * TIME_QUANTUM) % grid
            built = self._build(t0 + step * period + offset)
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
