"""Value-function whole-body controller (VWBC, paper Sec. V-A, Eq. (34)): the Riccati policy (33) in a QP.

At each low-level tick (500 Hz) the VWBC solves

    min_{qdd, tau, F}  Q_k(x ⊖ x*_k, tau - tau*_k)                                   (34a)
    s.t.  M(q) qdd + h(q, v) = S' tau + Jc' F                                          (34b)
          Jc qdd + Jcdot v = -alpha Jc v        (feet in the stance set C)              (34c)
          -tau_lim <= tau <= tau_lim                                                    (34d)
          Fz >= 0                                                                       (34e)
          |Fx|, |Fy| <= mu Fz                   (inner friction pyramid)                (34f)

with ``Q_k(dx, dtau) = 0.5 dtau' Quu dtau + dtau' (Qux dx + Qu)`` (the dx-only terms of the action-value
function (6) are constant in the QP and dropped). ``k`` is the plan knot whose interval holds ``t`` and ``dx =
x ⊖ x*_k`` uses the Riccati controller's convention (``pin.difference(q*, q)``, ``v - v*``). With
``VWBCSettings.state_reference = "interpolated"`` ``x*_k`` is replaced by the plan's state at ``t``
(``Plan.state_at``): over a 10 ms knot of a flip's push the state moves by several tenths of a rad/s in
pitch rate, and the feedback on the error to the held ``x*_k`` took back up to half the planned force by the
interval's end (docs/tasks.md, backflip). Without the
inequality constraints the dynamics (34b)-(34c) determine ``qdd`` and ``F`` from ``tau``, so the minimiser is
the unconstrained policy (7) ``tau* - Quu^{-1} (Qux dx + Qu)`` (with ``Qu = 0`` exactly the Riccati torque
(33)). The QP is therefore strictly convex on its feasible set although its Hessian is singular in ``qdd`` and
``F``; no regularisation is added by default (``VWBCSettings.regularization`` adds ``0.5 eps |(qdd, F)|^2`` if
a solver ever needs it — it biases the solution away from (7)).

Contacts: Jacobians and forces are expressed in ``LOCAL_WORLD_ALIGNED`` at the foot frames (forces are the
world-frame ground reaction forces, as in ``Plan.forces``); ``Jcdot v`` is the classical foot acceleration
at zero joint acceleration. The stance set ``C`` is the plan knot's contact flags (the paper's choice);
``VWBCSettings.stance_source = "intersect"`` uses the feet that are planned *and* measured in contact
(``Measurement.contacts``), ``"detected"`` (the run config's default) the contact detector's
(``low_level.contact_detection``). Off flat ground (``ground_plane``, ``terrain: blind``) the pyramid (34f)
and (34e) are taken about the normal of the contact detector's ground plane (``_StanceQP.orient_cone``): on
a 20 degree slope a cone about world z allows forces that slide the feet down. With a height map
(``terrain_map.cone: map``) about the map's normal under the feet instead (``cone_normal``).

Solvers: one preallocated solver object and matrix set per stance pattern (sizes change with the number of
stance feet). ProxQP (``proxsuite.proxqp.dense``, ``solver="proxqp"``) solves (34) as written; it is a
proximal augmented-Lagrangian method, so its iteration counts are *not* the active-set counts the paper
reports for qpOASES, and its own equality-constrained initial guess beats a primal warm start by about one
iteration (measured in ``benchmarks/bench_vwbc.py``). DAQP (``solver="daqp"``, the default, warm-started
from the previous tick), a dual active-set method like qpOASES, solves the same QP condensed onto ``tau``
(``qdd`` and ``F`` are affine in ``tau`` through the KKT system of (34b)-(34c)); its iterations are
active-set changes. Warm start (paper end of Sec. V-A): the plan's ``[(v*_{k+1} - v*_k) / dt_k, tau*_k,
F*_k]`` or the previous tick's solution.

Fallback (when the QP is not solved, returns non-finite numbers, raises any exception — the solver's
object for that stance pattern is then rebuilt on its next tick — or, optionally, exceeds a wall-clock
budget): the clamped Riccati feedback ``tau*_k + K_k dx`` (33), counted in ``fallbacks`` with its reason.
The controller never returns NaN, and an error inside the QP never propagates out of ``compute``.

Friction-cone scoring (``low_level.contact_dynamics``): the contact forces a torque implies through the same
contact dynamics (34b)-(34c), so a Riccati controller and the VWBC are scored the same way. For a solved QP
these forces equal its ``F``.
"""

from __future__ import annotations

import math
import time
from collections import Counter
from collections.abc import Callable

import numpy as np
import proxsuite

