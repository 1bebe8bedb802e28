"""Offline trajectory optimisation (``cafe_mpc.trajopt``): the barrel-roll problem builds, one MS-iLQR
iteration lowers the merit, the task round-trips through YAML and overrides, the shipped trajectory is
dynamically feasible under the planning model and was made from the current preset.

The full solve is ``cafe-mpc optimize barrel-roll`` (README), not part of the suite."""

from __future__ import annotations

import itertools
from dataclasses import replace

import numpy as np
import pinocchio as pin
import pytest

from cafe_mpc.reference.trajectory_file import load_packaged_trajectory, packaged_trajectory_path
from cafe_mpc.solver import MSiLQRSolver
from cafe_mpc.trajopt.barrel_roll import barrel_roll_task
from cafe_mpc.trajopt.multiphase import build_problem, check_trajectory, roll_turned
from cafe_mpc.trajopt.outputs import cumulative_roll, write_plots
from cafe_mpc.trajopt.presets import load_task
from cafe_mpc.trajopt.task import TrajOptTaskError
from cafe_mpc_lab.cli import main

TWO_PI = 2.0 * np.pi


@pytest.fixture(scope="module")
def task():
    return barrel_roll_task()


@pytest.fixture(scope="module")
def shipped(robot):
    return load_packaged_trajectory("barrel-roll", robot)


def rotation_angle(quaternion_a: np.ndarray, quaternion_b: np.ndarray) -> float:
    """Angle of the rotation between two (x, y, z, w) quaternions."""
    ra = pin.Quaternion(quaternion_a).toRotationMatrix()
    rb = pin.Quaternion(quaternion_b).toRotationMatrix()
    return float(np.linalg.norm(pin.log3(ra.T @ rb)))


def test_barrel_roll_problem_builds(robot, task):
    built = build_problem(robot, task, task.constraints.warm_up_barriers)
    phases = built.problem.phases
    assert [p.name for p in phases] == ["stance", "right-stance", "flight", "landing", "hop", "stand"]
    assert [len(p.running_models) for p in phases] == [12, 21, 42, 15, 20, 15]
    assert built.n_knots == 125
    assert [layout.stance for layout in built.phases][:3] == [
        (True, True, True, True),
        (False, True, False, True),
        (False, False, False, False),
    ]
    # Touchdowns (end of the flight and of the hop) are switching constraints on all four feet and impacts.
    constrained = [p.switching_constraint is not None for p in phases]
    assert constrained == [False, False, True, False, True, False]
    assert [p.switching_constraint.dim for p in phases if p.switching_constraint is not None] == [4, 4]
    resets = [type(p.reset_map).__name__ for p in phases[:-1]]
    assert resets[2] == resets[4] == "ImpactReset"
    assert resets[0] == resets[1] == resets[3] == "IdentityReset"
    assert built.rollout_knots == [None, None, None, [0], None, [0]]
    # The planning robot carries the task's joint speed limit.
    np.testing.assert_allclose(built.robot.velocity_limits, 20.0)
    # Initial state: the authors' crouch with the feet on the floor (foot-sphere centres at the radius).
    feet = robot.foot_positions(built.problem.x0[: robot.nq])
    np.testing.assert_allclose(feet[:, 2], robot.foot_radius, atol=1e-4)


def test_guess_and_references_roll_the_long_way(robot, task):
    """Orientation pitfall: every running reference is within pi of the guess at its knot, and the guess
    turns through 2 pi (log3 distances stay small, the cumulative roll is monotone)."""
    built = build_problem(robot, task)
    nq = robot.nq
    angles = []
    for phase, xs in zip(built.problem.phases, built.initial_xs, strict=True):
        for k, knot in enumerate(phase.running_models):
            angles.append(rotation_angle(knot.reference.state[3:7], xs[k, 3:7]))
    assert max(angles) < 1e-9  # the guess sits on the interpolated references
    # The guess turns through 2 pi in small steps up to the landing (end of phase 3).
    path = np.concatenate([xs[:-1, 3:7] for xs in built.initial_xs[:3]] + [built.initial_xs[2][-1:, 3:7]])
    turned = sum(rotation_angle(a, b) for a, b in itertools.pairwise(path))
    assert turned == pytest.approx(TWO_PI, abs=1e-6)
    flight = built.problem.phases[2]
    references = [knot.reference.state for knot in flight.running_models]
    # Consecutive references differ by a small rotation (1.5 pi over 42 knots), never a jump back.
    steps = [rotation_angle(a[3:7], b[3:7]) for a, b in itertools.pairwise(references)]
    assert max(steps) < 0.2
    assert all(reference[nq + 3] > 10.0 for reference in references)  # roll rate of the interpolation


