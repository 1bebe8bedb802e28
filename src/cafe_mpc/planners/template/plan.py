"""The message from the template MPC (the HKD-MPC-style baseline of paper Sec. VII-C, Fig. 12) to its
low-level controller.

The template MPC plans over the single rigid body (SRB, Eqs. (29), (30)) only, so its plan has no joint
torques, gains or Q-function pieces (unlike ``planners.cafe.plan.Plan``). Per knot interval ``[times[k],
times[k] + dt[k])``: the stance flags and the planned world-frame ground reaction forces (held constant over
the interval, as the SRB model applies them); per knot time (``n + 1``, the last one ends the plan): the
planned SRB state and the reference foot positions and velocities (stance feet at their footholds, swing feet
on their swing curves), which the low level interpolates for its swing-leg controller.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from cafe_mpc.core.plan import PlanFormat, interval_at
from cafe_mpc.dynamics.srb import SRBState


@dataclass
class TemplatePlan:
    """Arrays over the ``n`` knot intervals of one template-MPC solution."""

    times: np.ndarray  # (n,) start time of each interval
    dt: np.ndarray  # (n,) duration of each interval
    base_states: (
        np.ndarray
    )  # (n + 1, 13) SRB states [c, quaternion (x, y, z, w), c_dot (world), omega (body)]
    forces: np.ndarray  # (n, n_feet, 3) world-frame planned ground reaction forces (zero on swing feet)
    contacts: np.ndarray  # (n, n_feet) bool stance flags, leg order
    foot_positions: np.ndarray  # (n + 1, n_feet, 3) world reference foot positions at the knot times
    foot_velocities: np.ndarray  # (n + 1, n_feet, 3) world reference foot velocities at the knot times

    def __post_init__(self) -> None:
        n = len(self.times)
        if n == 0:
            raise ValueError("a template plan needs at least one knot interval")
        for name in ("dt", "forces", "contacts"):
            if len(getattr(self, name)) != n:
                raise ValueError(
                    f"template plan field {name} has {len(getattr(self, name))} rows, times has {n}"
                )
        for name in ("base_states", "foot_positions", "foot_velocities"):
            if len(getattr(self, name)) != n + 1:
                raise ValueError(
                    f"template plan field {name} needs {n + 1} rows, got {len(getattr(self, name))}"
                )
        if np.any(self.dt <= 0):
            raise ValueError("template plan intervals must have positive durations")
        for name in ("times", "dt", "base_states", "forces", "foot_positions", "foot_velocities"):
            if not np.all(np.isfinite(getattr(self, name))):
                raise ValueError(f"template plan field {name} contains NaN or inf")

    @property
    def start_time(self) -> float:
        return float(self.times[0])

    @property
    def end_time(self) -> float:
        return float(self.times[-1] + self.dt[-1])

    @property
    def knot_times(self) -> np.ndarray:
        """The ``n + 1`` knot times (interval starts and the plan's end)."""
        return np.append(self.times, self.end_time)

    def knot_at(self, t: float) -> int:
        """Index of the interval that contains ``t`` (clamped to the plan): its forces and stance act at ``t``
        (zero-order hold, as in the SRB model)."""
        return interval_at(self.times, t)

    def knot_configurations(self, nq: int) -> None:
        """None: the template plans the single rigid body, not the robot's configurations."""
        return None

    def feet_at(self, t: float, positions: np.ndarray, velocities: np.ndarray) -> None:
        """Reference foot positions and velocities at ``t`` (cubic Hermite interpolation between the knots,
        exact for the cubic Bezier swings of the locomotion reference when a knot falls on the apex), written
        into ``positions`` and ``velocities`` (n_feet, 3)."""
        k = self.knot_at(t)
        h = float(self.dt[k])
        s = min(max((t - float(self.times[k])) / h, 0.0), 1.0)
        p0, p1 = self.foot_positions[k], self.foot_positions[k + 1]
        m0, m1 = self.foot_velocities[k] * h, self.foot_velocities[k + 1] * h
        s2, s3 = s * s, s * s * s
        h00, h10, h01, h11 = 2 * s3 - 3 * s2 + 1, s3 - 2 * s2 + s, -2 * s3 + 3 * s2, s3 - s2
        d00, d10, d01, d11 = 6 * s2 - 6 * s, 3 * s2 - 4 * s + 1, -6 * s2 + 6 * s, 3 * s2 - 2 * s
        positions[:] = h00 * p0 + h10 * m0 + h01 * p1 + h11 * m1
        velocities[:] = (d00 * p0 + d10 * m0 + d01 * p1 + d11 * m1) / h


TEMPLATE_PLAN_DTYPES = {"contacts": bool}
"""The fields of a ``TemplatePlan`` that are not float arrays, and their types."""


def template_plan_shapes(n: int, n_feet: int) -> dict[str, tuple[int, ...]]:
    """The array shapes of a template plan of ``n`` knot intervals (``TemplatePlan``'s field comments)."""
    return {
        "times": (n,),
        "dt": (n,),
        "base_states": (n + 1, SRBState.nx),
        "forces": (n, n_feet, 3),
        "contacts": (n, n_feet),
        "foot_positions": (n + 1, n_feet, 3),
        "foot_velocities": (n + 1, n_feet, 3),
    }


def template_plan_format(capacity: int, n_feet: int) -> PlanFormat[TemplatePlan]:
    """How template plans of at most ``capacity`` intervals travel as arrays (``core.plan.PlanFormat``)."""
    return PlanFormat(
        TemplatePlan, functools.partial(template_plan_shapes, n_feet=n_feet), capacity, TEMPLATE_PLAN_DTYPES
    )
