"""The running barrel roll (paper Sec. VII-C, Fig. 13-16): the composed reference (flying pace -> roll from
its right stance -> hop -> flying pace), the bar in the plant's scene, and the template-vs-CAFE comparison."""

import json

import mujoco
import numpy as np
import pytest

from cafe_mpc.assembly import build_reference, load_run_config, resolve
from cafe_mpc.config import ConfigError
from cafe_mpc_lab.experiments.sweep import run_experiment
from cafe_mpc_lab.report.metrics import roll_pitch_yaw
from cafe_mpc_lab.report.task_metrics import reference_trace, task_from_reference
from cafe_mpc_lab.sim.bar import Bar, bar_of
from cafe_mpc_lab.sim.scene import Scene

DT = 0.005


@pytest.fixture(scope="module")
def composed(robot):
    config = load_run_config("running-barrel-roll")
    return config, build_reference(resolve(config, robot))


def _trace(reference, robot, end: float):
    times = np.arange(0.0, end, DT)
    q = reference_trace(reference, times, robot.nq, robot.nv, robot.nu, robot.n_feet)
    return times, q


def test_running_roll_reference_follows_the_recipe(robot, composed):
    """Pace until the left legs end a stance, the roll from its right stance (FR, HR), a flight, a landing on
    all four, a hop, and the pace again; no full stance between the pace's start and the roll's take-off."""
    config, reference = composed
    roll_start = reference.segments[1].start
    task = task_from_reference(reference)
    assert task is not None and task.start == pytest.approx(roll_start)
    stance = {name: i for i, name in enumerate(robot.leg_names)}
    left = (stance["FL"], stance["HL"])
    right = (stance["FR"], stance["HR"])
    before = reference.stance_at(roll_start - 0.01)
    # the pace ends on the left legs, the roll starts on its right legs
    assert all(before[i] for i in left) and not any(before[i] for i in right)
    first = reference.stance_at(roll_start + 0.01)
    assert all(first[i] for i in right) and not any(first[i] for i in left)
    assert not any(reference.stance_at(0.5 * (task.takeoff + task.touchdown)))  # the roll's flight
    assert all(reference.stance_at(task.touchdown + 0.01))  # the landing on all four
    pace_start = config.reference.segments[0].gait.start_stance
    for t in np.arange(pace_start + 0.01, task.takeoff, DT):
        assert not all(reference.stance_at(float(t))), f"full stance at {t:.3f} s before the roll"
    # the hop: a flight after the landing, then the pace's side stances again
    after = [reference.stance_at(float(t)) for t in np.arange(task.touchdown + 0.05, task.end, DT)]
    assert any(not any(flags) for flags in after)
    later = [reference.stance_at(float(t)) for t in np.arange(task.end + 0.5, task.end + 1.5, DT)]
    assert any(flags == (True, False, True, False) for flags in later)
    assert any(flags == (False, True, False, True) for flags in later)


def test_running_roll_reference_is_continuous_and_turns_once(robot, composed):
    _, reference = composed
    times, q = _trace(reference, robot, 6.0)
    step = np.linalg.norm(np.diff(q[:, :2], axis=0), axis=1)  # the joins map (x, y, yaw): no jump
    assert step.max() < 0.01, f"base jumps {step.max():.3f} m at {times[np.argmax(step)]:.3f} s"
    # heights are absolute: the roll's stand (0.235 m) and the pace's (0.25 m) differ by a couple of cm
    assert np.abs(np.diff(q[:, 2])).max() < 0.03
    # sign-continuous across the 2 pi roll; one step in orientation where the roll starts: its right-stance
    # phase begins already rolled by the skipped first stance (the recipe starts the roll there)
    quaternion_dot = np.sum(q[1:, 3:7] * q[:-1, 3:7], axis=1)
    task = task_from_reference(reference)
    steps = times[1:][quaternion_dot < 0.999]
    assert np.all(np.abs(steps - task.start) <= DT), steps
    assert quaternion_dot.min() > np.cos(0.5 / 2.0)  # that step is below 0.5 rad
    roll = roll_pitch_yaw(q[:, 3:7])[:, 0]
    assert roll[0] == pytest.approx(0.0, abs=1e-6)
    assert roll[-1] == pytest.approx(2.0 * np.pi, abs=0.05)
    forward = np.diff(q[:, 0]) / DT  # the pace moves at its 0.8 m/s before and after the roll
    assert np.median(forward[(times[1:] > 1.0) & (times[1:] < task.start)]) == pytest.approx(0.8, abs=0.05)
    assert np.median(forward[times[1:] > task.end + 1.0]) == pytest.approx(0.8, abs=0.05)


