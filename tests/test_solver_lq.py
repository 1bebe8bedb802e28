"""MS-iLQR on linear-quadratic problems: exactness against a KKT solve and a Riccati recursion."""

from __future__ import annotations

import numpy as np
import pytest

from cafe_mpc.core.interfaces import MultiPhaseProblem, Phase
from cafe_mpc.solver import MSiLQRSolver, SolverOptions, evaluate_trajectory
from toy_models import AffineReset, LinearQuadraticModel

EXACT = SolverOptions(regularization_initial=0.0, regularization_min=0.0, max_iterations=20)


def random_cost(rng: np.random.Generator, n: int, m: int) -> tuple[np.ndarray, ...]:
    """A convex joint cost ``[[Q, N'], [N, R]] = L L' + 0.1 I`` with linear terms."""
    L = rng.standard_normal((n + m, n + m))
    H = L @ L.T / (n + m) + 0.1 * np.eye(n + m)
    return H[:n, :n], H[n:, n:], H[n:, :n], rng.standard_normal(n), rng.standard_normal(m)


def random_phase(rng: np.random.Generator, n: int, m: int, horizon: int, name: str) -> Phase:
    models = []
    for _ in range(horizon):
        Q, R, N, q, r = random_cost(rng, n, m)
        A = np.eye(n) + 0.2 * rng.standard_normal((n, n))
        B = rng.standard_normal((n, m))
        c = 0.1 * rng.standard_normal(n)
        models.append(LinearQuadraticModel(Q, q, A=A, B=B, c=c, R=R, r=r, N=N))
    Qf, _, _, qf, _ = random_cost(rng, n, 0)
    return Phase(models, LinearQuadraticModel(Qf, qf), name=name)


def solve_kkt(problem: MultiPhaseProblem) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """The exact optimum of an LQ multi-phase problem from one KKT linear system (dense numpy)."""
    blocks = []  # (phase, kind, k) -> offset
    offsets: dict[tuple[int, str, int], int] = {}
    size = 0
    for i, phase in enumerate(problem.phases):
        n, m = phase.state.nx, phase.running_models[0].nu
        for k in range(phase.horizon + 1):
            offsets[(i, "x", k)] = size
            size += n
        for k in range(phase.horizon):
            offsets[(i, "u", k)] = size
            size += m
        blocks.append((n, m))
    H = np.zeros((size, size))
    g = np.zeros(size)
    rows_C, rows_b = [], []
    for i, phase in enumerate(problem.phases):
        n, m = blocks[i]
        for k, model in enumerate(phase.running_models):
            ix, iu = offsets[(i, "x", k)], offsets[(i, "u", k)]
            H[ix : ix + n, ix : ix + n] += model.Q
            H[iu : iu + m, iu : iu + m] += model.R
            H[iu : iu + m, ix : ix + n] += model.N
            H[ix : ix + n, iu : iu + m] += model.N.T
            g[ix : ix + n] += model.q
            g[iu : iu + m] += model.r
            row = np.zeros((n, size))
            row[:, offsets[(i, "x", k + 1)] : offsets[(i, "x", k + 1)] + n] = np.eye(n)
            row[:, ix : ix + n] = -model.A
            row[:, iu : iu + m] = -model.B
            rows_C.append(row)
            rows_b.append(model.c)
        terminal = phase.terminal_model
        iN = offsets[(i, "x", phase.horizon)]
        H[iN : iN + n, iN : iN + n] += terminal.Q
        g[iN : iN + n] += terminal.q
        if i == 0:
            row = np.zeros((n, size))
            row[:, :n] = np.eye(n)
            rows_C.append(row)
            rows_b.append(problem.x0)
        if i + 1 < len(problem.phases):
            n_next = blocks[i + 1][0]
            row = np.zeros((n_next, size))
            i0 = offsets[(i + 1, "x", 0)]
            row[:, i0 : i0 + n_next] = np.eye(n_next)
            row[:, iN : iN + n] = -phase.reset_map.M
            rows_C.append(row)
            rows_b.append(phase.reset_map.m)
    C = np.vstack(rows_C)
    b = np.concatenate(rows_b)
    kkt = np.block([[H, C.T], [C, np.zeros((C.shape[0], C.shape[0]))]])
    solution = np.linalg.solve(kkt, np.concatenate([-g, b]))
    xs, us = [], []
    for i, phase in enumerate(problem.phases):
        n, m = blocks[i]
        xs.append(np.array([solution[offsets[(i, "x", k)] :][:n] for k in range(phase.horizon + 1)]))
        us.append(np.array([solution[offsets[(i, "u", k)] :][:m] for k in range(phase.horizon)]))
    return xs, us


def two_phase_problem(seed: int = 0) -> MultiPhaseProblem:
    rng = np.random.default_rng(seed)
    first = random_phase(rng, 4, 2, 6, "four")
    second = random_phase(rng, 3, 1, 5, "three")
    first.reset_map = AffineReset(rng.standard_normal((3, 4)), 0.1 * rng.standard_normal(3))
    return MultiPhaseProblem(x0=rng.standard_normal(4), phases=[first, second])


