"""Compiled (numba) glue of the whole-body dynamics derivatives: Euler-step Jacobians from Pinocchio's.

Pinocchio returns ``d qdd / d(q, v, tau)`` (and ``d F / d(q, v, tau)`` with contacts); turning them into the
tangent Jacobians ``Fx``, ``Fu`` of the discrete step (23) takes a dozen small array operations, which in
Python cost about as much as the Pinocchio call itself. Here they are one compiled call per knot.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from cafe_mpc.core.kernels import stack_columns_left_multiplied


@njit(cache=True, nogil=True)
def euler_velocity_rows(
    da_dq: np.ndarray,
    da_dv: np.ndarray,
    da_dtau: np.ndarray,
    symmetric_upper: bool,
    dt: float,
    Fx: np.ndarray,
    Fu: np.ndarray,
) -> None:
    """The velocity rows of an Euler step's Jacobians (Eq. (23), ``v+ = v + qdd dt``): ``Fx[nv:] = [dt
    da_dq | I + dt da_dv]``, ``Fu[nv:] = dt da_dtau[:, actuated]`` (``da_dtau`` read symmetrically from its
    upper triangle with ``symmetric_upper``), column by column (Pinocchio's matrices are column-major)."""
    nv = da_dq.shape[0]
    nu = Fu.shape[1]
    first_actuated = nv - nu
    for j in range(nv):
        for i in range(nv):
            Fx[nv + i, j] = dt * da_dq[i, j]
        for i in range(nv):
            Fx[nv + i, nv + j] = dt * da_dv[i, j]
    for i in range(nv):
        Fx[nv + i, nv + i] += 1.0
    for j in range(nu):
        c = first_actuated + j
        for i in range(nv):
            if symmetric_upper and c < i:
                Fu[nv + i, j] = dt * da_dtau[c, i]
            else:
                Fu[nv + i, j] = dt * da_dtau[i, c]


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
    euler_velocity_rows(da_dq, da_dv, da_dtau, symmetric_upper, dt, Fx, Fu)
    # configuration rows
    if explicit:
        for i in range(nv):
            for j in range(nv):
                Fx[i, j] = dintegrate_dq[i, j]
                Fx[i, nv + j] = dt * dintegrate_dstep[i, j]
            for j in range(nu):
                Fu[i, j] = 0.0
    else:
        # q+ = q ⊕ (v+ dt): d q+ = Dq dq + (Dstep dt) d v+, over the nonzeros of each row of Dstep (the
        # identity outside the free flyer's block)
        columns = np.empty(nv, dtype=np.int64)
        coefficients = np.empty(nv)
        for i in range(nv):
            count = 0
            for p in range(nv):
                if dintegrate_dstep[i, p] != 0.0:
                    columns[count] = p
                    coefficients[count] = dt * dintegrate_dstep[i, p]
                    count += 1
            for j in range(nv):
                total_q = dintegrate_dq[i, j]
                total_v = 0.0
                for c in range(count):
                    row = nv + columns[c]
                    total_q += coefficients[c] * Fx[row, j]
                    total_v += coefficients[c] * Fx[row, nv + j]
                Fx[i, j] = total_q
                Fx[i, nv + j] = total_v
            for j in range(nu):
                total = 0.0
                for c in range(count):
                    total += coefficients[c] * Fu[nv + columns[c], j]
                Fu[i, j] = total


@njit(cache=True, nogil=True)
def free_flyer_euler_step_jacobians(
    da_dq: np.ndarray,
    da_dv: np.ndarray,
    da_dtau: np.ndarray,
    symmetric_upper: bool,
    step: np.ndarray,
    dt: float,
    explicit: bool,
    blocks: np.ndarray,
    Fx: np.ndarray,
    Fu: np.ndarray,
) -> None:
    """``euler_step_jacobians`` for a free-flyer robot (``free_flyer_configuration_integrate``): the Jacobians
    of ``q ⊕ step`` are the identity but for the base's 6 x 6 blocks (``free_flyer_integrate_jacobians``,
    written into ``blocks``, 6 x 12), so the configuration rows are formed over those blocks only; the same
    values as with ``pin.dIntegrate``'s full matrices."""
    nv = da_dq.shape[0]
    nu = Fu.shape[1]
    dq_block, dstep_block = blocks[:, :6], blocks[:, 6:]
    free_flyer_integrate_jacobians(step, dq_block, dstep_block)
    euler_velocity_rows(da_dq, da_dv, da_dtau, symmetric_upper, dt, Fx, Fu)
    if explicit:
        for i in range(nv):
            for j in range(nv):
                Fx[i, j] = 0.0
                Fx[i, nv + j] = 0.0
            for j in range(nu):
                Fu[i, j] = 0.0
        for i in range(6):
            for j in range(6):
                Fx[i, j] = dq_block[i, j]
                Fx[i, nv + j] = dt * dstep_block[i, j]
        for i in range(6, nv):
            Fx[i, i] = 1.0
            Fx[i, nv + i] = dt
        return
    # q+ = q ⊕ (v+ dt): d q+ = Dq dq + (Dstep dt) d v+, accumulated over the nonzeros of Dstep's row in
    # order, each a contiguous pass over the columns
    for i in range(6):
        for j in range(nv):
            Fx[i, j] = dq_block[i, j] if j < 6 else 0.0
            Fx[i, nv + j] = 0.0
        for j in range(nu):
            Fu[i, j] = 0.0
        for p in range(6):
            coefficient = dstep_block[i, p]
            if coefficient == 0.0:
                continue
            coefficient *= dt
            for j in range(2 * nv):
                Fx[i, j] += coefficient * Fx[nv + p, j]
            for j in range(nu):
                Fu[i, j] += coefficient * Fu[nv + p, j]
    for i in range(6, nv):
        for j in range(nv):
            Fx[i, j] = dt * Fx[nv + i, j]
            Fx[i, nv + j] = dt * Fx[nv + i, nv + j]
        Fx[i, i] += 1.0
        for j in range(nu):
            Fu[i, j] = dt * Fu[nv + i, j]


@njit(cache=True, nogil=True)
def _skew_product_rows(
    vector: tuple, matrix: np.ndarray, row: int, column: int, scale: float, out: np.ndarray
) -> None:
    """``out[:3, column:column + 3] += scale [vector]x matrix[row:row + 3, row:row + 3]``."""
    x, y, z = vector
    for j in range(3):
        m0, m1, m2 = matrix[row, row + j], matrix[row + 1, row + j], matrix[row + 2, row + j]
        out[0, column + j] += scale * (y * m2 - z * m1)
        out[1, column + j] += scale * (z * m0 - x * m2)
        out[2, column + j] += scale * (x * m1 - y * m0)


@njit(cache=True, nogil=True)
def world_velocity_euler_step_jacobians(
    da_dq: np.ndarray,
    da_dv: np.ndarray,
    da_dtau: np.ndarray,
    symmetric_upper: bool,
    step: np.ndarray,
    base_velocity: np.ndarray,
    next_linear_velocity: np.ndarray,
    dt: float,
    blocks: np.ndarray,
    Fx: np.ndarray,
    Fu: np.ndarray,
) -> None:
    """Tangent Jacobians of ``world_velocity_euler_step`` (free-flyer robot; ``step = (v dt, w dt, joints'
    v dt)``, ``base_velocity = (v, w)`` before the step, ``next_linear_velocity = v+``).

    With ``E = exp3(w dt)`` (``E'`` is the ``dq`` block of ``free_flyer_integrate_jacobians``) and ``J =
    Jexp3(w dt)`` (its ``dstep`` block), tangent perturbations ``p ⊕ dp = p + R dp``, ``R ⊕ dθ = R exp3(dθ)``:

    * ``dp+ = E' (dp - dt [v]x dθ + dt dv)``, ``dθ+ = E' dθ + dt J dw``;
    * ``dv+ = E' ((I + dt [w]x) dv - dt [v]x dw + dt da_lin) + dt [v+]x J dw``;
    * the angular and joint rows as the explicit step's (``euler_velocity_rows``, ``q+ = q + v dt``).
    """
    nv = da_dq.shape[0]
    nu = Fu.shape[1]
    dq_block, dstep_block = blocks[:, :6], blocks[:, 6:]
    free_flyer_integrate_jacobians(step, dq_block, dstep_block)
    euler_velocity_rows(da_dq, da_dv, da_dtau, symmetric_upper, dt, Fx, Fu)
    for i in range(nv):
        for j in range(nv):
            Fx[i, j] = 0.0
            Fx[i, nv + j] = 0.0
        for j in range(nu):
            Fu[i, j] = 0.0
    v = (base_velocity[0], base_velocity[1], base_velocity[2])
    w = (base_velocity[3], base_velocity[4], base_velocity[5])
    v_next = (next_linear_velocity[0], next_linear_velocity[1], next_linear_velocity[2])
    # configuration rows: position by the world velocity, orientation as the explicit step's
    skew_v = np.zeros((3, 3))
    _set_skew_block(skew_v, 0, 0, -dt, v[0], v[1], v[2])
    for i in range(3):
        for j in range(3):
            rotation_t = dq_block[i, j]
            Fx[i, j] = rotation_t
            Fx[i, nv + j] = dt * rotation_t
            Fx[i, 3 + j] = (
                dq_block[i, 0] * skew_v[0, j] + dq_block[i, 1] * skew_v[1, j] + dq_block[i, 2] * skew_v[2, j]
            )
            Fx[3 + i, 3 + j] = dq_block[3 + i, 3 + j]
            Fx[3 + i, nv + 3 + j] = dt * dstep_block[3 + i, 3 + j]
    for i in range(6, nv):
        Fx[i, i] = 1.0
        Fx[i, nv + i] = dt
    # linear velocity rows: E' applied to (the explicit rows + the classical terms), then the rotation of
    # the frame by dw
    inner = np.empty((3, 2 * nv))
    for i in range(3):
        for j in range(2 * nv):
            inner[i, j] = Fx[nv + i, j]
    _set_skew_block(inner, 0, nv, dt, w[0], w[1], w[2])
    _set_skew_block(inner, 0, nv + 3, -dt, v[0], v[1], v[2])
    inner_u = np.empty((3, nu))
    for i in range(3):
        for j in range(nu):
            inner_u[i, j] = Fu[nv + i, j]
    for i in range(3):
        e0, e1, e2 = dq_block[i, 0], dq_block[i, 1], dq_block[i, 2]
        for j in range(2 * nv):
            Fx[nv + i, j] = e0 * inner[0, j] + e1 * inner[1, j] + e2 * inner[2, j]
        for j in range(nu):
            Fu[nv + i, j] = e0 * inner_u[0, j] + e1 * inner_u[1, j] + e2 * inner_u[2, j]
    _skew_product_rows(v_next, dstep_block, 3, nv + 3, dt, Fx[nv : nv + 3])


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
def _velocity_step(
    acceleration: np.ndarray,
    contact_forces: np.ndarray,
    x: np.ndarray,
    dt: float,
    explicit: bool,
    nq: int,
    acceleration_out: np.ndarray,
    forces: np.ndarray,
    x_next: np.ndarray,
    step: np.ndarray,
) -> bool:
    """The velocity half of Eq. (23) shared by the Euler steps: ``v+ = v + qdd dt`` into ``x_next[nq:]``, the
    configuration step ``step`` (``v dt`` explicit, ``v+ dt`` semi-implicit), the acceleration and the contact
    forces copied out of Pinocchio's data. ``False`` if the acceleration is not finite."""
    v_next = x_next[nq:]
    for i in range(step.shape[0]):
        a = acceleration[i]
        if not np.isfinite(a):
            return False
        v = x[nq + i]
        acceleration_out[i] = a
        v_next[i] = v + a * dt
        step[i] = (v if explicit else v_next[i]) * dt
    for i in range(forces.shape[0]):
        forces[i] = contact_forces[i]
    return True


@njit(cache=True, nogil=True)
def euler_step(
    acceleration: np.ndarray,
    contact_forces: np.ndarray,
    x: np.ndarray,
    dt: float,
    explicit: bool,
    nq: int,
    free_flyer: bool,
    acceleration_out: np.ndarray,
    forces: np.ndarray,
    x_next: np.ndarray,
    step: np.ndarray,
) -> bool:
    """One Euler step (23) after the contact dynamics: ``v+ = v + qdd dt``, the configuration step ``step``
    (``v dt`` explicit, ``v+ dt`` semi-implicit) and, for a free-flyer robot (``free_flyer``), ``q+ = q ⊕
    step`` (``free_flyer_configuration_integrate``; otherwise the caller integrates). Copies the acceleration
    and the contact forces out of Pinocchio's data. ``False`` if the acceleration is not finite."""
    if not _velocity_step(
        acceleration, contact_forces, x, dt, explicit, nq, acceleration_out, forces, x_next, step
    ):
        return False
    if free_flyer:
        free_flyer_configuration_integrate(x, step, nq, x_next)
    return True


@njit(cache=True, nogil=True)
def world_velocity_euler_step(
    acceleration: np.ndarray,
    contact_forces: np.ndarray,
    x: np.ndarray,
    dt: float,
    nq: int,
    acceleration_out: np.ndarray,
    forces: np.ndarray,
    x_next: np.ndarray,
    step: np.ndarray,
) -> bool:
    """One explicit Euler step of a free-flyer robot with the base's linear velocity stepped in the world
    frame (``"explicit_world"``): with the base velocity ``(v, w)`` (body frame) and Pinocchio's spatial
    acceleration ``(a_lin, a_ang)``, the classical acceleration ``a_c = a_lin + w x v`` and

        p+ = p + R v dt,   R+ = R exp3(w dt),   v+ = exp3(-w dt) (v + a_c dt),   w+ = w + a_ang dt,

    i.e. the world velocity ``R v`` advances by ``R a_c dt``: a spinning body in free fall keeps its
    horizontal velocity exactly. The joints step as the explicit step's. ``step`` gets ``(v dt, w dt, joints'
    v dt)`` (what the Jacobians read). Copies the acceleration and the contact forces out of Pinocchio's
    data. ``False`` if the acceleration is not finite."""
    if not _velocity_step(
        acceleration, contact_forces, x, dt, True, nq, acceleration_out, forces, x_next, step
    ):
        return False
    v_next = x_next[nq:]
    vx, vy, vz = x[nq], x[nq + 1], x[nq + 2]
    wx, wy, wz = x[nq + 3], x[nq + 4], x[nq + 5]
    # orientation and joints by the explicit step with no base translation, then the world translation
    linear = (step[0], step[1], step[2])
    step[0], step[1], step[2] = 0.0, 0.0, 0.0
    free_flyer_configuration_integrate(x, step, nq, x_next)
    step[0], step[1], step[2] = linear
    px, py, pz = _rotate(x[3], x[4], x[5], x[6], linear[0], linear[1], linear[2])
    x_next[0], x_next[1], x_next[2] = x[0] + px, x[1] + py, x[2] + pz
    # y = v + (a_lin + w x v) dt, then v+ = exp3(-w dt) y
    yx = v_next[0] + dt * (wy * vz - wz * vy)
    yy = v_next[1] + dt * (wz * vx - wx * vz)
    yz = v_next[2] + dt * (wx * vy - wy * vx)
    sx, sy, sz = -wx * dt, -wy * dt, -wz * dt
    a_sine, b_cosine, _ = exp_coefficients(np.sqrt(sx * sx + sy * sy + sz * sz))
    cx, cy, cz = sy * yz - sz * yy, sz * yx - sx * yz, sx * yy - sy * yx  # s x y
    v_next[0] = yx + a_sine * cx + b_cosine * (sy * cz - sz * cy)
    v_next[1] = yy + a_sine * cy + b_cosine * (sz * cx - sx * cz)
    v_next[2] = yz + a_sine * cz + b_cosine * (sx * cy - sy * cx)
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


@njit(cache=True, nogil=True)
def _rotate(qx: float, qy: float, qz: float, qw: float, x: float, y: float, z: float) -> tuple:
    """The vector ``(x, y, z)`` rotated by the unit quaternion ``(qx, qy, qz, qw)``."""
    tx = 2.0 * (qy * z - qz * y)
    ty = 2.0 * (qz * x - qx * z)
    tz = 2.0 * (qx * y - qy * x)
    return (
        x + qw * tx + (qy * tz - qz * ty),
        y + qw * ty + (qz * tx - qx * tz),
        z + qw * tz + (qx * ty - qy * tx),
    )


_TAYLOR = 1e-4  # below this rotation angle (rad) the exp/log coefficients use their Taylor series


@njit(cache=True, nogil=True)
def relative_rotation_log(
    ax: float, ay: float, az: float, aw: float, bx: float, by: float, bz: float, bw: float
) -> tuple:
    """``(w, theta)`` with ``w = log3(R(a)^T R(b))`` (angle ``theta = |w|`` in ``[0, pi]``) from the
    quaternions ``a``, ``b`` (xyzw; their norms cancel), as ``pin.log3`` of the rotation matrices."""
    rw = aw * bw + ax * bx + ay * by + az * bz
    rx = aw * bx - ax * bw - ay * bz + az * by
    ry = aw * by - ay * bw - az * bx + ax * bz
    rz = aw * bz - az * bw - ax * by + ay * bx
    if rw < 0.0:  # the shortest rotation: angle in [0, pi]
        rw, rx, ry, rz = -rw, -rx, -ry, -rz
    norm_squared = rx * rx + ry * ry + rz * rz
    norm = np.sqrt(norm_squared)
    theta = 2.0 * np.arctan2(norm, rw)
    # theta over the vector part's norm (scale-free), its series near 0
    factor = 2.0 / rw - (2.0 / 3.0) * norm_squared / (rw * rw * rw) if theta < _TAYLOR else theta / norm
    return factor * rx, factor * ry, factor * rz, theta


@njit(cache=True, nogil=True)
def log_coefficients(theta: float) -> tuple:
    """``alpha = (theta / 2) cot(theta / 2)`` and ``beta = (1 - alpha) / theta^2``: the inverse left Jacobian
    of SO(3), ``Jlog3 = alpha I + beta w w' + [w]x / 2``, and the translation part of ``log6``."""
    t2 = theta * theta
    if theta < 1e-2:  # the closed forms cancel
        beta = 1.0 / 12.0 + t2 / 720.0 + t2 * t2 / 30240.0
        return 1.0 - t2 * beta, beta
    st, ct = np.sin(theta), np.cos(theta)
    alpha = theta * st / (2.0 * (1.0 - ct))
    return alpha, (1.0 - alpha) / t2


@njit(cache=True, nogil=True)
def free_flyer_configuration_difference(q0: np.ndarray, q1: np.ndarray, nq: int, out: np.ndarray) -> None:
    """``out[:nq - 1] = q1 ⊖ q0`` for a free-flyer robot whose other joints are vector-space joints
    (``q = [p (3), quaternion xyzw (4), joints]``): the base's ``log6(M0^-1 M1)`` (linear, angular, in the
    base frame, as ``pin.difference``), then the joints' differences."""
    ax, ay, az, aw = q0[3], q0[4], q0[5], q0[6]
    px, py, pz = _rotate(-ax, -ay, -az, aw, q1[0] - q0[0], q1[1] - q0[1], q1[2] - q0[2])
    wx, wy, wz, theta = relative_rotation_log(ax, ay, az, aw, q1[3], q1[4], q1[5], q1[6])
    alpha, beta = log_coefficients(theta)
    wp = beta * (wx * px + wy * py + wz * pz)
    out[0] = alpha * px - 0.5 * (wy * pz - wz * py) + wp * wx
    out[1] = alpha * py - 0.5 * (wz * px - wx * pz) + wp * wy
    out[2] = alpha * pz - 0.5 * (wx * py - wy * px) + wp * wz
    out[3], out[4], out[5] = wx, wy, wz
    for i in range(7, nq):
        out[i - 1] = q1[i] - q0[i]


@njit(cache=True, nogil=True)
def free_flyer_state_difference(x0: np.ndarray, x1: np.ndarray, nq: int, nv: int, out: np.ndarray) -> None:
    """``out = x1 ⊖ x0`` on the whole-body state ``[q, v]`` (``free_flyer_configuration_difference`` on
    ``q``, the velocities subtracted)."""
    free_flyer_configuration_difference(x0, x1, nq, out)
    for i in range(nv):
        out[nv + i] = x1[nq + i] - x0[nq + i]


@njit(cache=True, nogil=True)
def free_flyer_configuration_integrate(q: np.ndarray, dq: np.ndarray, nq: int, out: np.ndarray) -> None:
    """``out[:nq] = q ⊕ dq`` for the configuration of ``free_flyer_configuration_difference``: the base
    ``M exp6(dq_base)`` (its quaternion on the side of the input's and normalised to first order, as
    ``pin.integrate``), the joints added."""
    vx, vy, vz, wx, wy, wz = dq[0], dq[1], dq[2], dq[3], dq[4], dq[5]
    t2 = wx * wx + wy * wy + wz * wz
    theta = np.sqrt(t2)
    if theta < _TAYLOR:
        alpha_cross = 0.5 - t2 / 24.0
        alpha_v = 1.0 - t2 / 6.0
        alpha_w = 1.0 / 6.0 - t2 / 120.0
        half_sine = 0.5 - t2 / 48.0  # sin(theta / 2) / theta
        half_cosine = 1.0 - t2 / 8.0
    else:
        st, ct = np.sin(theta), np.cos(theta)
        alpha_cross = (1.0 - ct) / t2
        alpha_v = st / theta
        alpha_w = (1.0 - alpha_v) / t2
        half_sine = np.sin(0.5 * theta) / theta
        half_cosine = np.cos(0.5 * theta)
    wv = alpha_w * (wx * vx + wy * vy + wz * vz)
    tx = alpha_v * vx + wv * wx + alpha_cross * (wy * vz - wz * vy)
    ty = alpha_v * vy + wv * wy + alpha_cross * (wz * vx - wx * vz)
    tz = alpha_v * vz + wv * wz + alpha_cross * (wx * vy - wy * vx)
    ax, ay, az, aw = q[3], q[4], q[5], q[6]
    px, py, pz = _rotate(ax, ay, az, aw, tx, ty, tz)
    out[0], out[1], out[2] = q[0] + px, q[1] + py, q[2] + pz
    ex, ey, ez, ew = half_sine * wx, half_sine * wy, half_sine * wz, half_cosine
    qw = aw * ew - ax * ex - ay * ey - az * ez
    qx = aw * ex + ax * ew + ay * ez - az * ey
    qy = aw * ey + ay * ew + az * ex - ax * ez
    qz = aw * ez + az * ew + ax * ey - ay * ex
    if qx * ax + qy * ay + qz * az + qw * aw < 0.0:
        qx, qy, qz, qw = -qx, -qy, -qz, -qw
    scale = 0.5 * (3.0 - (qx * qx + qy * qy + qz * qz + qw * qw))
    out[3], out[4], out[5], out[6] = qx * scale, qy * scale, qz * scale, qw * scale
    for i in range(7, nq):
        out[i] = q[i] + dq[i - 1]


@njit(cache=True, nogil=True)
def free_flyer_state_integrate(x: np.ndarray, dx: np.ndarray, nq: int, nv: int, out: np.ndarray) -> None:
    """``out = x ⊕ dx`` on the state of ``free_flyer_state_difference``: the configuration's
    ``free_flyer_configuration_integrate``, the velocities added."""
    free_flyer_configuration_integrate(x, dx, nq, out)
    for i in range(nv):
        out[nq + i] = x[nq + i] + dx[nv + i]


@njit(cache=True, nogil=True)
def free_flyer_difference(x0: np.ndarray, x1: np.ndarray, out: np.ndarray) -> None:
    """``free_flyer_state_difference`` with the sizes from the arrays' (``ndx = 2 nv``, ``nx = nq + nv``):
    the free-flyer state's compiled ``difference`` (``core.interfaces.CompiledStateOperations``)."""
    nv = out.shape[0] // 2
    free_flyer_state_difference(x0, x1, x0.shape[0] - nv, nv, out)


@njit(cache=True, nogil=True)
def free_flyer_integrate(x: np.ndarray, dx: np.ndarray, out: np.ndarray) -> None:
    """``free_flyer_state_integrate`` with the sizes from the arrays': the free-flyer state's compiled
    ``integrate``."""
    nv = dx.shape[0] // 2
    free_flyer_state_integrate(x, dx, x.shape[0] - nv, nv, out)


@njit(cache=True, nogil=True)
def free_flyer_state_integrate_rows(
    xs: np.ndarray, dxs: np.ndarray, nq: int, nv: int, out: np.ndarray
) -> None:
    """``free_flyer_state_integrate`` on every row of a trajectory."""
    for k in range(xs.shape[0]):
        free_flyer_state_integrate(xs[k], dxs[k], nq, nv, out[k])


@njit(cache=True, nogil=True)
def exp_coefficients(theta: float) -> tuple:
    """``(sin t / t, (1 - cos t) / t^2, (1 - sin t / t) / t^2)`` at ``t = theta`` without cancellation
    (series below 1e-2 rad, the half-angle form of ``1 - cos``): the coefficients of ``exp3`` and of its
    right Jacobian ``Jexp3(w) = a I - b [w]x + c w w'``."""
    t2 = theta * theta
    if theta < 1e-2:
        return (
            1.0 - t2 / 6.0 + t2 * t2 / 120.0,
            0.5 - t2 / 24.0 + t2 * t2 / 720.0,
            1.0 / 6.0 - t2 / 120.0 + t2 * t2 / 5040.0,
        )
    sine = np.sin(theta) / theta
    half = np.sin(0.5 * theta)
    return sine, 2.0 * half * half / t2, (1.0 - sine) / t2


@njit(cache=True, nogil=True)
def se3_log_coefficients(theta: float) -> tuple:
    """``(alpha, beta, beta'(t) / t)`` at ``t = theta`` with ``alpha = (t / 2) cot(t / 2)`` and ``beta = (1 -
    alpha) / t^2`` (as ``log_coefficients``): the coefficients of ``Jlog3`` and of the coupling blocks of
    ``Jlog6`` and ``Jexp6``. Their closed forms cancel (``beta'/t`` to ``2 eps / t^6``: 1 % off at 1e-2 rad),
    so below 0.3 rad ``beta`` and ``beta'/t`` are the series ``beta = sum c_k t^(2k)``, ``beta'/t = sum 2k c_k
    t^(2k-2)`` (``c_k`` from the Bernoulli numbers, truncated below 1e-16 relative) and ``alpha = 1 - t^2
    beta``; above, ``alpha`` from the half angle."""
    t2 = theta * theta
    if theta < 0.3:
        tail = 1.0 / 1209600.0 + t2 * (1.0 / 47900160.0 + t2 * (691.0 / 1307674368000.0))
        beta = 1.0 / 12.0 + t2 * (1.0 / 720.0 + t2 * (1.0 / 30240.0 + t2 * tail))
        beta_dot = 1.0 / 360.0 + t2 * (
            1.0 / 7560.0 + t2 * (1.0 / 201600.0 + t2 * (1.0 / 5987520.0 + t2 * (6910.0 / 1307674368000.0)))
        )
        return 1.0 - t2 * beta, beta, beta_dot
    half = 0.5 * theta
    alpha = half * np.cos(half) / np.sin(half)
    st, ct = np.sin(theta), np.cos(theta)
    return alpha, (1.0 - alpha) / t2, -2.0 / (t2 * t2) + (1.0 + st / theta) / t2 / (2.0 * (1.0 - ct))


@njit(cache=True, nogil=True)
def _set_skew_block(out: np.ndarray, row: int, column: int, a: float, x: float, y: float, z: float) -> None:
    """``out[row:row+3, column:column+3] += a [(x, y, z)]x``."""
    out[row, column + 1] -= a * z
    out[row + 1, column] += a * z
    out[row, column + 2] += a * y
    out[row + 2, column] -= a * y
    out[row + 1, column + 2] -= a * x
    out[row + 2, column + 1] += a * x


@njit(cache=True, nogil=True)
def _rotation_blocks(
    out: np.ndarray, diagonal: float, outer: float, skew: float, wx: float, wy: float, wz: float
) -> None:
    """Both 3 x 3 diagonal blocks of the 6 x 6 ``out`` set to ``diagonal I + outer w w' + skew [w]x`` and the
    lower-left block to zero: the rotation-shaped blocks of ``Ad``, ``Jexp6`` and ``Jlog6``."""
    w = (wx, wy, wz)
    for i in range(3):
        for j in range(3):
            value = outer * w[i] * w[j]
            out[i, j] = value
            out[3 + i, 3 + j] = value
            out[3 + i, j] = 0.0
        out[i, i] += diagonal
        out[3 + i, 3 + i] += diagonal
    _set_skew_block(out, 0, 0, skew, wx, wy, wz)
    _set_skew_block(out, 3, 3, skew, wx, wy, wz)


@njit(cache=True, nogil=True)
def _se3_coupling(
    beta: float, beta_dot: float, w: tuple, p: tuple, theta2: float, scratch: np.ndarray
) -> None:
    """``scratch = [p]x / 2 + (beta_dot w.p) w w' - (t^2 beta_dot + 2 beta) p w' + beta (w.p I + w p')``:
    the matrix that, times the rotation block, gives the coupling block of ``Jlog6`` (``Jexp6``: minus)."""
    w_p = w[0] * p[0] + w[1] * p[1] + w[2] * p[2]
    ww = beta_dot * w_p
    pw = theta2 * beta_dot + 2.0 * beta
    for i in range(3):
        for j in range(3):
            scratch[i, j] = (ww * w[i] - pw * p[i]) * w[j] + beta * w[i] * p[j]
        scratch[i, i] += w_p * beta
    _set_skew_block(scratch, 0, 0, 0.5, p[0], p[1], p[2])


@njit(cache=True, nogil=True)
def free_flyer_integrate_jacobians(step: np.ndarray, dq_block: np.ndarray, dstep_block: np.ndarray) -> None:
    """The free flyer's 6 x 6 blocks of ``pin.dIntegrate(q, s)`` for the base step ``s = step[:6]`` (linear,
    angular; they do not depend on ``q``): ``d(q ⊕ s)/dq = Ad(exp6(s)^-1)`` into ``dq_block`` and the right
    Jacobian ``d(q ⊕ s)/ds = Jexp6(s)`` into ``dstep_block`` (Pinocchio's ``Jexp6`` formula), with the
    coefficients of ``exp_coefficients`` and ``se3_log_coefficients``: accurate at every angle, where
    Pinocchio's closed forms lose up to 1e-5 between 1e-4 and 1e-2 rad."""
    vx, vy, vz, wx, wy, wz = step[0], step[1], step[2], step[3], step[4], step[5]
    w = (wx, wy, wz)
    t2 = wx * wx + wy * wy + wz * wz
    theta = np.sqrt(t2)
    a, b, c = exp_coefficients(theta)
    # exp6(s) = (R, p): R = cos t I + a [w]x + b w w', p = a v + c (w.v) w + b w x v
    cosine = 1.0 - b * t2
    wv = c * (wx * vx + wy * vy + wz * vz)
    px = a * vx + wv * wx + b * (wy * vz - wz * vy)
    py = a * vy + wv * wy + b * (wz * vx - wx * vz)
    pz = a * vz + wv * wz + b * (wx * vy - wy * vx)
    # Ad(exp6(s)^-1) = [[R', -R' [p]x], [0, R']]
    _rotation_blocks(dq_block, cosine, b, -a, wx, wy, wz)
    for i in range(3):
        r0, r1, r2 = dq_block[i, 0], dq_block[i, 1], dq_block[i, 2]
        dq_block[i, 3] = -(r1 * pz - r2 * py)
        dq_block[i, 4] = -(r2 * px - r0 * pz)
        dq_block[i, 5] = -(r0 * py - r1 * px)
    # Jexp6(s) = [[J3, -J3 X], [0, J3]], J3 = Jexp3(w) = a I - b [w]x + c w w', X of p3 = J3' v
    _rotation_blocks(dstep_block, a, c, -b, wx, wy, wz)
    p3 = (
        dstep_block[0, 0] * vx + dstep_block[1, 0] * vy + dstep_block[2, 0] * vz,
        dstep_block[0, 1] * vx + dstep_block[1, 1] * vy + dstep_block[2, 1] * vz,
        dstep_block[0, 2] * vx + dstep_block[1, 2] * vy + dstep_block[2, 2] * vz,
    )
    _, beta, beta_dot = se3_log_coefficients(theta)
    coupling = np.empty((3, 3))
    _se3_coupling(beta, beta_dot, w, p3, t2, coupling)
    for i in range(3):
        for j in range(3):
            dstep_block[i, 3 + j] = -(
                dstep_block[i, 0] * coupling[0, j]
                + dstep_block[i, 1] * coupling[1, j]
                + dstep_block[i, 2] * coupling[2, j]
            )


@njit(cache=True, nogil=True)
def free_flyer_difference_jacobian(q0: np.ndarray, q1: np.ndarray, out: np.ndarray) -> None:
    """``out`` (6 x 6) = the free flyer's block of ``pin.dDifference(q0, q1, ARG1)``: the right Jacobian
    ``Jlog6(M0^-1 M1) = [[J3, C J3], [0, J3]]`` with ``J3 = Jlog3 = alpha I + beta w w' + [w]x / 2`` and
    Pinocchio's ``C`` of the translation ``p = R0' (p1 - p0)``; the rotation log from the quaternions as in
    ``free_flyer_configuration_difference``, the coefficients by ``se3_log_coefficients`` (accurate at every
    angle, where Pinocchio's lose up to 1e-5)."""
    ax, ay, az, aw = q0[3], q0[4], q0[5], q0[6]
    px, py, pz = _rotate(-ax, -ay, -az, aw, q1[0] - q0[0], q1[1] - q0[1], q1[2] - q0[2])
    wx, wy, wz, theta = relative_rotation_log(ax, ay, az, aw, q1[3], q1[4], q1[5], q1[6])
    alpha, beta, beta_dot = se3_log_coefficients(theta)
    w = (wx, wy, wz)
    _rotation_blocks(out, alpha, beta, 0.5, wx, wy, wz)
    coupling = np.empty((3, 3))
    _se3_coupling(beta, beta_dot, w, (px, py, pz), theta * theta, coupling)
    for i in range(3):
        for j in range(3):
            out[i, 3 + j] = (
                coupling[i, 0] * out[0, j] + coupling[i, 1] * out[1, j] + coupling[i, 2] * out[2, j]
            )


@njit(cache=True, nogil=True)
def free_flyer_difference_jacobian_product_stacked(
    x0: np.ndarray, x1: np.ndarray, left: np.ndarray, right: np.ndarray, out: np.ndarray
) -> None:
    """``out = ∂(x1 ⊖ x0)/∂x1 [left | right]`` on the state of ``free_flyer_state_difference``: the base's
    ``Jlog6`` (``free_flyer_difference_jacobian``) on the first 6 rows, the identity on the others."""
    jacobian = np.empty((6, 6))
    free_flyer_difference_jacobian(x0, x1, jacobian)
    stack_columns_left_multiplied(jacobian, 6, left, right, out)
