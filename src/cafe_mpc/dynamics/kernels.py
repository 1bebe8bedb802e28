"""Compiled (numba) glue of the whole-body dynamics derivatives: Euler-step Jacobians from Pinocchio's.

Pinocchio returns ``d qdd / d(q, v, tau)`` (and ``d F / d(q, v, tau)`` with contacts); turning them into the
tangent Jacobians ``Fx``, ``Fu`` of the discrete step (23) takes a dozen small array operations, which in
Python cost about as much as the Pinocchio call itself. Here they are one compiled call per knot.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def euler_step_jacobians(
    da_dq: np.ndarray,
    da_dv: np.ndarray,
    da_dtau: np.ndarray,
    symmetric_upper: bool,
    dintegrate_dq: np.ndarray,
    dintegrate_dstep: np.ndarray,
    dt: float,
    explicit: bool,
    Fx: np.ndarray,
    Fu: np.ndarray,
) -> None:
    """Tangent Jacobians of one Euler step (Eq. (23)) from the acceleration derivatives.

    ``v+ = v + qdd dt``; explicit: ``q+ = q ⊕ v dt``; semi-implicit: ``q+ = q ⊕ v+ dt``. ``da_dtau`` is
    ``nv x nv`` (its actuated columns ``6:`` are used); with ``symmetric_upper`` only its upper triangle is
    valid (Pinocchio's ``Minv`` after ABA derivatives) and it is read symmetrically.
    """
    nv = da_dq.shape[0]
    nu = Fu.shape[1]
    first_actuated = nv - nu
    # velocity rows
    for i in range(nv):
        for j in range(nv):
            Fx[nv + i, j] = dt * da_dq[i, j]
            Fx[nv + i, nv + j] = dt * da_dv[i, j]
        Fx[nv + i, nv + i] += 1.0
        for j in range(nu):
            c = first_actuated + j
            if symmetric_upper and c < i:
                Fu[nv + i, j] = dt * da_dtau[c, i]
            else:
                Fu[nv + i, j] = dt * da_dtau[i, c]
    # configuration rows
    if explicit:
        for i in range(nv):
            for j in range(nv):
                Fx[i, j] = dintegrate_dq[i, j]
                Fx[i, nv + j] = dt * dintegrate_dstep[i, j]
            for j in range(nu):
                Fu[i, j] = 0.0
    else:
        # q+ = q ⊕ (v+ dt): d q+ = Dq dq + (Dstep dt) d v+
        for i in range(nv):
            for j in range(nv):
                total_q = dintegrate_dq[i, j]
                total_v = 0.0
                for p in range(nv):
                    coefficient = dt * dintegrate_dstep[i, p]
                    if coefficient != 0.0:
                        total_q += coefficient * Fx[nv + p, j]
                        total_v += coefficient * Fx[nv + p, nv + j]
                Fx[i, j] = total_q
                Fx[i, nv + j] = total_v
            for j in range(nu):
                total = 0.0
                for p in range(nv):
                    total += dt * dintegrate_dstep[i, p] * Fu[nv + p, j]
                Fu[i, j] = total


@njit(cache=True, nogil=True)
def copy_force_derivatives(
    dlambda_dq: np.ndarray,
    dlambda_dv: np.ndarray,
    dlambda_dtau: np.ndarray,
    dforces_dx: np.ndarray,
    dforces_du: np.ndarray,
) -> None:
    """``dF/dx = [dF/dq | dF/dv]`` and ``dF/du = dF/dtau[:, actuated]``."""
    nf, nv = dlambda_dq.shape
    nu = dforces_du.shape[1]
    for i in range(nf):
        for j in range(nv):
            dforces_dx[i, j] = dlambda_dq[i, j]
            dforces_dx[i, nv + j] = dlambda_dv[i, j]
        for j in range(nu):
            dforces_du[i, j] = dlambda_dtau[i, nv - nu + j]


@njit(cache=True, nogil=True)
def euler_velocity_step(
    acceleration: np.ndarray,
    v: np.ndarray,
    dt: float,
    explicit: bool,
    acceleration_out: np.ndarray,
    v_next: np.ndarray,
    step: np.ndarray,
) -> bool:
    """``v+ = v + qdd dt`` and the configuration step of Eq. (23) (``v dt`` explicit, ``v+ dt``
    semi-implicit); ``False`` if the acceleration is not finite."""
    for i in range(v.shape[0]):
        a = acceleration[i]
        if not np.isfinite(a):
            return False
        acceleration_out[i] = a
        v_next[i] = v[i] + a * dt
        step[i] = (v[i] if explicit else v_next[i]) * dt
    return True


@njit(cache=True, nogil=True)
def quaternion_rotation_into(quaternion: np.ndarray, out: np.ndarray) -> None:
    """Rotation matrix of the quaternion ``(x, y, z, w)`` into ``out`` (3 x 3), Eigen's
    ``Quaternion::toRotationMatrix`` term by term (no normalisation)."""
    x, y, z, w = quaternion[0], quaternion[1], quaternion[2], quaternion[3]
    tx, ty, tz = 2.0 * x, 2.0 * y, 2.0 * z
    twx, twy, twz = tx * w, ty * w, tz * w
    txx, txy, txz = tx * x, ty * x, tz * x
    tyy, tyz, tzz = ty * y, tz * y, tz * z
    out[0, 0] = 1.0 - (tyy + tzz)
    out[0, 1] = txy - twz
    out[0, 2] = txz + twy
    out[1, 0] = txy + twz
    out[1, 1] = 1.0 - (txx + tzz)
    out[1, 2] = tyz - twx
    out[2, 0] = txz - twy
    out[2, 1] = tyz + twx
    out[2, 2] = 1.0 - (txx + tyy)


@njit(cache=True, nogil=True)
def foot_point_velocities(
    jacobian: np.ndarray,
    v: np.ndarray,
    positions: np.ndarray,
    legs: np.ndarray,
    columns: np.ndarray,
    n_columns: np.ndarray,
    position_jacobians: np.ndarray,
    velocities: np.ndarray,
) -> None:
    """World position Jacobians and world velocities of the foot points of ``legs``.

    ``jacobian``: Pinocchio's joint Jacobian in the WORLD frame (``data.J``, 6 x nv: velocity of the point at
    the origin, angular velocity); ``positions[leg]``: the foot point in the world. Over the columns
    ``columns[leg, :n_columns[leg]]`` of the leg's kinematic chain it writes ``J_k = lin_k + ang_k x p`` into
    ``position_jacobians[leg]`` (the other columns are never written: zero) and ``pdot = sum_k J_k v_k``.
    """
    for leg in legs:
        px, py, pz = positions[leg, 0], positions[leg, 1], positions[leg, 2]
        out = position_jacobians[leg]
        vx = vy = vz = 0.0
        for c in range(n_columns[leg]):
            m = columns[leg, c]
            ax, ay, az = jacobian[3, m], jacobian[4, m], jacobian[5, m]
            jx = jacobian[0, m] + ay * pz - az * py
            jy = jacobian[1, m] + az * px - ax * pz
            jz = jacobian[2, m] + ax * py - ay * px
            out[0, m], out[1, m], out[2, m] = jx, jy, jz
            vx += jx * v[m]
            vy += jy * v[m]
            vz += jz * v[m]
        velocities[leg, 0], velocities[leg, 1], velocities[leg, 2] = vx, vy, vz


@njit(cache=True, nogil=True)
def foot_velocity_q_jacobians(
    jacobian: np.ndarray,
    v: np.ndarray,
    velocity_legs: np.ndarray,
    columns: np.ndarray,
    joint_starts: np.ndarray,
    n_columns: np.ndarray,
    position_jacobians: np.ndarray,
    velocities: np.ndarray,
    velocity_dq: np.ndarray,
) -> None:
    """``d pdot / d q`` of the feet's world velocities from ``foot_point_velocities``' results.

    ``d pdot / d q_m = w_m x (pdot - P_<m) + W_<m x J_m``: a column ``m`` moves everything after its joint
    rigidly (axis ``w_m``), which turns the part of ``pdot`` those joints make; the joints before ``m``'s
    (velocity ``P_<m`` of the point, angular velocity ``W_<m``) see the point move by ``J_m``. On the free
    flyer's own columns the right-perturbation convention of ``pin.integrate`` gives the same form.
    ``joint_starts`` marks the first column of each joint. Equal to ``getPointVelocityDerivatives`` in
    ``LOCAL_WORLD_ALIGNED`` (tested), without its forward-kinematics derivatives pass.
    """
    for leg in velocity_legs:
        jp = position_jacobians[leg]
        dq = velocity_dq[leg]
        vx, vy, vz = velocities[leg, 0], velocities[leg, 1], velocities[leg, 2]
        before_x = before_y = before_z = 0.0  # point velocity from the joints before the current one
        spin_x = spin_y = spin_z = 0.0  # angular velocity of the current joint's parent
        through_x = through_y = through_z = 0.0  # point velocity through the current joint
        turn_x = turn_y = turn_z = 0.0  # angular velocity through the current joint
        for c in range(n_columns[leg]):
            m = columns[leg, c]
            if joint_starts[leg, c]:
                before_x, before_y, before_z = through_x, through_y, through_z
                spin_x, spin_y, spin_z = turn_x, turn_y, turn_z
            wx, wy, wz = jacobian[3, m], jacobian[4, m], jacobian[5, m]
            jx, jy, jz = jp[0, m], jp[1, m], jp[2, m]
            rx, ry, rz = vx - before_x, vy - before_y, vz - before_z
            dq[0, m] = wy * rz - wz * ry + spin_y * jz - spin_z * jy
            dq[1, m] = wz * rx - wx * rz + spin_z * jx - spin_x * jz
            dq[2, m] = wx * ry - wy * rx + spin_x * jy - spin_y * jx
            vm = v[m]
            through_x += jx * vm
            through_y += jy * vm
            through_z += jz * vm
            turn_x += wx * vm
            turn_y += wy * vm
            turn_z += wz * vm
