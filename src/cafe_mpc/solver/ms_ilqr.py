"""Multi-phase multiple-shooting iLQR (MS-iLQR, paper Sec. III).

The solver sees only the per-knot interface of ``cafe_mpc.core.interfaces``: phases of running models,
terminal models, reset maps between phases and switching (phase-terminal) equality constraints. States live
on manifolds; every perturbation, defect and value-function model is expressed in the tangent space at the
nominal state, defects are ``d_{k+1} = f(x̄_k, ū_k) ⊖ x̄_{k+1}`` (Eq. (4)) and ``P(x̄_N) ⊖ x̄_0`` (Eq. (15)).

The steps are public, as in Crocoddyl's solvers, and ``solve`` is made of them: ``linearize`` (the
derivatives Eq. (8) needs), ``backward`` (Eqs. (7)-(10), (16)), ``try_step`` (the line search's trial,
Eqs. (11)-(13), (15)); ``prepare`` and ``feedback`` are the real-time iteration's two phases.

One inner iteration:

* **Backward sweep** (Eqs. (7)-(10)) with the defect terms ``ŝ = s + S d``, Gauss-Newton (the
  second-order dynamics terms of (8d)-(8f) and (16c) are dropped: iLQR), across reset maps with Eq. (16)
  and the reset Jacobian, with ``mu I`` added to ``Quu`` (Cholesky; on failure ``mu`` grows and the sweep
  restarts). The value function is updated with the regularised gains and the *unregularised* ``Quu``
  (``S = Qxx + K'Quu K + K'Qux + Qux'K``), which equals Eq. (9) when ``mu = 0`` and keeps the expected cost
  change of the quadratic model exact for ``mu > 0``.
* **Forward sweep** (Eqs. (11)-(13)): ``u' = ū + α k + K (x' ⊖ x̄)``. In the paper's *hybrid* roll-out a
  shooting knot follows the linearised dynamics with the *full* defect (Eq. (12), in tangent form
  ``x'_{k+1} = x̄_{k+1} ⊕ (A δx + B δu + d̄_{k+1})``) and a roll-out knot is overwritten with the nonlinear
  ``x'_{k+1} = f(x'_k, u'_k)`` (Eq. (13)); across a reset the same rule applies with ``P`` and the reset
  defect. For a linear-quadratic problem one full step lands on the optimum whatever the defects (tested).
  We keep this update (not Crocoddyl-FDDP's ``(1 - α)`` defect scaling) and add two things, because on its
  own it stalls near feasibility: the defects it leaves are the linearisation remainders, and once the
  defects are small the L1 merit rejects every step whose remainder exceeds them (the Maratos effect; see
  ``test_wild_guess_does_not_stall_near_feasibility``):

  - if the hybrid trial fails the Armijo test, the same step is tried with the *nonlinear* roll-out on every
    knot (a second-order correction: no remainders, the trial is feasible);
  - once the nominal is feasible (max defect ``<= defect_tolerance``) only the nonlinear roll-out is used,
    so the iterates stay feasible (plain iLQR steps with the cost-only Armijo test).

* **Line search** on the merit ``φ = J + ρ ||d||_1`` (``J`` includes the augmented-Lagrangian terms). The
  model of the change of ``J`` is exact for linear dynamics and quadratic costs (the paper's "exact expected
  cost change"): ``ΔJ(α) = c0 + α Σ Qu'k + ½ α² Σ k'Quu k`` with ``c0 = Σ (s'd + ½ d'S d)`` over all defects
  (value function at the knot receiving the defect). The model's defects after the step are zero, so the
  expected merit change is ``ΔJ(α) - ρ ||d̄||_1``, negative with
  ``ρ = max(|ΔJ(0)|, |ΔJ(1)|) / ((1 - 0.2) ||d̄||_1) + 1`` (docs/settings.md). Armijo:
  ``φ(α) - φ(0) <= 0.1 (ΔJ(α) - ρ ||d̄||_1)``; steps are halved down to ``line_search_min_step``; a trial with
  a non-finite cost or defect is rejected; if every step fails, ``mu`` grows and the iteration is repeated.
* **Augmented Lagrangian** outer loop (Sec. III-B-2) for the switching constraints ``g_i(x_N) = 0``
  (Eq. (2)). Inequality constraints are relaxed-barrier costs inside the models; only their violation is
  reported.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import replace
from typing import Literal

import numpy as np

from cafe_mpc.core.buffers import ArrayLender, ArraySet
from cafe_mpc.core.interfaces import MultiPhaseProblem
from cafe_mpc.solver.kernels import (
    CHOLESKY_FAILED,
    backward_phase,
    linear_feedback_pass,
    rollout_knot_end,
    rollout_policy,
)
from cafe_mpc.solver.options import SolverOptions
from cafe_mpc.solver.results import (
    PhaseSolution,
    SolverResult,
    SolverStatistics,
    SolveStatus,
    SweepOutcome,
    TrajectoryEvaluation,
    TrajectoryTotals,
)
from cafe_mpc.solver.workspace import EMPTY_CONTROL, PhaseWorkspace, Workspace


class _Run:
    """The state of one ``solve`` (or ``prepare``) between its steps."""

    __slots__ = (
        "budget_start",
        "inner_converged",
        "last_backward_time",
        "last_iteration_time",
        "last_line_search_time",
        "nominal",
        "pending_step",
        "policy_valid",
        "start",
        "statistics",
        "status",
    )

    def __init__(self, start: float, statistics: SolverStatistics, nominal: TrajectoryTotals) -> None:
        self.start = start
        self.budget_start = start
        """Where ``SolverOptions.time_budget`` counts from (``solve``'s ``budget_start``)."""
        self.statistics = statistics
        self.nominal = nominal
        self.status = SolveStatus.MAX_ITERATIONS
        self.inner_converged = False
        self.policy_valid = False
        """The workspace's policy is the sweep's at the nominal (or its shift to it)."""
        self.last_iteration_time = 0.0
        self.last_backward_time = 0.0
        self.last_line_search_time = 0.0
        self.pending_step: float | None = None
        """The step of the last accepted iteration while the derivatives are not yet those at its result (the
        linearisation is deferred to the next iteration, or replaced by a shift: ``final_policy``)."""


class MSiLQRSolver:
    """Multi-phase MS-iLQR with augmented Lagrangian for switching constraints (paper Sec. III).

    Create once and call ``solve`` repeatedly; the per-knot workspace is kept between solves and reused for
    phases built from the same model objects.
    """

    def __init__(self, options: SolverOptions | None = None) -> None:
        self.options = options if options is not None else SolverOptions()
        self.workspace: Workspace | None = None
        self._regularization = self.options.regularization_initial
        self._merit_weight = 0.0
        # Backward-sweep sums of the expected cost change ΔJ(α) = c0 + α g + ½ α² h.
        self._expected_constant = 0.0
        self._expected_linear = 0.0
        self._expected_quadratic = 0.0
        self._sums = np.zeros(4)  # sums of the compiled backward sweep (``backward_phase``)
        self._lender = ArrayLender()
        """The buffers of the results' trajectories (``SolverOptions.lend_results``)."""
        self._feedback_lender = ArrayLender()
        """The buffers of the feedbacks' trajectories (``SolverOptions.lend_results``)."""

    # ---------------------------------------------------------------------------------------------- public
    def solve(
        self,
        problem: MultiPhaseProblem,
        initial_xs: Sequence[np.ndarray | None] | None = None,
        initial_us: Sequence[np.ndarray | None] | None = None,
        rollout_knots: Sequence[object] | None = None,
        *,
        initial_multipliers: Sequence[np.ndarray | None] | None = None,
        initial_penalties: Sequence[float | None] | None = None,
        budget_start: float | None = None,
    ) -> SolverResult:
        """Solve ``problem`` from a (possibly infeasible) initial guess.

        ``initial_xs``/``initial_us``: one entry per phase, ``(N_i + 1, nx_i)`` states and ``(N_i, nu_i)``
        controls; an entry (or the whole argument) may be ``None``: missing controls are zeros, a phase
        without states is seeded by simulating the dynamics from its start. The first state is always
        replaced by ``problem.x0``.
        ``rollout_knots``: one entry per phase, either a boolean mask of length ``N_i + 1``, a collection of
        knot indices or ``None`` (no roll-out knot). Roll-out states (set ``M~``) are overwritten by
        simulating ``f`` (or the reset map for index 0) during initialisation and in every forward sweep
        (Eq. (13)); the others are shooting states (set ``M``). Default: every knot is a roll-out knot
        when ``initial_xs`` is ``None`` (single shooting), otherwise none is.
        ``initial_multipliers``/``initial_penalties``: augmented-Lagrangian parameters per phase (warm start
        of the AL loop; ``None`` entries use ``0`` and ``options.al_initial_penalty``).
        ``budget_start``: the ``time.perf_counter()`` instant ``options.time_budget`` counts from (default:
        this call), so that a caller's own work before the solve (an MPC's problem build) is inside it.

        The steps: evaluate and linearise the guess; per augmented-Lagrangian iteration up to
        ``max_iterations`` MS-iLQR iterations (``backward``, then a line search of ``try_step`` trials), then
        the multiplier update; last the policy at the returned trajectory (``final_policy``).

        Raises ``ValueError`` when the initial guess has the wrong shapes or a non-finite cost or defect.
        """
        options = self.options
        run = self._start(
            problem, initial_xs, initial_us, rollout_knots, initial_multipliers, initial_penalties
        )
        if budget_start is not None:
            run.budget_start = budget_start
        for al_iteration in range(options.max_al_iterations):
            run.statistics.al_iterations = al_iteration + 1
            self._iterate(run)
            if run.status in (SolveStatus.REGULARIZATION_LIMIT, SolveStatus.NON_FINITE):
                break
            # Also after the last AL iteration and when the wall-clock budget ran out: the parameters
            # warm-start the next (MPC) solve (skipping it on a budget stop froze the touchdown multipliers).
            if not self._update_multipliers(run) or run.status == SolveStatus.TIME_BUDGET:
                break
        return self._finish(run, options.final_backward_pass)

    def prepare(
        self,
        problem: MultiPhaseProblem,
        initial_xs: Sequence[np.ndarray | None] | None = None,
        initial_us: Sequence[np.ndarray | None] | None = None,
        rollout_knots: Sequence[object] | None = None,
        *,
        initial_multipliers: Sequence[np.ndarray | None] | None = None,
        initial_penalties: Sequence[float | None] | None = None,
    ) -> SolverResult:
        """The preparation phase of the real-time iteration: the policy at the initial guess, no step.

        Evaluates and linearises the guess (arguments as ``solve``'s), updates the augmented-Lagrangian
        parameters where a switching constraint is violated (once per ``max_al_iterations``), and sweeps
        backward there (Eqs. (7)-(10), (16)): the result is the guess with its policy (``K``, ``k``, ``Qu``,
        ``Quu``, ``Qux``), what ``feedback`` embeds a measured state into (with ``feedforward=1`` it takes
        the prepared step). The same as ``solve`` with ``max_iterations=0``, whatever ``max_iterations``
        and ``final_backward_pass`` say.
        """
        options = self.options
        run = self._start(
            problem, initial_xs, initial_us, rollout_knots, initial_multipliers, initial_penalties
        )
        for al_iteration in range(options.max_al_iterations):
            run.statistics.al_iterations = al_iteration + 1
            if not self._update_multipliers(run):
                break
        return self._finish(run, final_backward_pass=True)

    def linearize(self) -> None:
        """Derivatives at the nominal trajectory of the current problem (the last ``solve``'s or
        ``prepare``'s): the cost derivatives, ``[A_k | B_k]`` of every running knot and the reset Jacobians,
        in the tangent spaces at the nominal states (the inputs of Eq. (8)).

        The knots' data must hold the nominal's evaluation; after a ``try_step`` that was not accepted (or a
        nonlinear ``feedback``) they hold another point's (``RuntimeError``)."""
        workspace = self._current_workspace()
        if workspace.data_off_nominal:
            raise RuntimeError(
                "the knots' data are not at the nominal (a trial step or a nonlinear feedback)"
            )
        self._linearize(workspace)

    def backward(self, statistics: SolverStatistics | None = None) -> SweepOutcome:
        """The backward sweep at the last linearisation (Eqs. (7)-(10) with the defect terms, Eq. (16) across
        reset maps, ``mu I`` added to ``Quu``): the policy ``K``, ``k`` and ``Qu``, ``Quu``, ``Qux`` in the
        workspace, and the model of the cost change a step makes (the line search's). After a failed
        Cholesky factorisation ``mu`` grows and the sweep restarts (counted in ``statistics``).

        Returns ``OK``, ``REGULARIZATION_LIMIT`` (``mu`` passed ``regularization_max``) or ``NON_FINITE``."""
        return self._backward_pass_with_regularization(self._current_workspace(), statistics)

    def feedback(
        self,
        prepared: SolverResult,
        x0: np.ndarray,
        feedforward: float = 0.0,
        rollout: Literal["linear", "nonlinear"] = "linear",
    ) -> SolverResult:
        """The feedback phase of the real-time iteration: embed a measured initial state into a prepared
        solution through its policy (paper Eqs. (11)-(13)).

        ``prepared`` is the result of the last ``prepare`` (or ``solve``) of this solver (its workspace
        still holds the linearisation ``A``, ``B`` and reset Jacobians the policy was computed from). From
        ``dx_0 = x0 ⊖ xs_0``: ``du_k = a k_k + K_k dx_k``, ``u'_k = us_k + du_k`` and, with
        ``rollout = "linear"``, ``dx_{k+1} = A_k dx_k + B_k du_k + a d_{k+1}`` (across a reset
        ``dx_0 = P dx_N + a d_0``) and ``x'_k = xs_k ⊕ dx_k`` (the tangential predictor of the real-time
        iteration: matrix products only); with ``"nonlinear"``, ``x'_{k+1} = f(x'_k, u'_k)`` and the reset
        maps themselves (one model evaluation per knot). ``a = feedforward``: 0 when the preparation already
        took its step (the solution's remaining feed-forward is then ``(1 - step) k``, not applied again), 1
        to take the prepared Newton step here (after ``prepare``). With ``x0`` equal to ``xs_0`` and
        ``a = 0`` the result is the prepared solution. The returned policy is the prepared one moved to the
        new trajectory to first order: ``K``, ``Quu``, ``Qux`` unchanged, ``Qu`` and ``k`` scaled by
        ``1 - a`` (as ``final_policy = "shift"`` does).
        """
        workspace = self.workspace
        if workspace is None or len(workspace.phases) != len(prepared.phases):
            raise ValueError("feedback needs the result of this solver's last prepare or solve")
        x0 = np.asarray(x0, dtype=float)
        first = workspace.phases[0]
        if x0.shape != (first.nx,):
            raise ValueError(f"x0 has shape {x0.shape}, the first phase's state needs ({first.nx},)")
        a = float(feedforward)
        nonlinear = rollout == "nonlinear"
        arrays = self._feedback_lender.take() if self.options.lend_results else None
        phases = []
        dx = first.difference(prepared.phases[0].xs[0], x0)
        previous: PhaseWorkspace | None = None
        previous_x_end: np.ndarray | None = None
        for i, (work, solution) in enumerate(zip(workspace.phases, prepared.phases, strict=True)):
            xs, us, K, kff = solution.xs, solution.us, solution.K, solution.k
            n = len(us)
            out_x = _empty_like(xs, arrays, ("feedback xs", i))
            out_u = _empty_like(us, arrays, ("feedback us", i))
            if previous is None:
                out_x[0] = x0
            elif nonlinear:
                assert previous_x_end is not None
                previous.reset_map.calc(previous.reset_data, previous_x_end)
                out_x[0] = previous.reset_data.x_next
                dx = work.difference(xs[0], out_x[0])
            else:
                dx = previous.reset_jacobian @ dx + a * solution.defects[0]
                out_x[0] = work.integrate(xs[0], dx)
            if nonlinear:
                workspace.data_off_nominal = True
                for k in range(n):
                    du = a * kff[k] + K[k] @ dx
                    out_u[k] = us[k] + du
                    model, data = work.models[k], work.running_data[k]
                    model.calc(data, out_x[k], out_u[k])
                    out_x[k + 1] = data.x_next
                    dx = work.difference(xs[k + 1], out_x[k + 1])
            else:
                ndx = dx.shape[0]
                dxs = (
                    np.empty((n + 1, ndx))
                    if arrays is None
                    else arrays.rows(("feedback dxs", i), n + 1, (ndx,))
                )
                linear_feedback_pass(dx, us, K, kff, work.A, work.B, solution.defects, a, dxs, out_u)
                work.state.integrate_rows_into(xs[1:], dxs[1:], out_x[1:])
                dx = dxs[-1]
            previous, previous_x_end = work, out_x[-1]
            if a == 0.0:  # no step taken here: the feed-forward and Qu stay the prepared ones
                phases.append(replace(solution, xs=out_x, us=out_u))
            else:
                out_k = _empty_like(kff, arrays, ("feedback k", i))
                out_Qu = _empty_like(solution.Qu, arrays, ("feedback Qu", i))
                np.multiply(1.0 - a, kff, out=out_k)
                np.multiply(1.0 - a, solution.Qu, out=out_Qu)
                phases.append(replace(solution, xs=out_x, us=out_u, k=out_k, Qu=out_Qu))
        return replace(prepared, phases=phases)

    def evaluate(
        self, problem: MultiPhaseProblem, xs: Sequence[np.ndarray], us: Sequence[np.ndarray]
    ) -> TrajectoryEvaluation:
        """Cost, defects and constraint violations of the trajectory ``(xs, us)`` (no roll-out, no AL terms).

        ``xs[0][0]`` is used as given (not replaced by ``problem.x0``).
        """
        workspace = self._prepare_workspace(problem)
        seed_states = self._initialize(workspace, xs, us, None)
        for work in workspace.phases:
            work.multiplier[:] = 0.0
            work.penalty = 0.0
        totals = self._evaluate_nominal(workspace, np.asarray(xs[0][0], dtype=float), seed_states)
        return TrajectoryEvaluation(
            cost=totals.cost,
            defects=[work.defects.copy() for work in workspace.phases],
            defect_max=totals.defect_max,
            defect_l1=totals.defect_l1,
            switching_values=[
                work.switching_value.copy() if work.constraint is not None else None
                for work in workspace.phases
            ],
            switching_violation=totals.switching_violation,
            inequality_violation=totals.inequality_violation,
        )

    # ------------------------------------------------------------------------------------ steps of a solve
    def _start(
        self,
        problem: MultiPhaseProblem,
        initial_xs: Sequence[np.ndarray | None] | None,
        initial_us: Sequence[np.ndarray | None] | None,
        rollout_knots: Sequence[object] | None,
        initial_multipliers: Sequence[np.ndarray | None] | None,
        initial_penalties: Sequence[float | None] | None,
    ) -> _Run:
        """Set the guess (``solve``'s arguments), evaluate it (Eqs. (4), (13), (15)) and linearise it: the
        first linearisation fused with the evaluation (each knot's ``calc_diff`` right after its ``calc``,
        while its data are in the cache), except on a thread pool."""
        options = self.options
        start = time.perf_counter()
        workspace = self._prepare_workspace(problem)
        seed_states = self._initialize(workspace, initial_xs, initial_us, rollout_knots)
        self._initialize_augmented_lagrangian(workspace, initial_multipliers, initial_penalties)
        statistics = SolverStatistics()
        fused = options.threads == 1
        nominal = self._evaluate_nominal(workspace, problem.x0, seed_states, statistics if fused else None)
        if not nominal.finite():
            raise ValueError("the initial guess has a non-finite cost or defect")
        statistics.setup_time = time.perf_counter() - start - statistics.linearize_time
        if not fused:
            self._timed_linearize(statistics)
        self._regularization = options.regularization_initial
        return _Run(start, statistics, nominal)

    def _iterate(self, run: _Run) -> None:
        """Up to ``max_iterations`` MS-iLQR iterations, while the time budget lasts (an iteration is not
        started when the elapsed time plus the last iteration's would exceed it, with the final policy's
        linearisation and backward sweep when the result needs one; the first always runs)."""
        options = self.options
        run.inner_converged, run.status = False, SolveStatus.MAX_ITERATIONS
        reserve_final = options.final_backward_pass and options.final_policy == "relinearize"
        statistics = run.statistics
        budget = options.time_budget
        for _ in range(options.max_iterations):
            if budget is not None and statistics.iterations > 0:
                linearize = statistics.linearize_time / max(statistics.linearizations, 1)
                sweep = linearize + run.last_backward_time
                needed = sweep + run.last_line_search_time + (sweep if reserve_final else 0.0)
                if time.perf_counter() - run.budget_start + needed > budget:
                    run.status = SolveStatus.TIME_BUDGET
                    return
            if not self._iteration(run):
                return

    def _iteration(self, run: _Run) -> bool:
        """One MS-iLQR iteration: the deferred linearisation, the backward sweep, the convergence test, the
        line search and the regularisation's update. Returns whether the inner loop goes on."""
        options, statistics = self.options, run.statistics
        iteration_start = time.perf_counter()
        if run.pending_step is not None:
            self._timed_linearize(statistics)
            run.pending_step = None
        clock = time.perf_counter()
        outcome = self._timed_backward(statistics)
        run.last_backward_time = time.perf_counter() - clock
        run.policy_valid = outcome == SweepOutcome.OK
        if not run.policy_valid:
            run.status = SolveStatus(outcome.value)
            return False
        decrease = -(self._expected_linear + 0.5 * self._expected_quadratic)
        nominal = run.nominal
        if nominal.defect_max <= options.defect_tolerance and decrease <= options.expected_decrease_tolerance:
            run.inner_converged, run.status = True, SolveStatus.CONVERGED
            return False
        regularization = self._regularization
        clock = time.perf_counter()
        trial, alpha, n_trials, mode = self._line_search(nominal)
        run.last_line_search_time = time.perf_counter() - clock
        statistics.line_search_time += run.last_line_search_time
        cost_change = math.inf
        if trial is not None:
            cost_change = trial.augmented_cost - nominal.augmented_cost
            self._accept_trial()
            run.nominal = trial
            run.pending_step = alpha
            run.policy_valid = False
            self._regularization = max(
                regularization / options.regularization_decrease, options.regularization_min
            )
        run.last_iteration_time = time.perf_counter() - iteration_start
        self._record(
            statistics, run.nominal, regularization, decrease, alpha, n_trials, mode, run.last_iteration_time
        )
        if trial is None:
            if not self._increase_regularization():
                run.status = SolveStatus.REGULARIZATION_LIMIT
                return False
        elif (
            run.nominal.defect_max <= options.defect_tolerance
            and abs(cost_change) <= options.cost_change_tolerance
        ):
            run.inner_converged, run.status = True, SolveStatus.CONVERGED
            return False
        return True

    def _update_multipliers(self, run: _Run) -> bool:
        """The augmented-Lagrangian update (``_update_augmented_lagrangian``) unless every switching
        constraint meets ``switching_tolerance``; returns whether it was made (the policy is then stale)."""
        if run.nominal.switching_violation <= self.options.switching_tolerance:
            return False
        workspace = self._current_workspace()
        self._update_augmented_lagrangian(workspace)
        run.nominal = self._totals_from_nominal(workspace, run.nominal)
        run.policy_valid = False
        return True

    def _finish(self, run: _Run, final_backward_pass: bool) -> SolverResult:
        """The policy at the returned trajectory (``final_backward_pass``, ``final_policy``), the status and
        the result."""
        options, statistics = self.options, run.statistics
        workspace = self._current_workspace()
        if final_backward_pass and not run.policy_valid and run.status != SolveStatus.NON_FINITE:
            if run.pending_step is not None and options.final_policy == "shift":
                self._shift_policy(run.pending_step)
                run.policy_valid = True
            else:
                if run.pending_step is not None:
                    self._timed_linearize(statistics)
                run.policy_valid = self._timed_backward(statistics) == SweepOutcome.OK
        converged = run.inner_converged and run.nominal.switching_violation <= options.switching_tolerance
        status = run.status
        if status == SolveStatus.CONVERGED and not converged:
            status = SolveStatus.MAX_ITERATIONS
        statistics.solve_time = time.perf_counter() - run.start
        if workspace.data_off_nominal:
            self._recalc_running(workspace)
        return self._make_result(
            workspace,
            run.nominal,
            converged,
            status,
            statistics,
            run.policy_valid,
            options.keep_value_function,
            options.copy_policy,
            self._lender.take() if options.lend_results else None,
        )

    def _shift_policy(self, step: float) -> None:
        """Move the last sweep's expansion point to the result of the step ``step`` it was taken with, to
        first order (``final_policy = "shift"``): ``Qu`` and ``k`` scaled by ``1 - step``."""
        for work in self._current_workspace().phases:
            work.Qu *= 1.0 - step
            work.k *= 1.0 - step

    def _timed_linearize(self, statistics: SolverStatistics) -> None:
        clock = time.perf_counter()
        self._linearize(self._current_workspace())
        statistics.linearize_time += time.perf_counter() - clock
        statistics.linearizations += 1

    def _timed_backward(self, statistics: SolverStatistics) -> SweepOutcome:
        clock = time.perf_counter()
        outcome = self._backward_pass_with_regularization(self._current_workspace(), statistics)
        statistics.backward_time += time.perf_counter() - clock
        return outcome

    def _current_workspace(self) -> Workspace:
        """The workspace of the current problem (``RuntimeError`` before the first ``solve``/``prepare``)."""
        workspace = self.workspace
        if workspace is None or workspace.problem is None:
            raise RuntimeError("no problem yet: call solve or prepare first")
        return workspace

    # ---------------------------------------------------------------------------------------------- set-up
    def _prepare_workspace(self, problem: MultiPhaseProblem) -> Workspace:
        if self.workspace is None:
            self.workspace = Workspace()
        self.workspace.setup(problem)
        return self.workspace

    def _initialize(
        self,
        workspace: Workspace,
        initial_xs: Sequence[np.ndarray | None] | None,
        initial_us: Sequence[np.ndarray | None] | None,
        rollout_knots: Sequence[object] | None,
    ) -> list[np.ndarray]:
        """Copy the guess into the workspace; return per phase the states the initial roll-out overwrites."""
        n_phases = len(workspace.phases)
        for name, guess in (("initial_xs", initial_xs), ("initial_us", initial_us)):
            if guess is not None and len(guess) != n_phases:
                raise ValueError(f"{name} has {len(guess)} entries for {n_phases} phases")
        workspace.set_rollout_knots(rollout_knots, default=initial_xs is None)
        seed_states: list[np.ndarray] = []
        for i, work in enumerate(workspace.phases):
            us_guess = None if initial_us is None else initial_us[i]
            if us_guess is None:
                work.us[:] = 0.0
            else:
                us_array = np.asarray(us_guess, dtype=float).reshape(work.horizon, work.nu)
                work.us[:] = us_array
            xs_guess = None if initial_xs is None else initial_xs[i]
            if xs_guess is None:
                seed_states.append(np.ones(work.horizon + 1, dtype=bool))
                work.xs[:] = 0.0
            else:
                xs_array = np.asarray(xs_guess, dtype=float)
                if xs_array.shape != work.xs.shape:
                    raise ValueError(
                        f"phase {i}: initial states have shape {xs_array.shape}, need {work.xs.shape}"
                    )
                work.xs[:] = xs_array
                seed_states.append(work.rollout)
        return seed_states

    def _initialize_augmented_lagrangian(
        self,
        workspace: Workspace,
        initial_multipliers: Sequence[np.ndarray | None] | None,
        initial_penalties: Sequence[float | None] | None,
    ) -> None:
        for i, work in enumerate(workspace.phases):
            multiplier = None if initial_multipliers is None else initial_multipliers[i]
            penalty = None if initial_penalties is None else initial_penalties[i]
            work.multiplier[:] = 0.0 if multiplier is None else np.asarray(multiplier, dtype=float)
            work.penalty = self.options.al_initial_penalty if penalty is None else float(penalty)

    # ------------------------------------------------------------------------ evaluation and linearisation
    def _evaluate_nominal(
        self,
        workspace: Workspace,
        x0: np.ndarray,
        seed_states: list[np.ndarray],
        linearize: SolverStatistics | None = None,
    ) -> TrajectoryTotals:
        """Evaluate cost, defects (Eqs. (4), (15)) and switching constraints of the nominal trajectory.

        States flagged in ``seed_states`` are overwritten by simulating the dynamics (roll-out, Eq. (13)); the
        first state of the first phase is set to ``x0``. With ``linearize`` (the solve's statistics, which
        get the time it took) every knot is also linearised right after its evaluation, as ``_linearize``
        does (same results, the knot's data still in the cache).
        """
        totals = TrajectoryTotals()
        previous: PhaseWorkspace | None = None
        clock = time.perf_counter
        linearize_time = 0.0
        for work, seed in zip(workspace.phases, seed_states, strict=True):
            xs, us, defects = work.xs, work.us, work.defects
            if previous is None:
                xs[0] = x0
                defects[0] = 0.0
            else:
                reset_state = previous.reset_data.x_next
                if seed[0]:
                    xs[0] = reset_state
                    defects[0] = 0.0
                else:
                    work.difference_into(xs[0], reset_state, defects[0])
                if linearize is not None:
                    started = clock()
                    work.transport(xs[0], reset_state, previous.reset_data.Px, previous.reset_jacobian)
                    linearize_time += clock() - started
            F, transport = work.F, work.transport_stacked
            for k, (model, data) in enumerate(zip(work.models, work.running_data, strict=True)):
                model.calc(data, xs[k], us[k])
                totals.cost += data.cost
                if data.constraint_violation > totals.inequality_violation:
                    totals.inequality_violation = data.constraint_violation
                if seed[k + 1]:
                    xs[k + 1] = data.x_next
                    defects[k + 1] = 0.0
                else:
                    work.difference_into(xs[k + 1], data.x_next, defects[k + 1])
                if linearize is not None and math.isfinite(data.cost):
                    started = clock()
                    model.calc_diff(data, xs[k], us[k])
                    transport(xs[k + 1], data.x_next, data.Fx, data.Fu, F[k])  # [A_k | B_k]
                    linearize_time += clock() - started
            self._evaluate_phase_end(work, xs[-1], work.switching_value, totals)
            if linearize is not None and math.isfinite(totals.cost):
                started = clock()
                work.terminal_model.calc_diff(work.terminal_data, xs[-1], EMPTY_CONTROL)
                if work.constraint is not None:
                    work.constraint.calc_diff(work.constraint_data, xs[-1])
                if work.reset_map is not None:
                    work.reset_map.calc_diff(work.reset_data, xs[-1])
                linearize_time += clock() - started
            previous = work
        if linearize is not None:
            linearize.linearize_time += linearize_time
            linearize.linearizations += 1
        workspace.data_off_nominal = False
        self._sum_defects(workspace, totals, trial=False)
        totals.augmented_cost += totals.cost
        return totals

    @staticmethod
    def _evaluate_phase_end(
        work: PhaseWorkspace, x_end: np.ndarray, switching_out: np.ndarray, totals: TrajectoryTotals
    ) -> None:
        """Terminal cost, switching constraint (with its augmented-Lagrangian terms) and reset map."""
        data = work.terminal_data
        work.terminal_model.calc(data, x_end, EMPTY_CONTROL)
        totals.cost += data.cost
        if data.constraint_violation > totals.inequality_violation:
            totals.inequality_violation = data.constraint_violation
        if work.constraint is not None:
            constraint_data = work.constraint_data
            work.constraint.calc(constraint_data, x_end)
            value = constraint_data.value
            switching_out[:] = value
            totals.augmented_cost += float(work.multiplier @ value) + 0.5 * work.penalty * float(
                value @ value
            )
            if value.size:
                totals.switching_violation = max(totals.switching_violation, float(np.max(np.abs(value))))
        if work.reset_map is not None:
            work.reset_map.calc(work.reset_data, x_end)

    @staticmethod
    def _sum_defects(workspace: Workspace, totals: TrajectoryTotals, trial: bool) -> None:
        for work in workspace.phases:
            magnitudes = np.abs(work.defects_try if trial else work.defects, out=work.magnitudes)
            if magnitudes.size:
                totals.defect_l1 += float(magnitudes.sum())
                totals.defect_max = max(totals.defect_max, float(magnitudes.max()))

    @staticmethod
    def _augmented_lagrangian_terms(workspace: Workspace) -> float:
        total = 0.0
        for work in workspace.phases:
            if work.constraint is not None:
                value = work.switching_value
                total += float(work.multiplier @ value) + 0.5 * work.penalty * float(value @ value)
        return total

    def _totals_from_nominal(self, workspace: Workspace, nominal: TrajectoryTotals) -> TrajectoryTotals:
        """The nominal totals after the augmented-Lagrangian parameters changed."""
        nominal.augmented_cost = nominal.cost + self._augmented_lagrangian_terms(workspace)
        return nominal

    def _linearize(self, workspace: Workspace) -> None:
        """Derivatives at the nominal trajectory; ``A``, ``B`` and the reset Jacobian in the tangent spaces.

        ``A = J Fx`` and ``B = J Fu`` with ``J = ∂(y ⊖ x̄_{k+1})/∂y`` at ``y = f(x̄_k, ū_k)``: a perturbation
        of the knot then maps to a perturbation of the *next nominal state* (identity on Euclidean states).
        The cost derivatives land directly in the phase's stacked arrays (the data are bound to them).
        The models' ``calc`` ran last at the nominal trajectory (initial evaluation or accepted trial).
        With ``options.threads > 1`` the running knots go to a thread pool in contiguous blocks.
        """
        phases = workspace.phases
        threads = self.options.threads
        pending = []
        if threads > 1:
            pool = self._thread_pool()
            for work in phases:
                n_knots = work.horizon
                block = -(-n_knots // threads)
                for first in range(block, n_knots, block):
                    pending.append(pool.submit(_linearize_knots, work, first, min(first + block, n_knots)))
        try:
            for i, work in enumerate(phases):
                _linearize_knots(work, 0, -(-work.horizon // threads) if threads > 1 else work.horizon)
                xs = work.xs
                work.terminal_model.calc_diff(work.terminal_data, xs[-1], EMPTY_CONTROL)
                if work.constraint is not None:
                    work.constraint.calc_diff(work.constraint_data, xs[-1])
                if work.reset_map is not None:
                    reset_data = work.reset_data
                    work.reset_map.calc_diff(reset_data, xs[-1])
                    following = phases[i + 1]
                    following.transport(
                        following.xs[0], reset_data.x_next, reset_data.Px, work.reset_jacobian
                    )
        finally:
            for future in pending:  # every block done (and its error raised) before the data are read
                future.result()

    def _thread_pool(self):
        """The solver's linearisation pool (``options.threads - 1`` workers; the caller's thread is one)."""
        pool = getattr(self, "_pool", None)
        if pool is None:
            from concurrent.futures import ThreadPoolExecutor

            pool = ThreadPoolExecutor(max_workers=self.options.threads - 1, thread_name_prefix="ms-ilqr")
            self._pool = pool
        return pool

    # -------------------------------------------------------------------------------------- backward sweep
    def _backward_pass_with_regularization(
        self, workspace: Workspace, stats: SolverStatistics | None
    ) -> SweepOutcome:
        """Run the backward sweep, raising ``mu`` after each failed Cholesky factorisation (counted in
        ``stats``, if given).

        Returns ``OK``, ``REGULARIZATION_LIMIT`` or ``NON_FINITE``.
        """
        while True:
            outcome = self._backward_pass(workspace)
            if outcome != SweepOutcome.CHOLESKY:
                return outcome
            if stats is not None:
                stats.backward_failures += 1
            if not self._increase_regularization():
                return SweepOutcome.REGULARIZATION_LIMIT

    def _backward_pass(self, workspace: Workspace) -> SweepOutcome:
        """Riccati-like sweep of Eqs. (8)-(10) with defects, and Eq. (16) across reset maps (Gauss-Newton).

        Also accumulates the quadratic model of the cost change along the step (see the module docstring).
        Returns ``OK``, ``CHOLESKY`` (``Quu + mu I`` not positive definite) or ``NON_FINITE``.
        """
        mu = self._regularization
        constant = 0.0
        sums = self._sums
        sums[:] = 0.0
        following: PhaseWorkspace | None = None
        for work in reversed(workspace.phases):
            n_knots = work.horizon
            S, s, defects, rollout = work.S, work.s, work.defects, work.rollout
            # Boundary condition (10), plus the augmented-Lagrangian terms of the switching constraint (2).
            S_end, s_end = S[n_knots], s[n_knots]
            s_end[:] = work.terminal_data.Lx
            S_end[:] = work.terminal_data.Lxx
            if work.constraint is not None:
                jacobian = work.constraint_data.Hx
                s_end += jacobian.T @ (work.multiplier + work.penalty * work.switching_value)
                product = np.matmul(jacobian.T, jacobian, out=work.kept("switching Hessian", S_end.shape))
                product *= work.penalty
                S_end += product
            if following is not None:
                # Eq. (16): value function across the reset map (second-order term of (16c) dropped).
                S0, s0 = following.S[0], following.s[0]
                if following.rollout[0]:
                    s_hat = s0
                else:
                    defect = following.defects[0]
                    S_defect = S0 @ defect
                    s_hat = s0 + S_defect
                    constant += float(s0 @ defect) + 0.5 * float(defect @ S_defect)
                P = work.reset_jacobian
                s_end += P.T @ s_hat
                S0_P = np.matmul(S0, P, out=work.kept("S0 P", P.shape))
                S_end += np.matmul(P.T, S0_P, out=work.kept("P' S0 P", S_end.shape))
            status = backward_phase(
                S,
                s,
                work.F,
                work.G,
                work.H,
                defects,
                rollout,
                mu,
                work.K,
                work.k,
                work.Qu,
                work.Quu,
                work.Qux,
                sums,
                work.rhs,
                work.cholesky,
                work.SF,
                work.Q,
                work.q,
                work.s_hat,
                work.gains,
            )
            if status == CHOLESKY_FAILED:
                if not (np.isfinite(work.Quu).all() and np.isfinite(S[n_knots]).all()):
                    return SweepOutcome.NON_FINITE
                return SweepOutcome.CHOLESKY
            following = work
        constant += float(sums[0])
        linear, quadratic = float(sums[1]), float(sums[2])
        check = constant + linear + quadratic + float(sums[3])  # sums[3]: s[0], S[0] of the first phase
        if not math.isfinite(check):
            return SweepOutcome.NON_FINITE
        self._expected_constant = constant
        self._expected_linear = linear
        self._expected_quadratic = quadratic
        return SweepOutcome.OK

    def _increase_regularization(self) -> bool:
        options = self.options
        self._regularization = max(
            self._regularization * options.regularization_increase, options.regularization_failure_min
        )
        return self._regularization <= options.regularization_max

    # --------------------------------------------------------------------------------------- forward sweep
    def _line_search(self, nominal: TrajectoryTotals) -> tuple[TrajectoryTotals | None, float, int, str]:
        """Backtracking on the merit ``J + ρ ||d||_1`` with the Armijo test (see the module docstring).

        Infeasible nominal: the hybrid roll-out of Eqs. (12)-(13) first; if it fails the test, the same step
        with the nonlinear roll-out on every knot (a second-order correction that removes the linearisation
        remainders, the Maratos effect of the L1 merit). Feasible nominal (max defect <=
        ``defect_tolerance``): nonlinear roll-out only, so the trajectory stays feasible, with the cost-only
        Armijo test. Returns the accepted trial totals (``None`` if none), the step, the number of trials and
        the roll-out that was accepted (``"hybrid"``, ``"nonlinear"`` or ``""``).
        """
        options = self.options
        constant, linear, quadratic = self._expected_constant, self._expected_linear, self._expected_quadratic
        feasibility = nominal.defect_l1
        feasible = nominal.defect_max <= options.defect_tolerance or feasibility == 0.0
        if feasible:
            merit_weight = 0.0
        else:
            largest_change = max(abs(constant), abs(constant + linear + 0.5 * quadratic))
            merit_weight = largest_change / ((1.0 - options.merit_feasibility_weight) * feasibility) + 1.0
        self._merit_weight = merit_weight
        merit_nominal = nominal.augmented_cost + merit_weight * feasibility
        slack = 1e-13 * (1.0 + abs(merit_nominal))  # round-off allowance near convergence
        alpha, n_trials = 1.0, 0
        while alpha >= options.line_search_min_step:
            expected = (
                constant + alpha * linear + 0.5 * alpha * alpha * quadratic - merit_weight * feasibility
            )
            threshold = merit_nominal + options.armijo * min(expected, 0.0) + slack
            for nonlinear in (True,) if feasible else (False, True):
                n_trials += 1
                try:
                    trial = self.try_step(alpha, nonlinear)
                except (FloatingPointError, np.linalg.LinAlgError):
                    # A model that cannot evaluate the trial point (e.g. a singular contact KKT system far
                    # from the nominal) rejects the step like a non-finite cost does.
                    continue
                if trial.finite() and trial.augmented_cost + merit_weight * trial.defect_l1 <= threshold:
                    return trial, alpha, n_trials, "nonlinear" if nonlinear else "hybrid"
            alpha *= options.line_search_decrease
        return None, 0.0, n_trials, ""

    def try_step(self, alpha: float, nonlinear: bool = False) -> TrajectoryTotals:
        """The trial roll-out of the step ``alpha`` along the last backward sweep's policy (the line search's
        trial): the controls of Eq. (11), ``u' = ū + α k + K (x' ⊖ x̄)``; a shooting knot follows the
        linearised dynamics with the full defect (Eq. (12)), a roll-out knot the model (Eq. (13)); across a
        reset the same with the reset map and its defect (Eq. (15)). ``nonlinear``: every knot is a roll-out
        knot (Eq. (13) everywhere: no defects left). Writes the workspace's trial arrays (``xs_try``,
        ``us_try``, ``defects_try``) and returns their cost and feasibility; the nominal is unchanged (the
        knots' data then hold the trial's evaluation).

        Between two knots' ``calc`` one compiled call (``rollout_knot_end``) does the rest of the roll-out on
        manifolds with compiled operations; on others the workspace's Python equivalent.
        """
        workspace = self._current_workspace()
        workspace.data_off_nominal = True
        totals = TrajectoryTotals()
        previous: PhaseWorkspace | None = None
        dx_end = EMPTY_CONTROL
        for work in workspace.phases:
            xs, defects = work.xs, work.defects
            xs_try, us_try, defects_try = work.xs_try, work.us_try, work.defects_try
            rollout = work.all_rollout if nonlinear else work.rollout
            if previous is None:
                xs_try[0] = xs[0]
                defects_try[0] = 0.0
            else:
                reset_state = previous.reset_data.x_next
                if rollout[0]:
                    xs_try[0] = reset_state
                    defects_try[0] = 0.0
                else:
                    xs_try[0] = work.integrate(xs[0], previous.reset_jacobian @ dx_end + defects[0])
                    defects_try[0] = work.difference(xs_try[0], reset_state)
            operations = work.operations
            if operations is not None:
                integrate, difference = operations.integrate, operations.difference
            us, kff, K, F = work.us, work.k, work.K, work.F
            dx, du, step = work.dx, work.du, work.step
            if work.horizon:
                if operations is None:
                    work.rollout_policy(0, alpha)
                else:
                    rollout_policy(difference, 0, alpha, xs, xs_try, us, us_try, kff, K, dx, du)  # Eq. (11)
            cost, violation = totals.cost, totals.inequality_violation
            for k, (model, data) in enumerate(zip(work.models, work.running_data, strict=True)):
                model.calc(data, xs_try[k], us_try[k])
                cost += data.cost
                if data.constraint_violation > violation:
                    violation = data.constraint_violation
                if operations is None:
                    work.rollout_knot_end(k, alpha, data.x_next, rollout)
                else:  # Eqs. (12), (13), then (11) for knot k + 1
                    rollout_knot_end(
                        integrate, difference, k, alpha, data.x_next, rollout, xs, xs_try, us, us_try, kff,
                        K, F, defects, defects_try, dx, du, step,
                    )  # fmt: skip
            totals.cost, totals.inequality_violation = cost, violation
            dx_end = work.dx_end
            work.difference_into(xs[-1], xs_try[-1], dx_end)
            self._evaluate_phase_end(work, xs_try[-1], work.switching_value_try, totals)
            previous = work
            if not math.isfinite(totals.cost):
                break
        self._sum_defects(workspace, totals, trial=True)
        totals.augmented_cost += totals.cost
        return totals

    def _accept_trial(self) -> None:
        """Make the trial of the last ``try_step`` the nominal (no copies; the knots' data hold its
        evaluation)."""
        workspace = self._current_workspace()
        for work in workspace.phases:
            work.swap_trial()
        workspace.data_off_nominal = False

    # -------------------------------------------------------------------------------- augmented Lagrangian
    def _update_augmented_lagrangian(self, workspace: Workspace) -> None:
        """Outer update (authors' rule: sigma x5 while ``|g| > threshold``, else ``lambda += sigma g``)."""
        options = self.options
        for work in workspace.phases:
            if work.constraint is None or work.switching_value.size == 0:
                continue
            violation = float(np.max(np.abs(work.switching_value)))
            if violation > options.al_update_threshold:
                work.penalty = min(work.penalty * options.al_penalty_growth, options.al_max_penalty)
            else:
                work.multiplier += work.penalty * work.switching_value

    # ---------------------------------------------------------------------------------------------- output
    def _record(
        self,
        stats: SolverStatistics,
        nominal: TrajectoryTotals,
        regularization: float,
        decrease: float,
        alpha: float,
        n_trials: int,
        mode: str,
        duration: float,
    ) -> None:
        stats.iterations += 1
        stats.line_search_steps.append(n_trials)
        stats.step_sizes.append(alpha)
        stats.forward_modes.append(mode)
        stats.regularizations.append(regularization)
        stats.merit_weights.append(self._merit_weight)
        stats.expected_decreases.append(decrease)
        predicted = self._expected_constant + alpha * (
            self._expected_linear + 0.5 * alpha * self._expected_quadratic
        )
        stats.predicted_cost_changes.append(predicted if alpha > 0.0 else 0.0)
        stats.costs.append(nominal.cost)
        stats.defect_norms.append(nominal.defect_l1)
        stats.iteration_times.append(duration)
        self._log(stats, nominal, alpha)

    def _log(self, stats: SolverStatistics, nominal: TrajectoryTotals, alpha: float) -> None:
        if not self.options.verbose:
            return
        if stats.iterations == 1:
            print(
                f"{'it':>4} {'cost':>14} {'defect_l1':>10} {'expected':>10} {'step':>8} {'mu':>8} {'ms':>7}"
            )
        print(
            f"{stats.iterations:4d} {nominal.cost:14.7e} {nominal.defect_l1:10.3e} "
            f"{stats.expected_decreases[-1]:10.3e} {alpha:8.4f} {stats.regularizations[-1]:8.1e} "
            f"{1e3 * stats.iteration_times[-1]:7.2f}"
        )

    @staticmethod
    def _recalc_running(workspace: Workspace) -> None:
        """Evaluate the running knots at the nominal again (their data then describe the returned plan,
        e.g. its contact forces)."""
        for work in workspace.phases:
            xs, us = work.xs, work.us
            for k, (model, data) in enumerate(zip(work.models, work.running_data, strict=True)):
                model.calc(data, xs[k], us[k])

    @staticmethod
    def _make_result(
        workspace: Workspace,
        nominal: TrajectoryTotals,
        converged: bool,
        status: SolveStatus,
        stats: SolverStatistics,
        policy_valid: bool,
        keep_value_function: bool = True,
        copy_policy: bool = True,
        arrays: ArraySet | None = None,
    ) -> SolverResult:
        """The solution in the workspace as a result (``SolverOptions``: ``keep_value_function``,
        ``copy_policy``: without it the policy arrays are the workspace's own; ``arrays``: the lent buffers
        the trajectory is copied into, ``lend_results``)."""
        owned = np.copy if copy_policy else _same
        phases = []
        for i, work in enumerate(workspace.phases):
            has_constraint = work.constraint is not None
            if keep_value_function:
                S, s = work.S.copy(), work.s.copy()
            else:
                S, s = work.no_value_function
            phases.append(
                PhaseSolution(
                    xs=_copy(work.xs, arrays, ("xs", i)),
                    us=_copy(work.us, arrays, ("us", i)),
                    K=owned(work.K),
                    k=owned(work.k),
                    Qu=owned(work.Qu),
                    Quu=owned(work.Quu),
                    Qux=owned(work.Qux),
                    S=S,
                    s=s,
                    defects=_copy(work.defects, arrays, ("defects", i)),
                    rollout_knots=_copy(work.rollout, arrays, ("rollout", i)),
                    switching_value=_copy(work.switching_value, arrays, ("switching", i))
                    if has_constraint
                    else None,
                    multiplier=_copy(work.multiplier, arrays, ("multiplier", i)) if has_constraint else None,
                    penalty=work.penalty if has_constraint else None,
                    name=work.phase.name,
                    forces=_stacked_forces(work, arrays, ("forces", i)),
                )
            )
        return SolverResult(
            phases=phases,
            cost=nominal.cost,
            augmented_cost=nominal.augmented_cost,
            defect_max=nominal.defect_max,
            defect_l1=nominal.defect_l1,
            switching_violation=nominal.switching_violation,
            inequality_violation=nominal.inequality_violation,
            converged=converged,
            status=status,
            statistics=stats,
            policy_valid=policy_valid,
        )


def _same(array: np.ndarray) -> np.ndarray:
    """The array itself (the result borrows the workspace's: ``SolverOptions.copy_policy``)."""
    return array


def _empty_like(source: np.ndarray, arrays: ArraySet | None, key: tuple) -> np.ndarray:
    """An uninitialised array of ``source``'s shape and type: new, or rows lent by ``arrays``
    (``SolverOptions.lend_results``)."""
    if arrays is None:
        return np.empty_like(source)
    return arrays.rows(key, len(source), source.shape[1:], source.dtype)


def _copy(source: np.ndarray, arrays: ArraySet | None, key: tuple) -> np.ndarray:
    """A copy of ``source`` (``_empty_like``)."""
    if arrays is None:
        return source.copy()
    out = _empty_like(source, arrays, key)
    out[...] = source
    return out


def _linearize_knots(work: PhaseWorkspace, first: int, last: int) -> None:
    """``calc_diff`` of the running knots ``first..last-1`` of a phase and their ``[A_k | B_k]``."""
    xs, us, F = work.xs, work.us, work.F
    transport = work.transport_stacked
    models, datas = work.models, work.running_data
    for k in range(first, last):
        data = datas[k]
        models[k].calc_diff(data, xs[k], us[k])
        transport(xs[k + 1], data.x_next, data.Fx, data.Fu, F[k])  # [A_k | B_k]


def _stacked_forces(
    work: PhaseWorkspace, arrays: ArraySet | None = None, key: tuple = ()
) -> np.ndarray | None:
    """``data.forces`` of every running knot (model-defined layout), stacked (into rows lent by ``arrays``
    under ``key``, if given); ``None`` if the models have none."""
    datas = work.running_data
    if not datas or getattr(datas[0], "forces", None) is None:
        return None
    first = np.asarray(datas[0].forces)
    if arrays is None:
        out = np.empty((len(datas), *first.shape))
    else:
        out = arrays.rows(key, len(datas), first.shape)
    for k, data in enumerate(datas):
        out[k] = data.forces
    return out


def evaluate_trajectory(
    problem: MultiPhaseProblem, xs: Sequence[np.ndarray], us: Sequence[np.ndarray]
) -> TrajectoryEvaluation:
    """Total cost, defects (Eqs. (4), (15)), switching and inequality violations of ``(xs, us)``.

    Uses a fresh workspace (data objects are created for this call); for repeated evaluations of one problem
    use ``MSiLQRSolver.evaluate``, which reuses the solver's workspace.
    """
    return MSiLQRSolver().evaluate(problem, xs, us)