from cafe_mpc.config import ContactDetectionSettings, VWBCSettings
from cafe_mpc.config.run import WarmStart
from cafe_mpc.core.controller import LowLevelController
from cafe_mpc.core.ground import contact_frame
from cafe_mpc.core.measurement import Measurement
from cafe_mpc.low_level.contact_detection import ContactDetector
from cafe_mpc.low_level.contact_dynamics import (
    ContactDynamicsTerms,
    contact_forces_for_torque,
    friction_cone_violation,
)
from cafe_mpc.low_level.riccati import state_error
from cafe_mpc.planners.cafe.plan import Plan, riccati_torque
from cafe_mpc.planners.resolved import ContactModel
from cafe_mpc.robots.robot import Robot

_PROXQP = proxsuite.proxqp
_INITIAL_GUESS = {
    "plan": _PROXQP.InitialGuess.WARM_START,
    "previous": _PROXQP.InitialGuess.WARM_START,
    "equality": _PROXQP.InitialGuess.EQUALITY_CONSTRAINED_INITIAL_GUESS,
    "none": _PROXQP.InitialGuess.NO_INITIAL_GUESS,
}
_SOLVED = _PROXQP.QPSolverOutput.PROXQP_SOLVED
#: Real-time budget of one 500 Hz tick's QP (ms); slower solves are always counted, and trigger the
#: fallback only if ``VWBCSettings.time_budget_ms`` is set.
REAL_TIME_BUDGET_MS = 2.0


class _StanceQP:
    """Preallocated matrices of (34) for one stance pattern, shared by the solver backends.

    Variables ``z = [qdd (nv), tau (nu), F (3 nc)]``. Equalities ``A z = b``: (34b) then (34c). Inequalities
    ``l <= C z <= u`` (constant per pattern): torque bounds (34d), then per foot the four pyramid faces (34f),
    then ``Fz >= 0`` (34e) for every foot.
    """

    solver_name = ""

    def __init__(
        self, stance: tuple[bool, ...], nv: int, nu: int, limits: np.ndarray, s: VWBCSettings, mu: float
    ):
        self.stance = np.array(stance, dtype=bool)
        nc = int(self.stance.sum())
        self.nc, self.nv, self.nu = nc, nv, nu
        n, n_eq, n_in = nv + nu + 3 * nc, nv + 3 * nc, nu + 5 * nc
        self.n, self.n_eq, self.n_in = n, n_eq, n_in
        self.tau = slice(nv, nv + nu)
        self.force = slice(nv + nu, n)
        self.H = np.zeros((n, n))
        if s.regularization > 0:
            self.H[:nv, :nv] = s.regularization * np.eye(nv)
            self.H[self.force, self.force] = s.regularization * np.eye(3 * nc)
        self.g = np.zeros(n)
        self.A = np.zeros((n_eq, n))
        self.A[nv - nu : nv, self.tau] = -np.eye(nu)  # -S' tau (actuated joints are the last nu of v)
        self.b = np.zeros(n_eq)
        self.C = np.zeros((n_in, n))
        self.C[:nu, self.tau] = np.eye(nu)
        self.l = np.full(n_in, -np.inf)
        self.u = np.full(n_in, np.inf)
        self.l[:nu], self.u[:nu] = -limits, limits
        for i in range(nc):
            fx = nv + nu + 3 * i
            rows = nu + 4 * i
            for face, (axis, sign) in enumerate(((0, 1.0), (0, -1.0), (1, 1.0), (1, -1.0))):
                self.C[rows + face, fx + axis] = sign
                self.C[rows + face, fx + 2] = -mu
                self.u[rows + face] = 0.0
            self.C[nu + 4 * nc + i, fx + 2] = 1.0
            self.l[nu + 4 * nc + i] = 0.0
        self.normal = np.array([0.0, 0.0, 1.0])  # the ground normal the pyramid is taken about
        self.mu = mu
        self.x0 = np.zeros(n)  # primal warm start from the plan
        self.x = np.zeros(n)  # solution of the last solve
        self.iterations = 0
        self.status = ""
        self.solved = False
        self.has_previous = False  # the backend holds a solution of this pattern from the previous tick

    def orient_cone(self, normal: np.ndarray) -> None:
        """Take the pyramid (34f) and the unilateral rows (34e) about the ground's unit ``normal`` (world)
        instead of world z: faces ``+-t . F <= mu n . F`` for two tangents ``t`` of the ground, ``n . F >= 0``
        (a sloped ground's cone; with ``n = z`` the rows of (34e)-(34f) as built)."""
        if np.array_equal(normal, self.normal):
            return
        self.normal[:] = normal
        along, across, _ = contact_frame(normal)
        nv, nu, nc = self.nv, self.nu, self.nc
        for i in range(nc):
            fx = nv + nu + 3 * i
            rows = nu + 4 * i
            for face, (tangent, sign) in enumerate(
                ((along, 1.0), (along, -1.0), (across, 1.0), (across, -1.0))
            ):
                self.C[rows + face, fx : fx + 3] = sign * tangent - self.mu * normal
            self.C[nu + 4 * nc + i, fx : fx + 3] = normal
        self._cone_changed()

    def _cone_changed(self) -> None:
        """The backend's copy of the constraint rows follows ``C``."""

    def cap_normal_forces(self, caps: np.ndarray) -> None:
        """Bound each stance foot's normal force (the unilateral row (34e), about the cone's normal) above by
        ``caps`` (N, one per stance foot in order; inf: unbounded): ``0 <= n . F_i <= caps[i]``."""
        rows = slice(self.nu + 4 * self.nc, self.nu + 5 * self.nc)
        if np.array_equal(self.u[rows], caps):
            return
        self.u[rows] = caps
        self._bounds_changed()

    def _bounds_changed(self) -> None:
        """The backend's copy of the bounds follows ``l`` and ``u``."""

    def fill(self, terms: ContactDynamicsTerms, Quu: np.ndarray, g_tau: np.ndarray) -> None:
        """Write the tick's dynamics (34b)-(34c) and cost (34a) into the preallocated matrices."""
        nv, tau, force = self.nv, self.tau, self.force
        self.H[tau, tau] = Quu
        self.H[tau, tau] += Quu.T
        self.H[tau, tau] *= 0.5
        self.g[tau] = g_tau
        self.A[:nv, :nv] = terms.M
        self.A[:nv, force] = -terms.Jc.T
        self.A[nv:, :nv] = terms.Jc
        np.negative(terms.h, out=self.b[:nv])
        np.negative(terms.drift, out=self.b[nv:])

    def solve(self, mode: WarmStart) -> None:
        """Solve with the warm start ``mode``; sets ``x``, ``iterations``, ``status`` and ``solved``."""
        raise NotImplementedError


