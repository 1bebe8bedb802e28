"""CAFE-MPC's plan: the message from its MPC to the low-level controller, the whole-body part of a solution.

Per whole-body running knot: time, planned state ``x*`` and torque ``tau*``, gain ``K`` and the local
Q-function pieces ``Qu, Quu, Qux`` (paper Eq. (6)-(8)), stance flags and planned contact forces.
``knot_at(t)`` returns the knot the low-level controller uses at time ``t``: the one whose interval
``[t_k, t_k+1)`` contains ``t`` (zero-order hold: its torque acts over that interval in the plan's own
discretisation, as in the authors' controller; the nearest knot would pick, half an interval before a
touchdown, a knot of the next contact phase). ``riccati_torque`` is the plan's feedback law (33).
``state_at(model, t, k, out)`` is the planned state at ``t`` inside that interval (configuration on the
manifold, velocity linearly between ``x*_k`` and ``x*_k+1``): the state a low level running faster than the
knots may measure its error against instead of ``x*_k`` held over the interval.

``PlanBuffers`` lends the arrays an MPC writes its plans into, so that an update allocates no plan, and
never lends arrays a published plan still uses.
"""

from __future__ import annotations

import copy
import functools
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from cafe_mpc.core.buffers import ArrayLender
from cafe_mpc.core.kernels import all_finite
from cafe_mpc.core.plan import PlanFormat, interval_at

PLAN_FIELDS = ("times", "xs", "us", "K", "Qu", "Quu", "Qux", "contacts", "forces", "dt")
"""The array fields of a ``Plan``, in the order of its constructor."""
PLAN_DTYPES = {"contacts": bool}
"""The fields that are not float arrays, and their types."""


@dataclass
class Plan:
    """Arrays over the ``n`` whole-body running knots of one MPC solution."""

    times: np.ndarray  # (n,)
    xs: np.ndarray  # (n + 1, nx): states, the last one ends the whole-body part
    us: np.ndarray  # (n, nu)
    K: np.ndarray  # (n, nu, ndx)
    Qu: np.ndarray  # (n, nu)
    Quu: np.ndarray  # (n, nu, nu)
    Qux: np.ndarray  # (n, nu, ndx)
    contacts: np.ndarray  # (n, n_feet) bool, leg order
    forces: np.ndarray  # (n, n_feet, 3) world-frame planned ground reaction forces
    dt: np.ndarray  # (n,) time step of each knot

    def __post_init__(self) -> None:
        n = len(self.times)
        if n == 0:
            raise ValueError("a plan needs at least one whole-body knot")
        shapes = {
            "us": self.us,
            "K": self.K,
            "Qu": self.Qu,
            "Quu": self.Quu,
            "Qux": self.Qux,
            "contacts": self.contacts,
            "forces": self.forces,
            "dt": self.dt,
        }
        for name, array in shapes.items():
            if len(array) != n:
                raise ValueError(f"plan field {name} has {len(array)} knots, times has {n}")
        if len(self.xs) != n + 1:
            raise ValueError(f"plan xs needs {n + 1} states, got {len(self.xs)}")
        for name in ("xs", "us", "K", "Qu", "Quu", "Qux", "forces"):
            _check_finite(name, getattr(self, name))

    def with_trajectory(self, xs: np.ndarray, us: np.ndarray, Qu: np.ndarray | None = None) -> Plan:
        """This plan with another state and torque trajectory (and ``Qu``): what the real-time iteration's
        feedback phase changes. The other fields were checked with this plan and are shared, so that the
        feedback does not copy and re-check the gains and Q-function blocks (most of a plan's bytes)."""
        plan = copy.copy(self)
        plan.xs, plan.us = xs, us
        if Qu is not None:
            plan.Qu = Qu
        n = len(self.times)
        if len(xs) != n + 1 or len(us) != n or len(plan.Qu) != n:
            raise ValueError(f"a trajectory for {n} knots needs {n + 1} states and {n} torques and Qu")
        for name in ("xs", "us") if Qu is None else ("xs", "us", "Qu"):
            _check_finite(name, getattr(plan, name))
        return plan

    @property
    def start_time(self) -> float:
        return float(self.times[0])

    @property
    def end_time(self) -> float:
        return float(self.times[-1] + self.dt[-1])

    def knot_at(self, t: float) -> int:
        """Index of the knot whose interval contains ``t`` (clamped to the plan; module docstring)."""
        return interval_at(self.times, t)

    def state_at(self, model: pin.Model, t: float, k: int, out: np.ndarray) -> np.ndarray:
        """The planned state at ``t`` in knot ``k``'s interval, written into ``out``: the configuration
        interpolated on the manifold between ``q*_k`` and ``q*_k+1`` (``pin.interpolate``), the velocity
        linearly between ``v*_k`` and ``v*_k+1``, except over an interval that ends in a touchdown, whose
        ``v*_k+1`` is the velocity after the impact: there ``v*_k`` is held. ``t`` outside the interval is
        clamped to it."""
        nq = model.nq
        start, step = self.times[k], self.dt[k]
        s = min(max((t - start) / step, 0.0), 1.0)
        current, following = self.xs[k], self.xs[k + 1]
        out[:nq] = pin.interpolate(model, current[:nq], following[:nq], s)
        touchdown = k + 1 < len(self.contacts) and bool(np.any(self.contacts[k + 1] & ~self.contacts[k]))
        if touchdown:
            out[nq:] = current[nq:]
        else:
            np.multiply(current[nq:], 1.0 - s, out=out[nq:])
            out[nq:] += s * following[nq:]
        return out

    def knot_configurations(self, nq: int) -> np.ndarray:
        """The planned configurations ``q*`` at the ``n + 1`` knot times (a view of ``xs``)."""
        return self.xs[:, :nq]


