"""Compiled (numba) evaluation of a whole-body knot's cost and its Gauss-Newton derivatives.

A whole-body knot (``cafe_mpc.ocp.knots.WholeBodyKnot``) stacks everything it prices into two vectors:

* the **weighted residual** ``r`` (weights ``w``) of the cost (18): state tracking (``ndx`` rows), swing-foot
  positions and velocities (3 rows per swing foot), torque regularisation (``nu`` rows); the cost is
  ``0.5 r' diag(w) r`` (times ``dt`` on running knots);
* the **constraint values** ``g >= 0`` of (26), (27) and the minimum base height, each priced by the relaxed
  barrier ``eps B(g)`` (Sec. III-B-2): friction pyramid rows ``[fz - fz_min, mu fz -+ fx, mu fz -+ fy]`` per
  stance foot (``fz_min``: the knot's minimum normal force, 0 in (26)), the force's components taken in the
  ground's contact frame (``contact_frame``: rows tangent, tangent, normal; the identity on flat ground, where
  they are world x, y, z as in (26)), box rows ``sign * z + offset`` on
  one coordinate of ``x`` or ``u`` (torque, joint-position and joint-speed limits), and the base-height row.

``whole_body_cost`` fills the residual rows (the state rows too, for a free-flyer robot or the ``"world"``
base error), the constraint values, and returns cost and worst violation; ``whole_body_derivatives`` forms
the base Jacobian, the gradient ``J' (w r) + G' B'`` and the Gauss-Newton Hessian
``J' diag(w) J + G' diag(B'') G`` in one pass, exploiting which rows have an identity Jacobian (most of them)
and which are dense (the base block, the feet, the friction rows). Doing this in one compiled call replaces
about forty small numpy calls per knot.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from cafe_mpc.dynamics.kernels import (
    free_flyer_configuration_difference,
    free_flyer_difference_jacobian,
    log_coefficients,
    quaternion_rotation_into,
    relative_rotation_log,
)


@njit(cache=True, nogil=True)
def relaxed_barrier(
    g: np.ndarray, delta: np.ndarray, eps: np.ndarray, d1: np.ndarray, d2: np.ndarray
) -> float:
    """``sum eps B(g)`` with ``B = -ln g`` above ``delta`` and its quadratic extension below; writes
    ``d1 = eps B'(g)``, ``d2 = eps B''(g)``."""
    total = 0.0
    for i in range(g.shape[0]):
        gi, de, ep = g[i], delta[i], eps[i]
        if gi > de:
            total += -ep * math.log(gi)
            d1[i] = -ep / gi
            d2[i] = ep / (gi * gi)
        else:
            z = (gi - 2.0 * de) / de
            total += ep * (0.5 * (z * z - 1.0) - math.log(de))
            d1[i] = ep * z / de
            d2[i] = ep / (de * de)
    return total


# A knot's constants are packed into one integer and one float array, and its data's outputs live in one
# float buffer (``WholeBodyKnot._pack_parameters``): the compiled calls then take a dozen arrays instead of
# some forty arguments, each of which costs its unboxing on every call. The integer array starts with the
# header: the integer scalars, then the start of every section of the integer array (after the header), of
# the float array (after its scalars) and of the workspace, each followed by the end of its last section.
FEET_ROW, TORQUE_ROW, N_FRICTION, HEIGHT_INDEX, VELOCITY_ROWS_FROM, NQ, NV, NU_TORQUE, BASE_ERROR = range(9)
NO_STATE, TANGENT_FREE_FLYER, TANGENT_GENERIC, WORLD = range(4)
"""``BASE_ERROR``: no state tracking; ``x ⊖ x_ref`` of a free-flyer robot (compiled); of another robot (the
caller sets the rows ``r[:nv]`` and the base Jacobian); the ``"world"`` base error."""
INT_SECTIONS = 16
POSITION_LEGS, VELOCITY_LEGS, BOX_ON_CONTROL, BOX_INDEX, BOX_COLUMN = range(5)
STANCE_LEGS, BASE_ROWS, BASE_MASK = range(5, 8)
FLOAT_SECTIONS = INT_SECTIONS + 9
MU, MINIMUM_HEIGHT, SCALE, MINIMUM_NORMAL_FORCE = range(4)
FLOAT_SCALARS = 4
"""The float scalars, before the float sections."""
WEIGHTS, BOX_SIGN, BOX_OFFSET, DELTA, EPS = range(5)
WORK_SECTIONS = FLOAT_SECTIONS + 6
R, WR, G, D1, D2, VALUES, LAST_X, LAST_U, FORCES, BASE_ROTATION, ROTATION_ERROR, BASE_JACOBIAN = range(12)
HEADER = WORK_SECTIONS + 13