class _ProxQPStance(_StanceQP):
    """(34) as is, solved by ProxQP (dense). Box constraints are not used: ProxQP's warm start cannot take
    their duals."""

    solver_name = f"proxsuite.proxqp.dense {proxsuite.__version__}"

    def __init__(
        self, stance: tuple[bool, ...], nv: int, nu: int, limits: np.ndarray, s: VWBCSettings, mu: float
    ):
        super().__init__(stance, nv, nu, limits, s, mu)
        self.qp = _PROXQP.dense.QP(self.n, self.n_eq, self.n_in)
        self.qp.settings.eps_abs = s.eps_abs
        self.qp.settings.eps_rel = s.eps_rel
        self.qp.settings.max_iter = s.max_iter
        self.qp.settings.verbose = False
        self.initialized = False
        self.cone_changed = False
        self.bounds_changed = False
        self.y0 = np.zeros(self.n_eq)
        self.z0 = np.zeros(self.n_in)
        self.prev_x = np.zeros(self.n)
        self.prev_y = np.zeros(self.n_eq)
        self.prev_z = np.zeros(self.n_in)

    def _cone_changed(self) -> None:
        self.cone_changed = True

    def _bounds_changed(self) -> None:
        self.bounds_changed = True

    def solve(self, mode: WarmStart) -> None:
        qp = self.qp
        if not self.initialized:
            qp.init(self.H, self.g, self.A, self.b, self.C, self.l, self.u)
            self.initialized = True
        elif self.bounds_changed:
            qp.update(H=self.H, g=self.g, A=self.A, b=self.b, C=self.C, l=self.l, u=self.u)
        elif self.cone_changed:
            qp.update(H=self.H, g=self.g, A=self.A, b=self.b, C=self.C)
        else:
            qp.update(H=self.H, g=self.g, A=self.A, b=self.b)
        self.cone_changed = False
        self.bounds_changed = False
        qp.settings.initial_guess = _INITIAL_GUESS[mode]
        if mode == "previous" and self.has_previous:
            qp.solve(self.prev_x, self.prev_y, self.prev_z)
        elif mode in ("plan", "previous"):
            qp.solve(self.x0, self.y0, self.z0)  # primal from the plan, zero multipliers
        else:
            qp.solve()
        results = qp.results
        self.iterations = int(results.info.iter)
        self.status = results.info.status.name
        self.solved = results.info.status == _SOLVED
        self.x[:] = results.x
        if self.solved:
            self.prev_x[:] = results.x
            self.prev_y[:] = results.y
            self.prev_z[:] = results.z


_DAQP_INF = 1e30  # DAQP's bound magnitude treated as infinite
_DAQP_ACTIVE, _DAQP_LOWER = 1, 2  # DAQP constraint sense bits


