"""The message from the MPC to the low-level controller: the whole-body part of the latest solution.

Per whole-body running knot: time, planned state ``x*`` and torque ``tau*``, gain ``K`` and the local
Q-function pieces ``Qu, Quu, Qux`` (paper Eq. (6)-(8)), stance flags and planned contact forces.
``knot_at(t)`` returns the knot the low-level controller uses at time ``t``: the one whose interval
``[t_k, t_k+1)`` contains ``t`` (zero-order hold: its torque acts over that interval in the plan's own
discretisation, as in the authors' controller; the nearest knot would pick, half an interval before a
touchdown, a knot of the next contact phase).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np


def nearest_knot(times: np.ndarray, t: float) -> int:
    """Index of the entry of the sorted ``times`` closest to ``t`` (clamped to the first and last)."""
    index = int(np.searchsorted(times, t))
    if index <= 0:
        return 0
    if index >= len(times):
        return len(times) - 1
    return index if times[index] - t < t - times[index - 1] else index - 1


def interval_at(times: np.ndarray, t: float) -> int:
    """Index ``k`` of the interval ``[times[k], times[k + 1])`` that contains ``t`` (clamped to the first and
    last); a time within 1 ns of a knot time belongs to the interval that starts there."""
    index = int(np.searchsorted(times, t + 1e-9, side="right")) - 1
    return min(max(index, 0), len(times) - 1)


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
            if not np.all(np.isfinite(getattr(self, name))):
                raise ValueError(f"plan field {name} contains NaN or inf")

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
            if not np.all(np.isfinite(getattr(plan, name))):
                raise ValueError(f"plan field {name} contains NaN or inf")
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
