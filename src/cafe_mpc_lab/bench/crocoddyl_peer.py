"""Crocoddyl: the peer we benchmark against (never our engine).

``crocoddyl_problem`` builds Crocoddyl's version of a whole-body multi-contact problem that our own
models also build (``cafe_mpc_lab.bench.problems``): the same robot, contact sequence, time step, initial
state, state-tracking and torque-regularisation costs. The Crocoddyl side uses
``DifferentialActionModelContactFwdDynamics`` with 3D point contacts in ``LOCAL_WORLD_ALIGNED`` and
Baumgarte gains ``[0, alpha]`` (our Eq. (20)), ``IntegratedActionModelEuler`` (semi-implicit Euler, so our
models are built with ``scheme="semi_implicit"`` for comparisons), and ``ActionModelImpulseFwdDynamics``
knots for touchdowns (our impact reset map (22)). Costs are ``0.5 * r' diag(w) r`` on
``r = x ⊖ x_ref`` and on ``r = tau``, scaled by ``dt`` on running knots, as ours.
"""

from __future__ import annotations

from collections.abc import Sequence

import crocoddyl
import numpy as np
import pinocchio as pin

from cafe_mpc.robots.robot import Robot


def _cost_sum(
    state: crocoddyl.StateMultibody,
    nu: int,
    x_ref: np.ndarray,
    state_weights: np.ndarray,
    torque_weight: float,
) -> crocoddyl.CostModelSum:
    costs = crocoddyl.CostModelSum(state, nu)
    if np.any(state_weights > 0):
        residual = crocoddyl.ResidualModelState(state, x_ref, nu)
        activation = crocoddyl.ActivationModelWeightedQuad(np.asarray(state_weights, dtype=float))
        costs.addCost("state", crocoddyl.CostModelResidual(state, activation, residual), 1.0)
    if torque_weight > 0:
        residual = crocoddyl.ResidualModelControl(state, nu)
        activation = crocoddyl.ActivationModelWeightedQuad(np.full(nu, float(torque_weight)))
        costs.addCost("torque", crocoddyl.CostModelResidual(state, activation, residual), 1.0)
    return costs


def crocoddyl_contact_action(
    robot: Robot,
    stance: Sequence[bool],
    dt: float,
    costs: crocoddyl.CostModelSum | None = None,
    baumgarte_alpha: float = 10.0,
    state: crocoddyl.StateMultibody | None = None,
) -> crocoddyl.IntegratedActionModelEuler:
    """Crocoddyl's equivalent of our ``WholeBodyDynamics(stance, dt, integration="semi_implicit")``:
    3D point contacts in ``LOCAL_WORLD_ALIGNED`` with Baumgarte gains ``[0, alpha]`` (free dynamics in
    flight), semi-implicit Euler; ``dt = 0`` gives a terminal model. ``costs`` defaults to an empty sum."""
    state = state or crocoddyl.StateMultibody(robot.model)
    actuation = crocoddyl.ActuationModelFloatingBase(state)
    nu = actuation.nu
    costs = costs if costs is not None else crocoddyl.CostModelSum(state, nu)
    if any(stance):
        contacts = crocoddyl.ContactModelMultiple(state, nu)
        gains = np.array([0.0, baumgarte_alpha])
        for foot, frame_id in enumerate(robot.foot_frame_ids):
            if stance[foot]:
                contact = crocoddyl.ContactModel3D(
                    state, frame_id, np.zeros(3), pin.LOCAL_WORLD_ALIGNED, nu, gains
                )
                contacts.addContact(robot.foot_frame_names[foot], contact)
        differential = crocoddyl.DifferentialActionModelContactFwdDynamics(
            state, actuation, contacts, costs, 0.0, True
        )
    else:
        differential = crocoddyl.DifferentialActionModelFreeFwdDynamics(state, actuation, costs)
    return crocoddyl.IntegratedActionModelEuler(differential, dt)


def crocoddyl_problem(
    robot: Robot,
    x0: np.ndarray,
    phases: Sequence[tuple[Sequence[bool], int]],
    dt: float,
    x_ref: np.ndarray,
    state_weights: np.ndarray,
    torque_weight: float,
    terminal_weights: np.ndarray,
    baumgarte_alpha: float = 10.0,
) -> crocoddyl.ShootingProblem:
    """Crocoddyl shooting problem for ``phases`` = [(stance flags in leg order, number of knots), ...].

    Between phases, feet that touch down get an impulse knot (zero cost); the last phase ends with the
    terminal cost ``terminal_weights``. Non-final phases have no terminal cost (ours must match).
    """
    state = crocoddyl.StateMultibody(robot.model)
    nu = robot.nu
    running: list[crocoddyl.ActionModelAbstract] = []

    previous: Sequence[bool] | None = None
    for stance, knots in phases:
        if previous is not None:
            touchdown = [s and not p for s, p in zip(stance, previous, strict=True)]
            if any(touchdown):
                impulses = crocoddyl.ImpulseModelMultiple(state)
                for foot, frame_id in enumerate(robot.foot_frame_ids):
                    if touchdown[foot]:
                        impulse = crocoddyl.ImpulseModel3D(state, frame_id, pin.LOCAL_WORLD_ALIGNED)
                        impulses.addImpulse(robot.foot_frame_names[foot], impulse)
                costs = crocoddyl.CostModelSum(state, 0)
                running.append(
                    crocoddyl.ActionModelImpulseFwdDynamics(state, impulses, costs, 0.0, 0.0, True)
                )
        costs = _cost_sum(state, nu, x_ref, state_weights, torque_weight)
        integrated = crocoddyl_contact_action(robot, stance, dt, costs, baumgarte_alpha, state)
        running.extend([integrated] * knots)
        previous = stance
    terminal_costs = _cost_sum(state, nu, x_ref, terminal_weights, 0.0)
    terminal = crocoddyl_contact_action(
        robot, previous or [True] * robot.n_feet, 0.0, terminal_costs, baumgarte_alpha, state
    )
    problem = crocoddyl.ShootingProblem(np.asarray(x0, dtype=float), running, terminal)
    problem.nthreads = 1  # one core, as ours (Crocoddyl defaults to all cores with OpenMP)
    return problem