def test_measured_join_places_the_roll_where_the_pace_now_ends(robot):
    """``join: measured``: the pace re-anchors on the measurement, and the roll (not started yet) is placed at
    the pace's new end; the trace stays continuous across the join (the preset now joins fixed)."""
    config = load_run_config("running-barrel-roll", ["reference.join=measured"])
    reference = build_reference(resolve(config, robot))
    before = reference.offset_of(1)
    q = robot.q_standing.copy()
    q[:2] = [0.35, 0.04]  # the robot is somewhere other than the plan's start
    v = np.zeros(robot.nv)
    reference.update(0.4, q, v)
    after = reference.offset_of(1)
    assert np.linalg.norm(np.subtract(after[:2], before[:2])) > 0.02
    roll_start = reference.segments[1].start
    times = np.array([roll_start - 1e-4, roll_start + 1e-4])
    ends = reference_trace(reference, times, robot.nq, robot.nv, robot.nu, robot.n_feet)
    assert np.linalg.norm(ends[1, :2] - ends[0, :2]) < 0.01


def test_bar_in_the_scene_collides_with_legs_only_where_it_is(robot):
    config = load_run_config("running-barrel-roll")
    bar = bar_of(config.scene)
    assert bar == Bar(0.4, (2.0, -0.30), 0.0, 2.0, 0.005)
    assert bar_of(load_run_config("running-barrel-roll", ["scene.bar_height=0"]).scene) is None
    model = mujoco.MjModel.from_xml_string(Scene(bar=bar).mjcf(robot))
    geom = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "bar")
    assert geom >= 0 and model.geom_pos[geom][2] == pytest.approx(0.4)
    with pytest.raises(ConfigError, match="bar"):
        load_run_config("running-barrel-roll", ["scene.bar_radius=-1"])


@pytest.mark.slow
def test_template_vs_cafe_compares_both_planners(tmp_path):
    """A short comparison (the roll's first 0.6 s, fixed latency, no video): both planners run the same
    reference and the comparison files name both."""
    out = tmp_path / "comparison"
    run_experiment(
        "template-vs-cafe",
        out,
        duration=0.6,
        overrides=["mpc.latency=fixed", "output.render=false"],
        scheduler="synchronous",
    )
    comparison = json.loads((out / "comparison.json").read_text())
    assert set(comparison["variants"]) == {"cafe", "template"}
    for name, row in comparison["variants"].items():
        assert row["status"] == "ok", name
        assert row["timing_mode"] == "fixed"
        assert row["fell"] is False, name  # 0.6 s: the stand and the start of the roll's stance
    text = (out / "comparison.md").read_text()
    assert "CAFE-MPC + VWBC" in text and "template MPC" in text
    assert (out / "comparison.png").is_file()
    with pytest.raises(ConfigError, match="not an acrobatic task"):
        run_experiment("template-vs-cafe", tmp_path / "x", duration=0.1, scheduler="synchronous", task="trot")


