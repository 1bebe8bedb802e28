"""The CAFE-MPC loop: receding horizon, warm start, policy lag, and a low-level controller at 500 Hz.

The closed-loop composition of the MPC (``cafe_mpc.mpc``) and a ``LowLevelController`` (``cafe_mpc.wbc``).

Every ``period`` seconds of simulated time the controller builds the CAFE problem from the measured
state, warm-starts MS-iLQR from the shifted previous solution and turns the whole-body part of the
solution into a ``Plan``. The new plan takes effect only after the solve's latency (the measured wall-clock
solve time, or a configured constant in the deterministic mode), so the simulation is honest about
delay; until then the previous plan keeps driving the low-level controller (Riccati feedback (33) or
VWBC (34)) at every control tick.

A failed solve (exception, non-finite result, invalid policy) keeps the previous plan and is counted in
``failures``; with no plan at all the robot is held by the PD standing controller, and says so in the log.
The low-level controller gets the whole ``Measurement`` (contacts included) and the active plan every tick.
"""

from __future__ import annotations

import logging
import time
from collections import deque
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np

from cafe_mpc.core.controller import LowLevelController
from cafe_mpc.core.measurement import Measurement
from cafe_mpc.core.plan import Plan
from cafe_mpc.mpc.problem import BuiltProblem, CafeProblemBuilder, WarmStart
from cafe_mpc.reference.locomotion import LocomotionReference
from cafe_mpc.robots.robot import Robot
from cafe_mpc.solver import MSiLQRSolver, SolverOptions, SolverResult
from cafe_mpc.wbc.pd import PDController

logger = logging.getLogger(__name__)


@dataclass
class MpcSettings:
    """Receding-horizon settings (docs/settings.md: "MPC loop" and "Solver (MS-iLQR)")."""

    period: float = 0.02
    latency: Literal["fixed", "measured"] = "fixed"
    fixed_latency: float = 0.0
    # The paper's first-solve and in-loop settings (SolverOptions presets) with two changes: a tighter
    # first solve (it seeds every later warm start), and no wall-clock budget, so a simulated run does not
    # depend on the machine's load (latency is modelled by ``latency`` instead).
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
    update_solve: SolverOptions = field(
        default_factory=lambda: replace(
            SolverOptions.paper_mpc(), time_budget=None, regularization_initial=1e-6, regularization_min=1e-6
        )
    )

    def __post_init__(self) -> None:
        if not self.period > 0:
            raise ValueError(f"MPC period must be positive, got {self.period}")
        if self.fixed_latency < 0:
            raise ValueError("MPC latency must be >= 0")


@dataclass
class MpcStatistics:
    solves: int = 0
    failures: int = 0
    iterations: list[int] = field(default_factory=list)
    iteration_times: list[float] = field(default_factory=list)
    solve_times: list[float] = field(default_factory=list)
    line_search_steps: list[int] = field(default_factory=list)
    costs: list[float] = field(default_factory=list)
    defects: list[float] = field(default_factory=list)
    statuses: list[str] = field(default_factory=list)
    fallback_ticks: int = 0

    def summary(self) -> dict:
        def median(values: list[float]) -> float | None:
            return float(np.median(values)) * 1e3 if values else None

        return {
            "solves": self.solves,
            "failures": self.failures,
            "iterations_mean": float(np.mean(self.iterations)) if self.iterations else None,
            "iteration_time_ms_median": median(self.iteration_times),
            "iteration_time_ms_p99": float(np.percentile(self.iteration_times, 99)) * 1e3
            if self.iteration_times
            else None,
            "solve_time_ms_median": median(self.solve_times),
            "solve_time_ms_p99": float(np.percentile(self.solve_times, 99)) * 1e3
            if self.solve_times
            else None,
            "line_search_steps_mean": float(np.mean(self.line_search_steps))
            if self.line_search_steps
            else None,
            "defect_max_median": float(np.median(self.defects)) if self.defects else None,
            "pd_fallback_ticks": self.fallback_ticks,
        }