@pytest.mark.parametrize("warm_start", ["infeasible", "rollout"])
def test_two_phase_lq_matches_kkt_in_one_iteration(warm_start: str) -> None:
    problem = two_phase_problem()
    xs_kkt, us_kkt = solve_kkt(problem)
    rng = np.random.default_rng(1)
    solver = MSiLQRSolver(EXACT)
    if warm_start == "infeasible":
        # Random states on every shooting knot: large defects everywhere, including across the reset.
        initial_xs = [rng.standard_normal(x.shape) for x in xs_kkt]
        initial_us = [rng.standard_normal(u.shape) for u in us_kkt]
        assert evaluate_trajectory(problem, initial_xs, initial_us).defect_max > 0.1
        result = solver.solve(problem, initial_xs, initial_us)
    else:
        result = solver.solve(problem)
    assert result.converged, result.status
    assert result.statistics.iterations == 1
    assert result.statistics.step_sizes == [1.0]
    for i in range(2):
        np.testing.assert_allclose(result.xs[i], xs_kkt[i], atol=1e-8)
        np.testing.assert_allclose(result.us[i], us_kkt[i], atol=1e-8)
    assert result.defect_max < 1e-10
    evaluation = evaluate_trajectory(problem, xs_kkt, us_kkt)
    assert result.cost == pytest.approx(evaluation.cost, abs=1e-9)


def test_passive_phase_without_controls() -> None:
    """A phase whose knots have ``nu == 0`` (e.g. a ballistic flight) between two controlled phases."""
    rng = np.random.default_rng(11)
    phases = [
        random_phase(rng, 4, 2, 4, "a"),
        random_phase(rng, 3, 0, 3, "passive"),
        random_phase(rng, 3, 1, 4, "b"),
    ]
    phases[0].reset_map = AffineReset(rng.standard_normal((3, 4)))
    phases[1].reset_map = AffineReset(np.eye(3) + 0.3 * rng.standard_normal((3, 3)), rng.standard_normal(3))
    problem = MultiPhaseProblem(x0=rng.standard_normal(4), phases=phases)
    xs_kkt, us_kkt = solve_kkt(problem)
    initial_xs = [rng.standard_normal(x.shape) for x in xs_kkt]
    result = MSiLQRSolver(EXACT).solve(problem, initial_xs)
    assert result.converged and result.statistics.iterations == 1
    assert result.us[1].shape == (3, 0)
    for i in range(3):
        np.testing.assert_allclose(result.xs[i], xs_kkt[i], atol=1e-8)
        np.testing.assert_allclose(result.us[i], us_kkt[i], atol=1e-8)


def test_expected_change_is_exact_for_lq() -> None:
    """The first step's actual cost change equals the quadratic model's prediction (merit bookkeeping)."""
    problem = two_phase_problem(seed=3)
    rng = np.random.default_rng(4)
    initial_xs = [rng.standard_normal((p.horizon + 1, p.state.nx)) for p in problem.phases]
    initial_us = [rng.standard_normal((p.horizon, p.running_models[0].nu)) for p in problem.phases]
    initial_xs[0][0] = problem.x0
    before = evaluate_trajectory(problem, initial_xs, initial_us)
    solver = MSiLQRSolver(SolverOptions(regularization_initial=0.0, regularization_min=0.0, max_iterations=1))
    result = solver.solve(problem, initial_xs, initial_us)
    assert result.statistics.step_sizes == [1.0]
    predicted = result.statistics.predicted_cost_changes[0]
    assert abs(predicted) > 1.0
    assert result.cost - before.cost == pytest.approx(predicted, rel=1e-9, abs=1e-9)


def test_gains_match_discrete_riccati() -> None:
    rng = np.random.default_rng(5)
    n, m, horizon = 4, 2, 12
    A = np.eye(n) + 0.1 * rng.standard_normal((n, n))
    B = rng.standard_normal((n, m))
    Q, R, N, _, _ = random_cost(rng, n, m)
    Qf, _, _, _, _ = random_cost(rng, n, 0)
    model = LinearQuadraticModel(Q, np.zeros(n), A=A, B=B, R=R, r=np.zeros(m), N=N)
    problem = MultiPhaseProblem(
        x0=rng.standard_normal(n), phases=[Phase([model] * horizon, LinearQuadraticModel(Qf, np.zeros(n)))]
    )
    result = MSiLQRSolver(EXACT).solve(problem)
    assert result.converged
    P = Qf.copy()
    for k in range(horizon - 1, -1, -1):
        gain = -np.linalg.solve(R + B.T @ P @ B, N + B.T @ P @ A)
        np.testing.assert_allclose(result.phases[0].K[k], gain, atol=1e-9)
        P = Q + A.T @ P @ A + (N + B.T @ P @ A).T @ gain
        P = 0.5 * (P + P.T)
        np.testing.assert_allclose(result.phases[0].S[k], P, atol=1e-8)
    # Quu is the positive definite matrix the gains were computed with.
    for k in range(horizon):
        phase = result.phases[0]
        assert np.all(np.linalg.eigvalsh(phase.Quu[k]) > 0)
        np.testing.assert_allclose(phase.Quu[k] @ phase.K[k], -phase.Qux[k], atol=1e-9)
