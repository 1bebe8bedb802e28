"""The forward roll-out's compiled calls (Eqs. (11)-(13)) equal the manifold methods they replace, bit
for bit.

``MSiLQRSolver.try_step`` runs, between two knots' ``calc``, one compiled call (``rollout_knot_end``) on
manifolds with compiled operations (``StateManifold.compiled``) and the workspace's Python sequence of
``difference``, ``policy_step``, ``linear_step``, ``integrate`` on the others. Forcing the Python sequence
on the same workspace must give the same trial trajectory: on whole-body (free-flyer), SRB and Euclidean
phases, across an impact, the whole-body -> SRB transition and a Euclidean reset, with the hybrid and the
nonlinear roll-out.
"""

from __future__ import annotations

import copy
import pickle
import subprocess
import sys

import numpy as np
import pytest
from numba import njit

from cafe_mpc.core.interfaces import EUCLIDEAN_OPERATIONS, EuclideanState, MultiPhaseProblem, Phase
from cafe_mpc.core.kernels import call_state_operation
from cafe_mpc.dynamics.multibody_state import FREE_FLYER_OPERATIONS, MultibodyState
from cafe_mpc.dynamics.srb import SRB_OPERATIONS, SRBState
from cafe_mpc.ocp.knots import SRBModelFactory, WholeBodyModelFactory, weight_split_forces
from cafe_mpc.robots.robot import load_robot
from cafe_mpc.solver import MSiLQRSolver, SolverOptions
from cafe_mpc.solver.kernels import linear_step, policy_step, transport_stacked
from cafe_mpc_lab.bench.problems import whole_body_problem
from toy_models import PendulumImpactReset, PendulumModel

TROT = [((True, False, False, True), 6), ((False, True, True, False), 5)]


@pytest.fixture(scope="module")
def robot():
    return load_robot("mini_cheetah")


def whole_body_and_srb(robot) -> tuple[MultiPhaseProblem, list[np.ndarray], list[np.ndarray]]:
    """Two whole-body trot phases (impact between them), then the transition to an SRB tail."""
    peer = whole_body_problem(robot, TROT)
    factory = WholeBodyModelFactory(robot)
    srb = SRBModelFactory(robot=robot)
    last = peer.problem.phases[-1]
    stance = TROT[-1][0]
    transition = factory.transition_to_srb(stance, (True, True, True, True))
    data = transition.create_data()
    transition.calc(data, peer.problem.x0)
    srb_x = data.x_next.copy()
    feet = robot.foot_positions(robot.q_standing)
    contacts = (True, True, True, True)
    running = [srb.running_knot(srb.reference(srb_x, feet, contacts)) for _ in range(4)]
    tail = Phase(running, srb.terminal_knot(srb.reference(srb_x, feet, contacts)), dt=0.05, name="srb")
    phases = [*peer.problem.phases[:-1], Phase(last.running_models, last.terminal_model, transition), tail]
    rng = np.random.default_rng(3)
    xs = [*peer.initial_xs, np.tile(srb_x, (5, 1)) + 0.01 * rng.standard_normal((5, 13))]
    xs[-1][:, 3:7] /= np.linalg.norm(xs[-1][:, 3:7], axis=1, keepdims=True)
    us = [*peer.initial_us, np.tile(weight_split_forces(np.ones(4), srb.weight), (4, 1))]
    return MultiPhaseProblem(peer.problem.x0, phases), xs, us


def two_phase_pendulum() -> tuple[MultiPhaseProblem, list[np.ndarray], list[np.ndarray]]:
    first = Phase([PendulumModel(0.05, target=1.0)] * 8, PendulumModel(None, target=1.0, terminal_weight=1.0))
    first.reset_map = PendulumImpactReset()
    second = Phase(
        [PendulumModel(0.05, target=2.0)] * 7, PendulumModel(None, target=2.0, terminal_weight=10.0)
    )
    rng = np.random.default_rng(5)
    xs = [rng.standard_normal((9, 2)), rng.standard_normal((8, 2))]
    return MultiPhaseProblem(np.array([0.2, 0.0]), [first, second]), xs, [np.zeros((8, 1)), np.zeros((7, 1))]


