"""Compiled (numba) SRB dynamics (Eqs. (29), (30)) and the SO(3) maths they need.

The SRB tail has few knots, but in Python each of its knots costs a few dozen small numpy and Pinocchio
calls (rotations, cross products, ``exp3``, ``log3`` and their Jacobians), as much as a whole-body knot's
Pinocchio work. Here each knot's step, its Jacobians, and the SRB state manifold's operations are single
compiled calls. The SO(3) functions follow the closed forms Pinocchio uses (``exp3``, ``log3``, ``Jexp3``,
``Jlog3``, with series near zero and the symmetric-part formula near pi); tests compare them with Pinocchio.

Conventions as in ``dynamics/srb.py``: state ``[c, quaternion (x, y, z, w), c_dot (world), omega (body)]``,
tangent ``[dc, dtheta (body, R exp(dtheta)), dc_dot, domega]``, controls: four world foot forces.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

_SMALL = 1e-8


@njit(cache=True, nogil=True)
def quaternion_to_rotation(q: np.ndarray, out: np.ndarray) -> None:
    """Rotation matrix of a quaternion ``(x, y, z, w)`` (normalised on the fly)."""
    x, y, z, w = q[0], q[1], q[2], q[3]
    n = 1.0 / math.sqrt(x * x + y * y + z * z + w * w)
    x, y, z, w = x * n, y * n, z * n, w * n
    out[0, 0] = 1.0 - 2.0 * (y * y + z * z)
    out[0, 1] = 2.0 * (x * y - z * w)
    out[0, 2] = 2.0 * (x * z + y * w)
    out[1, 0] = 2.0 * (x * y + z * w)
    out[1, 1] = 1.0 - 2.0 * (x * x + z * z)
    out[1, 2] = 2.0 * (y * z - x * w)
    out[2, 0] = 2.0 * (x * z - y * w)
    out[2, 1] = 2.0 * (y * z + x * w)
    out[2, 2] = 1.0 - 2.0 * (x * x + y * y)


@njit(cache=True, nogil=True)
def skew(v: np.ndarray, out: np.ndarray) -> None:
    out[0, 0] = 0.0
    out[0, 1] = -v[2]
    out[0, 2] = v[1]
    out[1, 0] = v[2]
    out[1, 1] = 0.0
    out[1, 2] = -v[0]
    out[2, 0] = -v[1]
    out[2, 1] = v[0]
    out[2, 2] = 0.0


@njit(cache=True, nogil=True)
def exp3(w: np.ndarray, out: np.ndarray) -> None:
    """``exp([w]x)`` (Rodrigues)."""
    theta2 = w[0] * w[0] + w[1] * w[1] + w[2] * w[2]
    theta = math.sqrt(theta2)
    if theta < 1e-4:
        a = 1.0 - theta2 / 6.0
        b = 0.5 - theta2 / 24.0
    else:
        a = math.sin(theta) / theta
        b = (1.0 - math.cos(theta)) / theta2
    K = np.empty((3, 3))
    skew(w, K)
    for i in range(3):
        for j in range(3):
            total = a * K[i, j]
            for p in range(3):
                total += b * K[i, p] * K[p, j]
            out[i, j] = total + (1.0 if i == j else 0.0)


@njit(cache=True, nogil=True)
def log3(R: np.ndarray, out: np.ndarray) -> float:
    """``log(R)`` as a rotation vector in ``out``; returns the angle in ``[0, pi]``."""
    trace = R[0, 0] + R[1, 1] + R[2, 2]
    cos_theta = min(max(0.5 * (trace - 1.0), -1.0), 1.0)
    vx = 0.5 * (R[2, 1] - R[1, 2])
    vy = 0.5 * (R[0, 2] - R[2, 0])
    vz = 0.5 * (R[1, 0] - R[0, 1])
    theta = math.atan2(math.sqrt(vx * vx + vy * vy + vz * vz), cos_theta)  # accurate also near 0 and pi
    if theta < 1e-4:
        factor = 1.0 + theta * theta / 6.0
        out[0], out[1], out[2] = factor * vx, factor * vy, factor * vz
    elif theta < math.pi - 1e-3:
        factor = theta / math.sin(theta)
        out[0], out[1], out[2] = factor * vx, factor * vy, factor * vz
    else:
        # Near pi the antisymmetric part vanishes: the axis from the symmetric part R = 2 a a' - I (+ ...).
        k = 0
        if R[1, 1] > R[k, k]:
            k = 1
        if R[2, 2] > R[k, k]:
            k = 2
        denominator = 1.0 - cos_theta
        axis = np.zeros(3)
        axis[k] = math.sqrt(max((R[k, k] - cos_theta) / denominator, 0.0))
        for j in range(3):
            if j != k:
                axis[j] = 0.5 * (R[j, k] + R[k, j]) / (denominator * axis[k])
        if axis[0] * vx + axis[1] * vy + axis[2] * vz < 0.0:
            for j in range(3):
                axis[j] = -axis[j]
        norm = math.sqrt(axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2])
        for j in range(3):
            out[j] = theta * axis[j] / norm
    return theta


@njit(cache=True, nogil=True)
def jexp3(w: np.ndarray, out: np.ndarray) -> None:
    """Right Jacobian of ``exp3`` (Pinocchio's ``Jexp3``): ``exp(w + dw) = exp(w) exp(Jexp3(w) dw)``."""
    theta2 = w[0] * w[0] + w[1] * w[1] + w[2] * w[2]
    theta = math.sqrt(theta2)
    if theta < 1e-4:
        a = 0.5 - theta2 / 24.0
        b = 1.0 / 6.0 - theta2 / 120.0
    else:
        a = (1.0 - math.cos(theta)) / theta2
        b = (theta - math.sin(theta)) / (theta2 * theta)
    K = np.empty((3, 3))
    skew(w, K)
    for i in range(3):
        for j in range(3):
            total = -a * K[i, j]
            for p in range(3):
                total += b * K[i, p] * K[p, j]
            out[i, j] = total + (1.0 if i == j else 0.0)


@njit(cache=True, nogil=True)
def jlog3(theta: float, w: np.ndarray, out: np.ndarray) -> None:
    """Jacobian of ``log3`` (Pinocchio's ``Jlog3``) at the rotation whose log is ``w`` (angle ``theta``)."""
    if theta < 1e-4:
        alpha = 1.0 / 12.0 + theta * theta / 720.0
    else:
        alpha = 1.0 / (theta * theta) - (1.0 + math.cos(theta)) / (2.0 * theta * math.sin(theta))
    K = np.empty((3, 3))
    skew(w, K)
    for i in range(3):
        for j in range(3):
            total = 0.5 * K[i, j]
            for p in range(3):
                total += alpha * K[i, p] * K[p, j]
            out[i, j] = total + (1.0 if i == j else 0.0)


@njit(cache=True, nogil=True)
def quaternion_step(q: np.ndarray, w: np.ndarray, out: np.ndarray) -> None:
    """``out = q ⊗ exp(w)`` (quaternions ``(x, y, z, w)``), normalised."""
    theta = math.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
    half = 0.5 * theta
    s = 0.5 - theta * theta / 48.0 if theta < 1e-8 else math.sin(half) / theta
    bx, by, bz, bw = s * w[0], s * w[1], s * w[2], math.cos(half)
    ax, ay, az, aw = q[0], q[1], q[2], q[3]
    x = aw * bx + ax * bw + ay * bz - az * by
    y = aw * by - ax * bz + ay * bw + az * bx
    z = aw * bz + ax * by - ay * bx + az * bw
    r = aw * bw - ax * bx - ay * by - az * bz
    n = 1.0 / math.sqrt(x * x + y * y + z * z + r * r)
    out[0], out[1], out[2], out[3] = x * n, y * n, z * n, r * n


@njit(cache=True, nogil=True)
def relative_rotation(q0: np.ndarray, q1: np.ndarray, out: np.ndarray) -> None:
    """``R0' R1``."""
    R0 = np.empty((3, 3))
    R1 = np.empty((3, 3))
    quaternion_to_rotation(q0, R0)
    quaternion_to_rotation(q1, R1)
    for i in range(3):
        for j in range(3):
            out[i, j] = R0[0, i] * R1[0, j] + R0[1, i] * R1[1, j] + R0[2, i] * R1[2, j]


# ------------------------------------------------------------------------------------ SRB state manifold
@njit(cache=True, nogil=True)
def srb_difference(x0: np.ndarray, x1: np.ndarray, out: np.ndarray) -> None:
    """``x1 ⊖ x0 = [c1 - c0, log3(R0' R1), c_dot1 - c_dot0, omega1 - omega0]``."""
    E = np.empty((3, 3))
    relative_rotation(x0[3:7], x1[3:7], E)
    for i in range(3):
        out[i] = x1[i] - x0[i]
    log3(E, out[3:6])
    for i in range(6):
        out[6 + i] = x1[7 + i] - x0[7 + i]


@njit(cache=True, nogil=True)
def srb_integrate(x: np.ndarray, dx: np.ndarray, out: np.ndarray) -> None:
    """``x ⊕ dx`` (``R exp(dtheta)``)."""
    for i in range(3):
        out[i] = x[i] + dx[i]
    quaternion_step(x[3:7], dx[3:6], out[3:7])
    for i in range(6):
        out[7 + i] = x[7 + i] + dx[6 + i]


@njit(cache=True, nogil=True)
def srb_difference_jacobian_product(
    x0: np.ndarray, x1: np.ndarray, matrix: np.ndarray, out: np.ndarray
) -> None:
    """``∂(x1 ⊖ x0)/∂x1 @ matrix``: identity but for the rotation rows, ``Jlog3(R0' R1) @ matrix[3:6]``."""
    E = np.empty((3, 3))
    relative_rotation(x0[3:7], x1[3:7], E)
    w = np.empty(3)
    theta = log3(E, w)
    J = np.empty((3, 3))
    jlog3(theta, w, J)
    columns = matrix.shape[1]
    for i in range(matrix.shape[0]):
        if 3 <= i < 6:
            continue
        for j in range(columns):
            out[i, j] = matrix[i, j]
    for i in range(3):
        for j in range(columns):
            out[3 + i, j] = J[i, 0] * matrix[3, j] + J[i, 1] * matrix[4, j] + J[i, 2] * matrix[5, j]


@njit(cache=True, nogil=True)
def srb_difference_jacobian_product_stacked(
    x0: np.ndarray, x1: np.ndarray, left: np.ndarray, right: np.ndarray, out: np.ndarray
) -> None:
    """``out = ∂(x1 ⊖ x0)/∂x1 @ [left | right]`` (``srb_difference_jacobian_product`` on either block of
    columns)."""
    n_left = left.shape[1]
    srb_difference_jacobian_product(x0, x1, left, out[:, :n_left])
    srb_difference_jacobian_product(x0, x1, right, out[:, n_left:])


# -------------------------------------------------------------------------------------- SRB dynamics
@njit(cache=True, nogil=True)
def srb_step(
    x: np.ndarray,
    u: np.ndarray,
    feet: np.ndarray,
    contacts: np.ndarray,
    mass: float,
    inertia: np.ndarray,
    inertia_inverse: np.ndarray,
    gravity: float,
    dt: float,
    x_next: np.ndarray,
    rotation: np.ndarray,
    active_forces: np.ndarray,
    moment_map: np.ndarray,
    body_moment: np.ndarray,
    linear_acceleration: np.ndarray,
    angular_acceleration: np.ndarray,
) -> bool:
    """One explicit Euler step (30) of the SRB dynamics (29); ``False`` if the result is not finite.

    ``c+ = c + c_dot dt``, ``R+ = R exp(omega dt)``, ``c_dot+ = c_dot + c_ddot dt``,
    ``omega+ = omega + omega_dot dt`` with ``c_ddot = sum s_j f_j / m - g`` and
    ``omega_dot = I^-1 (R' sum s_j (p_j - c) x f_j - omega x I omega)``.
    """
    quaternion_to_rotation(x[3:7], rotation)
    world_moment = np.zeros(3)
    force_sum = np.zeros(3)
    for leg in range(feet.shape[0]):
        s = contacts[leg]
        fx, fy, fz = s * u[3 * leg], s * u[3 * leg + 1], s * u[3 * leg + 2]
        active_forces[3 * leg], active_forces[3 * leg + 1], active_forces[3 * leg + 2] = fx, fy, fz
        lx, ly, lz = feet[leg, 0] - x[0], feet[leg, 1] - x[1], feet[leg, 2] - x[2]
        # rows of [l]x, side by side: world moment = moment_map @ f
        c = 3 * leg
        moment_map[0, c], moment_map[0, c + 1], moment_map[0, c + 2] = 0.0, -lz, ly
        moment_map[1, c], moment_map[1, c + 1], moment_map[1, c + 2] = lz, 0.0, -lx
        moment_map[2, c], moment_map[2, c + 1], moment_map[2, c + 2] = -ly, lx, 0.0
        world_moment[0] += ly * fz - lz * fy
        world_moment[1] += lz * fx - lx * fz
        world_moment[2] += lx * fy - ly * fx
        force_sum[0] += fx
        force_sum[1] += fy
        force_sum[2] += fz
    for i in range(3):
        body_moment[i] = (
            rotation[0, i] * world_moment[0]
            + rotation[1, i] * world_moment[1]
            + rotation[2, i] * world_moment[2]
        )
        linear_acceleration[i] = force_sum[i] / mass
    linear_acceleration[2] -= gravity
    omega = x[10:13]
    Iw = inertia @ omega
    gyro = np.empty(3)
    gyro[0] = omega[1] * Iw[2] - omega[2] * Iw[1]
    gyro[1] = omega[2] * Iw[0] - omega[0] * Iw[2]
    gyro[2] = omega[0] * Iw[1] - omega[1] * Iw[0]
    for i in range(3):
        total = 0.0
        for j in range(3):
            total += inertia_inverse[i, j] * (body_moment[j] - gyro[j])
        angular_acceleration[i] = total
    step = np.empty(3)
    for i in range(3):
        x_next[i] = x[i] + dt * x[7 + i]
        x_next[7 + i] = x[7 + i] + dt * linear_acceleration[i]
        x_next[10 + i] = x[10 + i] + dt * angular_acceleration[i]
        step[i] = dt * omega[i]
    quaternion_step(x[3:7], step, x_next[3:7])
    return np.all(np.isfinite(x_next))


@njit(cache=True, nogil=True)
def srb_step_jacobians(
    x: np.ndarray,
    contacts: np.ndarray,
    mass: float,
    inertia: np.ndarray,
    inertia_inverse: np.ndarray,
    dt: float,
    rotation: np.ndarray,
    active_forces: np.ndarray,
    moment_map: np.ndarray,
    body_moment: np.ndarray,
    Fx: np.ndarray,
    Fu: np.ndarray,
) -> None:
    """Tangent Jacobians of ``srb_step`` (which must have run at ``x``, filling the per-step arrays).

    ``Fx`` is the identity plus: ``d c+/d c_dot = dt I``; orientation ``R+ = R exp(omega dt)``:
    ``exp3(omega dt)'`` and ``dt Jexp3(omega dt)``; ``d omega+/d c = dt I^-1 R' [F]x``,
    ``d omega+/d theta = dt I^-1 [R' m]x``, ``d omega+/d omega = I + dt I^-1 ([I omega]x - [omega]x I)``;
    ``Fu``: ``dt/m`` on the stance feet's linear rows and ``dt I^-1 R' [l_j]x`` on their angular rows.
    """
    omega = x[10:13]
    for i in range(12):
        for j in range(12):
            Fx[i, j] = 1.0 if i == j else 0.0
    for i in range(3):
        Fx[i, 6 + i] = dt
    step = np.empty(3)
    for i in range(3):
        step[i] = dt * omega[i]
    E = np.empty((3, 3))
    exp3(step, E)
    J = np.empty((3, 3))
    jexp3(step, J)
    for i in range(3):
        for j in range(3):
            Fx[3 + i, 3 + j] = E[j, i]
            Fx[3 + i, 9 + j] = dt * J[i, j]
    # body_map = dt I^-1 R'
    body_map = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            body_map[i, j] = dt * (
                inertia_inverse[i, 0] * rotation[j, 0]
                + inertia_inverse[i, 1] * rotation[j, 1]
                + inertia_inverse[i, 2] * rotation[j, 2]
            )
    force_sum = np.zeros(3)
    n_feet = contacts.shape[0]
    for leg in range(n_feet):
        for a in range(3):
            force_sum[a] += active_forces[3 * leg + a]
    S = np.empty((3, 3))
    skew(force_sum, S)
    for i in range(3):
        for j in range(3):
            Fx[9 + i, j] = body_map[i, 0] * S[0, j] + body_map[i, 1] * S[1, j] + body_map[i, 2] * S[2, j]
    skew(body_moment, S)
    for i in range(3):
        for j in range(3):
            Fx[9 + i, 3 + j] = dt * (
                inertia_inverse[i, 0] * S[0, j]
                + inertia_inverse[i, 1] * S[1, j]
                + inertia_inverse[i, 2] * S[2, j]
            )
    Iw = inertia @ omega
    A = np.empty((3, 3))
    skew(Iw, A)
    W = np.empty((3, 3))
    skew(omega, W)
    G = A - W @ inertia
    for i in range(3):
        for j in range(3):
            Fx[9 + i, 9 + j] += dt * (
                inertia_inverse[i, 0] * G[0, j]
                + inertia_inverse[i, 1] * G[1, j]
                + inertia_inverse[i, 2] * G[2, j]
            )
    for i in range(12):
        for j in range(Fu.shape[1]):
            Fu[i, j] = 0.0
    for leg in range(n_feet):
        s = contacts[leg]
        for a in range(3):
            c = 3 * leg + a
            Fu[6 + a, c] = s * dt / mass
            for i in range(3):
                Fu[9 + i, c] = s * (
                    body_map[i, 0] * moment_map[0, c]
                    + body_map[i, 1] * moment_map[1, c]
                    + body_map[i, 2] * (moment_map[2, c])
                )


@njit(cache=True, nogil=True)
def srb_cost(
    x: np.ndarray,
    u: np.ndarray,
    x_reference: np.ndarray,
    forces_reference: np.ndarray,
    state_weights: np.ndarray,
    force_weights: np.ndarray,
    scale: float,
    r: np.ndarray,
    weighted_r: np.ndarray,
    force_residual: np.ndarray,
    rotation_log: np.ndarray,
) -> float:
    """Cost (28): ``scale * (0.5 r' W r + 0.5 (u - f_ref)' Wf (u - f_ref))`` with ``r = x ⊖ x_ref``.

    Writes ``r``, ``W r``, ``u - f_ref`` and, in ``rotation_log[0]``, the rotation angle (for ``jlog3``)."""
    srb_difference(x_reference, x, r)
    rotation_log[0] = math.sqrt(r[3] * r[3] + r[4] * r[4] + r[5] * r[5])
    cost = 0.0
    for i in range(12):
        weighted_r[i] = state_weights[i] * r[i]
        cost += weighted_r[i] * r[i]
    for i in range(u.shape[0]):
        force_residual[i] = u[i] - forces_reference[i]
        cost += force_weights[i] * force_residual[i] * force_residual[i]
    return 0.5 * scale * cost


@njit(cache=True, nogil=True)
def srb_cost_derivatives(
    r: np.ndarray,
    weighted_r: np.ndarray,
    force_residual: np.ndarray,
    state_weights: np.ndarray,
    force_weights: np.ndarray,
    theta: float,
    scale: float,
    Lx: np.ndarray,
    Lu: np.ndarray,
    Lxx: np.ndarray,
    Luu: np.ndarray,
    Lux: np.ndarray,
) -> None:
    """Gauss-Newton derivatives of ``srb_cost`` (the rotation rows through ``Jlog3``)."""
    J = np.empty((3, 3))
    jlog3(theta, r[3:6], J)
    for i in range(12):
        Lx[i] = scale * weighted_r[i]
        for j in range(12):
            Lxx[i, j] = 0.0
        Lxx[i, i] = scale * state_weights[i]
    for i in range(3):
        total = 0.0
        for k in range(3):
            total += J[k, i] * weighted_r[3 + k]
        Lx[3 + i] = scale * total
        for j in range(3):
            total = 0.0
            for k in range(3):
                total += J[k, i] * state_weights[3 + k] * J[k, j]
            Lxx[3 + i, 3 + j] = scale * total
    for i in range(Lu.shape[0]):
        Lu[i] = scale * force_weights[i] * force_residual[i]
        for j in range(Luu.shape[1]):
            Luu[i, j] = 0.0
        Luu[i, i] = scale * force_weights[i]
        for j in range(12):
            Lux[i, j] = 0.0
