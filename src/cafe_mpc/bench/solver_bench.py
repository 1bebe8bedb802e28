"""``cafe-mpc bench solver``: MS-iLQR time per iteration against Crocoddyl FDDP, in one run.

Three problems, each solved ``repeats`` times from the same initial guess:

* ``whole_body_25``: the 25-knot (10 ms) whole-body trot-cycle problem of ``bench.problems`` (ours);
* ``crocoddyl_fddp_25``: the same problem in Crocoddyl (FDDP);
* ``cafe_s4``: the CAFE problem of one MPC update: 25 whole-body knots at 10 ms + SRB tail 0.4 s at 50 ms,
  trotting at 0.5 m/s, all constraints on the whole-body part.

Ours: the median of the per-iteration wall times the solver records (backward sweep + line search).
Crocoddyl: the wall time of a solve divided by its iterations (median over repeats). Medians, because these
machines are noisy.
"""

from __future__ import annotations

import time

import numpy as np

from cafe_mpc.bench.problems import TROT_CYCLE, whole_body_problem
from cafe_mpc.robots.robot import Robot, load_robot
from cafe_mpc.solver import MSiLQRSolver, SolverOptions


def _ours(problem, xs, us, iterations: int, repeats: int) -> dict:
    times, counts, costs = [], [], []
    for _ in range(repeats):
        solver = MSiLQRSolver(SolverOptions(max_iterations=iterations, max_al_iterations=1))
        result = solver.solve(problem, xs, us)
        times.extend(result.statistics.iteration_times)
        counts.append(result.statistics.iterations)
        costs.append(result.cost)
    return {
        "iteration_ms_median": float(np.median(times)) * 1e3,
        "iteration_ms_p90": float(np.percentile(times, 90)) * 1e3,
        "iterations": int(np.median(counts)),
        "cost": float(costs[-1]),
    }


def _crocoddyl(robot: Robot, peer, iterations: int, repeats: int) -> dict:
    import crocoddyl

    problem, xs, us = peer.crocoddyl(robot)
    per_iteration, counts, cost = [], [], 0.0
    for _ in range(repeats):
        solver = crocoddyl.SolverFDDP(problem)
        start = time.perf_counter()
        solver.solve(xs, us, iterations, False)
        elapsed = time.perf_counter() - start
        per_iteration.append(elapsed / max(1, solver.iter))
        counts.append(solver.iter)
        cost = solver.cost
    return {
        "iteration_ms_median": float(np.median(per_iteration)) * 1e3,
        "iterations": int(np.median(counts)),
        "cost": float(cost),
    }


def _cafe(robot: Robot, iterations: int, repeats: int) -> dict:
    from cafe_mpc.mpc.problem import CafeProblemBuilder, ModelSchedule, WarmStart
    from cafe_mpc.ocp.contact_schedule import get_gait
    from cafe_mpc.ocp.knots import SRBModelFactory, WholeBodyModelFactory
    from cafe_mpc.reference.locomotion import LocomotionReference, VelocityCommand

    reference = LocomotionReference(robot, get_gait("trot"), [VelocityCommand(0.0, 0.5)])
    builder = CafeProblemBuilder(
        WholeBodyModelFactory(robot), SRBModelFactory(robot=robot), ModelSchedule.named("S4")
    )
    x0 = robot.x_standing
    reference.update(0.0, x0[: robot.nq], x0[robot.nq :])
    built = builder.build(0.0, x0, reference)
    guess = WarmStart().guess(built, None, None)
    result = _ours(built.problem, guess.xs, guess.us, iterations, repeats)
    result["knots"] = {"whole_body": builder.schedule.whole_body_knots, "srb": builder.schedule.srb_knots}
    return result


def run_solver_benchmark(iterations: int = 10, repeats: int = 5) -> dict:
    """Median time per iteration of ours (WB, CAFE) and Crocoddyl FDDP (WB) measured in the same run."""
    robot = load_robot("mini_cheetah")
    peer = whole_body_problem(robot, TROT_CYCLE)
    whole_body = _ours(peer.problem, peer.initial_xs, peer.initial_us, iterations, repeats)
    crocoddyl_result = _crocoddyl(robot, peer, iterations, repeats)
    cafe = _cafe(robot, iterations, repeats)
    return {
        "whole_body_25": whole_body,
        "cafe_s4": cafe,
        "crocoddyl_fddp_25": crocoddyl_result,
        "ratio_vs_crocoddyl": whole_body["iteration_ms_median"] / crocoddyl_result["iteration_ms_median"],
        "paper_ms_per_iteration": 5.3,
        "settings": {"iterations": iterations, "repeats": repeats, "threads": 1},
    }


def format_report(result: dict) -> str:
    lines = ["problem              ms/iteration (median)   iterations   cost"]
    for key in ("whole_body_25", "crocoddyl_fddp_25", "cafe_s4"):
        entry = result[key]
        lines.append(
            f"{key:<20} {entry['iteration_ms_median']:>10.2f}              {entry['iterations']:>4}    "
            f"{entry['cost']:.6f}"
        )
    lines.append(f"ratio ours / Crocoddyl (whole body, 25 knots): {result['ratio_vs_crocoddyl']:.2f}")
    lines.append("paper (C++, 4 threads): 5.3 ms per iteration")
    return "\n".join(lines)