class _DaqpStance(_StanceQP):
    """(34) condensed onto ``tau`` and solved by DAQP (dual active set).

    The dynamics (34b)-(34c) are a nonsingular KKT system in ``(qdd, F)`` for given ``tau`` (the stance-foot
    Jacobian has full row rank), so ``qdd = qdd0 + Gq tau`` and ``F = F0 + GF tau`` exactly, and (34) becomes
    a strictly convex QP in ``tau`` alone: ``Quu`` is positive definite, as DAQP requires (the uncondensed
    Hessian is singular in ``qdd`` and ``F``). Same minimiser as (34); ``qdd`` and ``F`` are recovered.
    Warm start: ``"previous"`` keeps DAQP's working set from the last solve of this pattern, ``"plan"``
    starts from the constraints active at the plan torque ``tau*_k``, ``"none"``/``"equality"`` from the
    empty working set. Iterations are active-set changes, comparable to the paper's qpOASES counts.

    In flight (no stance foot) the condensed QP has no general constraints, only the torque bounds, which
    DAQP takes as simple bounds: ``A`` has zero rows. ``daqp.Model.update`` (0.11) indexes ``A[0, 0]``
    whenever ``A`` is passed, so ``A`` is only passed when it has rows. ``update`` also silently ignores
    arrays whose shape differs from ``setup``'s and reports failures only in its return value; the model is
    therefore set up again whenever the problem dimensions differ from those it was set up with or an
    update fails, instead of solving stale data.
    """

    def __init__(
        self, stance: tuple[bool, ...], nv: int, nu: int, limits: np.ndarray, s: VWBCSettings, mu: float
    ):
        import daqp  # optional dependency: only with VWBCSettings.solver = "daqp"

        super().__init__(stance, nv, nu, limits, s, mu)
        self.solver_name = f"daqp {_package_version('daqp')}"
        self._daqp = daqp
        nc3, n_gen = 3 * self.nc, 5 * self.nc
        self.kkt = np.zeros((nv + nc3, nv + nc3))
        self.rhs = np.zeros((nv + nc3, 1 + nu))
        self.rhs[nv - nu : nv, 1:] = np.eye(nu)  # S' columns
        self.Cf = np.ascontiguousarray(self.C[nu:, self.force])  # pyramid + unilateral rows on F
        self.Hc = np.zeros((nu, nu))
        self.fc = np.zeros(nu)
        self.Ac = np.zeros((n_gen, nu))
        self.bu = np.concatenate([limits, np.minimum(self.u[nu:], _DAQP_INF)])
        self.bl = np.concatenate([-limits, np.maximum(self.l[nu:], -_DAQP_INF)])
        self.bu_const, self.bl_const = self.bu[nu:].copy(), self.bl[nu:].copy()
        self.sense = np.zeros(nu + n_gen, dtype=np.int32)
        self.model = daqp.Model()
        self.model_dims: tuple[int, int, int] | None = None  # (n, m, rows of A) of the last setup
        self.settings = {"primal_tol": s.eps_abs, "iter_limit": s.max_iter}

    def _cone_changed(self) -> None:
        self.Cf[:] = self.C[self.nu :, self.force]

    def _bounds_changed(self) -> None:
        np.minimum(self.u[self.nu :], _DAQP_INF, out=self.bu_const)

    def _condense(self) -> tuple[np.ndarray, np.ndarray]:
        nv, nu = self.nv, self.nu
        self.kkt[:nv, :nv] = self.A[:nv, :nv]
        self.kkt[:nv, nv:] = self.A[:nv, self.force]
        self.kkt[nv:, :nv] = self.A[nv:, :nv]
        self.rhs[:, 0] = self.b
        solution = np.linalg.solve(self.kkt, self.rhs)  # [[qdd0, Gq]; [F0, GF]]
        self.Hc[:] = self.H[self.tau, self.tau]
        self.fc[:] = self.g[self.tau]
        F0, GF = solution[nv:, 0], solution[nv:, 1:]
        np.matmul(self.Cf, GF, out=self.Ac)
        shift = self.Cf @ F0
        np.subtract(self.bu_const, shift, out=self.bu[nu:])
        np.subtract(self.bl_const, shift, out=self.bl[nu:])
        return solution[:, 0], solution[:, 1:]

    def _plan_sense(self) -> None:
        """Working set of the constraints active (within 1e-9) at the plan torque."""
        tau = self.x0[self.tau]
        values = np.concatenate([tau, self.Ac @ tau])
        self.sense[:] = 0
        self.sense[values >= self.bu - 1e-9] = _DAQP_ACTIVE
        self.sense[values <= self.bl + 1e-9] = _DAQP_ACTIVE | _DAQP_LOWER

    def solve(self, mode: WarmStart) -> None:
        nv = self.nv
        offset, gain = self._condense()
        if mode == "plan" or (mode == "previous" and not self.has_previous):
            self._plan_sense()
        elif mode in ("none", "equality"):
            self.sense[:] = 0
        keep_working_set = mode == "previous" and self.has_previous
        if not self._update(keep_working_set):
            if keep_working_set:  # the previous working set is lost with the model: start from the plan's
                self._plan_sense()
            self._setup()
        tau, _, exitflag, info = self.model.solve()
        self.iterations = int(info["iterations"])
        self.status = f"DAQP_EXITFLAG_{exitflag}"
        self.solved = exitflag == 1
        self.x[self.tau] = tau
        qdd_f = offset + gain @ tau
        self.x[:nv] = qdd_f[:nv]
        self.x[self.force] = qdd_f[nv:]

    def _dims(self) -> tuple[int, int, int]:
        return self.nu, len(self.bu), self.Ac.shape[0]

    def _setup(self) -> None:
        """(Re)build the DAQP workspace for the current data and working set ``sense``."""
        self.model_dims = None
        exitflag, _ = self.model.setup(self.Hc, self.fc, self.Ac, self.bu, self.bl, self.sense)
        if exitflag < 0:
            raise RuntimeError(f"daqp setup failed (exitflag {exitflag})")
        self.model.settings = self.settings
        self.model_dims = self._dims()

    def _update(self, keep_working_set: bool) -> bool:
        """Update the set-up model in place; False when it must be set up (again) instead."""
        if self.model_dims != self._dims():  # not set up yet, or sizes changed
            return False
        data = {"H": self.Hc, "f": self.fc, "bupper": self.bu, "blower": self.bl}
        if self.Ac.shape[0] > 0:  # no general constraints in flight: update() would index A[0, 0]
            data["A"] = self.Ac
        if not keep_working_set:
            data["sense"] = self.sense
        return self.model.update(**data) >= 0


