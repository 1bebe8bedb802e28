"""The contact detector on scripted measurements: early and late touchdowns, the schedule's prior, release."""

from __future__ import annotations

import numpy as np
import pytest

from cafe_mpc.assembly import load_run_config
from cafe_mpc.config import ContactDetectionSettings
from cafe_mpc.core.measurement import Measurement
from cafe_mpc.core.physics import GRAVITY
from cafe_mpc.low_level.contact_detection import ContactDetector
from cafe_mpc.planners.cafe.plan import Plan

DT = 0.01
SWING_END = 0.10
"""The scripted plan: foot 0 swings until this time, then stands; the other feet stand throughout."""
TICK = 0.002


def scripted_plan(robot, n: int = 30) -> Plan:
    nu, ndx = robot.nu, 2 * robot.nv
    times = np.arange(n) * DT
    contacts = np.ones((n, robot.n_feet), dtype=bool)
    contacts[times < SWING_END - 1e-9, 0] = False
    return Plan(
        times=times,
        xs=np.tile(np.concatenate([robot.q_standing, np.zeros(robot.nv)]), (n + 1, 1)),
        us=np.zeros((n, nu)),
        K=np.zeros((n, nu, ndx)),
        Qu=np.zeros((n, nu)),
        Quu=np.tile(np.eye(nu), (n, 1, 1)),
        Qux=np.zeros((n, nu, ndx)),
        contacts=contacts,
        forces=np.zeros((n, robot.n_feet, 3)),
        dt=np.full(n, DT),
    )


def measurement(robot, t: float, lift: float, force_on_foot0: float) -> Measurement:
    """The robot standing, raised by ``lift`` (every foot that much above the ground), foot 0 pushed on with
    ``force_on_foot0`` newtons and the other feet carrying the rest of the weight."""
    q = robot.q_standing.copy()
    q[2] += lift
    share = robot.total_mass * GRAVITY / robot.n_feet
    forces = np.zeros((robot.n_feet, 3))
    forces[:, 2] = share
    forces[0, 2] = force_on_foot0
    return Measurement(t, q, np.zeros(robot.nv), np.ones(robot.n_feet, dtype=bool), forces)


@pytest.fixture
def detector(robot):
    return ContactDetector(robot, ContactDetectionSettings())


def run(detector, robot, plan, script):
    """Feed ``script(t) -> (lift, force)`` tick by tick; returns (times, foot 0's detected flag)."""
    times = np.arange(0.0, 0.2, TICK)
    flags = []
    for t in times:
        lift, force = script(t)
        flags.append(bool(detector.update(float(t), measurement(robot, float(t), lift, force), plan)[0]))
    return times, np.array(flags)


def test_an_early_touchdown_is_detected_within_a_few_ticks(robot, detector):
    """Foot 0 lands 40 ms before its planned touchdown (inside the early window): stance from then on."""
    plan = scripted_plan(robot)
    land = 0.06
    share = robot.total_mass * GRAVITY / robot.n_feet

    def script(t):
        return (0.0, share) if t >= land else (0.04, 0.0)

    times, flags = run(detector, robot, plan, script)
    first = times[np.argmax(flags)]
    assert flags.any() and land <= first <= land + 2 * TICK
    assert flags[times >= land].all()
    assert detector.early_touchdowns == 1


def test_a_loaded_foot_early_in_its_swing_is_not_a_touchdown(robot, detector):
    """Outside the early window (just after the planned lift-off) a loaded foot is lifting, not landing."""
    plan = scripted_plan(robot, n=60)
    plan.contacts[:, 0] = True
    plan.contacts[(plan.times >= 0.05) & (plan.times < 0.40), 0] = False  # a 0.35 s swing
    share = robot.total_mass * GRAVITY / robot.n_feet
    times, flags = run(detector, robot, plan, lambda t: (0.0, share))
    swing = (times >= 0.05) & (times < 0.40 - detector.settings.early_window)
    assert not flags[swing].any()


def test_a_late_touchdown_keeps_the_foot_out_of_the_stance_until_it_lands(robot, detector):
    """Planned stance from 0.10 s, the foot lands at 0.15 s: not in contact in between, detected after."""
    plan = scripted_plan(robot)
    land = 0.15
    share = robot.total_mass * GRAVITY / robot.n_feet

    def script(t):
        return (0.0, share) if t >= land else (0.05, 0.0)

    times, flags = run(detector, robot, plan, script)
    assert not flags[(times >= SWING_END) & (times < land)].any()
    assert flags[times >= land + 2 * TICK].all()
    assert detector.late_touchdown_ticks > 0


