"""Compiled (numba) sampling of the locomotion reference's swing feet.

Every MPC update samples the foot references at some forty knot times for four feet: in Python, the
per-time loop with its Bezier blends took about as long as a knot's linearisation. Here it is one compiled
call per foot over the swing segments the reference computed (``LocomotionReference.feet``).
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def _bezier(s: float) -> tuple[float, float]:
    """Cubic Bezier with control points (0, 0, 1, 1): ``3s^2 - 2s^3`` and its derivative (``s`` clamped)."""
    s = min(max(s, 0.0), 1.0)
    return 3.0 * s * s - 2.0 * s * s * s, 6.0 * s - 6.0 * s * s


@njit(cache=True, nogil=True)
def sample_foot(
    times: np.ndarray,
    liftoffs: np.ndarray,
    touchdowns: np.ndarray,
    starts: np.ndarray,
    ends: np.ndarray,
    stance_position: np.ndarray,
    swing_height: float,
    foot: int,
    stance: np.ndarray,
    positions: np.ndarray,
    velocities: np.ndarray,
) -> None:
    """One foot's reference at ``times`` from its swing segments ``[liftoffs[j], touchdowns[j])`` (from
    ``starts[j]`` to ``ends[j]``, ordered in time): on a segment, the Bezier swing (planar blend, apex
    ``swing_height`` above the higher end at mid-swing, zero velocity at both ends); elsewhere stance on the
    end of the last segment that touched down before ``t`` (``stance_position`` before any). Writes column
    ``foot`` of ``stance`` (n, n_feet), ``positions`` and ``velocities`` (n, n_feet, 3)."""
    tolerance = 1e-9
    for i in range(times.shape[0]):
        t = times[i]
        px, py, pz = stance_position[0], stance_position[1], stance_position[2]
        in_swing = False
        for j in range(liftoffs.shape[0]):
            liftoff, touchdown = liftoffs[j], touchdowns[j]
            if liftoff - tolerance <= t < touchdown - tolerance:
                in_swing = True
                duration = touchdown - liftoff
                s = (t - liftoff) / duration
                blend, dblend = _bezier(s)
                for a in range(2):
                    delta = ends[j, a] - starts[j, a]
                    positions[i, foot, a] = starts[j, a] + delta * blend
                    velocities[i, foot, a] = delta * dblend / duration
                z0, z1 = starts[j, 2], ends[j, 2]
                apex = max(z0, z1) + swing_height
                if s < 0.5:
                    blend, dblend = _bezier(2.0 * s)
                    positions[i, foot, 2] = z0 + (apex - z0) * blend
                    velocities[i, foot, 2] = (apex - z0) * dblend * 2.0 / duration
                else:
                    blend, dblend = _bezier(2.0 * s - 1.0)
                    positions[i, foot, 2] = apex + (z1 - apex) * blend
                    velocities[i, foot, 2] = (z1 - apex) * dblend * 2.0 / duration
                break
            if t >= touchdown - tolerance:
                px, py, pz = ends[j, 0], ends[j, 1], ends[j, 2]
        stance[i, foot] = not in_swing
        if not in_swing:
            positions[i, foot, 0] = px
            positions[i, foot, 1] = py
            positions[i, foot, 2] = pz
            for a in range(3):
                velocities[i, foot, a] = 0.0
