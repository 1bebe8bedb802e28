"""Compiled (numba) steps of the kinematic Kalman filter and the planned-contact trust (preallocated arrays).

State ``x = [p (3), v (3), (b (3),) p_foot_0 (3), ..., p_foot_{n-1} (3)]``, all in the world frame; ``P`` its
covariance; the feet start at ``feet_start`` (6 without the optional accelerometer bias ``b``, 9 with it). The
model is MIT's (``estimator`` module docstring):

* predict: ``p += dt v + dt^2 / 2 (a - b)``, ``v += dt (a - b)`` (``a`` the IMU's acceleration in the world
  frame), ``b`` and the feet constant; ``P = A P A' + Q``;
* measurements (one scalar at a time: ``R`` is diagonal, so sequential scalar updates equal the batch update
  of MIT's 28-row system): ``p_foot - p = R r`` (leg kinematics), ``v = -(R (w x r + J qd))`` (a stance
  foot at rest), ``p_foot_z = foot_height[i]`` (flat ground; the foot frame's height when it stands on it).

Each scalar update: ``s = h P h' + r``, ``K = P h' / s``, ``x += K (y - h x)``, ``P -= P h' h P / s``, with
``h = e_i + c e_j`` (one or two non-zero entries), O(n^2) and no allocation.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def kf_predict(
    x: np.ndarray,
    P: np.ndarray,
    acceleration: np.ndarray,
    dt: float,
    q_position: float,
    q_velocity: float,
    q_bias: float,
    feet_start: int,
    q_feet: np.ndarray,
) -> None:
    """Propagate ``x``, ``P`` over ``dt`` with the world-frame acceleration; add the process noise (variances
    per step: base position ``q_position``, base velocity ``q_velocity``, acceleration bias ``q_bias``, foot
    ``i`` ``q_feet[i]``). With ``feet_start == 9`` the state holds a world-frame accelerometer bias ``b`` at
    6..8 (``a - b`` is integrated, ``b`` a random walk); with 6 it has none (MIT's state)."""
    n = x.shape[0]
    half = 0.5 * dt * dt
    bias = feet_start == 9
    for i in range(3):
        correction = x[6 + i] if bias else 0.0
        x[i] += dt * x[3 + i] + half * (acceleration[i] - correction)
        x[3 + i] += dt * (acceleration[i] - correction)
    # P <- A P A' with A: p += dt v - dt^2/2 b, v -= dt b (rows first, each from rows not yet changed)
    for i in range(3):
        for j in range(n):
            P[i, j] += dt * P[3 + i, j] - (half * P[6 + i, j] if bias else 0.0)
    if bias:
        for i in range(3):
            for j in range(n):
                P[3 + i, j] -= dt * P[6 + i, j]
    for i in range(n):
        for j in range(3):
            P[i, j] += dt * P[i, 3 + j] - (half * P[i, 6 + j] if bias else 0.0)
    if bias:
        for i in range(n):
            for j in range(3):
                P[i, 3 + j] -= dt * P[i, 6 + j]
    for i in range(3):
        P[i, i] += q_position
        P[3 + i, 3 + i] += q_velocity
        if bias:
            P[6 + i, 6 + i] += q_bias
    for foot in range(q_feet.shape[0]):
        for k in range(3):
            index = feet_start + 3 * foot + k
            P[index, index] += q_feet[foot]


@njit(cache=True, nogil=True)
def kf_update_scalar(
    x: np.ndarray, P: np.ndarray, i: int, j: int, c: float, y: float, r: float, ph: np.ndarray
) -> float:
    """One scalar measurement ``y = x[i] + c x[j]`` (``j < 0``: ``y = x[i]``) with variance ``r``; returns
    the innovation. ``ph`` is an n-vector of scratch."""
    n = x.shape[0]
    for k in range(n):
        ph[k] = P[k, i] + (c * P[k, j] if j >= 0 else 0.0)
    s = ph[i] + (c * ph[j] if j >= 0 else 0.0) + r
    innovation = y - (x[i] + (c * x[j] if j >= 0 else 0.0))
    gain = innovation / s
    for k in range(n):
        x[k] += ph[k] * gain
    for a in range(n):
        scale = ph[a] / s
        for b in range(n):
            P[a, b] -= scale * ph[b]
    return innovation


NOISE_POSITION, NOISE_VELOCITY, VERTICAL_FACTOR, NOISE_HEIGHT, SUSPECT, SWING_VARIANCE, SLIP_THRESHOLD = (
    range(7)
)
"""Indices of ``kf_update_feet``'s ``parameters`` (one array: numba's dispatcher leaked 200 bytes per call
of a function with exactly 20 arguments, measured with numba 0.68)."""


@njit(cache=True, nogil=True)
def kf_update_feet(
    x: np.ndarray,
    P: np.ndarray,
    feet_start: int,
    relative: np.ndarray,
    base_velocity: np.ndarray,
    trust: np.ndarray,
    foot_height: np.ndarray,
    use_height: bool,
    parameters: np.ndarray,
    slip_patience: int,
    slip_streak: np.ndarray,
    slipping: np.ndarray,
    scratch: np.ndarray,
) -> None:
    """The measurements of every foot (``relative[i]``: world-frame foot minus base position from the legs;
    ``base_velocity[i]``: the base velocity leg ``i`` implies if its foot is at rest), MIT's trust scaling.

    ``parameters`` (indices above): measurement variances of the relative position, the leg velocity (times
    ``VERTICAL_FACTOR`` vertically) and the foot height; MIT's suspect factor; the variance of an unused foot;
    the slip threshold (m/s, 0: off). A foot with zero trust (swing, flight, not in contact) or slipping
    gives nothing: its state is re-anchored at its kinematic position with ``SWING_VARIANCE`` and no
    correlation with the rest. ``scratch`` (2 x n): the state before the updates (MIT blends a low-trust
    measurement toward the prediction) and the update's ``P h'``.
    """
    r_position = parameters[NOISE_POSITION]
    r_velocity = parameters[NOISE_VELOCITY]
    vertical_factor = parameters[VERTICAL_FACTOR]
    r_height = parameters[NOISE_HEIGHT]
    suspect = parameters[SUSPECT]
    swing_variance = parameters[SWING_VARIANCE]
    slip_threshold = parameters[SLIP_THRESHOLD]
    prior = scratch[0]
    ph = scratch[1]
    n = x.shape[0]
    for k in range(n):
        prior[k] = x[k]
    # Slip: a trusted foot whose leg velocity disagrees horizontally with the prediction by more than
    # ``slip_threshold`` gives nothing this tick. When every trusted foot has disagreed for more than
    # ``slip_patience`` ticks in a row the prediction may be the one that is off: they are used again.
    trusted = 0
    outliers = 0
    for foot in range(relative.shape[0]):
        slipping[foot] = False
        if trust[foot] > 0.0 and slip_threshold > 0.0:
            trusted += 1
            dx = base_velocity[foot, 0] - prior[3]
            dy = base_velocity[foot, 1] - prior[4]
            if dx * dx + dy * dy > slip_threshold * slip_threshold:
                slipping[foot] = True
                outliers += 1
    if trusted > 0 and outliers == trusted:
        slip_streak[0] += 1
        if slip_streak[0] > slip_patience:
            slip_streak[0] = 0
            for foot in range(relative.shape[0]):
                slipping[foot] = False
    else:
        slip_streak[0] = 0
    for foot in range(relative.shape[0]):
        base = feet_start + 3 * foot
        if trust[foot] <= 0.0 or slipping[foot]:  # a sliding foot moves: re-anchor it as a swinging one
            for k in range(3):
                x[base + k] = x[k] + relative[foot, k]
                for m in range(n):
                    P[base + k, m] = 0.0
                    P[m, base + k] = 0.0
                P[base + k, base + k] = swing_variance
            continue
        weight = trust[foot]
        factor = 1.0 + (1.0 - weight) * suspect
        for k in range(3):  # p_foot - p = R r
            kf_update_scalar(x, P, base + k, k, -1.0, relative[foot, k], r_position, ph)
        for k in range(3):  # v = -(R (w x r + J qd)), blended toward the prediction while trust < 1
            y = weight * base_velocity[foot, k] + (1.0 - weight) * prior[3 + k]
            scale = vertical_factor if k == 2 else 1.0
            kf_update_scalar(x, P, 3 + k, -1, 0.0, y, r_velocity * factor * scale, ph)
        if use_height:  # the foot on flat ground
            y = weight * foot_height[foot] + (1.0 - weight) * (prior[2] + relative[foot, 2])
            kf_update_scalar(x, P, base + 2, -1, 0.0, y, r_height * factor, ph)


@njit(cache=True, nogil=True)
def planned_trust(
    times: np.ndarray,
    dts: np.ndarray,
    contacts: np.ndarray,
    t: float,
    window: float,
    flags: np.ndarray,
    touchdown: np.ndarray,
    settled: np.ndarray,
    trust: np.ndarray,
) -> None:
    """Planned stance at ``t`` (the plan knot interval holding ``t``, zero-order hold) and each foot's trust.

    ``flags`` (in: the previous tick's planned stance; out: now), ``touchdown`` (time each foot's current
    stance began) and ``settled`` (its start ramp is over or was never needed) persist between ticks. Trust
    ramps from 0 to 1 over the first ``window`` fraction of the planned stance (lift-off found in the plan;
    otherwise the plan's end bounds it) and back to 0 over the last ``window`` fraction before a lift-off the
    plan holds (MIT's ``trust_window``); a foot in swing has trust 0.
    """
    n = times.shape[0]
    k = n - 1
    for index in range(n):
        if times[index] > t:
            k = index - 1
            break
    if k < 0:
        k = 0
    end = times[n - 1] + dts[n - 1]
    for foot in range(flags.shape[0]):
        stance = contacts[k, foot]
        if stance and not flags[foot]:
            touchdown[foot] = t
            settled[foot] = False
        flags[foot] = stance
        if not stance:
            trust[foot] = 0.0
            continue
        liftoff = end
        found = False
        for index in range(k + 1, n):
            if not contacts[index, foot]:
                liftoff = times[index]
                found = True
                break
        span = window * max(liftoff - touchdown[foot], 1e-6)
        value = 1.0
        if not settled[foot]:
            rise = (t - touchdown[foot]) / span
            if rise >= 1.0:
                settled[foot] = True
            else:
                value = max(rise, 0.0)
        if found:
            value = min(value, max((liftoff - t) / span, 0.0))
        trust[foot] = min(value, 1.0)


@njit(cache=True, nogil=True)
def leg_ground_forces(
    jacobians: np.ndarray, torques: np.ndarray, joints_per_leg: int, out: np.ndarray
) -> None:
    """World ground reaction force on each foot from its leg's joint torques, legs massless and static:
    ``tau = -J' F``, so ``F = -J'^-1 tau`` (``jacobians[i]``: 3 x 3 world-frame Jacobian of foot ``i`` w.r.t.
    its own joints; Cramer's rule; a singular leg gives 0)."""
    for leg in range(out.shape[0]):
        J = jacobians[leg]
        # solve J' F = -tau  (A = J', A[i, j] = J[j, i])
        a00, a01, a02 = J[0, 0], J[1, 0], J[2, 0]
        a10, a11, a12 = J[0, 1], J[1, 1], J[2, 1]
        a20, a21, a22 = J[0, 2], J[1, 2], J[2, 2]
        first = leg * joints_per_leg
        b0, b1, b2 = -torques[first], -torques[first + 1], -torques[first + 2]
        det = a00 * (a11 * a22 - a12 * a21) - a01 * (a10 * a22 - a12 * a20) + a02 * (a10 * a21 - a11 * a20)
        if abs(det) < 1e-9 or not np.isfinite(det):
            out[leg, 0] = 0.0
            out[leg, 1] = 0.0
            out[leg, 2] = 0.0
            continue
        out[leg, 0] = (
            b0 * (a11 * a22 - a12 * a21) - a01 * (b1 * a22 - a12 * b2) + a02 * (b1 * a21 - a11 * b2)
        ) / det
        out[leg, 1] = (
            a00 * (b1 * a22 - a12 * b2) - b0 * (a10 * a22 - a12 * a20) + a02 * (a10 * b2 - b1 * a20)
        ) / det
        out[leg, 2] = (
            a00 * (a11 * b2 - b1 * a21) - a01 * (a10 * b2 - b1 * a20) + b0 * (a10 * a21 - a11 * a20)
        ) / det


@njit(cache=True, nogil=True)
def foot_sink_step(
    sink: np.ndarray,
    rate: np.ndarray,
    touching: np.ndarray,
    load: np.ndarray,
    in_contact: np.ndarray,
    start_sink: np.ndarray,
    start_rate: np.ndarray,
    dt: float,
    compliance: float,
    frequency: float,
    damping: float,
) -> None:
    """How far each foot in contact has sunk into a compliant floor (``sink``, m, down positive) and how fast
    (``rate``, m/s), advanced over ``dt``: a spring-damper of natural frequency ``frequency`` (rad/s) and
    damping ratio ``damping`` driven by the foot's normal load ``load`` (N; ``compliance`` m/N at rest),

        s'' = frequency^2 (compliance max(load, 0) - s) - 2 damping frequency s'.

    A foot that comes into contact (``in_contact`` now, not ``touching`` before) starts from ``start_sink``
    and ``start_rate`` (where and how fast it hits the floor, each at least 0); a foot out of contact has
    ``sink`` and ``rate`` 0. ``touching`` (in/out) is the contact of the previous call. Semi-implicit Euler
    in steps of at most 0.05 / frequency."""
    steps = max(int(np.ceil(dt * frequency / 0.05)), 1)
    h = dt / steps
    w2 = frequency * frequency
    c = 2.0 * damping * frequency
    for foot in range(sink.shape[0]):
        if not in_contact[foot]:
            sink[foot] = 0.0
            rate[foot] = 0.0
            touching[foot] = False
            continue
        if not touching[foot]:
            touching[foot] = True
            sink[foot] = max(start_sink[foot], 0.0)
            rate[foot] = max(start_rate[foot], 0.0)
            continue
        target = compliance * max(load[foot], 0.0)
        s, r = sink[foot], rate[foot]
        for _ in range(steps):
            r += h * (w2 * (target - s) - c * r)
            s += h * r
        sink[foot] = s
        rate[foot] = r