def test_nominal_contacts_follow_the_plan(robot, detector):
    """A foot that lands when planned: no early touchdown, stance within a tick of the planned time."""
    plan = scripted_plan(robot)
    share = robot.total_mass * GRAVITY / robot.n_feet

    def script(t):
        return (0.0, share) if t >= SWING_END - 1e-9 else (0.03, 0.0)

    times, flags = run(detector, robot, plan, script)
    assert detector.early_touchdowns == 0
    assert not flags[times < SWING_END - 1e-9].any()
    assert flags[times >= SWING_END + TICK].all()


@pytest.mark.slow
def test_a_heavier_trunk_lands_early_in_the_pace_and_detection_keeps_it_up():
    """A reliability trial that fell (running roll's approach pace, trunk 9 % heavier, the sensors' noise of
    seed 1, fixed latency): the body flies lower than planned, the right feet land 70 ms before their planned
    touchdown and, driven along their swings, scuff and roll the robot over (it falls at 0.78 s with the
    schedule's stance, ``vwbc.stance_source=plan``). With the detected stance it paces on. The controller
    plans with the floor's friction (0.6) and starts its approach with a step to 0.8 m/s, as when the trial
    fell: with the default margin (0.4), or with the preset's ramp from rest, this trial no longer lands early
    enough to need the detector."""
    from cafe_mpc.config import load_config
    from cafe_mpc_lab.experiments.run import simulate_run

    config = load_config(
        "running-barrel-roll",
        [
            "mpc.latency=fixed",
            "plant.body_mass_scale=1.090093",
            "plant.seed=1",
            "simulation.duration=1.0",
            "mpc.warm_up=0.2",
            "vwbc.stance_source=detected",
            "mpc.friction=0.6",
            "calibration.online.enabled=false",  # the controller of the trial that fell
            "reference.segments.0.gait.command_ramp=0",  # its approach from a step (the preset now ramps)
            "reference.segments.0.gait.path_gain=1.0",
        ],
    )
    _, controller, log = simulate_run(config)
    assert not log.fell and log.time[-1] >= 0.99
    detector = controller.low_level.inner.detector
    assert detector.early_touchdowns >= 1


@pytest.mark.parametrize("landing_speed", [None, 0.3], ids=["unchecked", "checked"])
def test_off_flat_ground_a_loaded_foot_moving_down_has_not_landed(robot, landing_speed):
    """Blind (a ground plane): foot 0, planned in stance from 0.10 s, comes down 4 cm above the ground at
    1 m/s with a load (the echo of stance torques pushing a leg in the air) and lands at 0.15 s. With
    ``landing_speed`` it stays out of the stance until it has stopped on the ground; without (the default)
    the load counts at once."""
    settings = ContactDetectionSettings(landing_speed=landing_speed, force_estimate="static")
    detector = ContactDetector(robot, settings, ground_plane=True)
    plan = scripted_plan(robot)
    land = 0.15
    share = robot.total_mass * GRAVITY / robot.n_feet
    flags = []
    times = np.arange(0.0, 0.2, TICK)
    for t in times:
        state = measurement(robot, float(t), 0.0 if t >= land else 0.04, share)
        if t < land:
            state.v[2] = -1.0  # the base, and the feet with it, moving down
        flags.append(bool(detector.update(float(t), state, plan)[0]))
    flags = np.array(flags)
    in_the_air = (times >= SWING_END) & (times < land)
    if landing_speed is None:
        assert flags[in_the_air].all()
    else:
        assert not flags[in_the_air].any()
    assert flags[times >= land].all()


def test_off_flat_ground_an_early_touchdown_waits_for_the_foot_to_stop(robot):
    """Blind, ``landing_speed`` set: foot 0 swings down through its early window 4 cm above the plane, loaded
    by its swing torques and moving down at 1 m/s, and lands 40 ms early: an early touchdown from the
    landing, not before."""
    detector = ContactDetector(
        robot, ContactDetectionSettings(landing_speed=0.3, force_estimate="static"), ground_plane=True
    )
    plan = scripted_plan(robot)
    land = 0.06
    share = robot.total_mass * GRAVITY / robot.n_feet
    flags = []
    times = np.arange(0.0, 0.2, TICK)
    for t in times:
        state = measurement(robot, float(t), 0.0 if t >= land else 0.04, share)
        if t < land:
            state.v[2] = -1.0
        flags.append(bool(detector.update(float(t), state, plan)[0]))
    flags = np.array(flags)
    assert not flags[times < land].any()
    assert flags[times >= land].all()
    assert detector.early_touchdowns == 1