@pytest.mark.slow
def test_a_take_off_within_the_motors_clears_the_bar_in_a_randomised_trial():
    """Reliability trial 6 (default ranges, fixed latency), through the flight over the bar: with the plan's
    torque limits a soft barrier at the motors' limits (``mpc.torque_barrier_eps`` 0.01, fraction 1) the
    plans ask the right abduction motors for up to 1.26 x their 17 Nm in the take-off, the low level clamps
    and the trunk touches the bar at 2.76 s; with the preset's stiffer barrier at 0.9 of them the plans push
    within what the motors give and the robot clears the bar (docs/robustness.md). The approach here is the
    one this was measured with (path gain 2 rad/m, footholds from the measured base, ``path_anchor`` 0)."""
    from cafe_mpc_lab.experiments.run import simulate_run

    config = _randomised_trial(6, duration=3.1, overrides=APPROACH_WITHOUT_ANCHOR)
    assert config.mpc.plan_torque_fraction < 1.0 and config.mpc.torque_barrier_eps >= 1.0
    _, _, log = simulate_run(config)
    assert not log.fell and log.time[-1] >= 3.09
    assert not np.any(log.extra["bar_contact"])
    assert log.q[:, 2].max() > 0.52


@pytest.mark.slow
def test_the_approach_starts_from_rest_and_a_heavier_robot_paces_on(robot):
    """Reliability trial 37 (default ranges, whole robot about 3 % heavier, fixed latency), through the
    approach's second cycle. With the pace commanded at 0.8 m/s from the start (a step, ``command_ramp`` 0)
    the first left stance had to carry the robot from 0.34 to 0.9 m/s and into its first flight at once; this
    robot's body flew 2 cm lower than the nominal one's, its right feet met the floor 80 ms before their
    planned touchdown while the trunk still rose, rolled it over (7 rad/s within 60 ms) and it fell at
    0.91 s. With the preset's ramp from rest the right feet land on time and the robot paces on
    (docs/robustness.md, "The approach: its first push and its line")."""
    from cafe_mpc_lab.experiments.run import simulate_run

    config = _randomised_trial(37, duration=1.2)
    approach = config.reference.segments[0].gait
    assert approach.command_ramp > 0.0
    _, _, log = simulate_run(config)
    assert not log.fell and log.time[-1] >= 1.19
    # the right feet's first touchdown after the start stance: planned at 0.55 s (0.3 s stand, 0.15 s left
    # stance, 0.1 s flight)
    right = [robot.leg_names.index(name) for name in ("FR", "HR")]
    after_stand = log.time > approach.start_stance + 0.1
    for leg in right:
        first = log.time[after_stand][np.argmax(log.contacts[after_stand, leg])]
        assert first >= 0.55 - 0.03, f"leg {leg} landed at {first:.3f} s"


@pytest.mark.slow
def test_the_approach_holds_its_line_and_the_roll_clears_the_bar_in_a_randomised_trial():
    """Reliability trial 26 (default ranges, fixed latency), through the flight over the bar. The roll
    tracks no base position and starts where the pace ends, so where the robot is across its line then
    decides where it crosses the bar: the preset's approach holds its line (docs/robustness.md, "The
    approach: its first push and its line") and starts the roll within 3 cm of it."""
    from cafe_mpc_lab.experiments.run import simulate_run

    config = _randomised_trial(26, duration=3.1)
    approach = config.reference.segments[0].gait
    assert approach.path_gain > 0.0 and approach.path_anchor == 0.5
    _, _, log = simulate_run(config)
    assert not log.fell and log.time[-1] >= 3.09
    assert not np.any(log.extra["bar_contact"])
    roll_start = np.searchsorted(log.time, 2.45)
    assert abs(log.q[roll_start, 1]) < 0.03


@pytest.mark.slow
def test_the_approach_steps_onto_its_line_and_the_roll_clears_the_bar_in_a_randomised_trial():
    """Reliability trial 9 (default ranges, fixed latency), through the flight over the bar. With the pace's
    footholds placed from the measured base (``path_anchor`` 0) this robot started the roll 4.4 cm (path
    gain 2 rad/m) or 6.6 cm (1 rad/m) across its line and touched the bar on the way up at 2.73 or 2.71 s;
    with the reference anchored toward the line (``path_anchor`` 1 then, the preset's 0.5 now; path gain 1)
    the approach's steps bring it closer and it clears the bar
    (docs/robustness.md, "The approach's footholds on its line")."""
    from cafe_mpc_lab.experiments.run import simulate_run

    config = _randomised_trial(9, duration=3.3)
    assert config.reference.segments[0].gait.path_anchor == 0.5
    _, _, log = simulate_run(config)
    assert not log.fell and log.time[-1] >= 3.29
    assert not np.any(log.extra["bar_contact"])


