"""What the MS-iLQR solver hands back: the plan, the local policy/Q-function per knot and statistics.

The solver's workspace is reused by the next solve: a result's trajectory arrays are copies (new arrays, or
rows of buffers the solver lends and writes again only once nothing refers to them,
``SolverOptions.lend_results``), and so is its policy unless it was solved with ``copy_policy=False``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np


class SolveStatus(StrEnum):
    """Why an MS-iLQR solve stopped (a ``str``: it compares, prints and serialises as its value)."""

    CONVERGED = "converged"
    """The inner loop met its tolerances and every switching constraint met ``switching_tolerance``."""
    MAX_ITERATIONS = "max_iterations"
    """The iteration limits ran out first."""
    TIME_BUDGET = "time_budget"
    """The wall-clock cap (``SolverOptions.time_budget``, the MPC's 0.9 x period) stopped it."""
    REGULARIZATION_LIMIT = "regularization_limit"
    """No step was accepted up to the largest regularisation."""
    NON_FINITE = "non_finite"
    """The backward sweep met a non-finite value."""


class SweepOutcome(StrEnum):
    """The result of a backward sweep (Eqs. (8)-(10), (16); ``MSiLQRSolver.backward``)."""

    OK = "ok"
    CHOLESKY = "cholesky"
    """``Quu + mu I`` was not positive definite (raise ``mu`` and sweep again)."""
    REGULARIZATION_LIMIT = "regularization_limit"
    NON_FINITE = "non_finite"


class TrajectoryTotals:
    """Cost and feasibility of one trajectory of a solve: the nominal, or a trial step
    (``MSiLQRSolver.try_step``).

    ``cost``: running and terminal costs (barrier terms included); ``augmented_cost``: plus the
    augmented-Lagrangian terms of the switching constraints (Eq. (2)); ``defect_l1``, ``defect_max``: the L1
    and max norms of all defects (Eqs. (4), (15)); ``inequality_violation``: the largest
    ``constraint_violation`` the models reported; ``switching_violation``: the largest ``|g_i|``.
    """

    __slots__ = (
        "augmented_cost",
        "cost",
        "defect_l1",
        "defect_max",
        "inequality_violation",
        "switching_violation",
    )

    def __init__(self) -> None:
        self.cost = 0.0
        self.augmented_cost = 0.0
        self.defect_l1 = 0.0
        self.defect_max = 0.0
        self.inequality_violation = 0.0
        self.switching_violation = 0.0

    def finite(self) -> bool:
        """Whether the augmented cost and the defects' norm are finite."""
        return math.isfinite(self.augmented_cost) and math.isfinite(self.defect_l1)


@dataclass
class PhaseSolution:
    """One phase of the solution (``N`` running knots, ``N + 1`` states).

    ``K[k]`` (``nu x ndx``) and ``k[k]`` (the feed-forward increment ``δũ`` of Eq. (7)) define the policy
    ``u = us[k] + K[k] (x ⊖ xs[k])`` around the plan (at convergence ``k ≈ 0``). ``Qu``, ``Quu``, ``Qux`` are
    the partials of the action-value function (Eq. (8)) at the returned trajectory. ``Quu`` is the
    *regularised* matrix ``Luu + B' S B + mu I`` that was factorised (Cholesky succeeded, so it is positive
    definite) and ``K = -Quu^-1 Qux``, ``k = -Quu^-1 Qu`` hold exactly with it; at convergence ``mu`` is
    tiny (see ``SolverStatistics.regularizations``). ``S[k]``, ``s[k]`` are the Hessian and gradient of the
    quadratic value-function model at state ``k`` (Eq. (9), (10), (16)), in the tangent space at ``xs[k]``;
    ``s[0]`` of the first phase is the gradient of the optimal cost with respect to ``x0`` (both empty when
    solved with ``SolverOptions.keep_value_function=False``).
    ``defects[k]`` is ``f(xs[k-1], us[k-1]) ⊖ xs[k]`` (Eq. (4)); ``defects[0]`` is the reset defect (Eq. (15),
    zero in the first phase). ``switching_value`` is ``g_i(xs[N])`` (Eq. (2)) and ``multiplier``/``penalty``
    the augmented-Lagrangian parameters after the solve (``None`` without a switching constraint).
    """

    xs: np.ndarray
    us: np.ndarray
    K: np.ndarray
    k: np.ndarray
    Qu: np.ndarray
    Quu: np.ndarray
    Qux: np.ndarray
    S: np.ndarray
    s: np.ndarray
    defects: np.ndarray
    rollout_knots: np.ndarray
    switching_value: np.ndarray | None = None
    multiplier: np.ndarray | None = None
    penalty: float | None = None
    name: str = ""
    forces: np.ndarray | None = None
    """Contact forces of every running knot at the returned trajectory, ``(N, ...)`` in the layout of the
    models' ``data.forces`` (whole-body knots: world-frame GRF per foot, ``(N, n_feet, 3)``, zero on swing
    feet); ``None`` when the models have no forces (SRB knots: the controls are the forces)."""


@dataclass
class SolverStatistics:
    """Per-iteration logs (one entry per inner iteration, over all AL iterations) and totals.

    ``line_search_steps[j]`` counts the trial roll-outs of iteration ``j``; ``step_sizes[j]`` is the accepted
    step (0.0 when none was accepted, then ``mu`` grows); ``forward_modes[j]`` says which roll-out was
    accepted (``"hybrid"``: Eqs. (12)-(13), ``"nonlinear"``: Eq. (13) on every knot, ``""``: none);
    ``regularizations[j]`` is the ``mu`` of the backward sweep; ``merit_weights[j]`` the ``rho`` of the merit;
    ``expected_decreases[j]`` the decrease ``0.5 sum Qu' Quu^-1 Qu`` promised by the full feed-forward step;
    ``predicted_cost_changes[j]`` the quadratic model's cost change for the accepted step (defect closure
    included); ``costs[j]``/``defect_norms[j]`` the cost and L1 defect norm after the iteration;
    ``iteration_times[j]`` its wall-clock duration in seconds. ``backward_failures`` counts failed Cholesky
    factorisations over the solve.
    """

    iterations: int = 0
    al_iterations: int = 0
    backward_failures: int = 0
    line_search_steps: list[int] = field(default_factory=list)
    step_sizes: list[float] = field(default_factory=list)
    forward_modes: list[str] = field(default_factory=list)
    regularizations: list[float] = field(default_factory=list)
    merit_weights: list[float] = field(default_factory=list)
    costs: list[float] = field(default_factory=list)
    defect_norms: list[float] = field(default_factory=list)
    expected_decreases: list[float] = field(default_factory=list)
    predicted_cost_changes: list[float] = field(default_factory=list)
    iteration_times: list[float] = field(default_factory=list)
    solve_time: float = 0.0
    setup_time: float = 0.0
    """Workspace set-up, initial guess and its evaluation (s)."""
    linearize_time: float = 0.0
    """Derivatives of every knot along the accepted trajectories (s)."""
    linearizations: int = 0
    """Linearisations of the whole trajectory (the first one, fused with the first evaluation, included)."""
    backward_time: float = 0.0
    """Backward sweeps, the final one included (s)."""
    line_search_time: float = 0.0
    """Forward roll-outs of the line searches (s)."""


@dataclass
class SolverResult:
    """The solution of a ``MultiPhaseProblem`` and how it was found.

    ``cost`` is the problem's cost (running + terminal, barrier terms included); ``augmented_cost`` adds the
    augmented-Lagrangian terms of the switching constraints. ``defect_max``/``defect_l1`` are the max-norm and
    the L1 norm of all defects (Eq. (4), (15)); ``switching_violation`` is the largest ``|g_i|``;
    ``inequality_violation`` the largest ``constraint_violation`` reported by the models. ``converged`` means
    the inner loop met its tolerances and every switching constraint met ``switching_tolerance``. ``status``
    says why the solve stopped (``SolveStatus``).
    ``policy_valid``: ``K``, ``k``, ``Qu``, ``Quu``, ``Qux``, ``S``, ``s`` come from a successful backward
    sweep at the returned trajectory (false only if that sweep failed or ``final_backward_pass`` is off).
    """

    phases: list[PhaseSolution]
    cost: float
    augmented_cost: float
    defect_max: float
    defect_l1: float
    switching_violation: float
    inequality_violation: float
    converged: bool
    status: SolveStatus
    statistics: SolverStatistics
    policy_valid: bool = True

    @property
    def xs(self) -> list[np.ndarray]:
        """States per phase (each ``(N_i + 1, nx_i)``)."""
        return [phase.xs for phase in self.phases]

    @property
    def us(self) -> list[np.ndarray]:
        """Controls per phase (each ``(N_i, nu_i)``)."""
        return [phase.us for phase in self.phases]

    @property
    def value_gradient(self) -> np.ndarray:
        """Gradient of the optimal cost with respect to the initial state (tangent space at ``x0``)."""
        if not len(self.phases[0].s):
            raise ValueError("this result has no value function (solved with keep_value_function=False)")
        return self.phases[0].s[0]


@dataclass
class TrajectoryEvaluation:
    """Cost and feasibility of a given trajectory (see ``evaluate_trajectory``)."""

    cost: float
    defects: list[np.ndarray]
    defect_max: float
    defect_l1: float
    switching_values: list[np.ndarray | None]
    switching_violation: float
    inequality_violation: float
