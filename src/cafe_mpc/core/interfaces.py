"""The small per-knot interface between optimal-control problems and the MS-iLQR solver.

The solver (``cafe_mpc.solver``) depends on nothing but this package (``core``; and numpy, numba). It
follows Pinocchio's model/data split and Crocoddyl's action models:

* a *model* (``ActionModel``, ``ResetMap``, ``SwitchingConstraint``) is immutable after construction and
  may be shared by many knots (and by many problems);
* a *data* object holds every array the model writes; it is created once per knot with
  ``model.create_data()`` and reused across solver iterations and MPC updates, so the hot path only
  writes into preallocated arrays.

States live on a manifold (``StateManifold``): the solver works in the tangent space (``ndx``) and uses
``integrate``/``difference`` to move between points, so the floating-base orientation can be a unit
quaternion (no Euler-angle singularity at pitch +-pi/2) without the solver knowing. A manifold may hand the
solver compiled forms of these operations (``CompiledStateOperations``), which its compiled kernels run.

Conventions (all arrays are ``numpy.ndarray`` of float64):

* ``difference(x0, x1)`` is ``x1 ⊖ x0`` expressed in the tangent space at ``x0``;
  ``integrate(x, dx)`` is ``x ⊕ dx``. ``integrate(x0, difference(x0, x1)) == x1``.
* Running knot ``k`` of a phase: ``x_{k+1} = f(x_k, u_k)`` (paper Eq. (1)); ``Fx = ∂f/∂x`` maps the tangent
  at ``x_k`` to the tangent at ``f(x_k, u_k)``. The running cost already includes its time step.
* A phase with ``N`` running models has ``N + 1`` states; its last state carries the terminal cost
  (a model with ``nu == 0``) and, when the phase is not the last, goes through the phase's reset map
  ``x^{[i+1]}_0 = P_i(x^{[i]}_N)`` (Eq. (1)), which may change the state space (Eq. (24), (31)).
* Inequality constraints are turned into relaxed-barrier costs inside the models (Sec. III-B-2) and only
  their worst violation is reported (``constraint_violation``); switching equality constraints
  ``g_i(x_N) = 0`` (Eq. (2)) are handled by the solver's augmented-Lagrangian outer loop.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from numba.core.dispatcher import Dispatcher

from cafe_mpc.core.kernels import (
    POINT_OPERATION,
    TRANSPORT_OPERATION,
    compiled_address,
    euclidean_difference,
    euclidean_integrate,
    euclidean_transport_stacked,
)


class StateOperationAddresses(NamedTuple):
    """Where a manifold's compiled operations are (``CompiledStateOperations.addresses``): what compiled code
    calls (``core.kernels.call_state_operation``, ``call_state_transport``)."""

    integrate: int
    difference: int
    transport_stacked: int


class CompiledStateOperations:
    """A state manifold's ``⊕``, ``⊖`` and tangent transport as numba-compiled functions (for compiled code).

    ``integrate(x, dx, out)``: ``out = x ⊕ dx``; ``difference(x0, x1, out)``: ``out = x1 ⊖ x0``;
    ``transport_stacked(x0, x1, left, right, out)``: ``out = ∂(x1 ⊖ x0)/∂x1 @ [left | right]``. Each is an
    ``njit`` function of float64 arrays that returns nothing and equals the manifold's method bit for bit
    (``integrate_into``, ``difference_into``, ``difference_jacobian_product_stacked``); the sizes follow from
    the arrays'. The solver's compiled roll-out runs them inside its own compiled calls (several manifold
    operations and the algebra between them in one call, Eqs. (11)-(13)), through ``addresses``; its
    linearisation transports ``[Fx | Fu]`` with ``transport_stacked``. The manifold keeps its methods for
    everything else (and for callers in Python).
    """

    __slots__ = ("_addresses", "difference", "integrate", "transport_stacked")

    def __init__(self, integrate: Dispatcher, difference: Dispatcher, transport_stacked: Dispatcher) -> None:
        self.integrate = integrate
        self.difference = difference
        self.transport_stacked = transport_stacked
        self._addresses: StateOperationAddresses | None = None

    @property
    def addresses(self) -> StateOperationAddresses:
        """The addresses of the three functions compiled for writable C-contiguous float64 arrays (compiled,
        or loaded from numba's cache, on first use; valid in this process only)."""
        if self._addresses is None:
            self._addresses = StateOperationAddresses(
                compiled_address(self.integrate, POINT_OPERATION),
                compiled_address(self.difference, POINT_OPERATION),
                compiled_address(self.transport_stacked, TRANSPORT_OPERATION),
            )
        return self._addresses

    def __reduce__(self) -> tuple:
        """Pickled (and copied) without the addresses, which belong to this process."""
        return (CompiledStateOperations, (self.integrate, self.difference, self.transport_stacked))


class StateManifold(ABC):
    """A state space with ``nx`` coordinates and an ``ndx``-dimensional tangent space.

    ``compiled``: the manifold's operations as compiled functions (``CompiledStateOperations``), which the
    solver's compiled roll-out and linearisation run in place of the methods; ``None`` (the default): none,
    the solver calls the methods. A manifold sets it with ``own_operations`` so that a subclass overriding
    one of the ``STATE_OPERATIONS`` (whose compiled form would then differ from the method) falls back to
    its methods by itself.
    """

    nx: int
    ndx: int
    compiled: CompiledStateOperations | None = None

    @abstractmethod
    def zero(self) -> np.ndarray:
        """A neutral point of the manifold (shape ``(nx,)``)."""

    @abstractmethod
    def integrate(self, x: np.ndarray, dx: np.ndarray) -> np.ndarray:
        """``x ⊕ dx``."""

    @abstractmethod
    def difference(self, x0: np.ndarray, x1: np.ndarray) -> np.ndarray:
        """``x1 ⊖ x0``, in the tangent space at ``x0``."""

    @abstractmethod
    def jacobian_difference(self, x0: np.ndarray, x1: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Jacobians of ``difference(x0, x1)`` w.r.t. ``x0`` and ``x1`` (each ``ndx x ndx``)."""

    @abstractmethod
    def jacobian_integrate(self, x: np.ndarray, dx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Jacobians of ``integrate(x, dx)`` w.r.t. ``x`` and ``dx`` (each ``ndx x ndx``)."""

    def difference_jacobian_product_stacked(
        self, x0: np.ndarray, x1: np.ndarray, left: np.ndarray, right: np.ndarray, out: np.ndarray
    ) -> None:
        """``out = ∂(x1 ⊖ x0)/∂x1 @ [left | right]`` (the solver's ``[A | B]`` in one call)."""
        n_left = left.shape[1]
        self.difference_jacobian_product(x0, x1, left, out[:, :n_left])
        self.difference_jacobian_product(x0, x1, right, out[:, n_left:])

    def difference_into(self, x0: np.ndarray, x1: np.ndarray, out: np.ndarray) -> None:
        """``out = x1 ⊖ x0`` (in place; manifolds override it to skip the temporary)."""
        out[:] = self.difference(x0, x1)

    def integrate_into(self, x: np.ndarray, dx: np.ndarray, out: np.ndarray) -> None:
        """``out = x ⊕ dx`` (in place)."""
        out[:] = self.integrate(x, dx)

    def integrate_rows_into(self, xs: np.ndarray, dxs: np.ndarray, out: np.ndarray) -> None:
        """``out[k] = xs[k] ⊕ dxs[k]`` for every row (a trajectory at once; manifolds override it with one
        compiled loop)."""
        for k in range(xs.shape[0]):
            self.integrate_into(xs[k], dxs[k], out[k])

    def difference_jacobian_product(
        self, x0: np.ndarray, x1: np.ndarray, matrix: np.ndarray, out: np.ndarray
    ) -> None:
        """``out = ∂(x1 ⊖ x0)/∂x1 @ matrix`` (moves tangent vectors at ``x1`` to the tangent at ``x0``).

        The solver calls this once per knot and iteration; manifolds override it to skip the identity
        blocks (the default forms the full Jacobian)."""
        np.matmul(self.jacobian_difference(x0, x1)[1], matrix, out=out)


STATE_OPERATIONS = (
    "integrate",
    "difference",
    "integrate_into",
    "difference_into",
    "difference_jacobian_product",
    "difference_jacobian_product_stacked",
)
"""The methods ``StateManifold.compiled`` stands for."""


def own_operations(manifold: StateManifold, owner: type) -> bool:
    """Whether ``manifold``'s ``STATE_OPERATIONS`` are ``owner``'s own (no subclass overrides one), i.e.
    whether the compiled operations written for ``owner`` compute them."""
    cls = type(manifold)
    return all(getattr(cls, name, None) is getattr(owner, name, None) for name in STATE_OPERATIONS)


class EuclideanState(StateManifold):
    """``R^n`` with ``integrate = +`` and ``difference = -``."""

    def __init__(self, n: int) -> None:
        if n <= 0:
            raise ValueError(f"EuclideanState dimension must be positive, got {n}")
        self.nx = n
        self.ndx = n
        # a subclass may override difference/integrate (e.g. angle wrapping)
        self.compiled = EUCLIDEAN_OPERATIONS if own_operations(self, EuclideanState) else None
        self._eye = np.eye(n)

    def zero(self) -> np.ndarray:
        return np.zeros(self.nx)

    def integrate(self, x: np.ndarray, dx: np.ndarray) -> np.ndarray:
        return x + dx

    def difference(self, x0: np.ndarray, x1: np.ndarray) -> np.ndarray:
        return x1 - x0

    def integrate_rows_into(self, xs: np.ndarray, dxs: np.ndarray, out: np.ndarray) -> None:
        np.add(xs, dxs, out=out)

    def jacobian_difference(self, x0: np.ndarray, x1: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return -self._eye, self._eye.copy()

    def jacobian_integrate(self, x: np.ndarray, dx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self._eye.copy(), self._eye.copy()

    def difference_jacobian_product(
        self, x0: np.ndarray, x1: np.ndarray, matrix: np.ndarray, out: np.ndarray
    ) -> None:
        out[:] = matrix


EUCLIDEAN_OPERATIONS = CompiledStateOperations(
    euclidean_integrate, euclidean_difference, euclidean_transport_stacked
)
"""``EuclideanState``'s compiled operations (``+``, ``-``, the identity transport)."""


class ActionData:
    """Per-knot workspace written by ``ActionModel.calc`` / ``calc_diff``.

    Models may subclass it to keep extra results (contact forces, foot positions, ...). The solver binds
    ``Lx``, ``Lu``, ``Lxx``, ``Luu`` and ``Lux`` to rows of its stacked arrays (it replaces these attributes
    with views), so models must write them in place and never keep other references to them.
    """

    def __init__(self, model: ActionModel) -> None:
        ndx, nu = model.state.ndx, model.nu
        ndx_next = model.next_state.ndx
        self.x_next = np.zeros(model.next_state.nx)
        self.cost = 0.0
        self.constraint_violation = 0.0  # max over inequality constraints of max(0, -g)
        self.Fx = np.zeros((ndx_next, ndx))
        self.Fu = np.zeros((ndx_next, nu))
        self.Lx = np.zeros(ndx)
        self.Lu = np.zeros(nu)
        self.Lxx = np.zeros((ndx, ndx))
        self.Luu = np.zeros((nu, nu))
        self.Lux = np.zeros((nu, ndx))
        self.forces: np.ndarray | None = None
        """Contact forces of the last ``calc`` in a model-defined layout, or ``None``; the solver returns them
        per knot (``PhaseSolution.forces``)."""


class ActionModel(ABC):
    """A discrete-time knot: dynamics ``f(x, u)``, cost ``l(x, u)`` and barrier-penalised inequalities.

    A terminal model has ``nu == 0``; ``calc``/``calc_diff`` are then called with ``u`` of size 0 and must
    leave ``x_next``/``Fx``/``Fu`` untouched.
    """

    state: StateManifold
    next_state: StateManifold
    nu: int

    def create_data(self) -> ActionData:
        return ActionData(self)

    @abstractmethod
    def calc(self, data: ActionData, x: np.ndarray, u: np.ndarray) -> None:
        """Write ``data.x_next``, ``data.cost`` and ``data.constraint_violation``."""

    @abstractmethod
    def calc_diff(self, data: ActionData, x: np.ndarray, u: np.ndarray) -> None:
        """Write ``Fx, Fu, Lx, Lu, Lxx, Luu, Lux`` (Gauss-Newton Hessians). Assumes ``calc`` ran first."""


class ResetData:
    """Workspace of a reset map."""

    def __init__(self, reset: ResetMap) -> None:
        self.x_next = np.zeros(reset.next_state.nx)
        self.Px = np.zeros((reset.next_state.ndx, reset.state.ndx))


class ResetMap(ABC):
    """``x^{[i+1]}_0 = P_i(x^{[i]}_N)`` (paper Eq. (1), (24), (31)); may change the state space."""

    state: StateManifold
    next_state: StateManifold

    def create_data(self) -> ResetData:
        return ResetData(self)

    @abstractmethod
    def calc(self, data: ResetData, x: np.ndarray) -> None:
        """Write ``data.x_next``."""

    @abstractmethod
    def calc_diff(self, data: ResetData, x: np.ndarray) -> None:
        """Write ``data.Px`` (tangent to tangent). Assumes ``calc`` ran first."""


class IdentityReset(ResetMap):
    """The trivial reset (take-off, Sec. IV-A-2): ``x^+ = x^-``."""

    def __init__(self, state: StateManifold) -> None:
        self.state = state
        self.next_state = state
        self._eye = np.eye(state.ndx)

    def calc(self, data: ResetData, x: np.ndarray) -> None:
        data.x_next[:] = x

    def calc_diff(self, data: ResetData, x: np.ndarray) -> None:
        data.Px[:] = self._eye


class ConstraintData:
    """Workspace of a switching (phase-terminal) equality constraint."""

    def __init__(self, constraint: SwitchingConstraint) -> None:
        self.value = np.zeros(constraint.dim)
        self.Hx = np.zeros((constraint.dim, constraint.state.ndx))


class SwitchingConstraint(ABC):
    """``g_i(x_N) = 0`` at the end of a phase (paper Eq. (2), e.g. touchdown foot height (25))."""

    state: StateManifold
    dim: int

    def create_data(self) -> ConstraintData:
        return ConstraintData(self)

    @abstractmethod
    def calc(self, data: ConstraintData, x: np.ndarray) -> None:
        """Write ``data.value``."""

    @abstractmethod
    def calc_diff(self, data: ConstraintData, x: np.ndarray) -> None:
        """Write ``data.Hx``. Assumes ``calc`` ran first."""


@dataclass
class Phase:
    """One phase of a multi-phase problem (paper Eq. (14), (17)).

    ``running_models`` has one model per time step (``N`` of them, ``N >= 1``); ``terminal_model`` prices the
    phase's last state (``nu == 0``). ``reset_map`` leads to the next phase (``None`` only for the last phase;
    the problem substitutes an identity when the state spaces agree). ``dt`` is for bookkeeping (plan times)
    and is not used by the solver.
    """

    running_models: list[ActionModel]
    terminal_model: ActionModel
    reset_map: ResetMap | None = None
    switching_constraint: SwitchingConstraint | None = None
    dt: float = 0.0
    name: str = ""
    metadata: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        if len(self.running_models) == 0:
            raise ValueError(f"phase {self.name!r} has no running models (a phase needs a duration)")
        if self.terminal_model.nu != 0:
            raise ValueError(f"phase {self.name!r}: terminal model must have nu == 0")
        state = self.running_models[0].state
        for k, model in enumerate(self.running_models):
            if model.state.ndx != state.ndx or model.next_state.ndx != state.ndx:
                raise ValueError(f"phase {self.name!r}: knot {k} changes the state space inside a phase")
        if self.terminal_model.state.ndx != state.ndx:
            raise ValueError(f"phase {self.name!r}: terminal model state dimension does not match")
        if self.switching_constraint is not None and self.switching_constraint.state.ndx != state.ndx:
            raise ValueError(f"phase {self.name!r}: switching constraint state dimension does not match")

    @property
    def state(self) -> StateManifold:
        return self.running_models[0].state

    @property
    def horizon(self) -> int:
        return len(self.running_models)


@dataclass
class MultiPhaseProblem:
    """An ordered list of phases and the initial state (paper Eq. (14), (17))."""

    x0: np.ndarray
    phases: list[Phase]

    def __post_init__(self) -> None:
        if not self.phases:
            raise ValueError("a problem needs at least one phase")
        self.x0 = np.asarray(self.x0, dtype=float)
        if self.x0.shape != (self.phases[0].state.nx,):
            raise ValueError(
                f"x0 has shape {self.x0.shape}, the first phase's state needs ({self.phases[0].state.nx},)"
            )
        for i, (phase, following) in enumerate(zip(self.phases[:-1], self.phases[1:], strict=True)):
            if phase.reset_map is None:
                if phase.state.ndx != following.state.ndx:
                    raise ValueError(f"phase {i} changes state dimension but has no reset map")
                phase.reset_map = IdentityReset(phase.state)
            if phase.reset_map.state.ndx != phase.state.ndx:
                raise ValueError(f"phase {i}: reset map source dimension does not match the phase")
            if phase.reset_map.next_state.ndx != following.state.ndx:
                raise ValueError(f"phase {i}: reset map target dimension does not match phase {i + 1}")