@pytest.mark.slow
def test_the_run_out_starts_from_rest_on_a_slippery_floor(robot):
    """Envelope trial 0 at floor friction 0.35 (every other factor nominal, fixed latency), through the
    run-out's first cycle. The roll lands and stands still; with the pace after it commanded at 0.8 m/s from
    its start (a step, ``command_ramp`` 0) its first left stance asked the front-left foot for 0.44-0.48 of
    its load sideways (0.3 -> 0.95 m/s in 0.16 s), and on the 0.35 floor that foot slid at up to 2.6 m/s, the
    trunk flew 6 cm low and the front-right thigh went 2.8 cm into the floor when its foot landed (4.14 s);
    with the preset's ramp from rest the run-out paces on (docs/robustness.md, "Low friction: the
    run-out's first push")."""
    from cafe_mpc_lab.experiments.run import simulate_run
    from cafe_mpc_lab.report.task_metrics import CONTACT_TOLERANCE_M, body_floor_clearance

    config = _envelope_trial("friction", 0.35, seed=0, duration=4.4)
    assert config.reference.segments[2].gait.command_ramp > 0.0
    _, _, log = simulate_run(config)
    assert not log.fell and log.time[-1] >= 4.39
    clearance = body_floor_clearance(robot, log.q)
    for part in ("thigh", "knee"):
        assert clearance[part].min() > CONTACT_TOLERANCE_M, f"{part} {clearance[part].min():.3f} m"


@pytest.mark.slow
def test_a_heavier_robot_clears_the_bar_with_the_approach_anchored_halfway():
    """Envelope trial 0 at mass scale 1.15 (every other factor nominal, fixed latency), through the flight.
    With the approach's base reference and footholds on the line (``path_anchor`` 1) this robot's trunk
    came down on the bar at 3.0 s (7 of 10 such trials did, by 1-2 mm); anchored halfway (the preset's 0.5)
    it clears it (docs/robustness.md, "The approach's footholds on its line")."""
    from cafe_mpc_lab.experiments.run import simulate_run

    config = _envelope_trial("mass", 1.15, seed=0, duration=3.15)
    assert config.reference.segments[0].gait.path_anchor == 0.5
    _, _, log = simulate_run(config)
    assert not log.fell and log.time[-1] >= 3.14
    assert not np.any(log.extra["bar_contact"])


@pytest.mark.slow
def test_the_roll_holds_the_line_to_the_bar_after_a_push_in_the_approach():
    """Reliability trial 27 (default ranges, fixed latency), through the flight over the bar. A 0.48 m/s push
    toward the bar at 2.08 s starts the roll 12 cm across the run's line. With the roll placed where the
    pace then predicts its end (``reference.join`` measured) and no weight on its lateral position (the
    authors' set) nothing in the plans knows where the bar is: the trunk touched it at 2.69 s, on the way
    up. With the roll placed on the run's line at the start (``join`` fixed) and its world y tracked (weight
    100), the approach's last plans, which see the roll within their horizon, and the take-off steer the
    robot back and it clears the bar (docs/robustness.md, "The take-off told where the bar is")."""
    from cafe_mpc_lab.experiments.run import simulate_run

    config = _randomised_trial(27, duration=3.2)
    assert config.reference.join == "fixed"
    assert config.reference.costs.running.base_position[1] > 0.0
    _, _, log = simulate_run(config)
    assert not log.fell and log.time[-1] >= 3.19
    assert not np.any(log.extra["bar_contact"])


APPROACH_WITHOUT_ANCHOR = [
    "reference.segments.0.gait.path_gain=2.0",
    "reference.segments.0.gait.path_anchor=0",
]
"""The running roll's approach before its footholds were placed on its line."""