def _package_version(name: str) -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(name)
    except PackageNotFoundError:
        return "unknown"


class VWBCController(LowLevelController[Plan]):
    """VWBC (34) on the plan passed to ``compute``, with the Riccati fallback (33) and per-tick statistics.

    ``compute(t, measurement, plan)`` like every ``LowLevelController``; the measurement's contacts are used
    by ``stance_source = "intersect"`` (its state and foot forces by ``"detected"``) and counted in
    ``stance_mismatch_ticks``. The returned array is owned by the controller and overwritten on the next
    call. ``settings``: the QP and its solver (the ``vwbc``
    section); ``contact``: the friction of the pyramid (34f), the Baumgarte rate of (34c) and the cone
    tolerance of the violation count (a run's ``ContactModel``; default the reference robot's);
    ``torque_limits``: (34d) (default the robot's); ``detection``: the contact detector's thresholds with
    ``stance_source = "detected"`` (a run's, scaled to its robot; default ``settings.contact_detection`` as
    written); ``ground_plane``: the contact detector measures the feet's heights above the plane through
    their latest contact points (``terrain: blind``).
    """

    def __init__(
        self,
        robot: Robot,
        settings: VWBCSettings | None = None,
        torque_limits: np.ndarray | None = None,
        contact: ContactModel | None = None,
        detection: ContactDetectionSettings | None = None,
        ground_plane: bool = False,
    ) -> None:
        self.robot = robot
        self.model = robot.model
        self.settings = VWBCSettings() if settings is None else settings
        self.contact = ContactModel() if contact is None else contact
        limits = robot.torque_limits if torque_limits is None else np.asarray(torque_limits, dtype=float)
        if limits.shape != (robot.nu,) or np.any(limits < 0):
            raise ValueError(f"torque limits must be {robot.nu} non-negative numbers")
        self.limits = limits.copy()
        self._checked_plan: Plan | None = None  # the last plan whose sizes were checked
        if self.settings.solver == "daqp":
            try:
                import daqp  # noqa: F401
            except ImportError as error:
                raise ImportError("VWBC solver 'daqp' needs the daqp package (pip install daqp)") from error
            self.solver_name = f"daqp {_package_version('daqp')}"
        else:
            self.solver_name = _ProxQPStance.solver_name
        self.terms = ContactDynamicsTerms(robot, self.contact.baumgarte_alpha)
        self.detector = (
            ContactDetector(
                robot, self.settings.contact_detection if detection is None else detection, ground_plane
            )
            if self.settings.stance_source == "detected"
            else None
        )
        self.cone_normal: Callable[[], np.ndarray | None] | None = None
        """Where the pyramid's ground normal comes from when not from the detector's plane: the
        reference's height map under the feet (``LocomotionReference.terrain_normal``, wired by the
        assembly with ``terrain_map.cone: map``); its None falls back to the plane."""
        self._qps: dict[tuple[bool, ...], _StanceQP] = {}
        nv, nu = robot.nv, robot.nu
        self._dx = np.zeros(2 * nv)
        self._x_plan = np.zeros(robot.nq + nv)  # the plan's state at t (state_reference: interpolated)
        self._g_tau = np.zeros(nu)
        self._torques = np.zeros(nu)
        self.last_request = self._torques  # the QP respects the limits: the request is the output
        self._stance = np.zeros(robot.n_feet, dtype=bool)
        self._early_caps = np.full(robot.n_feet, np.inf)
        """Each stance foot's normal-force cap, in stance order (``early_force``; inf: unbounded)."""
        self._previous_pattern: tuple[bool, ...] | None = None
        # last tick's results (for tests, logging by the caller and the friction-cone score)
        self.last_knot = -1
        self.last_used_qp = False
        self.last_status = ""
        self.last_iterations = 0
        self.last_qdd = np.zeros(nv)
        self.last_forces = np.zeros((robot.n_feet, 3))
        self.last_stance = np.zeros(robot.n_feet, dtype=bool)
        self.last_error = ""  # the last exception raised inside the QP (type: message), '' if none
        self.reset_statistics()

    # ------------------------------------------------------------------ interface
    def reset(self) -> None:
        """Forget the previous tick's solution and the statistics."""
        self._previous_pattern = None
        if self.detector is not None:
            self.detector.reset()
        self.reset_statistics()

    def _check_plan(self, plan: Plan) -> None:
        if plan is not self._checked_plan:
            if plan.us.shape[1] != self.robot.nu or plan.K.shape[2] != 2 * self.robot.nv:
                raise ValueError("plan sizes do not match the robot")
            self._checked_plan = plan

    def state_error(self, q: np.ndarray, v: np.ndarray, x_plan: np.ndarray) -> np.ndarray:
        """``x ⊖ x*`` in the tangent space at ``x*`` (``low_level.riccati.state_error``) into a buffer."""
        return state_error(self.model, q, v, x_plan, self._dx)

    def compute(self, t: float, measurement: Measurement, plan: Plan | None) -> np.ndarray:
        """Joint torques for time ``t`` at the measured state, following ``plan``."""
        if plan is None:
            raise RuntimeError("VWBCController needs a plan")
        self._check_plan(plan)
        q, v, contacts = measurement.q, measurement.v, measurement.contacts
        start = time.perf_counter()
        s, contact = self.settings, self.contact
        k = plan.knot_at(t)
        self.last_knot = k
        x_plan = plan.xs[k] if s.state_reference == "knot" else plan.state_at(self.model, t, k, self._x_plan)
        dx = self.state_error(q, v, x_plan)
        np.copyto(self._stance, plan.contacts[k])
        contacts = np.asarray(contacts, dtype=bool)
        if s.stance_source == "intersect":
            self._stance &= contacts
        elif self.detector is not None:
            np.copyto(self._stance, self.detector.update(t, measurement, plan, self._torques))
        if np.any(contacts != plan.contacts[k]):
            self.stance_mismatch_ticks += 1
        self.last_stance[:] = self._stance
        self.last_status = ""
        self.last_iterations = 0
        self.ticks += 1

        try:
            reason = self._solve_qp(plan, k, q, v, dx)
        except Exception as error:  # any failure in the QP (solver, KKT, bindings): fall back, never raise
            reason = f"exception:{type(error).__name__}"
            self.last_error = f"{type(error).__name__}: {error}"
            self.exception_counts[type(error).__name__] += 1
            # the pattern's solver may be half-updated: build it afresh on its next tick
            self._qps.pop(tuple(bool(c) for c in self._stance), None)
        elapsed_ms = 1e3 * (time.perf_counter() - start)
        self._record_time(elapsed_ms)
        if elapsed_ms > REAL_TIME_BUDGET_MS:
            self.slow_ticks += 1
        if not reason and s.time_budget_ms is not None and elapsed_ms > s.time_budget_ms:
            reason = "time_budget"
        self.last_used_qp = not reason
        if reason:
            self._fallback(plan, k, dx, reason)
            try:  # score the fallback torque's implied forces like a Riccati controller's
                self.last_forces[:] = contact_forces_for_torque(
                    self.robot, q, v, self._torques, self._stance, contact.baumgarte_alpha, terms=self.terms
                )
            except Exception:  # scoring only; the fallback torque stands
                self.last_forces[:] = np.nan
        if friction_cone_violation(self.last_forces[self._stance], contact.friction) > contact.cone_tolerance:
            self.friction_cone_violations += 1
        return self._torques

    # ------------------------------------------------------------------ QP (34)
    def _qp_for(self, pattern: tuple[bool, ...]) -> _StanceQP:
        qp = self._qps.get(pattern)
        if qp is None:
            backend = _DaqpStance if self.settings.solver == "daqp" else _ProxQPStance
            qp = backend(
                pattern, self.robot.nv, self.robot.nu, self.limits, self.settings, self.contact.friction
            )
            self._qps[pattern] = qp
        return qp

    def _solve_qp(self, plan: Plan, k: int, q: np.ndarray, v: np.ndarray, dx: np.ndarray) -> str:
        """Assemble and solve (34); returns '' on success (torques set), else the failure reason."""
        s, nv, nq = self.settings, self.robot.nv, self.robot.nq
        pattern = tuple(bool(c) for c in self._stance)
        qp = self._qp_for(pattern)
        normal = self.cone_normal() if self.cone_normal is not None else None
        if normal is not None:
            qp.orient_cone(normal)
        elif self.detector is not None and self.detector.ground is not None:
            qp.orient_cone(self.detector.ground.normal())
        detector = self.detector
        if detector is not None and (
            detector.early_force_cap is not None or detector.early_low_force_cap is not None
        ):
            caps, count, planned = self._early_caps, 0, plan.contacts[k]
            early_cap, low_cap = detector.early_force_cap, detector.early_low_force_cap
            for foot, standing in enumerate(self._stance):
                if standing:  # the least cap that applies: an early foot (in the stance set before its
                    # planned touchdown; ``early_force``), one early on lower ground (``early_low_force``)
                    cap = np.inf if early_cap is None or planned[foot] else early_cap
                    if low_cap is not None and detector.lowered[foot]:
                        cap = min(cap, low_cap)
                    caps[count] = cap
                    count += 1
            qp.cap_normal_forces(caps[:count])
        self.terms.compute(q, v, self._stance)
        # linear term of (34a) in tau: Qux dx + Qu - Quu tau*
        np.matmul(plan.Qux[k], dx, out=self._g_tau)
        self._g_tau += plan.Qu[k]
        self._g_tau -= plan.Quu[k] @ plan.us[k]
        if self.detector is not None and (
            self.detector.late_reach_speed is not None
            or self.detector.stumble_force is not None
            or self.detector.early_hold_height is not None
        ):
            self._reach_with_late_feet(plan, k)
        elif self.detector is not None and self.detector.late_descent_speed is not None:
            self._unload_falling_late_feet(plan, k)
        qp.fill(self.terms, plan.Quu[k], self._g_tau)
        # warm start from the plan (paper end of Sec. V-A): finite-difference qdd, tau*_k, F*_k
        np.subtract(plan.xs[k + 1, nq:], plan.xs[k, nq:], out=qp.x0[:nv])
        qp.x0[:nv] /= plan.dt[k]
        qp.x0[qp.tau] = plan.us[k]
        qp.x0[qp.force] = plan.forces[k][qp.stance].ravel()
        qp.has_previous = self._previous_pattern == pattern
        self._previous_pattern = None
        solve_start = time.perf_counter()
        qp.solve(s.warm_start)
        solve_ms = 1e3 * (time.perf_counter() - solve_start)
        self.last_iterations = qp.iterations
        self.last_status = qp.status
        self.status_counts[qp.status] += 1
        self.iterations_histogram[qp.iterations] += 1
        self._record_solve_time(solve_ms)
        if not qp.solved:
            return f"status:{qp.status}"
        x = qp.x
        if not np.all(np.isfinite(x)):
            return "nan"
        # The solvers meet the bounds to their tolerance; clip the rest so no command exceeds the limits.
        np.clip(x[qp.tau], -self.limits, self.limits, out=self._torques)
        self.last_qdd[:] = x[:nv]
        self.last_forces[:] = 0.0
        self.last_forces[qp.stance] = x[qp.force].reshape(-1, 3)
        self._previous_pattern = pattern
        return ""

    def _reach_with_late_feet(self, plan: Plan, k: int) -> None:
        """A late foot (planned in stance, the detector's ``reaching``) is driven as a swing that reaches
        down (``ContactDetector._reach``): the linear term of (34a) is shifted so that the QP's unconstrained
        minimiser, the policy (7) ``tau_p = -H^-1 g`` (``H`` the symmetric part of ``Quu``), takes the
        detector's ``reach_torques`` on that leg's joints and stays the policy on the others'
        (``g <- g - H[:, leg] (tau_reach - tau_p[leg])`` moves the minimiser by exactly that shift). The
        plan's stance torques for that leg, its planned ground force ``-J' F*`` among them, are gone until
        the foot lands; the torque bounds (34d) and the stance feet's constraints still hold. A stumbling foot
        (``stumbling``, the stumble reflex) is driven the same way, and so is a foot held where it landed
        early on a higher tread (``holding``, ``early_hold_height``), which is in the stance set."""
        detector = self.detector
        assert detector is not None
        if not detector.reaching.any() and not detector.stumbling.any() and not detector.holding.any():
            return  # the common tick
        feet = np.flatnonzero(((detector.reaching | detector.stumbling) & ~self._stance) | detector.holding)
        if feet.size == 0:
            return
        quu = plan.Quu[k]
        hessian = 0.5 * (quu + quu.T)
        policy = -np.linalg.solve(hessian, self._g_tau)
        for foot in feet:
            columns = slice(3 * foot, 3 * foot + 3)
            shift = detector.reach_torques[foot] - policy[columns]
            self._g_tau -= hessian[:, columns] @ shift

    def _unload_falling_late_feet(self, plan: Plan, k: int) -> None:
        """A late foot (planned in stance, not in the stance set) whose leg moves it down faster than the
        detector's ``late_descent_speed`` ``c`` (``leg_descent_speeds`` ``w``: the joints' share of the
        foot's velocity, so a trunk coming down on its legs out of a flight does not count) has its planned
        ground force ``F*_f`` taken off its leg's torque reference in (34a), a share ``min(1, (w - c) / c)``
        of it: ``tau* + s J_f,leg' F*_f`` (the plan's stance torques push the ground with ``-J' F*``; with no
        ground under the foot they throw it down, 4-5 m/s onto a lower tread going down steps blind:
        docs/terrain-notes.md). The plan's feedback stays."""
        detector = self.detector
        assert detector is not None and detector.late_descent_speed is not None
        limit = detector.late_descent_speed
        for foot in np.flatnonzero(plan.contacts[k] & ~self._stance):
            share = min(1.0, (detector.leg_descent_speeds[foot] - limit) / limit)
            if share <= 0.0:
                continue
            columns = slice(3 * foot, 3 * foot + 3)
            shift = share * detector.leg_torque(int(foot), plan.forces[k][foot])
            self._g_tau -= plan.Quu[k][:, columns] @ shift

    def _fallback(self, plan: Plan, k: int, dx: np.ndarray, reason: str) -> None:
        """Clamped Riccati feedback (33); the plan torque alone if even that is not finite."""
        self.fallbacks += 1
        self.fallback_reasons[reason.split(":")[0]] += 1
        self.last_status = self.last_status or reason
        self._previous_pattern = None
        riccati_torque(plan, k, dx, self._torques)
        if not np.all(np.isfinite(self._torques)):
            self._torques[:] = plan.us[k]
        np.clip(self._torques, -self.limits, self.limits, out=self._torques)
        self.last_qdd[:] = np.nan

    # ------------------------------------------------------------------ statistics
    def reset_statistics(self) -> None:
        self.ticks = 0
        self.fallbacks = 0
        self.slow_ticks = 0
        self.friction_cone_violations = 0
        self.stance_mismatch_ticks = 0
        self.iterations_histogram: Counter[int] = Counter()
        self.status_counts: Counter[str] = Counter()
        self.fallback_reasons: Counter[str] = Counter()
        self.exception_counts: Counter[str] = Counter()  # exceptions inside the QP, by type
        self._solve_ms = np.zeros(1024)
        self._tick_ms = np.zeros(1024)
        self._n_solve = 0
        self._n_tick = 0

    def _record_solve_time(self, ms: float) -> None:
        if self._n_solve == len(self._solve_ms):
            self._solve_ms = np.concatenate([self._solve_ms, np.zeros(len(self._solve_ms))])
        self._solve_ms[self._n_solve] = ms
        self._n_solve += 1

    def _record_time(self, ms: float) -> None:
        if self._n_tick == len(self._tick_ms):
            self._tick_ms = np.concatenate([self._tick_ms, np.zeros(len(self._tick_ms))])
        self._tick_ms[self._n_tick] = ms
        self._n_tick += 1

    def statistics(self) -> dict:
        """Per-run counters: QP iterations histogram, solve/tick times (ms), fallbacks, cone violations."""

        def percentile(values: np.ndarray, p: float) -> float:
            return float(np.percentile(values, p)) if len(values) else math.nan

        solve, tick = self._solve_ms[: self._n_solve], self._tick_ms[: self._n_tick]
        return {
            "ticks": self.ticks,
            "qp_iterations_histogram": dict(sorted(self.iterations_histogram.items())),
            "qp_solve_time_ms_median": percentile(solve, 50),
            "qp_solve_time_ms_p99": percentile(solve, 99),
            "tick_time_ms_median": percentile(tick, 50),
            "tick_time_ms_p99": percentile(tick, 99),
            "fallbacks": self.fallbacks,
            "fallback_reasons": dict(self.fallback_reasons),
            "qp_exceptions": dict(self.exception_counts),
            "qp_status_counts": dict(self.status_counts),
            "friction_cone_violations": self.friction_cone_violations,
            "slow_ticks": self.slow_ticks,
            "stance_mismatch_ticks": self.stance_mismatch_ticks,
            "warm_start": self.settings.warm_start,
            **({"contact_detection": self.detector.statistics()} if self.detector is not None else {}),
            "solver": self.solver_name,
        }

    def contact_forces_for_torque(
        self, q: np.ndarray, v: np.ndarray, tau: np.ndarray, stance: np.ndarray
    ) -> np.ndarray:
        """Contact forces implied by ``tau`` through (34b)-(34c) (see the module function)."""
        return contact_forces_for_torque(self.robot, q, v, tau, stance, self.contact.baumgarte_alpha)