@njit
def call_at(address: int, a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:
    """A compiled manifold operation called from compiled code through its address."""
    call_state_operation(address, a, b, out)


def trial(solver: MSiLQRSolver, alpha: float, nonlinear: bool) -> tuple[list[np.ndarray], tuple[float, ...]]:
    workspace = solver.workspace
    totals = solver.try_step(alpha, nonlinear)
    arrays = [a.copy() for work in workspace.phases for a in (work.xs_try, work.us_try, work.defects_try)]
    return arrays, (totals.cost, totals.defect_l1, totals.defect_max, totals.inequality_violation)


@pytest.mark.parametrize("case", ["whole_body_srb", "pendulum"])
def test_compiled_rollout_equals_the_manifold_methods(robot, case: str) -> None:
    if case == "whole_body_srb":
        (problem, xs, us), kinds = (
            whole_body_and_srb(robot),
            [FREE_FLYER_OPERATIONS, FREE_FLYER_OPERATIONS, SRB_OPERATIONS],
        )
    else:
        (problem, xs, us), kinds = two_phase_pendulum(), [EUCLIDEAN_OPERATIONS, EUCLIDEAN_OPERATIONS]
    solver = MSiLQRSolver(SolverOptions(max_iterations=1, max_al_iterations=1, final_policy="relinearize"))
    solver.solve(problem, xs, us)  # a policy and linearisation at an infeasible nominal (every knot shooting)
    workspace = solver.workspace
    assert [work.state.compiled for work in workspace.phases] == kinds
    assert all(work.operations == kind.addresses for work, kind in zip(workspace.phases, kinds, strict=True))
    assert all(np.abs(work.defects).max() > 1e-6 for work in workspace.phases)
    for alpha in (1.0, 0.5):
        for nonlinear in (False, True):
            compiled, compiled_totals = trial(solver, alpha, nonlinear)
            for work in workspace.phases:
                work.operations = None
            methods, method_totals = trial(solver, alpha, nonlinear)
            for work, kind in zip(workspace.phases, kinds, strict=True):
                work.operations = kind.addresses
            assert compiled_totals == method_totals
            for a, b in zip(compiled, methods, strict=True):
                np.testing.assert_array_equal(a, b)
            # the step moved the trial away from the nominal, and the hybrid trial kept defects
            assert not np.array_equal(workspace.phases[-1].us_try, workspace.phases[-1].us)
            assert (compiled_totals[1] > 0.0) != nonlinear


def test_compiled_operations_equal_the_manifold_methods(robot) -> None:
    """Each manifold's compiled operations, called through their addresses from compiled code and directly,
    equal its methods bit for bit."""
    rng = np.random.default_rng(11)
    factory = WholeBodyModelFactory(robot)
    multibody = factory.state
    cases = [
        (multibody, FREE_FLYER_OPERATIONS),
        (SRBState(), SRB_OPERATIONS),
        (EuclideanState(5), EUCLIDEAN_OPERATIONS),
    ]
    for state, compiled in cases:
        assert state.compiled is compiled
        addresses = compiled.addresses
        for _ in range(5):
            x = state.integrate(state.zero(), rng.standard_normal(state.ndx))
            dx = rng.standard_normal(state.ndx)
            out, expected = np.empty(state.nx), state.integrate(x, dx)
            call_at(addresses.integrate, x, dx, out)
            np.testing.assert_array_equal(out, expected)
            compiled.integrate(x, dx, out)
            np.testing.assert_array_equal(out, expected)
            tangent = np.empty(state.ndx)
            call_at(addresses.difference, x, expected, tangent)
            np.testing.assert_array_equal(tangent, state.difference(x, expected))
            # [A | B] in the tangent space at a nominal state (the identity at the same point)
            left, right = rng.standard_normal((state.ndx, state.ndx)), rng.standard_normal((state.ndx, 3))
            plain = np.hstack([left, right])
            for y in (expected, x.copy()):
                stacked, reference = np.empty_like(plain), np.empty_like(plain)
                transport_stacked(addresses.transport_stacked, x, y, left, right, stacked)
                state.difference_jacobian_product_stacked(x, y, left, right, reference)
                np.testing.assert_array_equal(stacked, reference)
                same = y is not expected or compiled is EUCLIDEAN_OPERATIONS
                assert np.array_equal(stacked, plain) == same
                # a model's Jacobians that are not C-contiguous are copied, with the same result
                fortran_left, strided_y = np.asfortranarray(left), np.repeat(y, 2)[::2]
                transport_stacked(addresses.transport_stacked, x, strided_y, fortran_left, right, stacked)
                np.testing.assert_array_equal(stacked, reference)


def test_a_subclass_that_overrides_an_operation_uses_its_own_methods(robot) -> None:
    """A manifold's compiled operations stand for its own methods only: a subclass that overrides one of
    them (angle wrapping, say) is rolled out through its methods, one that does not keeps the compiled
    operations."""

    class Wrapped(EuclideanState):
        def difference(self, x0: np.ndarray, x1: np.ndarray) -> np.ndarray:
            return np.mod(x1 - x0 + np.pi, 2 * np.pi) - np.pi

    class Named(EuclideanState):
        label = "plain"

    class Shifted(MultibodyState):
        def integrate_into(self, x: np.ndarray, dx: np.ndarray, out: np.ndarray) -> None:
            super().integrate_into(x, dx, out)

    class Logged(SRBState):
        def integrate(self, x: np.ndarray, dx: np.ndarray) -> np.ndarray:
            return super().integrate(x, dx)

    class Transported(SRBState):
        def difference_jacobian_product(self, x0, x1, matrix, out) -> None:
            super().difference_jacobian_product(x0, x1, matrix, out)

    assert EuclideanState(2).compiled is EUCLIDEAN_OPERATIONS
    assert Wrapped(2).compiled is None
    assert Named(2).compiled is EUCLIDEAN_OPERATIONS
    assert MultibodyState(robot.model).compiled is FREE_FLYER_OPERATIONS
    assert Shifted(robot.model).compiled is None
    assert SRBState().compiled is SRB_OPERATIONS
    assert Logged().compiled is None
    assert Transported().compiled is None


def test_compiled_operations_travel_without_their_addresses(robot) -> None:
    """A manifold pickled into another process (or copied) takes its compiled functions, not this process's
    addresses of them: those are found again where they are used."""
    code = (
        "import pickle, sys, numpy as np\n"
        "state = pickle.loads(sys.stdin.buffer.read())\n"
        "x = state.zero(); dx = np.linspace(-0.3, 0.3, state.ndx); out = np.empty(state.nx)\n"
        "state.compiled.integrate(x, dx, out)\n"
        "sys.path.insert(0, 'tests'); from test_solver_rollout import call_at\n"
        "call_at(state.compiled.addresses.integrate, x, dx, out)\n"
        "sys.stdout.buffer.write(pickle.dumps(out))\n"
    )
    for state in (SRBState(), MultibodyState(robot.model), EuclideanState(3)):
        addresses = state.compiled.addresses
        copied = copy.deepcopy(state)
        assert copied.compiled._addresses is None and copied.compiled.integrate is state.compiled.integrate
        np.testing.assert_array_equal(copied.compiled.addresses, addresses)  # the same process: the same
        output = subprocess.run(
            [sys.executable, "-c", code], input=pickle.dumps(state), capture_output=True, check=True
        ).stdout
        dx = np.linspace(-0.3, 0.3, state.ndx)
        np.testing.assert_array_equal(pickle.loads(output), state.integrate(state.zero(), dx))


@pytest.mark.parametrize("rows", [1, 4, 7, 12, 36])
def test_policy_and_linear_steps_sum_each_row_in_order(rows: int) -> None:
    """Eqs. (11), (12): four rows at a time, each row summed as a plain loop over the columns would."""
    rng = np.random.default_rng(rows)
    ndx, nu = 9, 5
    M, dx, du, offset = (rng.standard_normal(shape) for shape in ((rows, ndx + nu), ndx, nu, rows))
    out = np.empty(rows)
    linear_step(M, dx, du, offset, out)
    expected = np.empty(rows)
    for i in range(rows):
        total = offset[i]
        for j, value in enumerate(np.concatenate([dx, du])):
            total += M[i, j] * value
        expected[i] = total
    np.testing.assert_array_equal(out, expected)
    np.testing.assert_allclose(out, M @ np.concatenate([dx, du]) + offset, rtol=1e-12, atol=1e-12)
    K, u = M[:, :ndx], rng.standard_normal(rows)
    u_out, du_out = np.empty(rows), np.empty(rows)
    policy_step(u, offset, K, dx, 0.3, u_out, du_out)
    for i in range(rows):
        total = 0.3 * offset[i]
        for j in range(ndx):
            total += K[i, j] * dx[j]
        expected[i] = total
    np.testing.assert_array_equal(du_out, expected)
    np.testing.assert_array_equal(u_out, u + expected)
