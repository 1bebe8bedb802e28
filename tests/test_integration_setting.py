"""The whole-body integration scheme as a setting: ``mpc.integration`` reaches every whole-body knot factory
of the MPC, a trajectory-optimisation task's ``integration`` its planning model and its check."""

from __future__ import annotations

import pytest

from cafe_mpc.assembly import load_run_config
from cafe_mpc.assembly.resolve import resolve
from cafe_mpc.config import ConfigError
from cafe_mpc.planners.cafe.setup import build_problem as build_mpc_problem
from cafe_mpc.reference.trajectory_file import load_packaged_trajectory
from cafe_mpc.trajopt.barrel_roll import barrel_roll_task
from cafe_mpc.trajopt.multiphase import build_problem, check_trajectory


@pytest.mark.parametrize("integration", [None, "explicit_world"])
def test_mpc_integration_reaches_every_whole_body_factory(robot, integration):
    overrides = [] if integration is None else [f"mpc.integration={integration}"]
    config = load_run_config("barrel-roll", overrides)
    builder = build_mpc_problem(resolve(config, robot))
    factories = [pair[0] for pair in builder.weight_factories.values()] + list(builder._intermediate.values())
    assert len(factories) == 4  # regular and barrel_roll weights, each with its intermediate terminal
    expected = integration or "explicit"
    assert {factory.settings.integration for factory in factories} == {expected}
    assert builder.whole_body.dynamics((1, 0, 0, 1)).integration == expected


def test_unknown_mpc_integration_is_a_config_error():
    with pytest.raises(ConfigError, match="integration"):
        load_run_config("trot", ["mpc.integration=rk4"])


def test_task_integration_reaches_the_planning_model_and_its_check(robot):
    task = barrel_roll_task().model_copy(update={"integration": "explicit_world"})
    built = build_problem(robot, task, task.constraints.warm_up_barriers)
    schemes = {knot.dynamics.integration for phase in built.problem.phases for knot in phase.running_models}
    assert schemes == {"explicit_world"}
    # the packaged roll was optimised with the explicit step: no defect there, some with the other scheme
    trajectory = load_packaged_trajectory("barrel-roll", robot)
    explicit = check_trajectory(robot, trajectory, task.phase_surface_heights())
    world = check_trajectory(robot, trajectory, task.phase_surface_heights(), "explicit_world")
    assert explicit.defects.max() < 1e-6 < world.defects.max()
