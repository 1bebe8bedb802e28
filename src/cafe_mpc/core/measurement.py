"""What a controller measures at a control tick, in the planning model's coordinates.

The simulator (``cafe_mpc_lab.sim.plant``) writes it; every controller reads it. Coordinates are Pinocchio's
free-flyer convention: ``q = [base position, base quaternion (x, y, z, w), joint angles]``,
``v = [base linear velocity (base frame), base angular velocity (base frame), joint rates]``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cafe_mpc.core.height_map import HeightMap


@dataclass
class Measurement:
    """Measured state, contacts and foot forces at ``time`` (a producer may overwrite its arrays in place
    on its next read: copy what must outlive the tick)."""

    time: float
    q: np.ndarray  # (nq,)
    v: np.ndarray  # (nv,)
    contacts: np.ndarray  # (n_feet,) bool, leg order
    foot_forces: np.ndarray  # (n_feet, 3) world-frame ground reaction forces on the feet
    height_map: HeightMap | None = None
    """The height map measured at this tick, relative to the base (``HeightMap.relative_to``); None on the
    ticks without a new map and on robots without the sensor."""

    @classmethod
    def zeros(cls, nq: int, nv: int, n_feet: int) -> Measurement:
        return cls(0.0, np.zeros(nq), np.zeros(nv), np.zeros(n_feet, dtype=bool), np.zeros((n_feet, 3)))

    @classmethod
    def of_state(cls, q: np.ndarray, v: np.ndarray, contacts: np.ndarray, time: float = 0.0) -> Measurement:
        """A measurement of ``(q, v)`` with the given contact flags and no force reading."""
        contacts = np.asarray(contacts, dtype=bool)
        return cls(
            float(time),
            np.asarray(q, dtype=float),
            np.asarray(v, dtype=float),
            contacts,
            np.zeros((len(contacts), 3)),
        )
