"""The MS-iLQR solver reaches the same optimum as Crocoddyl's FDDP on the same whole-body problem."""

import crocoddyl
import numpy as np
import pytest

from cafe_mpc.solver import MSiLQRSolver, SolverOptions, evaluate_trajectory
from cafe_mpc_lab.bench.problems import STAND, TROT_CYCLE, whole_body_problem


@pytest.mark.parametrize(("name", "phases"), [("stand", STAND), ("trot", TROT_CYCLE)])
def test_same_cost_as_crocoddyl_fddp(robot, name, phases):
    peer = whole_body_problem(robot, phases)
    ours = MSiLQRSolver(SolverOptions(max_iterations=100)).solve(
        peer.problem, peer.initial_xs, peer.initial_us
    )
    problem, xs, us = peer.crocoddyl(robot)
    # the two problems agree at the initial guess (same costs and dynamics)
    initial = evaluate_trajectory(peer.problem, peer.initial_xs, peer.initial_us)
    assert initial.cost == pytest.approx(problem.calc(xs, us), rel=1e-9)
    fddp = crocoddyl.SolverFDDP(problem)
    assert fddp.solve(xs, us, 100, False)
    assert ours.defect_max < 1e-6
    assert ours.cost == pytest.approx(fddp.cost, rel=0.01)
    # and they agree on the optimal first torque
    assert np.allclose(ours.phases[0].us[0], fddp.us[0], atol=0.05)


def test_the_solver_benchmark_times_both_final_policies_on_the_same_problem():
    """``cafe-mpc bench solver``: ours with the MPC's policy (the work of Crocoddyl's solve) and with the
    final re-linearisation reach the same cost as Crocoddyl in its 10 iterations; both ratios reported."""
    from cafe_mpc_lab.bench.solver_bench import format_report, run_solver_benchmark

    result = run_solver_benchmark(iterations=10, rounds=1, warm_up=0)
    shift, relinearize = result["whole_body_25"], result["whole_body_25_relinearize"]
    crocoddyl = result["crocoddyl_fddp_25"]
    assert shift["iterations"] == relinearize["iterations"] == crocoddyl["iterations"] == 10
    assert shift["cost"] == pytest.approx(crocoddyl["cost"], rel=1e-6)
    assert relinearize["cost"] == pytest.approx(crocoddyl["cost"], rel=1e-6)
    assert result["ratio_vs_crocoddyl"] > 0 and result["ratio_vs_crocoddyl_relinearize"] > 0
    assert "final re-linearisation" in format_report(result)