def pack_sections(header: np.ndarray, first: int, sections: list, dtype) -> np.ndarray:
    """The concatenation of ``sections`` (flattened), their starts and its end written into
    ``header[first:]``."""
    starts = np.cumsum([0] + [np.size(section) for section in sections])
    header[first : first + len(sections) + 1] = starts
    return np.concatenate([np.asarray(section, dtype=dtype).ravel() for section in sections])


@njit(cache=True, nogil=True, inline="always")
def _section(values: np.ndarray, header: np.ndarray, first: int, k: int, offset: int) -> np.ndarray:
    """Section ``k`` of ``values`` (its starts at ``header[first:]``) after ``offset`` leading entries."""
    return values[offset + header[first + k] : offset + header[first + k + 1]]


@njit(cache=True, nogil=True)
def same_inputs(x: np.ndarray, u: np.ndarray, last_x: np.ndarray, last_u: np.ndarray) -> bool:
    """``x == last_x`` and ``u == last_u`` element-wise (``calc_diff`` after ``calc`` at the same point)."""
    for i in range(x.shape[0]):
        if x[i] != last_x[i]:
            return False
    for i in range(u.shape[0]):  # noqa: SIM110 - an explicit loop compiles to a tight, early-exit loop
        if u[i] != last_u[i]:
            return False
    return True


@njit(cache=True, nogil=True)
def is_identity(frame: np.ndarray) -> bool:
    """Whether the 3 x 3 ``frame`` is exactly the identity (flat ground: the world frame)."""
    for i in range(3):
        for j in range(3):
            if frame[i, j] != (1.0 if i == j else 0.0):
                return False
    return True


@njit(cache=True, nogil=True)
def _in_frame(frame: np.ndarray, x: float, y: float, z: float) -> tuple[float, float, float]:
    """``frame @ (x, y, z)``: a world vector's components along the frame's rows."""
    return (
        frame[0, 0] * x + frame[0, 1] * y + frame[0, 2] * z,
        frame[1, 0] * x + frame[1, 1] * y + frame[1, 2] * z,
        frame[2, 0] * x + frame[2, 1] * y + frame[2, 2] * z,
    )


@njit(cache=True, nogil=True)
def _from_frame(frame: np.ndarray, x: float, y: float, z: float) -> tuple[float, float, float]:
    """``frame' @ (x, y, z)``: the world vector of components along the frame's rows."""
    return (
        frame[0, 0] * x + frame[1, 0] * y + frame[2, 0] * z,
        frame[0, 1] * x + frame[1, 1] * y + frame[2, 1] * z,
        frame[0, 2] * x + frame[1, 2] * y + frame[2, 2] * z,
    )


