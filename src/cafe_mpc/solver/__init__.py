"""Generic multi-phase multiple-shooting iLQR (paper Sec. III): knows phases, knots and reset maps only."""

from cafe_mpc.solver.ms_ilqr import MSiLQRSolver, evaluate_trajectory
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
from cafe_mpc.solver.workspace import PhaseWorkspace, Workspace

__all__ = [
    "MSiLQRSolver",
    "PhaseSolution",
    "PhaseWorkspace",
    "SolveStatus",
    "SolverOptions",
    "SolverResult",
    "SolverStatistics",
    "SweepOutcome",
    "TrajectoryEvaluation",
    "TrajectoryTotals",
    "Workspace",
    "evaluate_trajectory",
]
