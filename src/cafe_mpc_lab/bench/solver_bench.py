"""``cafe-mpc bench solver``: MS-iLQR against Crocoddyl FDDP, interleaved in one process.

Three problems, each solved from the same initial guess in every round:

* ``whole_body_25``: the 25-knot (10 ms) whole-body trot-cycle problem of ``bench.problems`` (ours), with
  the policy the MPC uses (``final_policy="shift"``): one linearisation, one backward sweep and one line
  search per iteration, which is the work of Crocoddyl's ``solve`` too (its returned gains are those of
  its last sweep);
* ``whole_body_25_relinearize``: the same with our offline default (``final_policy="relinearize"``): after
  the last step one more linearisation and sweep, so that the returned gains and Q-function belong to the
  returned trajectory (an 11th linearisation for 10 iterations);
* ``crocoddyl_fddp_25``: the same problem in Crocoddyl (FDDP, one thread);
* ``cafe_s4``: the CAFE problem of one MPC update: 25 whole-body knots at 10 ms + SRB tail 0.4 s at 50 ms,
  trotting at 0.5 m/s, all constraints on the whole-body part (ours only).

Each side's time per iteration is the wall time of a whole solve (set-up, first evaluation and
linearisation included, as Crocoddyl's ``solve`` does them too) divided by its iterations. The solvers are
made once and reused (their data persist, as in an MPC). In every round both solve once, in alternating
order, so that a change of the machine's load hits both sides of that round's ratio alike; the report is
the median over the rounds of the per-round ratio with its spread (interquartile range, min, max), and each
side's median. On a shared machine the ratio is what to read; the absolute times move with the load.

``per_knot`` breaks an iteration down per whole-body knot at the solution, timed interleaved the same way:
Crocoddyl's ``calc`` and ``calcDiff`` over its problem divided by its knots, ours (each knot's ``calc`` and
``calc_diff``), and the floor of ours: the Pinocchio calls of our knots' dynamics alone (the contact
dynamics and their derivatives; the free-flyer step and its Jacobians are compiled kernels). What a knot
takes beyond that floor is glue and costs.
"""

from __future__ import annotations

import time

import numpy as np

from cafe_mpc.robots.robot import Robot, load_robot
from cafe_mpc.solver import MSiLQRSolver, SolverOptions
from cafe_mpc_lab.bench.problems import TROT_CYCLE, whole_body_problem


class _Ours:
    """One of our problems with its initial guess and a persistent solver."""

    def __init__(self, problem, xs, us, iterations: int, final_policy: str = "shift") -> None:
        self.problem, self.xs, self.us = problem, xs, us
        self.solver = MSiLQRSolver(
            SolverOptions(max_iterations=iterations, max_al_iterations=1, final_policy=final_policy)
        )
        self.per_iteration: list[float] = []
        self.iterations = 0
        self.cost = float("nan")

    def run(self) -> float:
        start = time.perf_counter()
        result = self.solver.solve(self.problem, self.xs, self.us)
        elapsed = time.perf_counter() - start
        self.iterations = result.statistics.iterations
        self.cost = float(result.cost)
        self.per_iteration.append(elapsed / max(1, self.iterations))
        return self.per_iteration[-1]


class _Crocoddyl:
    """The same whole-body problem in Crocoddyl FDDP (one thread), solver made once."""

    def __init__(self, robot: Robot, peer, iterations: int) -> None:
        import crocoddyl

        self.problem, self.xs, self.us = peer.crocoddyl(robot)
        self.solver = crocoddyl.SolverFDDP(self.problem)
        self.max_iterations = iterations
        self.per_iteration: list[float] = []
        self.iterations = 0
        self.cost = float("nan")

    def run(self) -> float:
        start = time.perf_counter()
        self.solver.solve(self.xs, self.us, self.max_iterations, False)
        elapsed = time.perf_counter() - start
        self.iterations = int(self.solver.iter)
        self.cost = float(self.solver.cost)
        self.per_iteration.append(elapsed / max(1, self.iterations))
        return self.per_iteration[-1]


def _side(side) -> dict:
    times = np.asarray(side.per_iteration) * 1e3
    return {
        "iteration_ms_median": float(np.median(times)),
        "iteration_ms_p90": float(np.percentile(times, 90)),
        "iterations": side.iterations,
        "cost": side.cost,
    }


