"""Benchmark problems shared by tests, ``benchmarks/`` and ``cafe-mpc bench solver``.

``whole_body_problem`` builds a whole-body multi-contact problem with our models AND the same problem in
Crocoddyl (``crocoddyl_peer``): same robot, contact sequence, time step, initial state, costs (state
tracking on the manifold difference + torque regularisation), semi-implicit Euler (Crocoddyl's scheme),
impacts on the feet that touch down, no inequality constraints. ``cafe_problem`` builds the CAFE problem
of one MPC update (whole-body knots + SRB tail) for a trotting reference.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from cafe_mpc.config.weights import WholeBodyWeights
from cafe_mpc.core.interfaces import MultiPhaseProblem, Phase
from cafe_mpc.dynamics.statics import static_stance_torques
from cafe_mpc.ocp.constraints import WholeBodyConstraintSettings
from cafe_mpc.ocp.knots import WholeBodyModelFactory, WholeBodySettings
from cafe_mpc.robots.robot import Robot

STAND = [((True, True, True, True), 25)]
TROT_CYCLE = [((True, False, False, True), 12), ((False, True, True, False), 13)]
"""25 knots at 10 ms: one trot cycle squeezed into the 0.25 s whole-body horizon (stance pair FL+HR, then
FR+HL with the touchdown impact between them)."""

ZERO_WEIGHTS = WholeBodyWeights.zero()


@dataclass
class PeerProblem:
    """Our problem, its initial guess, and what Crocoddyl needs to build the same one."""

    problem: MultiPhaseProblem
    initial_xs: list[np.ndarray]
    initial_us: list[np.ndarray]
    phases: list[tuple[tuple[bool, ...], int]]
    dt: float
    x_ref: np.ndarray
    running_weights: np.ndarray
    terminal_weights: np.ndarray
    torque_weight: float

    def crocoddyl(self, robot: Robot):
        """The same problem in Crocoddyl, with the same initial guess (``problem, xs, us``)."""
        from cafe_mpc_lab.bench.crocoddyl_peer import crocoddyl_problem

        problem = crocoddyl_problem(
            robot,
            self.problem.x0,
            self.phases,
            self.dt,
            self.x_ref,
            self.running_weights,
            self.torque_weight,
            self.terminal_weights,
        )
        xs, us = [], []
        previous = None
        for (stance, knots), phase_xs, phase_us in zip(
            self.phases, self.initial_xs, self.initial_us, strict=True
        ):
            if previous is not None and any(s and not p for s, p in zip(stance, previous, strict=True)):
                xs.append(xs[-1] if xs else phase_xs[0])  # the impulse knot's state (pre-impact)
                us.append(np.zeros(0))
            xs.extend(phase_xs[:knots])
            us.extend(phase_us[:knots])
            previous = stance
        xs.append(self.initial_xs[-1][-1])
        return problem, xs, us


def whole_body_problem(robot: Robot, phases=TROT_CYCLE, dt: float = 0.01, seed: int = 0) -> PeerProblem:
    """An unconstrained whole-body problem from a perturbed standing state toward standing still."""
    rng = np.random.default_rng(seed)
    running = WholeBodyWeights(swing_foot_position=0.0, swing_foot_velocity=0.0)
    terminal = WholeBodyWeights.regular_terminal().model_copy(update={"swing_foot_velocity": 0.0})
    settings = WholeBodySettings(
        dt=dt,
        integration="semi_implicit",
        running_weights=running,
        terminal_weights=terminal,
        constraints=WholeBodyConstraintSettings.unconstrained(),
        terminal_constraints=False,
        impact_on_all_stance_feet=False,
    )
    factory = WholeBodyModelFactory(robot, settings)
    intermediate = WholeBodyModelFactory(robot, replace(settings, terminal_weights=ZERO_WEIGHTS))
    x_ref = robot.x_standing.copy()
    x0 = robot.x_standing.copy()
    x0[2] -= 0.02
    x0[robot.nq : robot.nq + 3] = [0.3, 0.0, 0.0]  # moving forward
    x0[robot.nq + 6 :] = rng.normal(scale=0.2, size=robot.nu)
    reference = factory.default_reference(x_ref)
    built = []
    for index, (stance, knots) in enumerate(phases):
        running_models = [factory.running_knot(stance, reference, dt) for _ in range(knots)]
        last = index == len(phases) - 1
        terminal_model = (factory if last else intermediate).terminal_knot(stance, reference)
        reset = None if last else factory.reset_map(stance, phases[index + 1][0])
        built.append(Phase(running_models, terminal_model, reset, dt=dt, name=f"wb{index}"))
    problem = MultiPhaseProblem(x0, built)
    xs = [np.tile(x0, (knots + 1, 1)) for _, knots in phases]
    us = [
        np.tile(static_stance_torques(robot, robot.q_standing, stance), (knots, 1))
        for stance, knots in phases
    ]
    return PeerProblem(
        problem,
        xs,
        us,
        [(tuple(s), n) for s, n in phases],
        dt,
        x_ref,
        running.state_weights(robot.nu),
        terminal.state_weights(robot.nu),
        float(running.torque),
    )
