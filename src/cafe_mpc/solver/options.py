"""Settings of the MS-iLQR solver (paper Sec. III; published values and sources: docs/settings.md, "Solver").

The defaults are tuned for *accurate* offline solves (tight tolerances, many iterations, no time budget),
which is what the unit tests and trajectory optimisation need. ``SolverOptions.paper_mpc()`` and
``SolverOptions.paper_first_solve()`` return the published real-time settings.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Literal


@dataclass
class SolverOptions:
    """Every knob of ``MSiLQRSolver``.

    Iterations and stopping
        ``max_iterations``: inner MS-iLQR iterations per augmented-Lagrangian (AL) iteration (one iteration
        is a backward sweep plus a line search; a backward sweep that only detects convergence does not
        count). ``max_al_iterations``: outer AL iterations (Sec. III-B-2, bi-level).
        ``time_budget``: wall-clock seconds for the whole ``solve`` (``None``: unlimited; ``solve``'s
        ``budget_start`` may start it earlier). An iteration is not started when the elapsed time plus the
        duration of the previous iteration, and of its linearisation and backward sweep again when the final
        policy is relinearised, would exceed the budget (the first iteration always runs, and so does the
        final backward sweep).
        The inner loop has converged when the largest defect (max-norm, tangent space) is at most
        ``defect_tolerance`` and either the expected decrease of the feed-forward step
        ``0.5 * sum Qu' Quu^-1 Qu`` is at most ``expected_decrease_tolerance`` or an accepted step changed
        the cost by at most ``cost_change_tolerance``. The AL loop stops when every switching constraint
        satisfies ``max|g_i| <= switching_tolerance``. ``defect_tolerance`` also decides when the nominal
        counts as feasible (from then on the forward sweep rolls the nonlinear dynamics out on every knot).
        ``final_backward_pass``: after the last accepted step, run one more backward sweep so that the
        returned gains and Q-function partials belong to the returned trajectory (needed by the VWBC).
        ``final_policy``: how that policy is made. ``"relinearize"`` (default): linearise at the returned
        trajectory and sweep again. ``"shift"``: keep the sweep of the last iteration (``K``, ``Quu``,
        ``Qux``, ``S``, ``s`` of the linearisation the step was taken from) and move its expansion point to
        the returned trajectory to first order: the accepted step was ``du = alpha k + K dx``, so
        ``Qu + Quu du + Qux dx = (1 - alpha) Qu`` and the remaining feed-forward is ``(1 - alpha) k``. That is
        the real-time iteration's policy: it saves one linearisation and one sweep per solve (about a
        quarter of an MPC update); the augmented-Lagrangian update after the last iteration then reaches the
        policy only at the next solve. A linearisation deferred this way is done at the start of the next
        iteration, so multi-iteration solves do the same work as before.

    Threads
        ``threads``: the running knots' linearisation (``calc_diff`` and the transport to the next nominal's
        tangent space) is split over a pool of this many threads, each taking a contiguous block of every
        phase's knots; 1 (default): no pool. Knots never share data, so the blocks are independent, but
        Python threads run in parallel only while the code they run has released the GIL: the compiled
        kernels do (``nogil``), Pinocchio 4.0.0's Python bindings do not (no ``PyEval_SaveThread`` in
        them), so most of a knot's linearisation stays serial (BENCHMARKS.md measures the gain).

    Result
        ``keep_value_function``: copy the value function's quadratic model (``S``, ``s`` of Eq. (9)) into the
        result. An MPC hands the low level the policy and the Q-function pieces only; without the copies
        (``False``: empty ``S``, ``s``) a solve allocates a tenth of what it did (the ``S`` of a 63-knot
        running-roll problem are 0.65 MB).
        ``copy_policy``: the result owns copies of the policy and the Q-function pieces (``K``, ``k``,
        ``Qu``, ``Quu``, ``Qux``). ``False``: they are views of the solver's workspace, valid until its next
        solve, for a caller that copies what it keeps (an MPC's plan copies the whole-body part; the
        real-time iteration's feedback reads them before the next preparation). Saves about half a
        megabyte per running-roll update.
        ``lend_results``: the trajectory arrays of a result (``xs``, ``us``, ``defects``, the roll-out flags,
        ``forces``, switching values and multipliers) and those ``feedback`` makes (``xs``, ``us``, and the
        scaled ``k``, ``Qu``) are written into row buffers the solver lends (``core.buffers.ArrayLender``)
        instead of new arrays. A buffer is written again only once nothing refers to it (no result, array
        or view made of it is alive), so such a result, unlike a borrowed policy, stays valid for as long as
        it is kept; a caller that keeps many results at once gets new arrays. For a loop that keeps one or
        two results at a time (an MPC): no trajectory allocated per update.

    Regularisation (``mu * I`` added to ``Quu``, Eq. (8e))
        Starts at ``regularization_initial`` every solve. On a failed Cholesky factorisation or a failed
        line search ``mu <- max(mu * regularization_increase, regularization_failure_min)``; the solve gives
        up when ``mu > regularization_max``. After an accepted step
        ``mu <- max(mu / regularization_decrease, regularization_min)``. Use ``0`` for
        ``regularization_initial`` and ``regularization_min`` to solve an LQ problem exactly.

    Line search (merit ``cost + rho * ||defects||_1``, Armijo against the model's expected change)
        Steps ``1, line_search_decrease, line_search_decrease^2, ...`` down to ``line_search_min_step``;
        acceptance ``merit(alpha) - merit(0) <= armijo * expected_merit_change(alpha)``;
        ``rho = max|expected cost change| / ((1 - merit_feasibility_weight) * ||d||_1) + 1``.

    Augmented Lagrangian for switching constraints (Eq. (2))
        Terminal cost ``lambda' g + 0.5 sigma ||g||^2``; after each inner solve, per phase: if
        ``max|g| > al_update_threshold`` then ``sigma <- min(sigma * al_penalty_growth, al_max_penalty)``
        else ``lambda <- lambda + sigma g``. ``sigma`` starts at ``al_initial_penalty``.
    """

    max_iterations: int = 100
    max_al_iterations: int = 20
    time_budget: float | None = None

    cost_change_tolerance: float = 1e-10
    expected_decrease_tolerance: float = 1e-12
    defect_tolerance: float = 1e-9
    switching_tolerance: float = 1e-3

    regularization_initial: float = 1e-9
    regularization_min: float = 1e-9
    regularization_failure_min: float = 1e-3
    regularization_increase: float = 2.0
    regularization_decrease: float = 20.0
    regularization_max: float = 1e2

    line_search_decrease: float = 0.5
    line_search_min_step: float = 1e-3
    armijo: float = 0.1
    merit_feasibility_weight: float = 0.2

    al_initial_penalty: float = 20.0
    al_max_penalty: float = 1e4
    al_penalty_growth: float = 5.0
    al_update_threshold: float = 5e-3

    final_backward_pass: bool = True
    final_policy: Literal["relinearize", "shift"] = "relinearize"
    threads: int = 1
    keep_value_function: bool = True
    copy_policy: bool = True
    lend_results: bool = False
    verbose: bool = False

    def __post_init__(self) -> None:
        if self.max_iterations < 0 or self.max_al_iterations < 1:
            raise ValueError("max_iterations must be >= 0 and max_al_iterations >= 1")
        if not 0.0 < self.line_search_decrease < 1.0:
            raise ValueError("line_search_decrease must be in (0, 1)")
        if not 0.0 < self.line_search_min_step <= 1.0:
            raise ValueError("line_search_min_step must be in (0, 1]")
        if not 0.0 < self.armijo < 1.0:
            raise ValueError("armijo must be in (0, 1)")
        if not 0.0 <= self.merit_feasibility_weight < 1.0:
            raise ValueError("merit_feasibility_weight must be in [0, 1)")
        if self.regularization_min < 0 or self.regularization_initial < 0:
            raise ValueError("regularisation values must be non-negative")
        if self.regularization_increase <= 1.0 or self.regularization_decrease <= 1.0:
            raise ValueError("regularisation increase/decrease factors must be > 1")
        if self.final_policy not in ("relinearize", "shift"):
            raise ValueError(f"final_policy must be 'relinearize' or 'shift', got {self.final_policy!r}")
        if self.threads < 1:
            raise ValueError(f"threads must be >= 1, got {self.threads}")
        if self.time_budget is not None and self.time_budget <= 0:
            raise ValueError("time_budget must be positive (or None)")

    @classmethod
    def paper_first_solve(cls) -> SolverOptions:
        """Published settings of the first (cold) MPC solve: 10 inner x 20 AL iterations, thresholds
        1e-2/1e-3."""
        return cls(
            max_iterations=10,
            max_al_iterations=20,
            cost_change_tolerance=1e-2,
            expected_decrease_tolerance=1e-3,
            defect_tolerance=1e-3,
            switching_tolerance=1e-3,
            regularization_initial=1e-3,
            regularization_min=1e-3,
        )

    @classmethod
    def paper_mpc(cls, time_budget: float | None) -> SolverOptions:
        """Published in-loop settings: 4 iterations, one AL update, the wall-clock cap ``time_budget`` (the
        caller's: the paper's is 0.9 of the MPC period, 18 ms of 20 ms, which the run config resolves,
        ``MpcSettings.budget``; ``None``: no cap)."""
        return replace(
            cls.paper_first_solve(), max_iterations=4, max_al_iterations=1, time_budget=time_budget
        )