def test_one_iteration_lowers_the_merit(robot, task):
    """One MS-iLQR iteration from the keyframe guess: the step is accepted and the merit
    ``J + 0.5 sigma ||g||^2 + rho ||d||_1`` (sigma the initial AL penalty, rho the iteration's) decreases."""
    built = build_problem(robot, task, task.constraints.warm_up_barriers)
    options = replace(task.solver.options(), max_al_iterations=1, final_backward_pass=False)

    def solve(iterations: int):
        solver = MSiLQRSolver(replace(options, max_iterations=iterations))
        return solver.solve(built.problem, built.initial_xs, built.initial_us, built.rollout_knots)

    before, after = solve(0), solve(1)
    assert after.statistics.iterations == 1 and after.statistics.step_sizes[0] > 0.0
    rho = after.statistics.merit_weights[0]
    sigma = options.al_initial_penalty

    def merit(result) -> float:
        switching = sum(
            0.5 * sigma * float(phase.switching_value @ phase.switching_value)
            for phase in result.phases
            if phase.switching_value is not None
        )
        return result.cost + switching + rho * result.defect_l1

    assert merit(after) < merit(before)
    assert after.defect_l1 < before.defect_l1


def test_shipped_trajectory_is_feasible(robot, shipped):
    """The packaged barrel roll under the planning model: every defect (dynamics and impacts) <= 1e-3,
    |tau| <= 17 Nm, touchdown feet at the ground, a 2 pi +- 0.05 roll at landing."""
    check = check_trajectory(robot, shipped)
    assert check.max_defect <= 1e-3
    assert check.max_abs_torque <= 17.0 + 1e-9
    assert check.landing_time == pytest.approx(0.75)
    assert [t for t, _ in check.touchdown_heights] == pytest.approx([0.75, 1.10])
    assert check.max_touchdown_height_error <= 1e-3
    assert check.roll_at_landing == pytest.approx(TWO_PI, abs=0.05)
    assert check.min_base_height >= 0.15 - 1e-3
    # Forces: the stance feet push (unilateral), swing feet carry none.
    stance = shipped.contacts.astype(bool)
    assert np.all(shipped.forces[stance][:, 2] > -1e-6)
    assert np.all(shipped.forces[~stance] == 0.0)
    assert roll_turned(shipped, 0.75) == pytest.approx(cumulative_roll(shipped)[75])


def test_feasibility_check_detects_a_broken_trajectory(robot, shipped):
    broken = replace(shipped, xs=shipped.xs.copy(), us=shipped.us.copy())
    broken.us[50, 4] += 5.0  # a torque the states do not follow (in flight)
    assert check_trajectory(robot, broken).max_defect > 1e-3
    moved = replace(shipped, xs=shipped.xs.copy())
    moved.xs[75:, 2] += 0.01  # landing 1 cm in the air
    check = check_trajectory(robot, moved)
    assert check.max_touchdown_height_error > 5e-3


def test_shipped_trajectory_matches_the_preset(task):
    """The packaged .yaml is the current preset: the shipped trajectory is not stale."""
    shipped_task = load_task(str(packaged_trajectory_path("barrel-roll").with_suffix(".yaml")))
    assert shipped_task == task


def test_shipped_running_roll_trajectory_is_feasible_and_current(robot):
    """The running barrel roll's trajectory (the in-place roll's optimisation with the running-roll phase
    durations): feasible under the planning model, 2 pi at landing, and made by the current preset."""
    shipped_running = load_packaged_trajectory("running-barrel-roll", robot)
    check = check_trajectory(robot, shipped_running)
    assert check.max_defect <= 1e-3
    assert check.max_abs_torque <= 17.0 + 1e-9
    assert [t for t, _ in check.touchdown_heights] == pytest.approx([0.83, 1.18])
    assert check.max_touchdown_height_error <= 1e-3
    assert check.roll_at_landing == pytest.approx(TWO_PI, abs=0.05)
    preset = load_task("running-barrel-roll")
    assert load_task(str(packaged_trajectory_path("running-barrel-roll").with_suffix(".yaml"))) == preset