def _check_finite(name: str, values: np.ndarray) -> None:
    """Raise ``ValueError`` if the plan field ``name`` holds a NaN or an infinity."""
    if not all_finite(np.asarray(values, dtype=float).reshape(-1)):
        raise ValueError(f"plan field {name} contains NaN or inf")


class PlanBuffers:
    """The arrays an MPC writes its plans into, reused from update to update (no plan allocated per update).

    A published plan may be followed by the low level, wait in flight (the latency), be read by the delay
    predictor, or be kept by any consumer for as long as it likes: its arrays must never change. A set of
    arrays is therefore lent again only when nothing but this object refers to any of its arrays
    (``core.buffers.unreferenced``, CPython's reference counts: a plan made of them, one of the arrays or a
    view of one held anywhere keeps the set busy). The MPC loop keeps three sets busy with a latency up to a
    period (the plan in effect, the one in flight, the prepared one), one more per further period of
    latency. With ``capacity`` sets busy, ``take`` returns new arrays that are not kept (a consumer that
    keeps every plan gets fresh ones, as without buffers).
    """

    def __init__(self, capacity: int = 8) -> None:
        self._lender = ArrayLender(capacity)

    def take(self, n: int, nx: int, nu: int, ndx: int, n_feet: int) -> dict[str, np.ndarray]:
        """Arrays (uninitialised, keyed by ``PLAN_FIELDS``) for a plan of ``n`` knots that no plan in use
        shares: row views of a free set of the lender (grown when shorter), else of a new set (kept while
        fewer than ``capacity`` are)."""
        loan = self._lender.take()
        return {
            name: loan.rows((name,), shape[0], shape[1:], PLAN_DTYPES.get(name, float))
            for name, shape in plan_shapes(n, nx, nu, ndx, n_feet).items()
        }

    @property
    def capacity(self) -> int:
        return self._lender.capacity

    @property
    def kept(self) -> int:
        """How many sets of arrays are kept for reuse."""
        return self._lender.kept


def plan_format(capacity: int, nx: int, nu: int, ndx: int, n_feet: int) -> PlanFormat[Plan]:
    """How plans of at most ``capacity`` knots of these dimensions travel as arrays
    (``core.plan.PlanFormat``)."""
    shapes = functools.partial(plan_shapes, nx=nx, nu=nu, ndx=ndx, n_feet=n_feet)
    return PlanFormat(Plan, shapes, capacity, PLAN_DTYPES)


def plan_shapes(n: int, nx: int, nu: int, ndx: int, n_feet: int) -> dict[str, tuple[int, ...]]:
    """The array shapes of a plan of ``n`` knots (``Plan``'s field comments)."""
    return {
        "times": (n,),
        "xs": (n + 1, nx),
        "us": (n, nu),
        "K": (n, nu, ndx),
        "Qu": (n, nu),
        "Quu": (n, nu, nu),
        "Qux": (n, nu, ndx),
        "contacts": (n, n_feet),
        "forces": (n, n_feet, 3),
        "dt": (n,),
    }


def riccati_torque(plan: Plan, k: int, dx: np.ndarray, out: np.ndarray) -> np.ndarray:
    """Eq. (33) at knot ``k``: ``out = tau*_k + K_k dx`` (unclamped), ``dx = x ⊖ x*_k``."""
    np.matmul(plan.K[k], dx, out=out)
    out += plan.us[k]
    return out