def _measured_in_the_air(robot, data, t, q, v, torques, jacobians, static) -> Measurement:
    """The measurement of a simulated tick: every foot flagged, its force the static (massless-leg) estimate
    of ``torques`` through the legs' Jacobians (written into ``jacobians`` and ``static``)."""
    import pinocchio as pin

    from cafe_mpc.estimation.kernels import leg_ground_forces

    pin.computeJointJacobians(robot.model, data, q)
    pin.updateFramePlacements(robot.model, data)
    for foot, frame_id in enumerate(robot.foot_frame_ids):
        columns = slice(6 + 3 * foot, 9 + 3 * foot)
        jacobians[foot] = pin.getFrameJacobian(robot.model, data, frame_id, pin.LOCAL_WORLD_ALIGNED)[
            :3, columns
        ]
    leg_ground_forces(jacobians, torques, 3, static)
    return Measurement(t, q.copy(), v.copy(), np.ones(robot.n_feet, dtype=bool), static.copy())


def _robot_in_the_air(robot, settings, push_on_foot0=None):
    """The robot in the air (Pinocchio's forward dynamics, no ground), leg 0's hip and knee driven by 5 N m
    at 15 Hz (a swing's torques, the leg swinging back and forth) from the standing pose, over 0.1 s; foot 0
    planned in swing until 0.10 s (its early window from 0.02 s), the other feet in stance.
    ``push_on_foot0``: instead of the swing, a world force (N) on foot 0 that its leg holds (its torques
    ``-J' F``, as a leg standing on the ground). Returns the times, foot 0's detected flags, the detector's
    estimated forces on foot 0 and the static (massless-leg) estimate of the same foot from the torques."""
    import pinocchio as pin

    detector = ContactDetector(robot, settings, ground_plane=True)
    plan = scripted_plan(robot)
    model = robot.model
    data = model.createData()
    q, v = robot.q_standing.copy(), np.zeros(robot.nv)
    torques = np.zeros(robot.nu)  # applied over the last tick, as the VWBC passes its previous output
    generalized = np.zeros(robot.nv)
    static = np.zeros((robot.n_feet, 3))
    jacobians = np.zeros((robot.n_feet, 3, 3))
    times = np.arange(0.0, 0.1, TICK)
    flags, estimated, statics = [], [], []
    for t in times:
        state = _measured_in_the_air(robot, data, float(t), q, v, torques, jacobians, static)
        flags.append(bool(detector.update(float(t), state, plan, torques)[0]))
        estimated.append(detector.estimated_forces[0].copy())
        statics.append(static[0].copy())
        generalized[:] = 0.0
        if push_on_foot0 is None:
            torques[1:3] = 5.0 * np.sin(2.0 * np.pi * 15.0 * t)
        else:
            torques[0:3] = -jacobians[0].T @ push_on_foot0
            foot_jacobian = pin.getFrameJacobian(
                model, data, robot.foot_frame_ids[0], pin.LOCAL_WORLD_ALIGNED
            )
            generalized += foot_jacobian[:3].T @ push_on_foot0
        generalized[6:] += torques
        acceleration = pin.aba(model, data, q, v, generalized)
        v = v + TICK * acceleration
        q = pin.integrate(model, q, TICK * v)
    return times, np.array(flags), np.array(estimated), np.array(statics)


def test_the_momentum_observer_reads_no_load_on_a_leg_swinging_in_the_air(robot):
    """A swing's torques on a leg in the air read as a load through the massless-leg (static) estimate
    (docs/terrain-notes.md: 25 N at the end of the bound's swing took a foot 6.6 cm above the floor in as
    landed);
    the momentum observer sees the leg's own motion and reads nothing, so the foot, in its early window and
    at the ground plane's height, is not taken in; the static estimate takes it in."""
    _, flags, estimated, statics = _robot_in_the_air(
        robot, ContactDetectionSettings(force_estimate="momentum")
    )
    threshold = 0.35 * robot.total_mass * GRAVITY / robot.n_feet
    assert np.abs(statics[:, 2]).max() > 2 * threshold
    assert np.abs(estimated).max() < 0.3 * threshold
    assert not flags.any()
    _, static_flags, _, _ = _robot_in_the_air(robot, ContactDetectionSettings(force_estimate="static"))
    assert static_flags.any()


def test_the_momentum_observer_reads_a_force_on_the_foot(robot):
    """A 60 N push up and 10 N forward on foot 0, held by its leg (the falling robot): the observer's
    estimate reaches it within its bandwidth (150 1/s: 95 % in 20 ms) and stays there."""
    push = np.array([10.0, 0.0, 60.0])
    times, _, estimated, _ = _robot_in_the_air(
        robot, ContactDetectionSettings(force_estimate="momentum"), push_on_foot0=push
    )
    settled = times >= 0.03
    assert np.abs(estimated[settled, 2] - push[2]).max() < 1.0  # the normal force the detector reads
    assert np.abs(estimated[settled, :2] - push[:2]).max() < 5.0  # the robot spinning under the push


def test_the_momentum_observer_needs_the_applied_torques(robot):
    detector = ContactDetector(robot, ContactDetectionSettings(force_estimate="momentum"), ground_plane=True)
    state = measurement(robot, 0.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="applied torques"):
        detector.update(0.0, state, scripted_plan(robot))


