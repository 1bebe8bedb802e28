"""The reference interface the CAFE problem builder consumes (paper Fig. 2: "reference trajectory in").

A reference answers, for any window of times: the contact schedule (stance flags of the interval that
starts at each time), the whole-body state to track (base pose with a quaternion, joint angles, base-frame
velocities, joint rates), the torque and ground-reaction-force references, the foot references (world
positions and velocities), and which weight set prices each knot. Implementations:

* ``LocomotionReference`` (``reference/locomotion.py``): the heuristic gait reference of Sec. VI-A;
* ``TrajectoryReference`` (``reference/trajectory.py``): a stored whole-body trajectory (e.g. the offline
  barrel roll of Sec. VI-B), sampled by time;
* ``ComposedReference`` (``reference/composition.py``): references joined in time with x, y, yaw offsets.

``sample(window)`` writes into a preallocated ``ReferenceWindow`` (the MPC calls it 50 times a second, so it
allocates nothing per knot); ``update(t, q, v)`` lets a reference re-anchor on the measured state before
each MPC update (the locomotion reference does; a stored trajectory does not).
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np

from cafe_mpc.core.height_map import HeightMap
from cafe_mpc.core.kernels import all_finite

STANCE_TIME_EPS = 1e-7
"""Stance flags of a knot are the schedule's a hair after the knot time (the interval the knot starts)."""

SWITCH_TIME_TOLERANCE = 1e-6
"""Switch times closer than this are one switch; a switch this close to a window's end is outside it."""


def switches_inside(times, t0: float, t1: float) -> list[float]:
    """The times strictly inside ``(t0, t1)`` (by ``SWITCH_TIME_TOLERANCE``), sorted, duplicates merged."""
    inside: list[float] = []
    for t in sorted(float(t) for t in times):
        if t0 + SWITCH_TIME_TOLERANCE < t < t1 - SWITCH_TIME_TOLERANCE and (
            not inside or t - inside[-1] > SWITCH_TIME_TOLERANCE
        ):
            inside.append(t)
    return inside


class ReferenceWindow:
    """Preallocated reference samples at ``n`` times (filled in place by ``Reference.sample``).

    ``stance`` (n, n_feet) bool: contact flags of the interval starting at each time; ``state`` (n, nq + nv):
    whole-body ``[q, v]``; ``torque`` (n, nu); ``forces`` (n, n_feet, 3): world GRF reference (zero on swing
    feet); ``foot_positions``/``foot_velocities`` (n, n_feet, 3): world foot references (stance feet at their
    footholds, swing feet on their swing curves); ``weight_set`` (n,) int: index into the reference's
    ``weight_sets``.

    ``joint_rows``: how many rows, from the first, need joint references (the joint angles and rates of
    ``state``). A reference that solves for them (the locomotion reference's leg inverse kinematics) may
    leave the later rows at its nominal joints with zero rates: the CAFE problem builder reads only the base
    of its SRB-tail rows. ``set_times`` sets it to all rows unless told otherwise.
    """

    def __init__(self, capacity: int, nq: int, nv: int, nu: int, n_feet: int) -> None:
        self.capacity = capacity
        self.nq, self.nv, self.nu, self.n_feet = nq, nv, nu, n_feet
        self._times = np.zeros(capacity)
        self._stance = np.zeros((capacity, n_feet), dtype=bool)
        self._state = np.zeros((capacity, nq + nv))
        self._torque = np.zeros((capacity, nu))
        self._forces = np.zeros((capacity, n_feet, 3))
        self._foot_positions = np.zeros((capacity, n_feet, 3))
        self._foot_velocities = np.zeros((capacity, n_feet, 3))
        self._weight_set = np.zeros(capacity, dtype=np.int64)
        self.set_times(np.zeros(0))

    def set_times(self, times: np.ndarray, joint_rows: int | None = None) -> None:
        """Use the first ``len(times)`` rows for these times (views; no allocation); joint references for
        the first ``joint_rows`` of them (all by default)."""
        n = len(times)
        if n > self.capacity:
            raise ValueError(f"reference window holds {self.capacity} times, asked for {n}")
        self.n = n
        self.joint_rows = n if joint_rows is None else min(max(int(joint_rows), 0), n)
        self.times = self._times[:n]
        self.times[:] = times
        self.stance = self._stance[:n]
        self.state = self._state[:n]
        self.torque = self._torque[:n]
        self.forces = self._forces[:n]
        self.foot_positions = self._foot_positions[:n]
        self.foot_velocities = self._foot_velocities[:n]
        self.weight_set = self._weight_set[:n]

    def check_finite(self, source: str) -> None:
        """One clear error if a reference produced a NaN/inf (instead of a NaN torque later)."""
        for name in ("state", "torque", "forces", "foot_positions", "foot_velocities"):
            if not all_finite(getattr(self, name).reshape(-1)):
                raise ValueError(f"{source}: reference field {name!r} is not finite over the window")


class Reference(ABC):
    """What the CAFE problem builder needs from a reference (see the module docstring)."""

    weight_sets: tuple[str, ...] = ("regular",)
    """Names of the weight sets this reference uses (``ReferenceWindow.weight_set`` indexes them)."""

    def update(self, t: float, q: np.ndarray, v: np.ndarray) -> None:  # noqa: B027 - optional hook
        """Re-anchor on the measured state before an MPC update (default: nothing)."""

    def observe_height_map(  # noqa: B027 - optional hook
        self, height_map: HeightMap, q: np.ndarray, v: np.ndarray | None = None
    ) -> None:
        """A height map relative to the base (``core.height_map``) taken at the tick of the measured state
        ``q`` (velocity ``v``): references that plan on terrain place it at ``q`` (default: ignored)."""

    def observe_estimate(self, t: float, q: np.ndarray, v: np.ndarray) -> None:  # noqa: B027 - optional hook
        """The state estimate of every control tick (not the predictions an update may start from):
        references that hold a height map to the estimator's frame follow it (default: ignored)."""

    def contact_frame(self) -> np.ndarray | None:
        """The ground's frame the plan's friction pyramid (26) is taken in (3 x 3, rows: two tangents and
        the normal, world; ``core.ground.contact_frame``), or None: world x, y, z (flat ground, the
        default)."""
        return None

    @abstractmethod
    def stance_at(self, t: float) -> tuple[bool, ...]:
        """Contact flags at time ``t``."""

    @abstractmethod
    def sample(self, window: ReferenceWindow) -> None:
        """Fill every field of ``window`` at ``window.times`` (in place)."""

    def switch_times(self, t0: float, t1: float) -> list[float]:
        """The times in ``(t0, t1)`` at which the contact flags change, increasing.

        The problem builder puts a knot boundary at each one, so that touchdowns and lift-offs happen at the
        reference's own times whatever time an update starts at. This default scans ``stance_at`` every
        millisecond (and refines each change by bisection); the references of this package answer from
        their schedules directly.
        """
        step = 1e-3
        times: list[float] = []
        previous_time, previous = t0, self.stance_at(t0 + STANCE_TIME_EPS)
        t = t0 + step
        while t < t1:
            flags = self.stance_at(t + STANCE_TIME_EPS)
            if flags != previous:
                low, high = previous_time, t
                for _ in range(20):
                    middle = 0.5 * (low + high)
                    if self.stance_at(middle + STANCE_TIME_EPS) == previous:
                        low = middle
                    else:
                        high = middle
                times.append(high)
                previous = flags
            previous_time = t
            t += step
        return switches_inside(times, t0, t1)

    @property
    def end_time(self) -> float:
        """Time after which the reference only holds its last state (``inf`` for periodic gaits)."""
        return float("inf")