def _randomised_trial(seed: int, duration: float, overrides: list[str] | None = None):
    """The running roll's reliability trial ``seed`` (default ranges, 12 trials' sampling, fixed latency),
    simulated for ``duration`` s, with the preset's ``overrides``."""
    from cafe_mpc.config import load_config
    from cafe_mpc_lab.experiments.reliability import RandomizationRanges, sample_trial

    preset = load_config("running-barrel-roll")
    sensors = preset.plant.sensors.model_dump(mode="json")
    plant, push = sample_trial(
        RandomizationRanges(), seed, 12, preset.simulation.duration, preset.estimator, sensors
    )
    return load_config(
        "running-barrel-roll",
        [
            f"plant={json.dumps(plant)}",
            f"pushes={json.dumps([push])}",
            "mpc.latency=fixed",
            f"simulation.duration={duration}",
            "mpc.warm_up=0.2",
            *(overrides or []),
        ],
    )


def _envelope_trial(
    factor: str, value: float, seed: int, duration: float, overrides: list[str] | None = None
):
    """The running roll's envelope trial ``seed`` at ``factor`` = ``value`` (every other factor nominal, as
    ``cafe-mpc experiment envelope``), fixed latency, simulated for ``duration`` s."""
    from cafe_mpc.config import load_config
    from cafe_mpc.robots.robot import load_robot
    from cafe_mpc_lab.experiments.envelope import point_ranges
    from cafe_mpc_lab.experiments.reliability import sample_trial

    preset = load_config("running-barrel-roll")
    robot = load_robot(preset.robot)
    sensors = preset.plant.sensors.model_dump(mode="json")
    ranges, mass = point_ranges(factor, value, robot.plant.floor_friction)
    plant, _ = sample_trial(ranges, seed, robot.nu, preset.simulation.duration, preset.estimator, sensors)
    plant["mass_scale"] = mass
    return load_config(
        "running-barrel-roll",
        [
            f"plant={json.dumps(plant)}",
            "mpc.latency=fixed",
            f"simulation.duration={duration}",
            "mpc.warm_up=0.2",
            *(overrides or []),
        ],
    )


@pytest.mark.slow
def test_the_run_out_keeps_its_heading_after_the_take_off_from_the_pace(robot, tmp_path):
    """Envelope trial 4 at floor friction 0.35 with the take-off optimised from the pace
    (catalogue/running_barrel_roll_from_pace.yaml), through the run-out's second cycle. That roll lands
    0.2 rad off its heading, yawing; with the run-out turning back to its line (``path_gain`` 1) and at
    0.8 m/s 0.5 s after it starts, its left stances slid at the floor's 0.35 and a thigh went 1-5 cm into
    the floor when the right pair landed; keeping its heading and ramping over 1 s, the preset's run-out
    paces on (docs/robustness.md, "Low friction: the run-out's first push")."""
    from cafe_mpc.reference.trajectory_file import save_trajectory
    from cafe_mpc.trajopt.multiphase import solve_task
    from cafe_mpc.trajopt.presets import load_task
    from cafe_mpc_lab.experiments.run import simulate_run
    from cafe_mpc_lab.report.task_metrics import CONTACT_TOLERANCE_M, body_floor_clearance

    result = solve_task(robot, load_task("running-barrel-roll-from-pace"))
    assert result.converged
    path = save_trajectory(tmp_path / "running_barrel_roll_from_pace.npz", result.trajectory, robot)
    config = _envelope_trial(
        "friction", 0.35, seed=4, duration=5.0, overrides=[f"reference.segments.1.trajectory={path}"]
    )
    run_out = config.reference.segments[2].gait
    assert run_out.path_gain == 0.0 and run_out.command_ramp == 1.0
    _, _, log = simulate_run(config)
    assert not log.fell and log.time[-1] >= 4.99
    clearance = body_floor_clearance(robot, log.q)
    for part in ("thigh", "knee"):
        assert clearance[part].min() > CONTACT_TOLERANCE_M, f"{part} {clearance[part].min():.3f} m"