class CafeMpcController:
    """Closed-loop CAFE-MPC with a plan-following low-level controller (the sim's ``Controller``)."""

    def __init__(
        self,
        robot: Robot,
        reference: LocomotionReference,
        builder: CafeProblemBuilder,
        low_level: LowLevelController,
        settings: MpcSettings | None = None,
    ) -> None:
        self.robot = robot
        self.reference = reference
        self.builder = builder
        self.low_level = low_level
        self.settings = settings or MpcSettings()
        self.first_solver = MSiLQRSolver(self.settings.first_solve)
        self.solver = MSiLQRSolver(self.settings.update_solve)
        self.warm_start = WarmStart()
        self.statistics = MpcStatistics()
        self.fallback = PDController(robot)
        self.plan: Plan | None = None
        self.pending: deque[tuple[float, Plan]] = deque()
        """Solved plans waiting for their latency to pass, oldest first (several when latency > period)."""
        self.previous: tuple[BuiltProblem, SolverResult] | None = None
        self.next_update = 0.0
        self._x = np.zeros(robot.nq + robot.nv)

    # -------------------------------------------------------------------------------------- interface
    def reset(self) -> None:
        self.plan, self.previous = None, None
        self.pending.clear()
        self.statistics = MpcStatistics()
        self.next_update = 0.0
        self.fallback.reset()
        self.low_level.reset()

    def compute(self, t: float, state: Measurement) -> np.ndarray:
        # A plan that comes due now takes effect before the next update starts (with a latency of one MPC
        # period the new update would otherwise replace it before it was ever used).
        self._activate_pending(t)
        if t + 1e-9 >= self.next_update:
            self._update(t, state)
            self.next_update += self.settings.period
            self._activate_pending(t)
        if self.plan is None:
            self.statistics.fallback_ticks += 1
            return self.fallback.compute(t, state, None)
        torques = self.low_level.compute(t, state, self.plan)
        if not np.all(np.isfinite(torques)):
            self.statistics.fallback_ticks += 1
            return self.fallback.compute(t, state, None)
        return torques

    def _activate_pending(self, t: float) -> None:
        due = None
        while self.pending and t + 1e-9 >= self.pending[0][0]:
            due = self.pending.popleft()[1]
        if due is not None:
            self.plan = due

    # ----------------------------------------------------------------------------------------- solves
    def _update(self, t: float, state: Measurement) -> None:
        self._x[: self.robot.nq] = state.q
        self._x[self.robot.nq :] = state.v
        first = self.previous is None
        start = time.perf_counter()
        try:
            self.reference.update(t, state.q, state.v)
            built = self.builder.build(t, self._x.copy(), self.reference)
            previous_built, previous_solution = self.previous if self.previous else (None, None)
            guess = self.warm_start.guess(built, previous_built, previous_solution)
            solver = self.first_solver if first else self.solver
            result = solver.solve(
                built.problem,
                guess.xs,
                guess.us,
                guess.rollout,
                initial_multipliers=guess.multipliers,
                initial_penalties=guess.penalties,
            )
            plan = self._plan_from(built, result, solver)
        except (ValueError, FloatingPointError, np.linalg.LinAlgError, RuntimeError) as error:
            self.statistics.failures += 1
            logger.warning("MPC solve at t = %.3f s failed (%s); keeping the previous plan", t, error)
            return
        elapsed = time.perf_counter() - start
        stats = result.statistics
        self.statistics.solves += 1
        self.statistics.iterations.append(stats.iterations)
        self.statistics.iteration_times.extend(stats.iteration_times)
        self.statistics.solve_times.append(elapsed)
        self.statistics.line_search_steps.append(int(sum(stats.line_search_steps)))
        self.statistics.costs.append(result.cost)
        self.statistics.defects.append(result.defect_max)
        self.statistics.statuses.append(result.status)
        if result.status == "non_finite" or not getattr(result, "policy_valid", True) or plan is None:
            self.statistics.failures += 1
            logger.warning("MPC solve at t = %.3f s returned %s; keeping the previous plan", t, result.status)
            return
        self.previous = (built, result)
        latency = elapsed if self.settings.latency == "measured" else self.settings.fixed_latency
        if self.plan is None or latency <= 0:
            self.plan = plan
            self.pending.clear()
        else:
            self.pending.append((t + latency, plan))

    def stance_torque(self, stance: tuple[bool, ...] | None) -> np.ndarray:
        """Static torques carrying the weight on ``stance`` at the standing pose (zero in flight)."""
        return self.builder.stance_torque(stance)

    def _plan_from(self, built: BuiltProblem, result: SolverResult, solver: MSiLQRSolver) -> Plan | None:
        times, xs, us, gains, qu, quu, qux, contacts, forces, dts = [], [], [], [], [], [], [], [], [], []
        for index in built.whole_body_phases:
            info = built.phases[index]
            phase = result.phases[index]
            n = len(phase.us)
            for k in range(n):
                times.append(info.times[k])
                xs.append(phase.xs[k])
                us.append(phase.us[k])
                gains.append(phase.K[k])
                qu.append(phase.Qu[k])
                quu.append(phase.Quu[k])
                qux.append(phase.Qux[k])
                contacts.append(info.stance)
                dts.append(info.times[k + 1] - info.times[k])
                forces.append(phase.forces[k])
            last_state = phase.xs[n]
        xs.append(last_state)
        return Plan(
            times=np.array(times),
            xs=np.array(xs),
            us=np.array(us),
            K=np.array(gains),
            Qu=np.array(qu),
            Quu=np.array(quu),
            Qux=np.array(qux),
            contacts=np.array(contacts, dtype=bool),
            forces=np.array(forces),
            dt=np.array(dts),
        )
