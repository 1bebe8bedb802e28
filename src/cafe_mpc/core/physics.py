"""Physical constants shared by the models, the references, the estimator and the plant description.

Gravity is defined here once: the SRB model (Eq. (29)), the statics and force references, the estimator's
specific-force correction, the MJCF the plant is built from and the scaling of robots all read it, so the
planner's model and the simulated world cannot disagree about it.
"""

from __future__ import annotations

import numpy as np

GRAVITY = 9.81
"""Magnitude of gravitational acceleration, m/s^2 (the plant's MJCF ``<option gravity>`` and the models')."""

GRAVITY_VECTOR = np.array([0.0, 0.0, -GRAVITY])
"""Gravitational acceleration in the world frame (z up), m/s^2."""
GRAVITY_VECTOR.flags.writeable = False