def _late_foot_below_the_plane(robot, settings, ground_at=0.14):
    """The robot in the air (Pinocchio's forward dynamics, no ground), its joints held by a PD, foot 0's leg
    stretched 4.6 cm below the other feet (a foot reaching down a step), planned in swing until 0.10 s and
    in stance after; from ``ground_at`` the ground pushes 60 N up on foot 0 (the lower tread it meets).
    The detector's ground plane runs through the other feet, so foot 0 is under it all along. Returns the
    times and foot 0's flags: in the stance set, and landed."""
    import pinocchio as pin

    detector = ContactDetector(robot, settings, ground_plane=True)
    plan = scripted_plan(robot)
    model = robot.model
    data = model.createData()
    q_held = robot.q_standing.copy()
    q_held[8] -= 0.15  # foot 0's hip and knee: the leg stretched down
    q_held[9] -= 0.3
    q, v = q_held.copy(), np.zeros(robot.nv)
    torques = np.zeros(robot.nu)  # applied over the last tick, as the VWBC passes its previous output
    static = np.zeros((robot.n_feet, 3))
    jacobians = np.zeros((robot.n_feet, 3, 3))
    push = np.array([0.0, 0.0, 60.0])
    times = np.arange(0.0, 0.2, TICK)
    stance, landed = [], []
    for t in times:
        state = _measured_in_the_air(robot, data, float(t), q, v, torques, jacobians, static)
        stance.append(bool(detector.update(float(t), state, plan, torques)[0]))
        landed.append(bool(detector.in_contact[0]))
        torques[:] = 40.0 * (q_held[7:] - q[7:]) - 1.0 * v[6:]
        generalized = np.zeros(robot.nv)
        generalized[6:] = torques
        if t >= ground_at:
            foot_jacobian = pin.getFrameJacobian(
                model, data, robot.foot_frame_ids[0], pin.LOCAL_WORLD_ALIGNED
            )
            generalized += foot_jacobian[:3].T @ push
        acceleration = pin.aba(model, data, q, v, generalized)
        v = v + TICK * acceleration
        q = pin.integrate(model, q, TICK * v)
    return times, np.array(stance), np.array(landed)


def test_with_the_momentum_observer_a_foot_under_the_plane_lands_when_the_ground_pushes(robot):
    """Going down a step, a late foot passes under the ground plane (through feet on the upper tread) before
    it meets the lower one. With the observer's force the detector waits for the ground: foot 0 is out of the
    stance set from its planned touchdown (0.10 s) until the ground pushes on it (0.14 s), then in within two
    ticks; by its height alone (the static estimate, whose force only echoes the torques) it was taken in at
    its planned touchdown, 4.6 cm in the air, and its point pulled the plane down."""
    ground_at = 0.14
    times, stance, landed = _late_foot_below_the_plane(
        robot, ContactDetectionSettings(force_estimate="momentum"), ground_at
    )
    late = (times >= SWING_END + TICK) & (times < ground_at)
    assert not stance[late].any() and not landed[late].any()
    assert stance[times >= ground_at + 2 * TICK].all()
    times, stance, _ = _late_foot_below_the_plane(
        robot, ContactDetectionSettings(force_estimate="static"), ground_at
    )
    assert stance[late].all()


def test_the_detection_benchmark_runs_and_finds_no_false_touchdown_in_a_short_nominal_trot():
    """``benchmarks/contact_detection.py`` on 1 s of the nominal trot (fixed latency): it runs against the
    detector's current interface, sees the trot's touchdowns, and calls none of them false."""
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "benchmarks" / "contact_detection.py"
    spec = importlib.util.spec_from_file_location("contact_detection_benchmark", path)
    benchmark = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(benchmark)
    row = benchmark.evaluate("trot", 1.0, [])
    assert row["touchdowns"] >= 4 and row["missed"] == 0
    assert row["false_touchdowns"] == 0
    assert row["delay_ms_max"] <= 10.0


def test_the_force_estimate_defaults_to_the_momentum_observer_off_flat_ground_only(robot):
    """``force_estimate: null`` resolves to ``static`` on flat ground and ``momentum`` on a ground plane
    (blind or height-map terrain); a value set is kept either way."""
    assert ContactDetector(robot, ContactDetectionSettings()).force_estimate == "static"
    assert ContactDetector(robot, ContactDetectionSettings(), ground_plane=True).force_estimate == "momentum"
    static = ContactDetectionSettings(force_estimate="static")
    assert ContactDetector(robot, static, ground_plane=True).force_estimate == "static"
    assert load_run_config("trot", ["terrain=blind"]).vwbc.contact_detection.force_estimate is None