def test_running_roll_from_the_pace_pushes_over_its_whole_right_stance(robot):
    """The running roll's candidate take-off (catalogue/running_barrel_roll_from_pace.yaml): from the pace's
    moving left stance (left feet planted, right feet in the air) it converges, sets the right feet down at
    0.15 s, pushes over the whole right stance (the in-place optimum: 22 % of the stance's vertical impulse
    in its first half), turns 2 pi by the landing, within 0.85 of the motors' limits and inside the
    controller's friction pyramid 0.4."""
    from cafe_mpc.assembly import load_run_config
    from cafe_mpc.trajopt.multiphase import solve_task

    task = load_task("running-barrel-roll-from-pace")
    result = solve_task(robot, task)
    assert result.converged
    trajectory, check = result.trajectory, result.check
    assert check.max_defect <= 1e-3
    assert [t for t, _ in check.touchdown_heights] == pytest.approx([0.15, 0.86, 1.21])
    assert check.max_touchdown_height_error <= 1e-3
    start_feet = robot.foot_positions(trajectory.xs[0, : robot.nq])
    np.testing.assert_allclose(start_feet[[0, 2], 2], robot.foot_radius, atol=1e-3)  # FL, HL planted
    assert np.all(start_feet[[1, 3], 2] > robot.foot_radius + 0.02)  # FR, HR swinging
    first, last = (round(t / trajectory.dt) for t in task.switching_times[1:3])
    vertical = trajectory.forces[first:last, :, 2].sum(axis=1)
    half = (last - first) // 2
    assert vertical[:half].sum() > 0.35 * vertical.sum()
    assert roll_turned(trajectory, task.switching_times[3]) == pytest.approx(TWO_PI, abs=0.05)
    limits = np.asarray(task.constraints.torque_limits(robot))
    assert limits == pytest.approx(0.85 * np.asarray(robot.plant.motor_torque_limits))
    assert np.all(np.abs(trajectory.us) <= limits + 0.2)
    friction = load_run_config("running-barrel-roll").mpc.friction
    forces = trajectory.forces[trajectory.contacts.astype(bool)]
    tangential = np.maximum(np.abs(forces[:, 0]), np.abs(forces[:, 1]))
    assert np.all(tangential <= friction * forces[:, 2] + 0.01)


def test_task_yaml_round_trip_and_overrides(tmp_path, task):
    path = tmp_path / "task.yaml"
    path.write_text(task.to_yaml("header\nline"))
    assert load_task(str(path)) == task
    changed = load_task("barrel-roll", ["phases.2.terminal.base_position.5=5", "solver.max_al_iterations=40"])
    assert changed.phases[2].terminal.base_position[5] == 5.0
    assert changed.solver.max_al_iterations == 40
    assert changed.phases[1] == task.phases[1]
    with pytest.raises(TrajOptTaskError, match=r"unknown task key 'solver\.bogus'"):
        load_task("barrel-roll", ["solver.bogus=1"])
    with pytest.raises(TrajOptTaskError, match=r"phases.1.contacts: unknown contact code"):
        load_task("barrel-roll", ["phases.1.contacts=XY"])
    with pytest.raises(TrajOptTaskError, match="switching_times"):
        load_task("barrel-roll", ["switching_times=[0, 0.12, 0.33]"])
    with pytest.raises(TrajOptTaskError, match="not a multiple of dt"):
        load_task("barrel-roll", ["switching_times.1=0.125"])
    with pytest.raises(TrajOptTaskError, match="unknown task"):
        load_task("somersault")


def test_torque_limits_from_the_joints_or_the_motors_with_a_margin(robot):
    """The TO's torque limits: the robot table's, the motors' saturation, or one value on every joint, each
    times the fraction the trajectory may use; a fraction outside (0, 1] is refused by its key."""
    joints = load_task("barrel-roll").constraints
    assert joints.torque_limits(robot) == pytest.approx(robot.torque_limits)
    motor = load_task(
        "barrel-roll", ["constraints.torque_limit_source=motor", "constraints.torque_limit_fraction=0.9"]
    ).constraints
    assert motor.torque_limits(robot) == pytest.approx(0.9 * robot.plant.motor_torque_limits)
    assert not np.allclose(robot.plant.motor_torque_limits, robot.torque_limits)  # the knees differ
    single = load_task(
        "barrel-roll", ["constraints.torque_limit=20", "constraints.torque_limit_fraction=0.5"]
    )
    assert single.constraints.torque_limits(robot) == pytest.approx([10.0] * robot.nu)
    for bad in ("0", "1.2"):
        with pytest.raises(TrajOptTaskError, match="torque_limit_fraction"):
            load_task("barrel-roll", [f"constraints.torque_limit_fraction={bad}"])
    with pytest.raises(TrajOptTaskError, match="torque_limit_source"):
        load_task("barrel-roll", ["constraints.torque_limit_source=datasheet"])


def test_plots_of_the_shipped_trajectory(tmp_path, robot, task, shipped):
    paths = write_plots(robot, task, shipped, tmp_path)
    assert sorted(p.name for p in paths) == [
        "grfs.png",
        "height.png",
        "lateral_position.png",
        "roll.png",
        "torques.png",
    ]
    assert all(p.stat().st_size > 1000 for p in paths)


def test_cli_optimize_bad_input(tmp_path, capsys):
    assert main(["optimize", "barrel-roll", "--set", "solver.bogus=1", "--out", str(tmp_path / "x")]) == 2
    error = capsys.readouterr().err.strip()
    assert error.startswith("cafe-mpc: error:") and "solver.bogus" in error and "\n" not in error
    occupied = tmp_path / "occupied"
    occupied.mkdir()
    (occupied / "file").write_text("x")
    assert main(["optimize", "barrel-roll", "--out", str(occupied)]) != 0
    assert "not empty" in capsys.readouterr().err
