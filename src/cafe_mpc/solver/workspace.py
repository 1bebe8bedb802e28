"""Preallocated, persistent storage of the MS-iLQR solver.

A ``Workspace`` lives as long as its solver. For every phase of the problem being solved it holds a
``PhaseWorkspace``: the nominal and trial trajectories, the defects, the stacked linearisation (``A``, ``B``,
``Lx``, ``Lu``, ``Lxx``, ``Luu``, ``Lux``) and the backward-sweep results, as views of arrays allocated once
with some spare capacity. Between solves nothing is reallocated:

* **data objects** (``model.create_data()``) are kept per model object and reused whenever that model object
  appears again (a receding-horizon problem that keeps its knot objects never creates data after its first
  solves); a model used twice in one problem gets one data object per occurrence;
* **phase arrays** are drawn from a pool by dimensions and capacity, so phases that change length from one
  MPC update to the next (the contact phases move through a fixed horizon) only take other views, which
  are kept per length (and per row for the data bindings), as are the reset Jacobians and switching arrays
  per shape: a set-up allocates nothing once the lengths and shapes have been seen;
* each running knot's cost derivatives are **bound** to the phase's stacked arrays over ``[x | u]``
  (``data.Lx = G[k, :ndx]``, ``data.Lxx = H[k, :ndx, :ndx]``, ...; and ``data.gradient = G[k]``,
  ``data.hessian = H[k]`` for data that keep the combined derivatives), so ``calc_diff`` writes straight into
  what the compiled backward sweep reads. Models must therefore write ``Lx``, ``Lu``, ``Lxx``, ``Luu``,
  ``Lux`` in place (never rebind them; note ``Lxx`` etc. are then strided views, so ``reshape(-1)`` makes a
  copy: use index assignment).
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
    StateOperationAddresses,
)
from cafe_mpc.core.kernels import same_point, stack_columns
from cafe_mpc.solver.kernels import linear_step, policy_step, transport_stacked

EMPTY_CONTROL = np.zeros(0)
"""The control of terminal knots (size 0; writable so compiled kernels see one array type)."""


def _written_zeros(shape: int | tuple[int, ...], dtype: type = float) -> np.ndarray:
    """An array of zeros whose every page is written now. ``np.zeros`` takes memory the OS maps at its
    first write, so a workspace's knots past those its first problems used would each cost an update some
    twenty page faults (a phase that grows into the horizon, one knot per update: a take-off's)."""
    array = np.empty(shape, dtype=dtype)
    array.fill(0)
    return array


class _Buffers:
    """The arrays of one phase workspace at full capacity (``capacity`` running knots)."""

    def __init__(self, nx: int, ndx: int, nu: int, capacity: int) -> None:
        n = capacity
        self.capacity = capacity
        self.xs = _written_zeros((n + 1, nx))
        self.us = _written_zeros((n, nu))
        self.defects = _written_zeros((n + 1, ndx))
        self.xs_try = _written_zeros((n + 1, nx))
        self.us_try = _written_zeros((n, nu))
        self.defects_try = _written_zeros((n + 1, ndx))
        self.magnitudes = _written_zeros((n + 1, ndx))  # |defects| (scratch of the defect norms)
        self.rollout = _written_zeros(n + 1, dtype=bool)
        self.all_rollout = np.ones(n + 1, dtype=bool)
        # Stacked over [x | u]: F = [A | B], G = [Lx | Lu], H = [[Lxx, .], [Lux, Luu]] (views below).
        self.F = _written_zeros((n, ndx, ndx + nu))
        self.G = _written_zeros((n, ndx + nu))
        self.H = _written_zeros((n, ndx + nu, ndx + nu))
        self.K = _written_zeros((n, nu, ndx))
        self.k = _written_zeros((n, nu))
        self.Qu = _written_zeros((n, nu))
        self.Quu = _written_zeros((n, nu, nu))
        self.Qux = _written_zeros((n, nu, ndx))
        self.S = _written_zeros((n + 1, ndx, ndx))
        self.s = _written_zeros((n + 1, ndx))
        self._views: dict[int, dict[str, np.ndarray]] = {}
        self._row_views: dict[int, tuple[np.ndarray, ...]] = {}

    def views(self, n_knots: int) -> dict[str, np.ndarray]:
        """The arrays of a phase of ``n_knots`` running knots, by ``PhaseWorkspace`` attribute: views of the
        first rows, and ``A``, ``B`` of ``F``. Made once per length and kept (the contact phases move
        through the horizon: a phase workspace serves a few lengths again and again)."""
        views = self._views.get(n_knots)
        if views is None:
            views = {name: getattr(self, name)[: n_knots + 1] for name in _STATE_ROWS}
            views.update({name: getattr(self, name)[:n_knots] for name in _CONTROL_ROWS})
            ndx = self.defects.shape[1]
            views["A"] = views["F"][:, :, :ndx]
            views["B"] = views["F"][:, :, ndx:]
            self._views[n_knots] = views
        return views

    def row_views(self, k: int) -> tuple[np.ndarray, ...]:
        """``G[k]``, ``H[k]`` and their blocks ``Lx``, ``Lu``, ``Lxx``, ``Luu``, ``Lux``: what a knot's data
        are bound to (made once per row and kept)."""
        views = self._row_views.get(k)
        if views is None:
            ndx = self.defects.shape[1]
            gradient, hessian = self.G[k], self.H[k]
            views = (
                gradient,
                hessian,
                gradient[:ndx],
                gradient[ndx:],
                hessian[:ndx, :ndx],
                hessian[ndx:, ndx:],
                hessian[ndx:, :ndx],
            )
            self._row_views[k] = views
        return views


_STATE_ROWS = ("xs", "defects", "xs_try", "defects_try", "magnitudes", "rollout", "all_rollout", "S", "s")
"""The ``_Buffers`` arrays with a row per state (``N + 1``)."""
_CONTROL_ROWS = ("us", "us_try", "F", "G", "H", "K", "k", "Qu", "Quu", "Qux")
"""The ``_Buffers`` arrays with a row per running knot (``N``)."""


class PhaseWorkspace:
    """Arrays of one phase (state-sized arrays are indexed ``0..N``, control-sized ones ``0..N-1``).

    ``defects[k + 1] = f(xs[k], us[k]) ⊖ xs[k + 1]`` lives in the tangent space at ``xs[k + 1]`` (Eq. (4));
    ``defects[0]`` is the reset defect ``P(x_N^prev) ⊖ xs[0]`` (Eq. (15)). ``A[k]``, ``B[k]`` map tangent
    perturbations at knot ``k`` to the tangent space at ``xs[k + 1]`` (the model's ``Fx``, ``Fu`` composed
    with the Jacobian of ``difference``), ``reset_jacobian`` does the same for the reset map.
    """

    def __init__(self, nx: int, ndx: int, nu: int, capacity: int) -> None:
        self.nx, self.ndx, self.nu = nx, ndx, nu
        self.buffers = _Buffers(nx, ndx, nu, capacity)
        # scratch of the compiled backward sweep
        self.rhs = np.zeros((nu, 1 + ndx))
        self.cholesky = np.zeros((nu, nu))
        self.SF = np.zeros((ndx, ndx + nu))
        self.Q = np.zeros((ndx + nu, ndx + nu))
        self.q = np.zeros(ndx + nu)
        self.s_hat = np.zeros(ndx)
        self.gains = np.zeros((nu, ndx))
        # scratch of the forward roll-out
        self.dx = np.zeros(ndx)
        self.du = np.zeros(nu)
        self.step = np.zeros(ndx)
        self.dx_end = np.zeros(ndx)
        # the value function of a result without one (``keep_value_function=False``): empty, read-only
        self.no_value_function = (np.empty((0, ndx, ndx)), np.empty((0, ndx)))
        for empty in self.no_value_function:
            empty.flags.writeable = False
        self.phase: Phase | None = None
        self.horizon = 0
        self._by_shape: dict[tuple[str, tuple[int, ...]], np.ndarray] = {}

    @property
    def capacity(self) -> int:
        return self.buffers.capacity

    def assign(
        self,
        phase: Phase,
        has_next_phase: bool,
        running_data: list[ActionData],
        terminal_data: ActionData,
        reset_data: ResetData | None,
        constraint_data: ConstraintData | None,
    ) -> None:
        """Make this workspace the storage of ``phase``: views of length ``N``, data bound to the stacks."""
        n_knots = len(phase.running_models)
        buffers = self.buffers
        self.phase = phase
        self.models = phase.running_models
        self.terminal_model = phase.terminal_model
        self.horizon = n_knots
        self.state: StateManifold = phase.state
        # Exact type: a subclass may override difference/integrate (e.g. angle wrapping).
        self.euclidean = type(self.state) is EuclideanState
        compiled = self.state.compiled
        self.operations: StateOperationAddresses | None = None if compiled is None else compiled.addresses
        """Where the manifold's compiled operations are (``CompiledStateOperations.addresses``), for the
        roll-out's and the linearisation's kernels; ``None``: the manifold has none (its methods are used)."""
        self.running_data = running_data
        self.terminal_data = terminal_data
        self.reset_map = phase.reset_map if has_next_phase else None
        self.reset_data = reset_data
        self.constraint = phase.switching_constraint
        self.constraint_data = constraint_data
        for name, view in buffers.views(n_knots).items():
            setattr(self, name, view)
        for k, data in enumerate(running_data):
            if getattr(data, "_bound_to", None) is buffers and data._bound_index == k:
                continue  # bound to this very row at an earlier update (the arrays never move)
            data._bound_to, data._bound_index = buffers, k
            gradient, hessian, data.Lx, data.Lu, data.Lxx, data.Luu, data.Lux = buffers.row_views(k)
            if hasattr(data, "gradient"):
                data.gradient = gradient
                data.hessian = hessian
        ndx_next = self.reset_map.next_state.ndx if self.reset_map is not None else 0
        if getattr(self, "reset_jacobian", None) is None or self.reset_jacobian.shape != (ndx_next, self.ndx):
            self.reset_jacobian = self.kept("reset_jacobian", (ndx_next, self.ndx))
        dim = self.constraint.dim if self.constraint is not None else 0
        if getattr(self, "multiplier", None) is None or self.multiplier.shape != (dim,):
            self.switching_value = self.kept("switching_value", (dim,))
            self.switching_value_try = self.kept("switching_value_try", (dim,))
            self.multiplier = self.kept("multiplier", (dim,))
        self.penalty = 0.0

    def kept(self, name: str, shape: tuple[int, ...]) -> np.ndarray:
        """The array ``name`` of this shape, kept from an earlier phase of the same dimensions (zeros when
        new; no allocation once seen). Each solve writes these before it reads them (the reset Jacobian in
        the linearisation, the switching values in the evaluation, the multipliers in the set-up, the
        backward sweep's scratch where it uses it)."""
        array = self._by_shape.get((name, shape))
        if array is None:
            array = np.zeros(shape)
            self._by_shape[(name, shape)] = array
        return array

    def matches(self, phase: Phase, has_next_phase: bool) -> bool:
        """Whether this workspace currently serves exactly these model objects."""
        if self.phase is None:
            return False
        reset_map = phase.reset_map if has_next_phase else None
        models = phase.running_models
        return (
            len(models) == self.horizon
            and phase.terminal_model is self.terminal_model
            and reset_map is self.reset_map
            and phase.switching_constraint is self.constraint
            and all(a is b for a, b in zip(models, self.models, strict=True))
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

    def difference_into(self, x0: np.ndarray, x1: np.ndarray, out: np.ndarray) -> None:
        """``out = x1 ⊖ x0``."""
        if self.euclidean:
            np.subtract(x1, x0, out=out)
        else:
            self.state.difference_into(x0, x1, out)

    def integrate_into(self, x: np.ndarray, dx: np.ndarray, out: np.ndarray) -> None:
        """``out = x ⊕ dx``."""
        if self.euclidean:
            np.add(x, dx, out=out)
        else:
            self.state.integrate_into(x, dx, out)

    def rollout_policy(self, k: int, alpha: float) -> None:
        """``solver.kernels.rollout_policy`` with the manifold's methods (a manifold without compiled
        operations): the trial control of knot ``k`` (Eq. (11)) into ``us_try[k]``, ``dx``, ``du``."""
        self.difference_into(self.xs[k], self.xs_try[k], self.dx)
        policy_step(self.us[k], self.k[k], self.K[k], self.dx, alpha, self.us_try[k], self.du)

    def rollout_knot_end(self, k: int, alpha: float, x_next: np.ndarray, rollout: np.ndarray) -> None:
        """``solver.kernels.rollout_knot_end`` with the manifold's methods: the trial state and defect of
        knot ``k + 1`` from ``x_next = f(x'_k, u'_k)`` (Eq. (13) on a roll-out knot, Eq. (12) on a shooting
        knot), then the control of knot ``k + 1``."""
        j = k + 1
        if rollout[j]:
            self.xs_try[j] = x_next  # Eq. (13)
            self.defects_try[j] = 0.0
        else:
            linear_step(self.F[k], self.dx, self.du, self.defects[j], self.step)  # Eq. (12)
            self.integrate_into(self.xs[j], self.step, self.xs_try[j])
            self.difference_into(self.xs_try[j], x_next, self.defects_try[j])
        if j < self.horizon:
            self.rollout_policy(j, alpha)

    def transport_stacked(
        self, x_nominal: np.ndarray, y: np.ndarray, Fx: np.ndarray, Fu: np.ndarray, out: np.ndarray
    ) -> None:
        """``out = ∂(y ⊖ x̄)/∂y @ [Fx | Fu]``: the knot's ``[A | B]`` (the identity map without a defect)."""
        operations = self.operations
        if operations is not None:
            transport_stacked(operations.transport_stacked, x_nominal, y, Fx, Fu, out)
        elif same_point(x_nominal, y):
            stack_columns(Fx, Fu, out)
        else:
            self.state.difference_jacobian_product_stacked(x_nominal, y, Fx, Fu, out)

    def transport(self, x_nominal: np.ndarray, y: np.ndarray, matrix: np.ndarray, out: np.ndarray) -> None:
        """``out = ∂(y ⊖ x̄)/∂y @ matrix`` (tangent at ``y`` -> tangent at the nominal ``x̄``)."""
        if self.euclidean or same_point(x_nominal, y):
            out[:] = matrix  # the Jacobian of the difference is the identity at y == x̄ (no defect)
        else:
            self.state.difference_jacobian_product(x_nominal, y, matrix, out)

    def swap_trial(self) -> None:
        """Make the trial trajectory the nominal one (no copies)."""
        self.xs, self.xs_try = self.xs_try, self.xs
        self.us, self.us_try = self.us_try, self.us
        self.defects, self.defects_try = self.defects_try, self.defects
        self.switching_value, self.switching_value_try = self.switching_value_try, self.switching_value


class _DataPool:
    """Data objects kept per (model object, occurrence in the problem), least recently used dropped."""

    def __init__(self) -> None:
        self._entries: dict[tuple[int, int], tuple[object, object, int]] = {}
        self._generation = 0
        self._seen: dict[int, int] = {}
        """Per owner (``id``), ``_base`` plus its occurrences so far in the current problem; a value from an
        earlier problem (at most ``_base``) counts as none. Kept across problems (no dict made per set-up),
        pruned with the entries."""
        self._base = 0

    def start(self) -> None:
        self._generation += 1
        self._base = self._generation << 32

    def get(self, owner, create):
        """The data of ``owner``'s next occurrence in the current problem (created on first use)."""
        base = self._base
        mark = self._seen.get(id(owner), base)
        occurrence = mark - base if mark > base else 0
        self._seen[id(owner)] = base + occurrence + 1
        key = (id(owner), occurrence)
        entry = self._entries.get(key)
        data = create() if entry is None or entry[0] is not owner else entry[1]
        self._entries[key] = (owner, data, self._generation)
        return data

    def trim(self, in_use: int) -> None:
        """Keep at most ``max(16 * in_use, 1024)`` entries, dropping down to half of that, the least recently
        used first (an MPC's warm-up creates the data of every knot object its next seconds will use, a few
        hundred for the running barrel roll; a whole-body knot's data is a few tens of kB)."""
        limit = max(16 * in_use, 1024)
        if len(self._entries) <= limit:
            return
        ordered = sorted(self._entries.items(), key=lambda item: item[1][2], reverse=True)
        self._entries = dict(ordered[: limit // 2])
        owners = {owner for owner, _ in self._entries}
        self._seen = {owner: mark for owner, mark in self._seen.items() if owner in owners}

    def __len__(self) -> int:
        return len(self._entries)


class Workspace:
    """Per-phase workspaces of the problem being solved, with pools that persist across problems."""

    def __init__(self, problem: MultiPhaseProblem | None = None) -> None:
        self.problem: MultiPhaseProblem | None = None
        self.phases: list[PhaseWorkspace] = []
        self.data_off_nominal = False
        """The knots' data hold an evaluation away from the nominal trajectory (a trial step's,
        ``MSiLQRSolver.try_step``, or a nonlinear feedback's), not the nominal's."""
        self._data = _DataPool()
        self._free: list[PhaseWorkspace] = []
        if problem is not None:
            self.setup(problem)

    def matches(self, problem: MultiPhaseProblem) -> bool:
        n_phases = len(problem.phases)
        return len(self.phases) == n_phases and all(
            work.matches(phase, i < n_phases - 1)
            for i, (work, phase) in enumerate(zip(self.phases, problem.phases, strict=True))
        )

    def setup(self, problem: MultiPhaseProblem) -> None:
        """Serve ``problem``: reuse what matches, draw the rest from the pools (allocation only on growth)."""
        if self.problem is problem or (self.phases and self.matches(problem)):
            self.problem = problem
            return
        self.problem = problem
        self._free.extend(self.phases)
        self.phases = []
        pool = self._data
        pool.start()
        n_phases = len(problem.phases)
        in_use = 0
        for i, phase in enumerate(problem.phases):
            has_next = i < n_phases - 1
            models = phase.running_models
            nu = models[0].nu
            state = phase.state
            for k, model in enumerate(models):
                if model.nu != nu:
                    raise ValueError(
                        f"phase {phase.name!r}: knot {k} has nu={model.nu}, knot 0 has nu={nu}; "
                        "the solver needs one control dimension per phase"
                    )
                if model.state.nx != state.nx or model.next_state.nx != state.nx:
                    raise ValueError(f"phase {phase.name!r}: knot {k} changes nx inside a phase")
            work = self._take(state.nx, state.ndx, nu, len(models))
            running = [pool.get(model, model.create_data) for model in models]
            terminal = pool.get(phase.terminal_model, phase.terminal_model.create_data)
            reset_map = phase.reset_map if has_next else None
            reset = pool.get(reset_map, reset_map.create_data) if reset_map is not None else None
            constraint = phase.switching_constraint
            constraint_data = pool.get(constraint, constraint.create_data) if constraint is not None else None
            work.assign(phase, has_next, running, terminal, reset, constraint_data)
            self.phases.append(work)
            in_use += len(models) + 3
        pool.trim(in_use)

    def _take(self, nx: int, ndx: int, nu: int, horizon: int) -> PhaseWorkspace:
        best = None
        for index, work in enumerate(self._free):
            fits = (work.nx, work.ndx, work.nu) == (nx, ndx, nu) and work.capacity >= horizon
            if fits and (best is None or work.capacity < self._free[best].capacity):
                best = index
        if best is not None:
            return self._free.pop(best)
        return PhaseWorkspace(nx, ndx, nu, max(horizon, 8))

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
