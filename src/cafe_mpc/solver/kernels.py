"""Compiled inner loops of MS-iLQR (numba): the backward sweep of one phase over stacked arrays, and the
forward roll-out's work between two knots' ``calc``.

The per-knot algebra of the backward sweep (Eqs. (8), (9)) is a dozen products of 36 x 36 and 36 x 12
matrices and one 12 x 12 Cholesky factorisation. In Python each of them is a separate numpy call with its
own dispatch overhead, which costs as much as the arithmetic; here the whole phase is one compiled call over
the phase's preallocated stacked arrays (``A[k]``, ``B[k]``, ``Lx[k]``, ...), with no allocation.

The maths is the textbook sweep (tests compare it with a plain numpy version and with closed-form LQ
solutions): Gauss-Newton (no second-order dynamics terms), defects through ``ŝ = s + S d`` (8a),
``mu I`` added to ``Quu`` (8e), the gains of Eq. (7) and the value-function update of Eq. (9) written with
the unregularised ``Quu`` so that the expected cost change of the quadratic model stays exact for
``mu > 0``.

The forward roll-out (Eqs. (11)-(13)) cannot be one compiled call per phase (each knot's ``calc`` is the
model's, e.g. Pinocchio's), but everything between two ``calc`` calls is: ``rollout_knot_end`` takes the
state the knot's model produced, sets the next trial state and defect, and forms the next knot's control,
with the manifold's compiled ``⊕``/``⊖``, in place of five separate calls. The manifold hands those over
as the addresses of its compiled functions (``CompiledStateOperations.addresses``, ``core.interfaces``),
which the kernels call through ``core.kernels``: one compiled kernel serves every manifold that has them.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from cafe_mpc.core.kernels import call_state_operation, call_state_transport, same_point, stack_columns

CHOLESKY_FAILED = 1
"""Status of ``backward_phase`` when ``Quu + mu I`` is not positive definite (or not finite)."""


@njit(cache=True, fastmath=True, nogil=True)
def cholesky_solve(matrix: np.ndarray, rhs: np.ndarray, lower: np.ndarray) -> bool:
    """Solve ``matrix @ X = rhs`` in place (``rhs`` becomes ``X``) by Cholesky; ``False`` if not PD.

    ``lower`` is scratch (``n x n``) for the factor. Small dense systems (``n = nu = 12``, 37 right-hand
    sides): a hand-written factorisation with row-wise substitutions beats a LAPACK call from compiled code,
    and it reports failure instead of raising.
    """
    n = matrix.shape[0]
    columns = rhs.shape[1]
    for j in range(n):
        total = matrix[j, j]
        for p in range(j):
            total -= lower[j, p] * lower[j, p]
        if not (total > 0.0) or not np.isfinite(total):
            return False
        diagonal = np.sqrt(total)
        lower[j, j] = diagonal
        for i in range(j + 1, n):
            value = matrix[i, j]
            for p in range(j):
                value -= lower[i, p] * lower[j, p]
            lower[i, j] = value / diagonal
    for i in range(n):
        for p in range(i):
            factor = lower[i, p]
            for c in range(columns):
                rhs[i, c] -= factor * rhs[p, c]
        inverse = 1.0 / lower[i, i]
        for c in range(columns):
            rhs[i, c] *= inverse
    for i in range(n - 1, -1, -1):
        for p in range(i + 1, n):
            factor = lower[p, i]
            for c in range(columns):
                rhs[i, c] -= factor * rhs[p, c]
        inverse = 1.0 / lower[i, i]
        for c in range(columns):
            rhs[i, c] *= inverse
    return True


@njit(cache=True, nogil=True)
def backward_phase(
    S: np.ndarray,
    s: np.ndarray,
    F: np.ndarray,
    G: np.ndarray,
    H: np.ndarray,
    defects: np.ndarray,
    rollout: np.ndarray,
    mu: float,
    K: np.ndarray,
    kff: np.ndarray,
    Qu: np.ndarray,
    Quu: np.ndarray,
    Qux: np.ndarray,
    sums: np.ndarray,
    rhs: np.ndarray,
    lower: np.ndarray,
    SF: np.ndarray,
    Q: np.ndarray,
    q: np.ndarray,
    s_hat: np.ndarray,
    gains: np.ndarray,
) -> int:
    """Backward sweep over the ``N`` running knots of one phase (Eqs. (8), (9)); ``S[N]``, ``s[N]`` are set.

    Stacked inputs over ``[x | u]`` (``n = ndx + nu``): ``F[k] = [A_k | B_k]`` (``ndx x n``), the cost
    gradient ``G[k] = [Lx | Lu]`` and Gauss-Newton Hessian ``H[k]`` (its ``Lxx``, ``Lux``, ``Luu`` blocks; the
    upper-right block is not read). Then ``Q = H + F' S F`` and ``q = G + F' ŝ`` hold all of Eq. (8b)-(8f) in
    two matrix products. Writes ``S[0..N-1]``, ``s[0..N-1]``, the gains ``K``, ``kff`` (Eq. (7)) and ``Qu``,
    ``Quu`` (regularised), ``Qux``. Adds to ``sums`` the terms of the expected cost change
    ``ΔJ(α) = c0 + α g + ½ α² h``: ``sums[0] += Σ (s'd + ½ d'S d)``, ``sums[1] += Σ Qu'k``,
    ``sums[2] += Σ (-Qu'k - mu k'k)``, and sets ``sums[3]`` to the sum of the entries of ``s[0]`` and
    ``S[0]`` (finite iff they all are, short of an overflow: the caller's check of the sweep). ``rhs``,
    ``lower``, ``SF``, ``Q``, ``q``, ``s_hat``, ``gains`` are scratch. Returns 0, or ``CHOLESKY_FAILED`` (the
    caller raises ``mu`` and restarts the sweep).
    """
    n_knots = F.shape[0]
    ndx = F.shape[1]
    n = F.shape[2]
    nu = n - ndx
    constant = 0.0
    linear = 0.0
    quadratic = 0.0
    for k in range(n_knots - 1, -1, -1):
        S_next = S[k + 1]
        s_hat[:] = s[k + 1]
        if not rollout[k + 1]:
            defect = defects[k + 1]
            S_defect = q[:ndx]  # scratch until q is formed below
            np.dot(S_next, defect, S_defect)
            s_hat += S_defect  # Eq. (8a)
            constant += s[k + 1] @ defect + 0.5 * (defect @ S_defect)
        F_k = F[k]
        np.dot(S_next, F_k, SF)
        np.dot(F_k.T, SF, Q)  # F' S F: Eqs. (8d)-(8f), Gauss-Newton
        H_k = H[k]
        for i in range(n):  # Q += H[k] (explicit loops compile to tighter code than the array expression)
            for j in range(n):
                Q[i, j] += H_k[i, j]
        np.dot(F_k.T, s_hat, q)  # F' ŝ: Eqs. (8b), (8c)
        q += G[k]
        for i in range(nu):
            Q[ndx + i, ndx + i] += mu
            rhs[i, 0] = q[ndx + i]
            for j in range(ndx):
                rhs[i, j + 1] = Q[ndx + i, j]
        Qu_k, Quu_k, Qux_k = Qu[k], Quu[k], Qux[k]
        for i in range(nu):
            Qu_k[i] = q[ndx + i]
            for j in range(nu):
                Quu_k[i, j] = Q[ndx + i, ndx + j]
            for j in range(ndx):
                Qux_k[i, j] = Q[ndx + i, j]
        if not cholesky_solve(Quu_k, rhs, lower):
            return CHOLESKY_FAILED
        K_k = K[k]
        k_ff = kff[k]
        qu_k = 0.0
        kk = 0.0
        for i in range(nu):
            k_ff[i] = -rhs[i, 0]  # Eq. (7): δũ = -Quu^-1 Qu
            qu_k += q[ndx + i] * k_ff[i]
            kk += k_ff[i] * k_ff[i]
            for j in range(ndx):
                K_k[i, j] = -rhs[i, j + 1]  # Eq. (7): K = -Quu^-1 Qux
        # Eq. (9) with the unregularised Quu (identical to (9) when mu = 0):
        # s = Qx + K'(Qu - mu k), S = Qxx + K'(Qux - mu K)
        for i in range(nu):
            rhs[i, 0] = q[ndx + i] - mu * k_ff[i]
            for j in range(ndx):
                gains[i, j] = Q[ndx + i, j] - mu * K_k[i, j]
        S_k = S[k]
        np.dot(K_k.T, gains, S_k)
        s_k = s[k]
        for i in range(ndx):
            total = q[i]
            for j in range(nu):
                total += K_k[j, i] * rhs[j, 0]
            s_k[i] = total
        for i in range(ndx):
            for j in range(i, ndx):
                value = 0.5 * (S_k[i, j] + S_k[j, i] + Q[i, j] + Q[j, i])
                S_k[i, j] = value
                S_k[j, i] = value
        linear += qu_k
        quadratic += -qu_k - mu * kk
    sums[0] += constant
    sums[1] += linear
    sums[2] += quadratic
    total = 0.0
    S_0, s_0 = S[0], s[0]
    for i in range(ndx):
        total += s_0[i]
        for j in range(ndx):
            total += S_0[i, j]
    sums[3] = total
    return 0


@njit(cache=True, nogil=True)
def policy_step(
    u: np.ndarray,
    k_ff: np.ndarray,
    K: np.ndarray,
    dx: np.ndarray,
    alpha: float,
    u_out: np.ndarray,
    du_out: np.ndarray,
) -> None:
    """Eq. (11): ``u' = ū + α k + K (x' ⊖ x̄)``; also writes ``δu = u' - ū``.

    Four rows at a time (``_affine_rows``): each row's sum keeps its order, the rows overlap in the
    pipeline."""
    _affine_rows(K, dx, dx[:0], k_ff, alpha, du_out)
    for i in range(u.shape[0]):
        u_out[i] = u[i] + du_out[i]


@njit(cache=True, nogil=True)
def linear_step(F: np.ndarray, dx: np.ndarray, du: np.ndarray, defect: np.ndarray, out: np.ndarray) -> None:
    """Eq. (12) in tangent form: ``out = A δx + B δu + d̄`` with ``F = [A | B]`` (``_affine_rows``)."""
    _affine_rows(F, dx, du, defect, 1.0, out)


@njit(cache=True, nogil=True)
def _affine_rows(
    M: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray, scale: float, out: np.ndarray
) -> None:
    """``out = scale c + M [a; b]``, each row summed in the order ``scale c_i``, then the columns left to
    right; four rows share one pass over the columns (independent sums the processor overlaps; a row at a
    time waits on every addition)."""
    na, nb = a.shape[0], b.shape[0]
    rows = M.shape[0]
    i = 0
    while i + 4 <= rows:
        M0, M1, M2, M3 = M[i], M[i + 1], M[i + 2], M[i + 3]
        t0, t1, t2, t3 = scale * c[i], scale * c[i + 1], scale * c[i + 2], scale * c[i + 3]
        for j in range(na):
            value = a[j]
            t0 += M0[j] * value
            t1 += M1[j] * value
            t2 += M2[j] * value
            t3 += M3[j] * value
        for j in range(nb):
            value = b[j]
            t0 += M0[na + j] * value
            t1 += M1[na + j] * value
            t2 += M2[na + j] * value
            t3 += M3[na + j] * value
        out[i], out[i + 1], out[i + 2], out[i + 3] = t0, t1, t2, t3
        i += 4
    for r in range(i, rows):
        total = scale * c[r]
        for j in range(na):
            total += M[r, j] * a[j]
        for j in range(nb):
            total += M[r, na + j] * b[j]
        out[r] = total


@njit(cache=True, nogil=True)
def transport_stacked(
    transport: int, x_nominal: np.ndarray, y: np.ndarray, left: np.ndarray, right: np.ndarray, out: np.ndarray
) -> None:
    """``out = ∂(y ⊖ x̄)/∂y @ [left | right]`` (a knot's ``[A | B]`` from its ``[Fx | Fu]``, in the tangent
    space at the next nominal state) by the manifold's compiled ``transport_stacked`` (its address); the plain
    ``[left | right]`` when ``y == x̄`` (no defect: the Jacobian is the identity). ``y``, ``left``, ``right``
    (the model's) are used as they are when C-contiguous, as they always are here, else copied."""
    if same_point(x_nominal, y):
        stack_columns(left, right, out)
    else:
        call_state_transport(
            transport,
            x_nominal,
            np.ascontiguousarray(y),
            np.ascontiguousarray(left),
            np.ascontiguousarray(right),
            out,
        )


@njit(cache=True, nogil=True)
def rollout_policy(
    difference: int,
    k: int,
    alpha: float,
    xs: np.ndarray,
    xs_try: np.ndarray,
    us: np.ndarray,
    us_try: np.ndarray,
    kff: np.ndarray,
    K: np.ndarray,
    dx: np.ndarray,
    du: np.ndarray,
) -> None:
    """The trial control of knot ``k`` (Eq. (11)): ``dx = xs_try[k] ⊖ xs[k]``, then ``policy_step``
    (``us_try[k]``, ``du``). ``difference``: the address of the state manifold's compiled ``difference``
    (``CompiledStateOperations.addresses``)."""
    call_state_operation(difference, xs[k], xs_try[k], dx)
    policy_step(us[k], kff[k], K[k], dx, alpha, us_try[k], du)


@njit(cache=True, nogil=True)
def rollout_knot_end(
    integrate: int,
    difference: int,
    k: int,
    alpha: float,
    x_next: np.ndarray,
    rollout: np.ndarray,
    xs: np.ndarray,
    xs_try: np.ndarray,
    us: np.ndarray,
    us_try: np.ndarray,
    kff: np.ndarray,
    K: np.ndarray,
    F: np.ndarray,
    defects: np.ndarray,
    defects_try: np.ndarray,
    dx: np.ndarray,
    du: np.ndarray,
    step: np.ndarray,
) -> None:
    """The roll-out after knot ``k``'s ``calc`` produced ``x_next = f(x'_k, u'_k)``, with ``dx``, ``du`` the
    knot's ``δx``, ``δu`` (``rollout_policy``); ``integrate``, ``difference``: the addresses of the state
    manifold's compiled operations.

    A roll-out knot ``k + 1`` (``rollout[k + 1]``) takes ``x_next`` (Eq. (13)) and no defect; a shooting knot
    follows the linearised dynamics with the full defect (Eq. (12) in the tangent space at the next nominal
    state: ``xs_try[k + 1] = xs[k + 1] ⊕ (A δx + B δu + d̄_{k+1})``) and keeps the defect
    ``x_next ⊖ xs_try[k + 1]``. Then, unless ``k + 1`` is the phase's last state, the control of knot
    ``k + 1`` (``rollout_policy``; ``dx``, ``du`` are overwritten). ``step`` is scratch.
    """
    j = k + 1
    if rollout[j]:
        for i in range(x_next.shape[0]):
            xs_try[j, i] = x_next[i]  # Eq. (13)
        for i in range(defects_try.shape[1]):
            defects_try[j, i] = 0.0
    else:
        linear_step(F[k], dx, du, defects[j], step)  # Eq. (12)
        call_state_operation(integrate, xs[j], step, xs_try[j])
        call_state_operation(difference, xs_try[j], np.ascontiguousarray(x_next), defects_try[j])
    if j < us.shape[0]:
        rollout_policy(difference, j, alpha, xs, xs_try, us, us_try, kff, K, dx, du)


@njit(cache=True, nogil=True)
def linear_feedback_pass(
    dx0: np.ndarray,
    us: np.ndarray,
    K: np.ndarray,
    k_ff: np.ndarray,
    A: np.ndarray,
    B: np.ndarray,
    defects: np.ndarray,
    feedforward: float,
    dxs_out: np.ndarray,
    us_out: np.ndarray,
) -> None:
    """The linear forward pass of the real-time iteration's feedback over one phase (Eqs. (11), (12) in
    tangent form): from ``dxs_out[0] = dx0``, ``du_k = a k_k + K_k dx_k``, ``u'_k = us_k + du_k``,
    ``dx_{k+1} = A_k dx_k + B_k du_k + a d_{k+1}`` (``a = feedforward``). The states ``xs_k ⊕ dx_k`` are the
    manifold's business (``integrate_rows_into``)."""
    n, nu = us.shape
    ndx = dx0.shape[0]
    du = np.empty(nu)
    for i in range(ndx):
        dxs_out[0, i] = dx0[i]
    for k in range(n):
        dx = dxs_out[k]
        for i in range(nu):
            total = feedforward * k_ff[k, i]
            for j in range(ndx):
                total += K[k, i, j] * dx[j]
            du[i] = total
            us_out[k, i] = us[k, i] + total
        for i in range(ndx):
            total = feedforward * defects[k + 1, i]
            for j in range(ndx):
                total += A[k, i, j] * dx[j]
            for j in range(nu):
                total += B[k, i, j] * du[j]
            dxs_out[k + 1, i] = total