def _cafe(robot: Robot, iterations: int) -> _Ours:
    from cafe_mpc.config import VelocityCommand
    from cafe_mpc.ocp.contact_schedule import get_gait
    from cafe_mpc.ocp.knots import SRBModelFactory, WholeBodyModelFactory
    from cafe_mpc.planners.cafe.problem import CafeProblemBuilder, ModelSchedule, WarmStart
    from cafe_mpc.reference.locomotion import LocomotionReference

    reference = LocomotionReference(robot, get_gait("trot"), [VelocityCommand(start=0.0, vx=0.5)])
    builder = CafeProblemBuilder(
        WholeBodyModelFactory(robot), SRBModelFactory(robot=robot), ModelSchedule.named("S4")
    )
    x0 = robot.x_standing
    reference.update(0.0, x0[: robot.nq], x0[robot.nq :])
    built = builder.build(0.0, x0, reference)
    guess = WarmStart().guess(built, None, None)
    return _Ours(built.problem, guess.xs, guess.us, iterations)


def _median_us(function, repeats: int) -> float:
    samples = []
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        samples.append(time.perf_counter() - start)
    return float(np.median(samples) * 1e6)


def per_knot_costs(ours: _Ours, theirs: _Crocoddyl, rounds: int = 5, repeats: int = 40) -> dict:
    """Microseconds per whole-body knot (medians over interleaved rounds) at each side's last solution:
    Crocoddyl's ``calc``/``calcDiff``, our knots' ``calc``/``calc_diff`` and their dynamics' Pinocchio
    calls (the floor)."""
    import pinocchio as pin

    solution = ours.solver.workspace
    knots = [
        (model, data, work.xs[k], work.us[k])
        for work in solution.phases
        for k, (model, data) in enumerate(zip(work.models, work.running_data, strict=True))
    ]
    n_theirs = theirs.problem.T
    xs, us = list(theirs.solver.xs), list(theirs.solver.us)

    def our_calc() -> None:
        for model, data, x, u in knots:
            model.calc(data, x, u)

    def our_both() -> None:
        for model, data, x, u in knots:
            data.last_x[0] = np.nan  # a new point: calc_diff may not reuse calc's results
            model.calc(data, x, u)
            model.calc_diff(data, x, u)

    def floor() -> None:
        for model, data, x, _ in knots:
            dynamics, dynamics_data = model.dynamics, data.dynamics
            robot_model, nq = dynamics.model, dynamics.model.nq
            pd = dynamics_data.pinocchio
            pin.constraintDynamics(
                robot_model, pd, x[:nq], x[nq:], dynamics_data.tau, dynamics.contact_models,
                dynamics_data.contact_datas, dynamics_data.proximal,
            )  # fmt: skip
            pin.computeConstraintDynamicsDerivatives(
                robot_model, pd, dynamics.contact_models, dynamics_data.contact_datas, dynamics_data.proximal
            )

    samples: dict[str, list[float]] = {key: [] for key in ("crocoddyl", "ours", "floor")}
    calc_samples: dict[str, list[float]] = {"crocoddyl": [], "ours": []}
    for _ in range(rounds):
        calc_samples["crocoddyl"].append(_median_us(lambda: theirs.problem.calc(xs, us), repeats) / n_theirs)
        samples["crocoddyl"].append(
            _median_us(lambda: (theirs.problem.calc(xs, us), theirs.problem.calcDiff(xs, us)), repeats)
            / n_theirs
        )
        calc_samples["ours"].append(_median_us(our_calc, repeats) / len(knots))
        samples["ours"].append(_median_us(our_both, repeats) / len(knots))
        samples["floor"].append(_median_us(floor, repeats) / len(knots))
    return {
        "crocoddyl_calc_us": float(np.median(calc_samples["crocoddyl"])),
        "crocoddyl_calc_and_diff_us": float(np.median(samples["crocoddyl"])),
        "ours_calc_us": float(np.median(calc_samples["ours"])),
        "ours_calc_and_diff_us": float(np.median(samples["ours"])),
        "ours_dynamics_floor_us": float(np.median(samples["floor"])),
    }


