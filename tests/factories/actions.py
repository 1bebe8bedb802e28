"""Every knot (``ActionModel``) of the library, as factory cases (``ACTION_CASES``).

* whole-body knots (``ocp.knots.WholeBodyKnot``, Eqs. (18)-(23), (26), (27)): running knots in all 16
  contact modes and terminal knots in all 16, every cost term weighted; variants of the settings (``"world"``
  base error, semi-implicit step, regularised contact dynamics, no constraints, torque-limit override,
  terminal knots without constraints), the library's weight sets (regular, barrel roll, the cost-free
  terminal of an intermediate phase); another robot (Go2);
* the knots of the trajectory optimisation problems (``trajopt.multiphase.build_problem``: the barrel rolls'
  phases, ``"world"`` base error, the tasks' barriers), about the problems' initial guesses;
* SRB knots (``ocp.knots.SRBKnot``, Eqs. (28)-(30)): running knots in all 16 contact modes, terminal knots,
  the regular weights;
* the template's SRB knots with GRF barriers (``planners.template.problem.ConstrainedSRBKnot``) in all 16
  modes, with the stance legs' torque maps at the standing pose.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np
import pinocchio as pin

from cafe_mpc.config import DEFAULT_FRICTION, TemplateSettings
from cafe_mpc.config.weights import WholeBodyWeights
from cafe_mpc.dynamics.srb import SRBDynamics
from cafe_mpc.ocp.barrier import RelaxedBarrier
from cafe_mpc.ocp.constraints import WholeBodyConstraintSettings
from cafe_mpc.ocp.knots import (
    SRBKnot,
    SRBModelFactory,
    SRBSettings,
    WholeBodyKnot,
    WholeBodyModelFactory,
    WholeBodySettings,
)
from cafe_mpc.planners.template.problem import (
    FRICTION_BARRIER,
    TORQUE_BARRIER,
    ConstrainedSRBKnot,
    template_running_weights,
    template_srb,
)
from cafe_mpc.robots.robot import Robot
from cafe_mpc.trajopt.multiphase import TrajOptProblem, build_problem
from cafe_mpc.trajopt.presets import TASKS, load_task
from factories.cases import ActionCase, CaseSpec, Library, OutputDerivative
from factories.points import (
    mode_name,
    srb_forces,
    srb_reference,
    srb_state,
    srb_weights,
    stance_modes,
    whole_body_reference,
    whole_body_state,
    whole_body_weights,
)

REFERENCE_ROBOT = "mini_cheetah"

# --------------------------------------------------------------------------------------------------
# What the knots promise: the structure of their Gauss-Newton Hessians
# --------------------------------------------------------------------------------------------------


def whole_body_gauss_newton(model: WholeBodyKnot, data, x, u) -> tuple[np.ndarray, np.ndarray]:
    """``dt (0.5 r' W r + sum eps B(g))`` (``ocp.kernels``): residual ``r`` with weights ``w``, constraint
    values ``g`` with barrier curvatures ``eps B''(g)`` (``data.d2``), all times the knot's time step."""
    return np.concatenate([data.r, data.g]), model.cost_scale * np.concatenate(
        [model.residual_weights, data.d2]
    )


def whole_body_inequalities(model: WholeBodyKnot, data, x, u) -> np.ndarray:
    return data.g


def srb_gauss_newton(model: SRBKnot, data, x, u) -> tuple[np.ndarray, np.ndarray]:
    """``dt (0.5 r' W r + 0.5 (u - f_ref)' Wf (u - f_ref))`` with ``r = x_ref ⊖ x``
    (``dynamics.srb_kernels``)."""
    weights = np.concatenate([model.state_weights, model.force_weights[: model.nu]])
    return np.concatenate([data.r, data.force_residual]), model.cost_scale * weights


def srb_inequalities(model: SRBKnot, data, x, u) -> np.ndarray:
    return np.zeros(0)


def _force_rows(model: ConstrainedSRBKnot, u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The GRF inequalities of the stance feet, ``offsets + rows . f >= 0``, with their barriers' deltas and
    weights (``ConstrainedSRBKnot``)."""
    values, deltas, weights = [], [], []
    for foot, in_stance in enumerate(model.reference.contacts > 0.5):
        if in_stance:
            values.append(model.offsets[foot] + model.rows[foot] @ u[3 * foot : 3 * foot + 3])
            deltas.append(model.deltas)
            weights.append(model.barrier_weights)
    if not values:
        return np.zeros(0), np.zeros(0), np.zeros(0)
    return np.concatenate(values), np.concatenate(deltas), np.concatenate(weights)


def constrained_srb_gauss_newton(model: ConstrainedSRBKnot, data, x, u) -> tuple[np.ndarray, np.ndarray]:
    """The SRB cost plus ``dt sum eps B(g)`` over the GRF inequalities (linear in ``u``)."""
    z, c = srb_gauss_newton(model, data, x, u)
    g, deltas, weights = _force_rows(model, u)
    if g.size:
        _, _, curvature = RelaxedBarrier(deltas, weights).derivatives(g)
    else:
        curvature = np.zeros(0)
    return np.concatenate([z, g]), np.concatenate([c, model.cost_scale * curvature])


def constrained_srb_inequalities(model: ConstrainedSRBKnot, data, x, u) -> np.ndarray:
    return _force_rows(model, u)[0]


def contact_forces(model: WholeBodyKnot) -> tuple[OutputDerivative, ...]:
    """The stance feet's contact forces of the KKT dynamics and their Jacobians (written when the friction
    cone is priced, whose Jacobian they are part of)."""
    if model.n_friction == 0:
        return ()
    return (
        OutputDerivative(
            "contact forces",
            lambda data: data.stance_forces,
            lambda data: data.dforces_dx,
            lambda data: data.dforces_du,
        ),
    )


# --------------------------------------------------------------------------------------------------
# Whole-body knots
# --------------------------------------------------------------------------------------------------


SettingsOf = Callable[[Robot, np.random.Generator], WholeBodySettings]
"""The settings of a whole-body case, for its robot and random generator."""


def _all_terms(robot: Robot, rng: np.random.Generator, **changes) -> WholeBodySettings:
    """Default settings with every cost term weighted (``points.whole_body_weights``), then ``changes``."""
    return replace(
        WholeBodySettings(),
        running_weights=whole_body_weights(rng),
        terminal_weights=whole_body_weights(rng),
        **changes,
    )


def _all_terms_with(**changes) -> SettingsOf:
    def settings(robot: Robot, rng: np.random.Generator) -> WholeBodySettings:
        return _all_terms(robot, rng, **changes)

    return settings


def _torque_limit_override(robot: Robot, rng: np.random.Generator) -> WholeBodySettings:
    """Torque limits of the settings (2 to 6 Nm, below the robot's) and another friction coefficient."""
    limits = tuple(float(v) for v in rng.uniform(2.0, 6.0, robot.nu))
    constraints = WholeBodyConstraintSettings(friction_coefficient=0.4, torque_limit_values=limits)
    return _all_terms(robot, rng, constraints=constraints)


def _library_weights(running: WholeBodyWeights, terminal: WholeBodyWeights) -> SettingsOf:
    def settings(robot: Robot, rng: np.random.Generator) -> WholeBodySettings:
        return replace(WholeBodySettings(), running_weights=running, terminal_weights=terminal)

    return settings


def _whole_body_case(
    library: Library,
    rng: np.random.Generator,
    robot_name: str,
    stance: tuple[bool, ...],
    running: bool,
    settings_of: SettingsOf,
) -> ActionCase:
    robot = library.robot(robot_name)
    factory = WholeBodyModelFactory(robot, settings_of(robot, rng))
    reference = whole_body_reference(robot, rng)
    knot = factory.running_knot(stance, reference) if running else factory.terminal_knot(stance, reference)
    nu = knot.nu

    def point() -> tuple[np.ndarray, np.ndarray]:
        return whole_body_state(robot, rng), 3.0 * rng.standard_normal(nu)

    x, u = point()
    return ActionCase(
        knot, x, u, point(), whole_body_gauss_newton, whole_body_inequalities, contact_forces(knot)
    )


def _whole_body_spec(
    name: str,
    stance: tuple[bool, ...],
    running: bool,
    settings_of: SettingsOf,
    robot_name: str = REFERENCE_ROBOT,
) -> CaseSpec:
    def make(library: Library, rng: np.random.Generator) -> ActionCase:
        return _whole_body_case(library, rng, robot_name, stance, running, settings_of)

    return CaseSpec(name, WholeBodyKnot, make)


def _whole_body_specs() -> list[CaseSpec]:
    specs = []
    for stance in stance_modes():
        mode = mode_name(stance)
        specs.append(_whole_body_spec(f"whole-body-running-{mode}", stance, True, _all_terms))
        specs.append(_whole_body_spec(f"whole-body-terminal-{mode}", stance, False, _all_terms))
    variants: dict[str, SettingsOf] = {
        "world-base-error": _all_terms_with(base_error="world"),
        "semi-implicit": _all_terms_with(integration="semi_implicit", dt=0.02),
        "explicit-world": _all_terms_with(integration="explicit_world", dt=0.02),
        "contact-damping": _all_terms_with(contact_damping=1e-3),
        "unconstrained": _all_terms_with(constraints=WholeBodyConstraintSettings.unconstrained()),
        "torque-limit-override": _torque_limit_override,
        "regular-weights": _library_weights(
            WholeBodyWeights.regular_running(), WholeBodyWeights.regular_terminal()
        ),
        "barrel-roll-weights": _library_weights(
            WholeBodyWeights.barrel_roll_running(), WholeBodyWeights.barrel_roll_terminal()
        ),
    }
    for variant, settings_of in variants.items():
        for stance in [(1, 1, 1, 1), (1, 0, 0, 1), (0, 1, 1, 0), (0, 0, 1, 0), (0, 0, 0, 0)]:
            stance = tuple(bool(flag) for flag in stance)
            mode = mode_name(stance)
            specs.append(_whole_body_spec(f"whole-body-running-{variant}-{mode}", stance, True, settings_of))
        specs.append(
            _whole_body_spec(
                f"whole-body-terminal-{variant}-1001", (True, False, False, True), False, settings_of
            )
        )
    intermediate = _library_weights(WholeBodyWeights.regular_running(), WholeBodyWeights.zero())
    no_terminal_constraints = _all_terms_with(terminal_constraints=False)
    for stance in [(True,) * 4, (False, True, True, False), (False,) * 4]:
        mode = mode_name(stance)
        specs.append(
            _whole_body_spec(f"whole-body-terminal-intermediate-{mode}", stance, False, intermediate)
        )
        specs.append(
            _whole_body_spec(
                f"whole-body-terminal-no-constraints-{mode}", stance, False, no_terminal_constraints
            )
        )
    for stance in [(True,) * 4, (True, False, False, True), (False,) * 4]:
        mode = mode_name(stance)
        specs.append(_whole_body_spec(f"go2-whole-body-running-{mode}", stance, True, _all_terms, "go2"))
        specs.append(_whole_body_spec(f"go2-whole-body-terminal-{mode}", stance, False, _all_terms, "go2"))
    return specs


# --------------------------------------------------------------------------------------------------
# Trajectory optimisation knots
# --------------------------------------------------------------------------------------------------


def trajopt_problem(library: Library, task: str) -> TrajOptProblem:
    """The multi-phase problem of a trajectory-optimisation task preset (built once per session)."""
    robot = library.robot(REFERENCE_ROBOT)
    return library.shared(("trajopt", task), lambda: build_problem(robot, load_task(task, [])))


def _trajopt_spec(task: str, phase_index: int, phase_name: str, running: bool) -> CaseSpec:
    kind = "running" if running else "terminal"

    def make(library: Library, rng: np.random.Generator) -> ActionCase:
        built = trajopt_problem(library, task)
        robot = built.robot
        phase = built.problem.phases[phase_index]
        k = phase.horizon // 2 if running else phase.horizon
        knot = phase.running_models[k] if running else phase.terminal_model
        guess_x = built.initial_xs[phase_index][k]
        guess_u = built.initial_us[phase_index][k] if running else np.zeros(0)

        def point() -> tuple[np.ndarray, np.ndarray]:
            x = whole_body_state(robot, rng, spread=0.1, speed=0.5, around=guess_x)
            return x, guess_u + 2.0 * rng.standard_normal(knot.nu)

        x, u = point()
        return ActionCase(
            knot, x, u, point(), whole_body_gauss_newton, whole_body_inequalities, contact_forces(knot)
        )

    return CaseSpec(f"trajopt-{task}-{phase_name}-{kind}", WholeBodyKnot, make)


TRAJOPT_PHASES = {
    task: [(phase.name, phase.stance) for phase in load_task(task, []).phases] for task in sorted(TASKS)
}
"""The phases (name, stance) of the trajectory-optimisation presets, in order."""


def _trajopt_specs() -> list[CaseSpec]:
    return [
        _trajopt_spec(task, index, phase, running)
        for task, phases in TRAJOPT_PHASES.items()
        for index, (phase, _) in enumerate(phases)
        for running in (True, False)
    ]


# --------------------------------------------------------------------------------------------------
# SRB knots
# --------------------------------------------------------------------------------------------------


def _srb_spec(
    name: str, contacts: tuple[bool, ...], running: bool, weights: str, dt: float | None = None
) -> CaseSpec:
    """An SRB knot with every term weighted (``weights`` ``"all-terms"``) or the regular weights."""

    def make(library: Library, rng: np.random.Generator) -> ActionCase:
        robot = library.robot(REFERENCE_ROBOT)
        if weights == "all-terms":
            settings = SRBSettings(running_weights=srb_weights(rng), terminal_weights=srb_weights(rng))
        else:
            settings = SRBSettings()
        factory = SRBModelFactory(settings, robot)
        reference = srb_reference(rng, contacts, factory.weight)
        knot = factory.running_knot(reference, dt) if running else factory.terminal_knot(reference)

        def point() -> tuple[np.ndarray, np.ndarray]:
            u = srb_forces(rng, factory.weight) if running else np.zeros(0)
            return srb_state(rng), u

        x, u = point()
        return ActionCase(knot, x, u, point(), srb_gauss_newton, srb_inequalities)

    return CaseSpec(name, SRBKnot, make)


def _srb_specs() -> list[CaseSpec]:
    specs = [_srb_spec(f"srb-running-{mode_name(c)}", c, True, "all-terms") for c in stance_modes()]
    specs += [
        _srb_spec("srb-terminal", (True,) * 4, False, "all-terms"),
        _srb_spec("srb-running-regular-weights-1001", (True, False, False, True), True, "regular"),
        _srb_spec(
            "srb-running-regular-weights-13ms-0110", (False, True, True, False), True, "regular", 0.013
        ),
        _srb_spec("srb-terminal-regular-weights", (True,) * 4, False, "regular"),
    ]
    return specs


# --------------------------------------------------------------------------------------------------
# The template's SRB knots with GRF constraints
# --------------------------------------------------------------------------------------------------


def standing_torque_map(robot: Robot) -> np.ndarray:
    """``d tau / d f = -J_leg'`` of every leg at the standing pose (what ``TemplateProblemBuilder.
    update_torque_maps`` sets per knot)."""
    model, data = robot.model, robot.model.createData()
    pin.computeJointJacobians(model, data, robot.q_standing)
    pin.updateFramePlacements(model, data)
    torque_map = np.zeros((robot.n_feet, 3, 3))
    for foot, frame_id in enumerate(robot.foot_frame_ids):
        jacobian = pin.getFrameJacobian(model, data, frame_id, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
        torque_map[foot] = -jacobian[:3, 6 + 3 * foot : 9 + 3 * foot].T
    return torque_map


def _template_spec(contacts: tuple[bool, ...]) -> CaseSpec:
    def make(library: Library, rng: np.random.Generator) -> ActionCase:
        robot = library.robot(REFERENCE_ROBOT)
        parameters, _ = template_srb(robot)
        weight = parameters.mass * parameters.gravity
        knot = ConstrainedSRBKnot(
            SRBDynamics(parameters, TemplateSettings().dt),
            template_running_weights(),
            srb_reference(rng, contacts, weight, forces=False),
            DEFAULT_FRICTION,
            FRICTION_BARRIER,
            robot.torque_limits,
            TORQUE_BARRIER,
        )
        knot.set_torque_map(standing_torque_map(robot))

        def point() -> tuple[np.ndarray, np.ndarray]:
            return srb_state(rng), srb_forces(rng, weight)

        x, u = point()
        return ActionCase(knot, x, u, point(), constrained_srb_gauss_newton, constrained_srb_inequalities)

    return CaseSpec(f"template-srb-running-{mode_name(contacts)}", ConstrainedSRBKnot, make)


ACTION_CASES: list[CaseSpec] = [
    *_whole_body_specs(),
    *_trajopt_specs(),
    *_srb_specs(),
    *(_template_spec(contacts) for contacts in stance_modes()),
]
"""Every knot case, by name."""
