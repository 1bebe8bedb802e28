"""Every reset map (``ResetMap``) and switching constraint (``SwitchingConstraint``) of the library, as
factory cases (``RESET_CASES``, ``CONSTRAINT_CASES``).

* impact maps (22), (24) (``dynamics.impact.ImpactReset``) for every non-empty set of constrained feet, and
  as the factory makes them (every post-switch stance foot, or only the touchdowns). Not with regularised
  contact dynamics (``damping > 0``): its ``Px`` is the Jacobian of the exact impact (Pinocchio's impulse
  derivatives), which differs from the regularised map's in proportion to ``damping`` (2.4e-4 relative at
  1e-3); no configuration sets it (``WholeBodySettings.contact_damping`` is 0);
* the identity (take-off) on the whole-body and on the SRB state;
* the whole-body -> SRB projection (32) (``dynamics.transition.WholeBodyToSRB``) and the transition (31), an
  impact followed by the projection (``ComposedReset``);
* the reset maps and touchdown constraints (25) of the trajectory-optimisation problems;
* touchdown constraints (``ocp.constraints.TouchdownFootHeight``) for several sets of feet and surface
  heights; the Go2's impact, transition and touchdown.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable

import numpy as np

from cafe_mpc.core.contacts import touchdown_flags
from cafe_mpc.core.interfaces import IdentityReset, ResetMap
from cafe_mpc.dynamics.impact import ImpactReset
from cafe_mpc.dynamics.multibody_state import MultibodyState
from cafe_mpc.dynamics.srb import SRBState
from cafe_mpc.dynamics.transition import ComposedReset, WholeBodyToSRB
from cafe_mpc.ocp.constraints import TouchdownFootHeight
from cafe_mpc.ocp.knots import WholeBodyModelFactory, WholeBodySettings
from cafe_mpc.robots.robot import Robot
from factories.actions import REFERENCE_ROBOT, TRAJOPT_PHASES, trajopt_problem
from factories.cases import CaseSpec, ConstraintCase, Library, ResetCase
from factories.points import mode_name, srb_state, stance_modes, whole_body_state


def _flags(text: str) -> tuple[bool, ...]:
    return tuple(c == "1" for c in text)


def _whole_body_reset(
    name: str, model_type: type, make_reset: Callable[[Robot], ResetMap], robot_name: str = REFERENCE_ROBOT
) -> CaseSpec:
    """A case of ``make_reset(robot)`` at random whole-body states."""

    def make(library: Library, rng: np.random.Generator) -> ResetCase:
        robot = library.robot(robot_name)
        return ResetCase(make_reset(robot), whole_body_state(robot, rng), whole_body_state(robot, rng))

    return CaseSpec(name, model_type, make)


def _switch_reset(
    before: str, after: str, to_srb: bool, all_stance_feet: bool = True
) -> Callable[[Robot], ResetMap]:
    """The reset map ``WholeBodyModelFactory`` makes for the switch ``before`` -> ``after`` (to the SRB tail
    with ``to_srb``)."""

    def reset(robot: Robot) -> ResetMap:
        factory = WholeBodyModelFactory(robot, WholeBodySettings(impact_on_all_stance_feet=all_stance_feet))
        if to_srb:
            return factory.transition_to_srb(_flags(before), _flags(after))
        return factory.reset_map(_flags(before), _flags(after))

    return reset


def _reset_specs() -> list[CaseSpec]:
    specs = []
    for feet in stance_modes()[1:]:
        specs.append(
            _whole_body_reset(
                f"impact-{mode_name(feet)}", ImpactReset, lambda robot, f=feet: ImpactReset(robot, f)
            )
        )
    specs += [
        _whole_body_reset("switch-1001-to-1111", ImpactReset, _switch_reset("1001", "1111", False)),
        _whole_body_reset(
            "switch-1001-to-1111-touchdowns-only", ImpactReset, _switch_reset("1001", "1111", False, False)
        ),
        _whole_body_reset(
            "switch-1111-to-0110-take-off", IdentityReset, _switch_reset("1111", "0110", False)
        ),
        _whole_body_reset(
            "projection-to-srb", WholeBodyToSRB, lambda robot: WholeBodyToSRB(MultibodyState(robot.model))
        ),
        _whole_body_reset(
            "transition-to-srb-1001-to-1111", ComposedReset, _switch_reset("1001", "1111", True)
        ),
        _whole_body_reset(
            "transition-to-srb-0000-to-0110", ComposedReset, _switch_reset("0000", "0110", True)
        ),
        _whole_body_reset(
            "transition-to-srb-1111-to-1001", WholeBodyToSRB, _switch_reset("1111", "1001", True)
        ),
        _whole_body_reset(
            "go2-impact-1001", ImpactReset, lambda robot: ImpactReset(robot, _flags("1001")), "go2"
        ),
        _whole_body_reset(
            "go2-transition-to-srb-0000-to-1111", ComposedReset, _switch_reset("0000", "1111", True), "go2"
        ),
        CaseSpec(
            "identity-srb",
            IdentityReset,
            lambda library, rng: ResetCase(IdentityReset(SRBState()), srb_state(rng), srb_state(rng)),
        ),
    ]
    specs += _trajopt_switch_specs(ResetCase)
    return specs


def _trajopt_switch_specs(kind: type) -> list[CaseSpec]:
    """The reset maps (``kind`` ``ResetCase``) or touchdown constraints (``ConstraintCase``) at the end of
    each phase of the trajectory-optimisation problems, about the guess's last state of the phase: an impact
    and a touchdown constraint (25) where the next phase is entered by a touchdown, the identity otherwise."""
    specs = []
    for task, phases in TRAJOPT_PHASES.items():
        for index, ((phase, stance), (following, next_stance)) in enumerate(itertools.pairwise(phases)):
            touchdown = any(touchdown_flags(stance, next_stance))
            if kind is ConstraintCase and not touchdown:
                continue

            def make(library: Library, rng: np.random.Generator, task=task, index=index):
                built = trajopt_problem(library, task)
                phase_model = built.problem.phases[index]
                guess = built.initial_xs[index][-1]

                def point() -> np.ndarray:
                    return whole_body_state(built.robot, rng, spread=0.1, speed=0.5, around=guess)

                if kind is ResetCase:
                    return ResetCase(phase_model.reset_map, point(), point())
                return ConstraintCase(phase_model.switching_constraint, point(), point())

            if kind is ConstraintCase:
                model_type, label = TouchdownFootHeight, "touchdown"
            else:
                model_type, label = (ImpactReset if touchdown else IdentityReset), "reset"
            specs.append(CaseSpec(f"trajopt-{task}-{phase}-to-{following}-{label}", model_type, make))
    return specs


def _touchdown_spec(name: str, feet: str, height, robot_name: str = REFERENCE_ROBOT) -> CaseSpec:
    def make(library: Library, rng: np.random.Generator) -> ConstraintCase:
        robot = library.robot(robot_name)
        constraint = TouchdownFootHeight(robot, _flags(feet), height)
        return ConstraintCase(constraint, whole_body_state(robot, rng), whole_body_state(robot, rng))

    return CaseSpec(name, TouchdownFootHeight, make)


def _constraint_specs() -> list[CaseSpec]:
    specs = [
        _touchdown_spec("touchdown-1000", "1000", 0.0),
        _touchdown_spec("touchdown-0110-step", "0110", 0.05),
        _touchdown_spec("touchdown-1111-per-foot-heights", "1111", (0.0, 0.02, -0.01, 0.04)),
        _touchdown_spec("go2-touchdown-1001", "1001", 0.0, "go2"),
    ]
    return specs + _trajopt_switch_specs(ConstraintCase)


RESET_CASES: list[CaseSpec] = _reset_specs()
CONSTRAINT_CASES: list[CaseSpec] = _constraint_specs()