def _spread(ratios: list[float]) -> dict:
    values = np.asarray(ratios)
    return {
        "q25": float(np.percentile(values, 25)),
        "q75": float(np.percentile(values, 75)),
        "min": float(values.min()),
        "max": float(values.max()),
    }


def run_solver_benchmark(iterations: int = 10, rounds: int = 20, warm_up: int = 2) -> dict:
    """``rounds`` interleaved rounds (after ``warm_up`` unrecorded ones) of ours (WB with each final
    policy, CAFE) and Crocoddyl FDDP (WB); per-round ratios ours / Crocoddyl on the same whole-body
    problem. The three whole-body solves of a round run in a rotating order."""
    robot = load_robot("mini_cheetah")
    peer = whole_body_problem(robot, TROT_CYCLE)
    ours = _Ours(peer.problem, peer.initial_xs, peer.initial_us, iterations, final_policy="shift")
    relinearizing = _Ours(peer.problem, peer.initial_xs, peer.initial_us, iterations, "relinearize")
    theirs = _Crocoddyl(robot, peer, iterations)
    cafe = _cafe(robot, iterations)
    sides = [ours, relinearizing, theirs]
    ratios: list[float] = []
    relinearized_ratios: list[float] = []
    for index in range(warm_up + rounds):
        times = {}
        for offset in range(len(sides)):
            side = sides[(index + offset) % len(sides)]
            times[id(side)] = side.run()
        cafe.run()
        if index >= warm_up:
            ratios.append(times[id(ours)] / times[id(theirs)])
            relinearized_ratios.append(times[id(relinearizing)] / times[id(theirs)])
        else:
            for side in (*sides, cafe):
                side.per_iteration.clear()
    knot_costs = per_knot_costs(ours, theirs)
    cafe_result = _side(cafe)
    cafe_result["knots"] = {"whole_body": 25, "srb": 8}
    return {
        "whole_body_25": _side(ours),
        "whole_body_25_relinearize": _side(relinearizing),
        "cafe_s4": cafe_result,
        "crocoddyl_fddp_25": _side(theirs),
        "ratio_vs_crocoddyl": float(np.median(ratios)),
        "ratio_spread": _spread(ratios),
        "ratio_vs_crocoddyl_relinearize": float(np.median(relinearized_ratios)),
        "ratio_spread_relinearize": _spread(relinearized_ratios),
        "per_knot": knot_costs,
        "paper_ms_per_iteration": 5.3,
        "settings": {"iterations": iterations, "rounds": rounds, "warm_up_rounds": warm_up, "threads": 1},
    }


def format_report(result: dict) -> str:
    lines = ["problem                     ms/iteration (median)   iterations   cost"]
    for key in ("whole_body_25", "whole_body_25_relinearize", "crocoddyl_fddp_25", "cafe_s4"):
        entry = result[key]
        lines.append(
            f"{key:<27} {entry['iteration_ms_median']:>10.2f}              {entry['iterations']:>4}    "
            f"{entry['cost']:.6f}"
        )
    rounds = result["settings"]["rounds"]
    for label, key, spread_key in (
        ("as Crocoddyl's solve (final_policy shift)", "ratio_vs_crocoddyl", "ratio_spread"),
        ("with a final re-linearisation", "ratio_vs_crocoddyl_relinearize", "ratio_spread_relinearize"),
    ):
        spread = result[spread_key]
        lines.append(
            f"ratio ours / Crocoddyl (whole body, 25 knots), {label}, median of {rounds} interleaved "
            f"rounds: {result[key]:.3f} (IQR {spread['q25']:.3f}-{spread['q75']:.3f}, "
            f"min {spread['min']:.3f}, max {spread['max']:.3f})"
        )
    knot = result["per_knot"]
    lines.append(
        f"per whole-body knot (us, calc / calc + calc_diff): Crocoddyl {knot['crocoddyl_calc_us']:.1f} / "
        f"{knot['crocoddyl_calc_and_diff_us']:.1f}, ours {knot['ours_calc_us']:.1f} / "
        f"{knot['ours_calc_and_diff_us']:.1f}, of which Pinocchio's dynamics calls "
        f"{knot['ours_dynamics_floor_us']:.1f}"
    )
    lines.append("paper (C++, 4 threads): 5.3 ms per iteration")
    return "\n".join(lines)