@njit(cache=True, nogil=True)
def whole_body_cost(
    x: np.ndarray,
    u: np.ndarray,
    x_reference: np.ndarray,
    ref_positions: np.ndarray,
    ref_velocities: np.ndarray,
    ref_torque: np.ndarray,
    integers: np.ndarray,
    floats: np.ndarray,
    work: np.ndarray,
    forces: np.ndarray,
    foot_positions: np.ndarray,
    foot_velocities: np.ndarray,
    contact_frame: np.ndarray,
) -> tuple[float, float]:
    """Cost of one knot from its packed parameters (``integers``, ``floats``; see ``HEADER``) into its
    workspace ``work`` (residual ``r``, weighted ``wr``, constraint values ``g`` and the barrier's ``d1``,
    ``d2``, ``values``, the evaluation point ``last_x``/``last_u``, the feet's forces, the base rotation).

    The state rows of ``r``: ``x ⊖ x_ref`` of a free-flyer robot (``free_flyer_configuration_difference``)
    or the ``"world"`` error (``world_base_error``) here; for another robot the caller sets ``r[:nv]``. The
    plain velocity rows ``v - v_ref``, the feet and torque rows and ``g`` follow. The stance forces
    (``forces``, 3 per stance foot, world frame) are scattered into the feet's forces (zero on swing feet);
    the pyramid takes their components in ``contact_frame`` (3 x 3, rows: the ground's two tangents and its
    normal; ``is_identity``: world x, y, z, the paper's (26)).

    ``values[0]`` = ``scale * (0.5 r' W r + sum eps B(g))``, ``values[1]`` = worst violation
    ``max(0, -min g)``; both are also returned (the knot's ``cost``, ``constraint_violation``).
    """
    h = integers
    feet_row, torque_row, n_friction = h[FEET_ROW], h[TORQUE_ROW], h[N_FRICTION]
    height_index, velocity_rows_from, nq, nv = h[HEIGHT_INDEX], h[VELOCITY_ROWS_FROM], h[NQ], h[NV]
    base_error = h[BASE_ERROR]
    position_legs = _section(h, h, INT_SECTIONS, POSITION_LEGS, HEADER)
    velocity_legs = _section(h, h, INT_SECTIONS, VELOCITY_LEGS, HEADER)
    box_on_control = _section(h, h, INT_SECTIONS, BOX_ON_CONTROL, HEADER)
    box_index = _section(h, h, INT_SECTIONS, BOX_INDEX, HEADER)
    stance_legs = _section(h, h, INT_SECTIONS, STANCE_LEGS, HEADER)
    mu, minimum_height, scale = floats[MU], floats[MINIMUM_HEIGHT], floats[SCALE]
    minimum_normal_force = floats[MINIMUM_NORMAL_FORCE]
    w = _section(floats, h, FLOAT_SECTIONS, WEIGHTS, FLOAT_SCALARS)
    box_sign = _section(floats, h, FLOAT_SECTIONS, BOX_SIGN, FLOAT_SCALARS)
    box_offset = _section(floats, h, FLOAT_SECTIONS, BOX_OFFSET, FLOAT_SCALARS)
    delta = _section(floats, h, FLOAT_SECTIONS, DELTA, FLOAT_SCALARS)
    eps = _section(floats, h, FLOAT_SECTIONS, EPS, FLOAT_SCALARS)
    r = _section(work, h, WORK_SECTIONS, R, 0)
    wr = _section(work, h, WORK_SECTIONS, WR, 0)
    g = _section(work, h, WORK_SECTIONS, G, 0)
    d1 = _section(work, h, WORK_SECTIONS, D1, 0)
    d2 = _section(work, h, WORK_SECTIONS, D2, 0)
    out = _section(work, h, WORK_SECTIONS, VALUES, 0)
    last_x = _section(work, h, WORK_SECTIONS, LAST_X, 0)
    last_u = _section(work, h, WORK_SECTIONS, LAST_U, 0)
    foot_forces = _section(work, h, WORK_SECTIONS, FORCES, 0)
    rotation = _section(work, h, WORK_SECTIONS, BASE_ROTATION, 0).reshape((3, 3))
    rotation_error = _section(work, h, WORK_SECTIONS, ROTATION_ERROR, 0)
    if base_error == WORLD or height_index >= 0:
        quaternion_rotation_into(x[3:7], rotation)
    if base_error == TANGENT_FREE_FLYER:
        free_flyer_configuration_difference(x_reference, x, nq, r)
    elif base_error == WORLD:
        world_base_error(x, x_reference, nq, nv, rotation, r, rotation_error)
    for i in range(velocity_rows_from, 2 * nv):
        r[i] = x[nq + i - nv] - x_reference[nq + i - nv]
    for i in range(foot_forces.shape[0]):
        foot_forces[i] = 0.0
    for c in range(min(stance_legs.shape[0], forces.shape[0] // 3)):
        for a in range(3):
            foot_forces[3 * stance_legs[c] + a] = forces[3 * c + a]
    for i in range(x.shape[0]):
        last_x[i] = x[i]
    for i in range(u.shape[0]):
        last_u[i] = u[i]
    row = feet_row
    for i in range(position_legs.shape[0]):
        leg = position_legs[i]
        for a in range(3):
            r[row + a] = foot_positions[leg, a] - ref_positions[leg, a]
        row += 3
    for i in range(velocity_legs.shape[0]):
        leg = velocity_legs[i]
        for a in range(3):
            r[row + a] = foot_velocities[leg, a] - ref_velocities[leg, a]
        row += 3
    if torque_row >= 0:
        for j in range(u.shape[0]):
            r[torque_row + j] = u[j] - ref_torque[j]
    cost = 0.0
    for i in range(r.shape[0]):
        wr[i] = w[i] * r[i]
        cost += wr[i] * r[i]
    cost *= 0.5
    # constraint values
    tilted = not is_identity(contact_frame)
    for c in range(n_friction):
        fx, fy, fz = forces[3 * c], forces[3 * c + 1], forces[3 * c + 2]
        if tilted:
            fx, fy, fz = _in_frame(contact_frame, fx, fy, fz)
        g[5 * c] = fz - minimum_normal_force
        g[5 * c + 1] = mu * fz - fx
        g[5 * c + 2] = mu * fz + fx
        g[5 * c + 3] = mu * fz - fy
        g[5 * c + 4] = mu * fz + fy
    first_box = 5 * n_friction
    for i in range(box_index.shape[0]):
        value = u[box_index[i]] if box_on_control[i] else x[box_index[i]]
        g[first_box + i] = box_sign[i] * value + box_offset[i]
    if height_index >= 0:
        g[height_index] = x[2] - minimum_height
    violation = 0.0
    barrier = 0.0
    if g.shape[0] > 0:
        barrier = relaxed_barrier(g, delta, eps, d1, d2)
        for i in range(g.shape[0]):
            if -g[i] > violation:
                violation = -g[i]
    out[0] = scale * (cost + barrier)
    out[1] = violation
    return out[0], violation


@njit(cache=True, nogil=True)
def whole_body_derivatives(
    gradient: np.ndarray,
    hessian: np.ndarray,
    x: np.ndarray,
    x_reference: np.ndarray,
    integers: np.ndarray,
    floats: np.ndarray,
    work: np.ndarray,
    position_jacobians: np.ndarray,
    velocity_dq: np.ndarray,
    dforces_dx: np.ndarray,
    dforces_du: np.ndarray,
    contact_frame: np.ndarray,
) -> None:
    """Gradient (``ndx + nu``) and Gauss-Newton Hessian of one knot over ``[tangent x | u]`` from its packed
    parameters and the workspace of the last ``whole_body_cost`` at ``x``.

    The base rows ``base_rows`` (``base_mask``) have a dense Jacobian ``base_jacobian``: ``Jlog6`` of the
    free flyer's ``x_ref ⊖ x`` (``free_flyer_difference_jacobian``) or the ``"world"`` error's
    (``world_base_error_jacobian``) made here, another robot's set by the caller; the other state rows are
    the identity. Foot rows use the Pinocchio foot Jacobians (velocity rows: ``[d v_foot / dq | J]``).
    Friction rows: ``G = P C dF/d(x, u)`` (``C``: ``contact_frame``, skipped when it is the identity); box
    rows: one column with a sign; the height row: the third row of the base rotation on the three
    base-position columns. ``d1``/``d2``: the barrier derivatives.
    """
    h = integers
    nv, feet_row, torque_row, nu_torque = h[NV], h[FEET_ROW], h[TORQUE_ROW], h[NU_TORQUE]
    n_friction, height_index, base_error = h[N_FRICTION], h[HEIGHT_INDEX], h[BASE_ERROR]
    ndx = 2 * nv
    position_legs = _section(h, h, INT_SECTIONS, POSITION_LEGS, HEADER)
    velocity_legs = _section(h, h, INT_SECTIONS, VELOCITY_LEGS, HEADER)
    box_column = _section(h, h, INT_SECTIONS, BOX_COLUMN, HEADER)
    base_rows = _section(h, h, INT_SECTIONS, BASE_ROWS, HEADER)
    base_mask = _section(h, h, INT_SECTIONS, BASE_MASK, HEADER)
    mu, scale = floats[MU], floats[SCALE]
    w = _section(floats, h, FLOAT_SECTIONS, WEIGHTS, FLOAT_SCALARS)
    box_sign = _section(floats, h, FLOAT_SECTIONS, BOX_SIGN, FLOAT_SCALARS)
    wr = _section(work, h, WORK_SECTIONS, WR, 0)
    d1 = _section(work, h, WORK_SECTIONS, D1, 0)
    d2 = _section(work, h, WORK_SECTIONS, D2, 0)
    rotation = _section(work, h, WORK_SECTIONS, BASE_ROTATION, 0).reshape((3, 3))
    rotation_error = _section(work, h, WORK_SECTIONS, ROTATION_ERROR, 0)
    nb = base_rows.shape[0]
    base_jacobian = _section(work, h, WORK_SECTIONS, BASE_JACOBIAN, 0).reshape((nb, nb))
    if base_error == TANGENT_FREE_FLYER:
        free_flyer_difference_jacobian(x_reference, x, base_jacobian)
    elif base_error == WORLD:
        world_base_error_jacobian(x, h[NQ], rotation, rotation_error, base_jacobian)
    height_gradient = rotation[2]
    n = gradient.shape[0]
    for i in range(n):
        gradient[i] = 0.0
        for j in range(n):
            hessian[i, j] = 0.0
    # state tracking: identity rows
    for i in range(ndx):
        if base_mask[i] == 0:
            gradient[i] += scale * wr[i]
            hessian[i, i] += scale * w[i]
    # state tracking: the base block
    nb = base_rows.shape[0]
    for a in range(nb):
        col_a = base_rows[a]
        total = 0.0
        for b in range(nb):
            total += base_jacobian[b, a] * wr[base_rows[b]]
        gradient[col_a] += scale * total
        for c in range(nb):
            col_c = base_rows[c]
            total = 0.0
            for b in range(nb):
                total += base_jacobian[b, a] * w[base_rows[b]] * base_jacobian[b, c]
            hessian[col_a, col_c] += scale * total
    # swing-foot positions: J (3 x nv) on the configuration tangent
    row = feet_row
    for i in range(position_legs.shape[0]):
        leg = position_legs[i]
        jac = position_jacobians[leg]
        for a in range(3):
            weight = scale * w[row + a]
            if weight == 0.0:
                continue
            residual = scale * wr[row + a]
            for p in range(nv):
                jp = jac[a, p]
                if jp == 0.0:
                    continue
                gradient[p] += jp * residual
                coefficient = weight * jp
                for q in range(nv):
                    hessian[p, q] += coefficient * jac[a, q]
        row += 3
    # swing-foot velocities: [d v / dq | J] (3 x 2 nv)
    for i in range(velocity_legs.shape[0]):
        leg = velocity_legs[i]
        jq = velocity_dq[leg]
        jv = position_jacobians[leg]
        for a in range(3):
            weight = scale * w[row + a]
            if weight == 0.0:
                continue
            residual = scale * wr[row + a]
            for p in range(2 * nv):
                jp = jq[a, p] if p < nv else jv[a, p - nv]
                if jp == 0.0:
                    continue
                gradient[p] += jp * residual
                coefficient = weight * jp
                for q in range(nv):
                    hessian[p, q] += coefficient * jq[a, q]
                    hessian[p, nv + q] += coefficient * jv[a, q]
        row += 3
    # torque regularisation
    for j in range(nu_torque):
        gradient[ndx + j] += scale * wr[torque_row + j]
        hessian[ndx + j, ndx + j] += scale * w[torque_row + j]
    # friction pyramid: G_c = P C F_c with F_c = d f_c / d(x, u) (3 x n), C the contact frame
    nu = n - ndx
    tilted = not is_identity(contact_frame)
    for c in range(n_friction):
        e0, e1, e2, e3, e4 = d1[5 * c], d1[5 * c + 1], d1[5 * c + 2], d1[5 * c + 3], d1[5 * c + 4]
        h0, h1, h2, h3, h4 = d2[5 * c], d2[5 * c + 1], d2[5 * c + 2], d2[5 * c + 3], d2[5 * c + 4]
        # P' d1 and P' diag(d2) P (3 x 3), P rows: [0,0,1], [-1,0,mu], [1,0,mu], [0,-1,mu], [0,1,mu]
        v0 = -e1 + e2
        v1 = -e3 + e4
        v2 = e0 + mu * (e1 + e2 + e3 + e4)
        m00 = h1 + h2
        m11 = h3 + h4
        m22 = h0 + mu * mu * (h1 + h2 + h3 + h4)
        m02 = mu * (h2 - h1)
        m12 = mu * (h4 - h3)
        for p in range(n):
            f0 = dforces_dx[3 * c, p] if p < ndx else dforces_du[3 * c, p - ndx]
            f1 = dforces_dx[3 * c + 1, p] if p < ndx else dforces_du[3 * c + 1, p - ndx]
            f2 = dforces_dx[3 * c + 2, p] if p < ndx else dforces_du[3 * c + 2, p - ndx]
            if tilted:
                f0, f1, f2 = _in_frame(contact_frame, f0, f1, f2)
            gradient[p] += scale * (v0 * f0 + v1 * f1 + v2 * f2)
            t0 = scale * (m00 * f0 + m02 * f2)
            t1 = scale * (m11 * f1 + m12 * f2)
            t2 = scale * (m02 * f0 + m12 * f1 + m22 * f2)
            if t0 == 0.0 and t1 == 0.0 and t2 == 0.0:
                continue
            if tilted:  # (C' t) . F_c: the row of the Hessian on the world-frame force derivatives
                t0, t1, t2 = _from_frame(contact_frame, t0, t1, t2)
            for q in range(ndx):
                hessian[p, q] += (
                    t0 * dforces_dx[3 * c, q]
                    + t1 * dforces_dx[3 * c + 1, q]
                    + t2 * (dforces_dx[3 * c + 2, q])
                )
            for q in range(nu):
                hessian[p, ndx + q] += (
                    t0 * dforces_du[3 * c, q]
                    + t1 * dforces_du[3 * c + 1, q]
                    + t2 * (dforces_du[3 * c + 2, q])
                )
    # box rows
    first_box = 5 * n_friction
    for i in range(box_column.shape[0]):
        col = box_column[i]
        gradient[col] += scale * box_sign[i] * d1[first_box + i]
        hessian[col, col] += scale * d2[first_box + i]
    # base height
    if height_index >= 0:
        e, h = scale * d1[height_index], scale * d2[height_index]
        for a in range(3):
            gradient[a] += e * height_gradient[a]
            for b in range(3):
                hessian[a, b] += h * height_gradient[a] * height_gradient[b]


@njit(cache=True, nogil=True)
def world_base_error(
    x: np.ndarray,
    x_ref: np.ndarray,
    nq: int,
    nv: int,
    rotation: np.ndarray,
    r: np.ndarray,
    log_error: np.ndarray,
) -> None:
    """The ``"world"`` base residual rows: ``r[0:3] = p - p_ref``, ``r[3:6] = log3(R_ref' R)``, the joints'
    differences in ``r[6:nv]`` and the world linear velocity error ``r[nv:nv+3] = R v - R_ref v_ref``
    (``rotation``: ``R`` of ``x``'s quaternion; ``R_ref`` of the normalised reference quaternion). Writes
    ``log_error = [log3(R_ref' R), angle]`` for ``world_base_error_jacobian``."""
    for i in range(3):
        r[i] = x[i] - x_ref[i]
    wx, wy, wz, theta = relative_rotation_log(x_ref[3], x_ref[4], x_ref[5], x_ref[6], x[3], x[4], x[5], x[6])
    r[3], r[4], r[5] = wx, wy, wz
    log_error[0], log_error[1], log_error[2], log_error[3] = wx, wy, wz, theta
    for i in range(7, nq):
        r[i - 1] = x[i] - x_ref[i]
    scale = 1.0 / np.sqrt(x_ref[3] ** 2 + x_ref[4] ** 2 + x_ref[5] ** 2 + x_ref[6] ** 2)
    qx, qy, qz, qw = x_ref[3] * scale, x_ref[4] * scale, x_ref[5] * scale, x_ref[6] * scale
    vx, vy, vz = x_ref[nq], x_ref[nq + 1], x_ref[nq + 2]
    tx, ty, tz = 2.0 * (qy * vz - qz * vy), 2.0 * (qz * vx - qx * vz), 2.0 * (qx * vy - qy * vx)
    reference_velocity = (
        vx + qw * tx + (qy * tz - qz * ty),
        vy + qw * ty + (qz * tx - qx * tz),
        vz + qw * tz + (qx * ty - qy * tx),
    )
    for i in range(3):
        velocity = rotation[i, 0] * x[nq] + rotation[i, 1] * x[nq + 1] + rotation[i, 2] * x[nq + 2]
        r[nv + i] = velocity - reference_velocity[i]


@njit(cache=True, nogil=True)
def world_base_error_jacobian(
    x: np.ndarray, nq: int, rotation: np.ndarray, log_error: np.ndarray, jacobian: np.ndarray
) -> None:
    """The dense blocks of the ``"world"`` base residual's Jacobian (rows position, orientation, world
    linear velocity; columns base translation, base rotation, base linear velocity, all local): ``R``,
    ``Jlog3(R_ref' R)`` (as ``pin.Jlog3``), ``-R [v]x`` and ``R``."""
    wx, wy, wz = log_error[0], log_error[1], log_error[2]
    alpha, beta = log_coefficients(log_error[3])
    vx, vy, vz = x[nq], x[nq + 1], x[nq + 2]
    for i in range(3):
        ri0, ri1, ri2 = rotation[i, 0], rotation[i, 1], rotation[i, 2]
        jacobian[i, 0], jacobian[i, 1], jacobian[i, 2] = ri0, ri1, ri2
        jacobian[6 + i, 6], jacobian[6 + i, 7], jacobian[6 + i, 8] = ri0, ri1, ri2
        # -R [v]x: row i of R times the columns of -[v]x
        jacobian[6 + i, 3] = -(ri1 * vz - ri2 * vy)
        jacobian[6 + i, 4] = -(ri2 * vx - ri0 * vz)
        jacobian[6 + i, 5] = -(ri0 * vy - ri1 * vx)
    log = (wx, wy, wz)
    for i in range(3):
        for j in range(3):
            jacobian[3 + i, 3 + j] = beta * log[i] * log[j] + (alpha if i == j else 0.0)
    jacobian[3, 4] -= 0.5 * wz
    jacobian[3, 5] += 0.5 * wy
    jacobian[4, 3] += 0.5 * wz
    jacobian[4, 5] -= 0.5 * wx
    jacobian[5, 3] -= 0.5 * wy
    jacobian[5, 4] += 0.5 * wx
