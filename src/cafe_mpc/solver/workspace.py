"""Preallocated per-knot storage of the MS-iLQR solver.

A ``Workspace`` holds, for every phase of a ``MultiPhaseProblem``, the model data objects (created once per
knot with ``create_data()``), the nominal and trial trajectories, the defects, the tangent-space linearisation
and the backward-sweep results. The solver keeps its workspace between solves; a phase whose models are the
same objects as before keeps its data objects and arrays, so repeated solves of one problem allocate nothing
per knot.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import numpy as np

from cafe_mpc.core.interfaces import (
    ActionData,
    ConstraintData,
    EuclideanState,
    MultiPhaseProblem,
    Phase,
    ResetData,
    StateManifold,
)

EMPTY_CONTROL = np.zeros(0)
EMPTY_CONTROL.setflags(write=False)


class PhaseWorkspace:
    """Arrays of one phase (state-sized arrays are indexed ``0..N``, control-sized ones ``0..N-1``).

    ``defects[k + 1] = f(xs[k], us[k]) ⊖ xs[k + 1]`` lives in the tangent space at ``xs[k + 1]`` (Eq. (4));
    ``defects[0]`` is the reset defect ``P(x_N^prev) ⊖ xs[0]`` (Eq. (15)). ``A[k]``, ``B[k]`` map tangent
    perturbations at knot ``k`` to the tangent space at ``xs[k + 1]`` (the model's ``Fx``, ``Fu`` composed
    with the Jacobian of ``difference``), ``reset_jacobian`` does the same for the reset map.
    """

    def __init__(self, phase: Phase, has_next_phase: bool) -> None:
        models = phase.running_models
        self.phase = phase
        self.models = list(models)
        self.terminal_model = phase.terminal_model
        self.horizon = n_knots = len(models)
        self.state: StateManifold = phase.state
        # Exact type: a subclass may override difference/integrate (e.g. angle wrapping).
        self.euclidean = type(self.state) is EuclideanState
        nx, ndx = self.state.nx, self.state.ndx
        nu = models[0].nu
        for k, model in enumerate(models):
            if model.nu != nu:
                raise ValueError(
                    f"phase {phase.name!r}: knot {k} has nu={model.nu}, knot 0 has nu={nu}; "
                    "the solver needs one control dimension per phase"
                )
            if model.state.nx != nx or model.next_state.nx != nx:
                raise ValueError(f"phase {phase.name!r}: knot {k} changes nx inside a phase")
        self.nx, self.ndx, self.nu = nx, ndx, nu

        self.running_data: list[ActionData] = [model.create_data() for model in models]
        self.terminal_data: ActionData = phase.terminal_model.create_data()
        self.reset_map = phase.reset_map if has_next_phase else None
        self.reset_data: ResetData | None = (
            self.reset_map.create_data() if self.reset_map is not None else None
        )
        self.constraint = phase.switching_constraint
        self.constraint_data: ConstraintData | None = (
            self.constraint.create_data() if self.constraint is not None else None
        )
        ndx_next = self.reset_map.next_state.ndx if self.reset_map is not None else 0

        self.xs = np.zeros((n_knots + 1, nx))
        self.us = np.zeros((n_knots, nu))
        self.defects = np.zeros((n_knots + 1, ndx))
        self.xs_try = np.zeros_like(self.xs)
        self.us_try = np.zeros_like(self.us)
        self.defects_try = np.zeros_like(self.defects)
        self.rollout = np.zeros(n_knots + 1, dtype=bool)
        self.all_rollout = np.ones(n_knots + 1, dtype=bool)

        self.A = np.zeros((n_knots, ndx, ndx))
        self.B = np.zeros((n_knots, ndx, nu))
        self.reset_jacobian = np.zeros((ndx_next, ndx))

        self.K = np.zeros((n_knots, nu, ndx))
        self.k = np.zeros((n_knots, nu))
        self.Qu = np.zeros((n_knots, nu))
        self.Quu = np.zeros((n_knots, nu, nu))
        self.Qux = np.zeros((n_knots, nu, ndx))
        self.S = np.zeros((n_knots + 1, ndx, ndx))
        self.s = np.zeros((n_knots + 1, ndx))
        self.rhs = np.zeros((n_knots, nu, 1 + ndx))  # [Qu | Qux], solved with one Cholesky back-substitution

        dim = self.constraint.dim if self.constraint is not None else 0
        self.switching_value = np.zeros(dim)
        self.switching_value_try = np.zeros(dim)
        self.multiplier = np.zeros(dim)
        self.penalty = 0.0

    def matches(self, phase: Phase, has_next_phase: bool) -> bool:
        """Whether this workspace was built for exactly these model objects (so its data can be reused)."""
        reset_map = phase.reset_map if has_next_phase else None
        return (
            len(phase.running_models) == self.horizon
            and all(a is b for a, b in zip(phase.running_models, self.models, strict=True))
            and phase.terminal_model is self.terminal_model
            and reset_map is self.reset_map
            and phase.switching_constraint is self.constraint
        )

    def difference(self, x0: np.ndarray, x1: np.ndarray) -> np.ndarray:
        """``x1 ⊖ x0`` (a plain subtraction on Euclidean states)."""
        if self.euclidean:
            return x1 - x0
        return self.state.difference(x0, x1)

    def integrate(self, x: np.ndarray, dx: np.ndarray) -> np.ndarray:
        """``x ⊕ dx`` (a plain addition on Euclidean states)."""
        if self.euclidean:
            return x + dx
        return self.state.integrate(x, dx)

    def swap_trial(self) -> None:
        """Make the trial trajectory the nominal one (no copies)."""
        self.xs, self.xs_try = self.xs_try, self.xs
        self.us, self.us_try = self.us_try, self.us
        self.defects, self.defects_try = self.defects_try, self.defects
        self.switching_value, self.switching_value_try = self.switching_value_try, self.switching_value


class Workspace:
    """Per-phase workspaces of one ``MultiPhaseProblem``."""

    def __init__(self, problem: MultiPhaseProblem, previous: Workspace | None = None) -> None:
        self.problem = problem
        n_phases = len(problem.phases)
        reusable = list(previous.phases) if previous is not None else []
        self.phases: list[PhaseWorkspace] = []
        for i, phase in enumerate(problem.phases):
            has_next = i < n_phases - 1
            found = None
            for j, candidate in enumerate(reusable):
                if candidate.matches(phase, has_next):
                    found = reusable.pop(j)
                    break
            self.phases.append(found if found is not None else PhaseWorkspace(phase, has_next))

    def matches(self, problem: MultiPhaseProblem) -> bool:
        n_phases = len(problem.phases)
        return len(self.phases) == n_phases and all(
            work.matches(phase, i < n_phases - 1)
            for i, (work, phase) in enumerate(zip(self.phases, problem.phases, strict=True))
        )

    def set_rollout_knots(self, rollout_knots: Sequence[object] | None, default: bool) -> None:
        """Mark roll-out knots (set ``M~`` of Sec. III-A); accepted forms: see ``MSiLQRSolver.solve``."""
        if rollout_knots is not None and len(rollout_knots) != len(self.phases):
            raise ValueError(f"rollout_knots has {len(rollout_knots)} entries for {len(self.phases)} phases")
        for i, work in enumerate(self.phases):
            mask = work.rollout
            if rollout_knots is None:
                mask[:] = default
                continue
            spec = rollout_knots[i]
            mask[:] = False
            if spec is None:
                continue
            array = np.asarray(spec)
            if array.dtype == bool:
                if array.shape != mask.shape:
                    raise ValueError(f"phase {i}: rollout mask has shape {array.shape}, needs {mask.shape}")
                mask[:] = array
            else:
                indices = np.asarray(list(spec) if isinstance(spec, Iterable) else [spec], dtype=int)
                if indices.size and (indices.min() < 0 or indices.max() > work.horizon):
                    raise ValueError(f"phase {i}: rollout knot index out of range 0..{work.horizon}")
                mask[indices] = True
