"""A floating base's state in a simulator's free-joint convention and in the planning coordinates.

MuJoCo (and simulators built on it) store a free joint as ``qpos = [position, quaternion (w, x, y, z),
joints]`` and ``qvel = [world-frame linear velocity, base-frame angular velocity, joint rates]``; the
planning model (Pinocchio's free flyer) as ``q = [position, quaternion (x, y, z, w), joints]`` and ``v =
[base-frame linear velocity, base-frame angular velocity, joint rates]``. The conversion is arithmetic on
arrays: the library front end (``cafe_mpc.api``: ``free_joint_measurement``) uses it without a simulator, the
plants (``sim``) on every tick.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from cafe_mpc.core.measurement import Measurement


def rotation_from_wxyz(quaternion_wxyz: np.ndarray, out: np.ndarray) -> None:
    """The rotation matrix (row-major, 9 values) of a unit quaternion ``(w, x, y, z)``, into ``out``."""
    w, x, y, z = (float(value) for value in quaternion_wxyz)
    out[0] = w * w + x * x - y * y - z * z
    out[1] = 2.0 * (x * y - w * z)
    out[2] = 2.0 * (x * z + w * y)
    out[3] = 2.0 * (x * y + w * z)
    out[4] = w * w - x * x + y * y - z * z
    out[5] = 2.0 * (y * z - w * x)
    out[6] = 2.0 * (x * z - w * y)
    out[7] = 2.0 * (y * z + w * x)
    out[8] = w * w - x * x - y * y + z * z


def planning_state(
    qpos: np.ndarray, qvel: np.ndarray, q: np.ndarray, v: np.ndarray, rotation: np.ndarray | None = None
) -> None:
    """Free-joint ``(qpos, qvel)`` -> planning coordinates ``(q, v)``, written into ``q`` and ``v``:
    quaternion (w, x, y, z) -> (x, y, z, w), world-frame -> base-frame linear velocity.

    ``rotation``: the base's rotation matrix (row-major, 9 values) when the caller has it already (a
    simulator computes it with its own routine: the plants pass MuJoCo's ``mju_quat2Mat``); else it is
    computed from the quaternion."""
    if rotation is None:
        rotation = np.empty(9)
        rotation_from_wxyz(qpos[3:7], rotation)
    q[:3] = qpos[:3]
    q[3:6] = qpos[4:7]
    q[6] = qpos[3]
    q[7:] = qpos[7:]
    v[:3] = rotation.reshape(3, 3).T @ qvel[:3]
    v[3:] = qvel[3:]


def free_joint_qpos(q: np.ndarray) -> np.ndarray:
    """Planning ``q`` -> free-joint ``qpos`` (quaternion (x, y, z, w) -> (w, x, y, z)), a new array."""
    return np.concatenate([q[:3], [q[6], q[3], q[4], q[5]], q[7:]])


def free_joint_measurement(
    qpos: np.ndarray,
    qvel: np.ndarray,
    nv: int,
    n_feet: int,
    time: float = 0.0,
    contacts: Sequence[bool] | None = None,
) -> Measurement:
    """A ``Measurement`` (new arrays) of a free-joint state ``(qpos, qvel)`` (``planning_state``) of a robot
    with ``nv`` velocities at ``time``: ``contacts``, the feet in contact (leg order; default none), no force
    reading. ``ValueError`` for arrays of other shapes."""
    qpos, qvel = np.asarray(qpos, dtype=float), np.asarray(qvel, dtype=float)
    if qpos.shape != (nv + 1,) or qvel.shape != (nv,):
        raise ValueError(
            f"qpos must have shape ({nv + 1},) (position, quaternion w x y z, {nv - 6} joints) and qvel "
            f"({nv},), got {qpos.shape} and {qvel.shape}"
        )
    q, v = np.zeros(nv + 1), np.zeros(nv)
    planning_state(qpos, qvel, q, v)
    flags = np.zeros(n_feet, dtype=bool) if contacts is None else np.asarray(contacts, dtype=bool)
    if flags.shape != (n_feet,):
        raise ValueError(f"contacts must have {n_feet} flags (leg order), got shape {flags.shape}")
    return Measurement(float(time), q, v, flags, np.zeros((n_feet, 3)))
