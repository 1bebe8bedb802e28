"""State estimation as on the robot (issue 23): sensors in the plant, the kinematic Kalman filter, the closed
loop that sees sensors only.

Synthetic tests feed the estimator readings made from a known motion (Pinocchio leg inverse kinematics: the
base moves, the feet stay on the ground, or one slides): the filter recovers a constant velocity, a slipping
stance foot raises its error (and the slip test catches it), a foot in swing or the whole robot in flight is
ignored (the IMU alone). Closed loops: standing (the IMU's orientation matches the truth; the controller gets
the estimator's measurement, not the plant's state) and a short trot with fixed latency that stays up.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import pinocchio as pin
import pytest
from scipy.spatial.transform import Rotation

from cafe_mpc.assembly import load_run_config
from cafe_mpc.config import ConfigError, EncoderSpec, ImuSpec, KinematicKFSettings
from cafe_mpc.core.sensors import ImuMounting, SensorReadings, rotation_to_quaternion
from cafe_mpc.estimation.estimator import StateEstimator, leg_velocity_indices
from cafe_mpc_lab.sim.mujoco_plant import MujocoPlant
from cafe_mpc_lab.sim.sensors import SensorSpec, SensorSuite, sensor_spec

DT = 0.002
LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED


@dataclass
class FakePlan:
    """Stance flags over knot intervals, as ``planners.cafe.plan.Plan`` carries them."""

    times: np.ndarray
    dt: np.ndarray
    contacts: np.ndarray


def steady_plan(n_feet: int, swing: tuple[int, ...] = (), duration: float = 10.0) -> FakePlan:
    times = np.arange(0.0, duration, 0.01)
    contacts = np.ones((len(times), n_feet), dtype=bool)
    contacts[:, list(swing)] = False
    return FakePlan(times, np.full(len(times), 0.01), contacts)


def synthetic_readings(
    robot,
    velocity: np.ndarray,
    duration: float,
    slip: tuple[int, np.ndarray, float] | None = None,
    tilt: tuple[float, float] = (0.05, -0.03),
    ramp: float = 0.2,
    raised: tuple[int, float] | None = None,
) -> list[SensorReadings]:
    """Readings of the base speeding up from rest to ``velocity`` (world) at a constant acceleration over
    ``ramp`` seconds, then translating at it, with a fixed tilted attitude, while the feet stay where they
    stand; ``slip = (leg, foot velocity, from time)``: that foot slides from then on. Joint angles from
    Pinocchio's leg kinematics (Newton on each leg's 3 joints), joint rates exact; the accelerometer reads
    the acceleration and gravity. ``raised = (leg, height)``: that foot stands that much higher (on a
    step)."""
    model, data = robot.model, robot.model.createData()
    legs = leg_velocity_indices(robot)
    rotation = Rotation.from_euler("xy", tilt)
    q = robot.q_standing.copy()
    q[3:7] = rotation.as_quat()
    feet0 = robot.foot_positions(robot.q_standing)  # standing feet, on the ground
    if raised is not None:
        feet0[raised[0], 2] += raised[1]
    base0 = q[:3].copy()
    readings = []
    for k in range(round(duration / DT) + 1):
        t = k * DT
        if t < ramp:
            q[:3] = base0 + velocity * t * t / (2.0 * ramp)
            base_velocity, acceleration = velocity * t / ramp, velocity / ramp
        else:
            q[:3] = base0 + velocity * (t - 0.5 * ramp)
            base_velocity, acceleration = velocity, np.zeros(3)
        feet = feet0.copy()
        foot_velocity = np.zeros_like(feet)
        if slip is not None and t >= slip[2]:
            feet[slip[0]] += slip[1] * (t - slip[2])
            foot_velocity[slip[0]] = slip[1]
        for _ in range(8):
            pin.framesForwardKinematics(model, data, q)
            pin.computeJointJacobians(model, data, q)
            for leg, frame in enumerate(robot.foot_frame_ids):
                error = feet[leg] - data.oMf[frame].translation
                jacobian = pin.getFrameJacobian(model, data, frame, LWA)[:3, legs[leg]]
                q[legs[leg] + 1] += np.linalg.solve(jacobian, error)
        pin.computeJointJacobians(model, data, q)
        qd = np.zeros(robot.nu)
        for leg, frame in enumerate(robot.foot_frame_ids):
            jacobian = pin.getFrameJacobian(model, data, frame, LWA)[:3, legs[leg]]
            qd[legs[leg] - 6] = np.linalg.solve(jacobian, foot_velocity[leg] - base_velocity)
        reading = SensorReadings.zeros(robot.nu)
        reading.time = t
        reading.orientation[:] = q[3:7]
        reading.accelerometer[:] = rotation.inv().apply(acceleration + np.array([0.0, 0.0, 9.81]))
        reading.joint_positions[:] = q[7:]
        reading.joint_velocities[:] = qd
        reading.joint_torques[:] = np.nan  # no torque sensing: no foot-load compensation
        readings.append(reading)
    return readings


def run_estimator(robot, readings, settings=None, plan=None) -> tuple[np.ndarray, StateEstimator]:
    """World-frame base velocity estimate at every reading. The synthetic feet are points (the foot frame
    stays put while the shank turns), so the filter's rolling-sphere correction is off."""
    estimator = StateEstimator(
        robot, (settings or KinematicKFSettings()).model_copy(update={"rolling_foot": False})
    )
    estimator.reset((0.0, 0.0))
    velocities = np.zeros((len(readings), 3))
    for row, reading in enumerate(readings):
        measurement = estimator.update(reading, plan)
        velocities[row] = Rotation.from_quat(measurement.q[3:7]).apply(measurement.v[:3])
    return velocities, estimator


def test_the_filter_recovers_a_constant_velocity_from_synthetic_readings(robot):
    velocity = np.array([0.15, -0.05, 0.0])
    readings = synthetic_readings(robot, velocity, 0.5)  # from rest to 0.15 m/s in 0.2 s, then constant
    for settings in (KinematicKFSettings(), KinematicKFSettings.mit()):
        estimates, estimator = run_estimator(robot, readings, settings)
        assert np.linalg.norm(estimates[0]) < 1e-9  # starts from rest
        constant = estimates[round(0.25 / DT) :]
        assert np.max(np.linalg.norm(constant - velocity, axis=1)) < 0.005, (settings, constant[-1])
        # the base height from the stance feet, the position integrated
        assert estimator.x[2] == pytest.approx(robot.q_standing[2], abs=0.003)
        assert estimator.x[0] == pytest.approx(velocity[0] * (0.5 - 0.1), abs=0.005)
    # the legs alone (no acceleration read) bring a filter that starts wrong to the velocity
    stepped = synthetic_readings(robot, velocity, 0.5, ramp=1e-9)
    estimates, _ = run_estimator(robot, stepped, KinematicKFSettings.mit())
    assert np.max(np.linalg.norm(estimates[-50:] - velocity, axis=1)) < 0.01


def test_a_slipping_stance_foot_raises_the_error_and_the_slip_test_catches_it(robot):
    slide = np.array([0.5, 0.2, 0.0])  # the front-left foot slides from 0.2 s on, the base stands still
    readings = synthetic_readings(robot, np.zeros(3), 0.4, slip=(0, slide, 0.2))
    still = slice(round(0.15 / DT), round(0.2 / DT))
    sliding = slice(round(0.25 / DT), None)
    mit, _ = run_estimator(robot, readings, KinematicKFSettings.mit())
    before, during = np.linalg.norm(mit[still], axis=1), np.linalg.norm(mit[sliding], axis=1)
    assert np.max(before) < 0.005
    assert np.max(during) > 0.03  # without a slip test the sliding foot drags the estimate along
    tested, estimator = run_estimator(robot, readings, KinematicKFSettings())
    assert np.max(np.linalg.norm(tested[sliding], axis=1)) < 0.3 * np.max(during)
    assert estimator.slipping[0] and not np.any(estimator.slipping[1:])


def test_a_foot_in_swing_is_ignored_and_in_flight_the_imu_alone_counts(robot):
    readings = synthetic_readings(robot, np.array([0.1, 0.0, 0.0]), 0.3)
    garbage = []
    rng = np.random.default_rng(0)
    for reading in readings:  # the front-right leg (planned in swing) moves wildly
        changed = SensorReadings.zeros(robot.nu)
        changed.copy_from(reading)
        changed.joint_positions[3:6] += rng.normal(0.0, 0.5, 3)
        changed.joint_velocities[3:6] += rng.normal(0.0, 20.0, 3)
        garbage.append(changed)
    plan = steady_plan(robot.n_feet, swing=(1,))
    clean, _ = run_estimator(robot, readings, plan=plan)
    noisy, estimator = run_estimator(robot, garbage, plan=plan)
    assert np.max(np.abs(clean - noisy)) < 1e-9  # the swing leg changes nothing
    assert estimator.trust[1] == 0.0 and not estimator.in_contact[1]
    # flight: every foot in swing, the IMU reads free fall; the estimate falls with g whatever the legs do
    flight = steady_plan(robot.n_feet, swing=(0, 1, 2, 3))
    estimator = StateEstimator(robot)
    estimator.reset()
    estimator.update(readings[0])  # starts standing (no plan: all feet down)
    for reading in garbage[1:101]:
        falling = SensorReadings.zeros(robot.nu)
        falling.copy_from(reading)
        falling.accelerometer[:] = 0.0
        estimator.update(falling, flight)
    assert estimator.world_velocity[2] == pytest.approx(-9.81 * 100 * DT, rel=0.02)
    assert not np.any(estimator.in_contact)


def test_a_foot_held_at_its_touchdown_height_keeps_feet_on_two_levels_consistent(robot):
    """``stance_height: touchdown`` off flat ground: a foot that lands 6 cm higher than the others (on a
    step) is held where it landed, and the base height stays the truth; measured at z = 0 (``ground``) it
    pulls the base height off."""
    rise = 0.06
    readings = synthetic_readings(robot, np.zeros(3), 0.6, raised=(0, rise))
    times = np.arange(0.0, 1.0, 0.01)
    contacts = np.ones((len(times), robot.n_feet), dtype=bool)
    contacts[times < 0.1, 0] = False  # the raised foot touches down at 0.1 s
    plan = FakePlan(times, np.full(len(times), 0.01), contacts)
    truth = robot.q_standing[2]
    errors = {}
    for mode in ("ground", "touchdown"):
        settings = KinematicKFSettings(rolling_foot=False, stance_height=mode)
        estimator = StateEstimator(robot, settings, flat_ground=False)
        estimator.reset()
        heights = np.array([estimator.update(reading, plan).q[2] for reading in readings])
        errors[mode] = np.max(np.abs(heights[round(0.1 / DT) :] - truth))
        if mode == "touchdown":
            assert estimator.touchdown_level[0] == pytest.approx(rise, abs=0.002)
            assert np.all(estimator.touchdown_level[1:] == 0.0)
    assert errors["touchdown"] < 0.002, errors
    assert errors["ground"] > 0.01, errors
    # on flat ground the option is refused at the boundary (every stance foot is on z = 0)
    with pytest.raises(ConfigError, match=r"kinematic_kf\.stance_height"):
        load_run_config("trot", ["kinematic_kf.stance_height=touchdown"])
    config = load_run_config("trot", ["terrain=blind", "kinematic_kf.stance_height=touchdown"])
    assert config.kinematic_kf.stance_height == "touchdown"


@dataclass
class PlanOnTop(FakePlan):
    """A ``FakePlan`` that also has configurations (every knot the robot standing ``top`` above the floor)."""

    top: float = 0.0
    configuration: np.ndarray | None = None

    @property
    def start_time(self) -> float:
        return float(self.times[0])

    def knot_at(self, t: float) -> int:
        return int(np.clip(np.searchsorted(self.times, t, side="right") - 1, 0, len(self.times) - 1))

    def knot_configurations(self, nq: int) -> np.ndarray:
        return np.tile(self.configuration, (len(self.times) + 1, 1))[:, :nq]


def test_stance_feet_measured_where_the_plan_puts_them_keep_a_robot_on_a_box_top_at_its_height(robot):
    """``stance_height: plan``: a robot whose plan lands it on a 0.30 m box top (a short flight, then every
    foot's touchdown there; its legs read as standing on the floor) is estimated 0.30 m up, every foot in
    contact; with ``ground`` the filter puts the feet on z = 0 and the base 0.30 m low. A plan that lands
    on the floor leaves the estimate as ``ground``'s."""
    top = 0.30
    readings = synthetic_readings(robot, np.zeros(3), 0.6)
    steady = steady_plan(robot.n_feet, duration=1.0)
    steady.contacts[steady.times < 0.02] = False  # in the air until the touchdown at 0.02 s
    heights = {}
    for mode, plan_top in (("ground", top), ("plan", top), ("plan", 0.0)):
        q = robot.q_standing.copy()
        q[2] += plan_top
        plan = PlanOnTop(steady.times, steady.dt, steady.contacts, plan_top, q)
        estimator = StateEstimator(robot, KinematicKFSettings(rolling_foot=False, stance_height=mode))
        estimator.reset()
        for reading in readings:
            measurement = estimator.update(reading, plan)
        heights[mode, plan_top] = measurement.q[2]
        assert np.all(estimator.in_contact)
        if mode == "plan":
            assert estimator.planned_level == pytest.approx(np.full(robot.n_feet, plan_top), abs=1e-9)
    truth = robot.q_standing[2]
    assert heights["plan", top] == pytest.approx(truth + top, abs=0.005)
    assert heights["ground", top] == pytest.approx(truth, abs=0.005)
    assert heights["plan", 0.0] == heights["ground", top]
    assert load_run_config("box-jump-30").kinematic_kf.stance_height == "plan"


def ideal_spec(average: bool = False) -> SensorSpec:
    return SensorSpec(
        ImuSpec(gyro_noise=0.0, accelerometer_noise=0.0, orientation_noise=0.0, average=average),
        EncoderSpec(position_resolution=0.0, velocity_resolution=0.0, torque_resolution=0.0),
    )


def test_sensor_suite_reads_mujoco_sensors_with_noise_bias_quantisation_and_delay(robot):
    from cafe_mpc.low_level.pd import PDController

    plant = MujocoPlant(robot)
    plant.reset(robot.q_standing)
    ideal = SensorSuite(robot.nu, ideal_spec(), 500.0)
    assert np.linalg.norm(ideal.read(plant).accelerometer) < 1e-6  # placed, feet unloaded: free fall
    stand = PDController(robot)
    for k in range(150):  # settle standing
        plant.step(stand.compute(k * DT, plant.read_state(), None), 2)
    readings = ideal.read(plant)
    state = plant.read_state()
    assert np.allclose(readings.joint_positions, state.q[7:]) and np.allclose(readings.gyro, state.v[3:6])
    assert np.allclose(np.abs(readings.orientation), np.abs(state.q[3:7]))
    assert readings.accelerometer[2] == pytest.approx(9.81, abs=0.3)  # standing: gravity, upwards
    spec = SensorSpec(
        ImuSpec(
            gyro_noise=0.01,
            gyro_bias=(0.02, 0.0, 0.0),
            accelerometer_noise=0.05,
            accelerometer_bias=(0.0, 0.1, 0.0),
            orientation_noise=0.01,
            average=False,
        ),
        EncoderSpec(),  # the Mini Cheetah's CAN resolutions, no noise
        seed=4,
    )
    suite = SensorSuite(robot.nu, spec, 500.0)
    gyro_error, accelerometer_error = [], []
    for k in range(200):
        truth = ideal.read(plant)
        gyro, accelerometer = truth.gyro.copy(), truth.accelerometer.copy()
        reading = suite.read(plant)
        gyro_error.append(reading.gyro - gyro)
        accelerometer_error.append(reading.accelerometer - accelerometer)
        steps = reading.joint_positions / spec.encoders.position_resolution
        assert np.allclose(steps, np.round(steps))  # quantised
        assert np.max(np.abs(reading.joint_positions - truth.joint_positions)) <= 0.5 * 25.0 / 65535.0 + 1e-12
        plant.step(stand.compute(k * DT, plant.read_state(), None), 2)
    assert np.mean(gyro_error, axis=0) == pytest.approx([0.02, 0.0, 0.0], abs=0.003)  # bias, noise
    assert np.std(gyro_error, axis=0) == pytest.approx([0.01] * 3, rel=0.2)
    assert np.mean(accelerometer_error, axis=0) == pytest.approx([0.0, 0.1, 0.0], abs=0.015)
    delayed = SensorSuite(robot.nu, replace(spec, delay_max_ticks=3), 500.0)
    seen = []
    for _ in range(100):  # latency jitter: never older than 3 ticks, never going back
        now = plant.time
        seen.append((now, delayed.read(plant).time))
        plant.step(np.zeros(robot.nu), 2)
    ages = [now - read for now, read in seen]
    assert max(ages) <= 3 * DT + 1e-9 and max(ages) > 0.0
    assert np.all(np.diff([read for _, read in seen]) >= 0.0)
    plant.reset(robot.q_standing)  # a seed gives the same readings
    suite.reset()
    first = suite.read(plant).gyro.copy()
    assert np.array_equal(first, SensorSuite(robot.nu, spec, 500.0).read(plant).gyro)
    with pytest.raises(ValueError, match="rate_hz"):
        SensorSuite(robot.nu, replace(spec, imu=spec.imu.model_copy(update={"rate_hz": 1000.0})), 500.0)


def test_latency_jitter_hands_over_every_imu_sample_late_not_lost(robot):
    """An averaging IMU read with latency jitter: the readings after a late one carry the mean over every
    tick since the previous readings, so the specific force integrated over the delivered readings (what
    the estimator's velocity integrates) is the one without jitter. With only the last tick's sample, the
    skipped ticks' samples were lost: a flip's push left the estimate 0.1 m/s off (docs/tasks.md)."""
    from cafe_mpc.low_level.pd import PDController

    stand = PDController(robot)

    def integrated(delay_max_ticks: int) -> dict[float, np.ndarray]:
        """time of each delivered reading -> the accelerometer and gyro integrated up to it."""
        plant = MujocoPlant(robot)
        plant.reset(robot.q_standing)
        suite = SensorSuite(
            robot.nu, replace(ideal_spec(average=True), delay_max_ticks=delay_max_ticks), 500.0
        )
        total, last_time, out = np.zeros(6), None, {}
        for k in range(200):  # standing, the legs shaken: the trunk's acceleration changes every tick
            reading = suite.read(plant)
            if last_time is not None and reading.time > last_time:
                total += (reading.time - last_time) * np.concatenate([reading.accelerometer, reading.gyro])
            if last_time is None or reading.time > last_time:
                out[round(reading.time, 9)] = total.copy()
                last_time = reading.time
            torque = stand.compute(k * DT, plant.read_state(), None) + 4.0 * np.sin(
                40.0 * k * DT + np.arange(robot.nu)
            )
            plant.step(torque, 2)
        return out

    exact, jittered = integrated(0), integrated(2)
    common = sorted(set(exact) & set(jittered))
    assert len(common) < len(exact) - 20  # the jitter skipped ticks
    start = common[0]
    for time in common[1:]:
        assert np.allclose(jittered[time] - jittered[start], exact[time] - exact[start], atol=1e-9), time


def test_estimator_config_is_validated_at_the_boundary():
    with pytest.raises(ConfigError, match=r"plant\.sensor_noise perturbs the true state"):
        load_run_config("trot", ["estimator=kinematic_kf", "plant.sensor_noise.base_position=0.01"])
    with pytest.raises(ConfigError, match=r"kinematic_kf\.trust_window"):
        load_run_config("trot", ["kinematic_kf.trust_window=0.8"])
    with pytest.raises(ConfigError, match=r"plant\.sensors\.imu\.gyro_bias"):
        load_run_config("trot", ["plant.sensors.imu.gyro_bias=[2, 0, 0]"])
    with pytest.raises(ConfigError, match="estimator"):
        load_run_config("trot", ["estimator=magic"])
    with pytest.raises(
        ConfigError, match=r"plant\.sensors\.imu\.rate_hz: 1000.0 Hz is above the control rate"
    ):
        load_run_config("trot", ["plant.sensors.imu.rate_hz=1000"])
    config = load_run_config("trot", ["estimator=kinematic_kf", "kinematic_kf.slip_threshold=null"])
    assert config.kinematic_kf.slip_threshold is None


@pytest.mark.parametrize("robot_name", ["mini_cheetah", "pegasus"])
def test_orientation_from_the_imu_matches_the_truth_in_a_short_closed_loop(robot_name):
    """Pegasus's IMU is mounted turned 90 degrees in yaw (its model file's ``imu`` site): its readings reach
    the estimator turned into the base frame."""
    from cafe_mpc_lab.experiments.run import run_metrics, simulate_run

    config = load_run_config(
        "stand",
        [f"robot={robot_name}", "estimator=kinematic_kf", "simulation.duration=0.6", "output.plots=false"],
    )
    resolved, controller, log = simulate_run(config)
    assert not log.fell
    estimate = log.extra["estimate_q"]
    assert estimate.shape == log.q.shape
    angle = (Rotation.from_quat(estimate[:, 3:7]).inv() * Rotation.from_quat(log.q[:, 3:7])).magnitude()
    noise = config.plant.sensors.imu.orientation_noise
    assert np.sqrt(np.mean(angle**2)) < 3.0 * noise and np.max(angle) < 8.0 * noise
    # m, m/s: the 83 kg Pegasus settles 6 mm onto its feet in this stand
    height_tolerance, velocity_tolerance = {"mini_cheetah": (0.01, 0.02), "pegasus": (0.02, 0.04)}[robot_name]
    assert np.max(np.abs(estimate[:, 2] - log.q[:, 2])) < height_tolerance
    metrics = run_metrics(resolved, controller, log)
    block = metrics["estimator"]
    assert block["kind"] == "kinematic_kf" and block["orientation_rms_error_rad"] < 3.0 * noise
    assert block["velocity_rms_error_m_s"] < velocity_tolerance


def test_the_controller_gets_the_estimate_not_the_plant_state(robot):
    from cafe_mpc.estimation.controller import SensingController
    from cafe_mpc_lab.sim.loop import SimulationOptions, simulate

    seen = []

    class Spy:
        """A controller that records what it measured and holds the stance with PD."""

        def __init__(self) -> None:
            from cafe_mpc.low_level.pd import PDController

            self.pd = PDController(robot)

        def reset(self) -> None:
            self.pd.reset()

        def compute(self, t, measurement):
            seen.append(measurement)
            return self.pd.compute(t, measurement, None)

    spec = sensor_spec(load_run_config("stand", ["estimator=kinematic_kf"]).plant, 500.0)
    estimator = StateEstimator(robot)
    sensing = SensingController(Spy(), estimator, capacity=10)
    plant = MujocoPlant(robot, sensors=SensorSuite(robot.nu, spec, 500.0))
    log = simulate(plant, sensing, SimulationOptions(0.02))
    assert len(seen) == log.ticks == 10
    assert all(measurement is estimator.measurement for measurement in seen)
    assert sensing.trace()["estimate_q"].shape == (10, robot.nq)


@pytest.mark.slow
def test_a_closed_loop_trot_with_the_estimator_stays_up():
    from cafe_mpc_lab.experiments.run import run_metrics, simulate_run

    duration = 1.5
    config = load_run_config(
        "trot",
        [
            "estimator=kinematic_kf",
            f"simulation.duration={duration}",
            "output.plots=false",
            "mpc.latency=fixed",
        ],
    )
    resolved, controller, log = simulate_run(config)
    metrics = run_metrics(resolved, controller, log)
    assert not log.fell, log.fall_reason
    assert log.q[-1, 0] - log.q[0, 0] > 0.25 * 0.5 * duration
    assert metrics["estimator"]["velocity_rms_error_m_s"] < 0.05
    assert metrics["mpc"]["failures"] == 0
    assert np.all(np.isfinite(log.torque_command))


def test_the_library_controller_runs_from_a_users_sensor_readings():
    """``cafe_mpc.Controller.measurement_from_sensors`` in a hand-written MuJoCo loop that reads its own IMU
    and joint sensors (the user's clock starts at 100 s)."""
    import mujoco

    from cafe_mpc.api import Controller
    from cafe_mpc_lab.sim.sensors import with_sensors

    with Controller("trot", ["mpc.latency=fixed"]) as controller:
        robot = controller.robot
        model = mujoco.MjModel.from_xml_string(with_sensors(robot.mjcf, robot.joint_names))
        data = mujoco.MjData(model)
        data.qpos[:] = controller.standing_qpos()
        mujoco.mj_forward(model, data)

        def read(name: str) -> np.ndarray:
            sensor = model.sensor(name)
            return data.sensordata[sensor.adr[0] : sensor.adr[0] + sensor.dim[0]]

        def measurement(t: float):
            joints = [read(f"jointpos_{joint}")[0] for joint in robot.joint_names]
            rates = [read(f"jointvel_{joint}")[0] for joint in robot.joint_names]
            return controller.measurement_from_sensors(
                t,
                read("imu_orientation"),
                read("imu_gyro"),
                read("imu_accelerometer"),
                joints,
                rates,
                scalar_first=True,
            )

        first = measurement(100.0)
        assert first.q[2] == pytest.approx(robot.q_standing[2], abs=0.005) and np.allclose(first.v[:3], 0.0)
        controller.reset(first)
        substeps = round(controller.control_period / model.opt.timestep)
        for _ in range(round(1.0 / controller.control_period)):
            t = 100.0 + data.time
            torques = controller.compute(t, measurement(t))
            assert np.all(np.isfinite(torques))
            data.ctrl[:] = torques
            for _ in range(substeps):
                mujoco.mj_step(model, data)
            mujoco.mj_forward(model, data)
        assert data.qpos[2] > 0.2 and data.qpos[0] > 0.15  # up, and moving forward
        estimate = measurement(100.0 + data.time)
        assert estimate.q[0] == pytest.approx(data.qpos[0], abs=0.03)
        with pytest.raises(ValueError, match="gyro must have shape"):
            controller.measurement_from_sensors(101.0, [0, 0, 0, 1], [0, 0], [0, 0, 9.81], joints(), joints())
        # bad values are held at their last good value and counted, never passed on
        t = 100.0 + data.time + controller.control_period
        held = controller.measurement_from_sensors(
            t, [0, 0, 0, 0], [0, 0, 0], [0, np.nan, 9.81], joints(), joints()
        )
        assert np.all(np.isfinite(held.q)) and np.all(np.isfinite(held.v))
        assert controller.faults()["sensors"]["rejected"] == {"orientation": 1, "accelerometer": 1}


def joints() -> np.ndarray:
    return np.zeros(12)


def test_a_landing_foot_sinks_past_its_load_and_settles_at_the_compliance():
    from cafe_mpc.estimation.kernels import foot_sink_step

    settings = KinematicKFSettings()
    compliance, frequency = settings.foot_compliance, settings.foot_contact_frequency
    sink, rate, touching = np.zeros(2), np.zeros(2), np.zeros(2, dtype=np.bool_)
    load = np.array([80.0, 80.0])
    contact = np.array([True, False])
    start_sink, start_rate = np.array([0.001, 0.01]), np.array([2.5, 2.5])  # the bound's hind feet's landing

    def step():
        foot_sink_step(
            sink, rate, touching, load, contact, start_sink, start_rate, DT, compliance, frequency, 1.03
        )

    step()  # touchdown: where and how fast it hits the floor; a foot in the air stays at 0
    assert sink[0] == 0.001 and rate[0] == 2.5 and touching[0]
    assert sink[1] == 0.0 and rate[1] == 0.0 and not touching[1]
    path = []
    for _ in range(round(0.3 / DT)):
        step()
        path.append(sink[0])
    static = compliance * load[0]
    # the landing speed drives it well past its static sink (MuJoCo's plant: 20 mm at 100 N), then it
    # rises back while still loaded and settles at compliance x load
    assert max(path) > 2.0 * static
    assert int(np.argmax(path)) * DT == pytest.approx(1.0 / frequency, abs=0.006)
    assert path[-1] == pytest.approx(static, rel=0.01)
    contact[0] = False
    step()  # lift-off: out of contact
    assert sink[0] == 0.0 and rate[0] == 0.0 and not touching[0]


def test_the_foot_contact_defaults_are_the_plants_soft_contact(robot):
    """``foot_compliance``, ``foot_contact_frequency`` and ``foot_contact_damping`` are MuJoCo's contact
    dynamics ``r'' = -b r' - k d r - R f`` at the plant's ``solref``/``solimp`` and its feet's inverse
    weights (``R = (1 - d) / d * invweight``); if the plant's floor changes, so must they."""
    import mujoco

    model = MujocoPlant(robot).model
    settings = KinematicKFSettings()
    feet = [
        g
        for g in range(model.ngeom)
        if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_SPHERE and model.geom_size[g, 0] == robot.foot_radius
    ]
    assert len(feet) == robot.n_feet
    for g in feet:
        timeconst, ratio = model.geom_solref[g]
        d = model.geom_solimp[g, 1]  # beyond the transition width (1 mm): every loaded foot
        k, b = 1.0 / (d * d * timeconst * timeconst * ratio * ratio), 2.0 / (d * timeconst)
        invweight = model.body_invweight0[model.geom_bodyid[g], 0]
        frequency = np.sqrt(k * d)
        assert settings.foot_compliance == pytest.approx((1.0 - d) / d * invweight / (k * d), rel=0.01)
        assert settings.foot_contact_frequency == pytest.approx(frequency, rel=0.01)
        assert settings.foot_contact_damping == pytest.approx(b / (2.0 * frequency), rel=0.01)


@pytest.mark.slow
@pytest.mark.parametrize("dynamic", [True, False])
def test_the_bounds_height_estimate_follows_its_landing_feet(dynamic):
    """The bound's hind feet land at 2.5 m/s and sink 20 mm: with the sink's dynamics the height estimate is
    within 2 mm RMS of the truth (1.1 mm); the static compliance read it 6 mm high in hind stance and 3 mm
    low in front stance (3.7 mm RMS), and the bound rode 1 cm higher than with the true state."""
    from cafe_mpc_lab.experiments.run import run_metrics, simulate_run

    overrides = [
        "estimator=kinematic_kf",
        "simulation.duration=2.0",
        "output.plots=false",
        "mpc.latency=fixed",
        "mpc.fixed_latency=0.025",
    ]
    if not dynamic:
        overrides += ["kinematic_kf.foot_compliance=1.2e-4", "kinematic_kf.foot_contact_frequency=null"]
    config = load_run_config("bound", overrides)
    resolved, controller, log = simulate_run(config)
    metrics = run_metrics(resolved, controller, log)
    assert not log.fell, log.fall_reason
    error = metrics["estimator"]["steady_state"]["height_rms_error_m"]
    if dynamic:
        assert error < 0.002
    else:  # the static model, so that the test can fail
        assert error > 0.003


def test_a_late_sample_reaches_the_controller_brought_forward_to_its_tick(robot):
    """Readings of the base translating at 0.5 m/s, handed over 4 ms late: the controller gets the state of
    its tick (the late estimate carried at its measured velocity), stamped with the tick's time; readings on
    time are handed over untouched."""
    from cafe_mpc.estimation.controller import SensingController

    seen = []

    class Spy:
        def reset(self) -> None: ...

        def compute(self, t, measurement):
            seen.append((t, measurement.time, measurement.q.copy(), measurement.v.copy()))
            return np.zeros(robot.nu)

    readings = synthetic_readings(robot, np.array([0.5, 0.0, 0.0]), 0.5)
    sensing = SensingController(Spy(), StateEstimator(robot), capacity=len(readings))
    sensing.reset()
    delay = 0.004
    for reading in readings:
        sensing.compute(reading.time + delay if reading.time > 0.3 else reading.time, reading)
    on_time = [(t, stamp) for t, stamp, _, _ in seen[:100]]
    assert all(t == stamp for t, stamp in on_time) and sensing.late_ticks == len(readings) - 151
    t, stamp, q, _ = seen[-1]
    assert stamp == pytest.approx(t)
    estimate = StateEstimator(robot)
    estimate.reset((0.0, 0.0))
    for reading in readings:
        late = estimate.update(reading)
    world_velocity = Rotation.from_quat(late.q[3:7]).apply(late.v[:3])
    assert q[:3] == pytest.approx(late.q[:3] + world_velocity * delay, abs=1e-9)
    assert np.linalg.norm(q[:3] - late.q[:3]) > 1.5e-3  # 4 ms at about 0.5 m/s


def test_rotation_to_quaternion_matches_scipy_near_every_branch():
    rotations = Rotation.random(200, random_state=4)
    turns = Rotation.from_rotvec(np.pi * np.eye(3) * 0.999999)  # near 180 degrees about each axis
    for rotation in [*rotations, *turns]:
        expected = rotation.as_quat()  # x, y, z, w
        got = rotation_to_quaternion(rotation.as_matrix())
        assert min(np.abs(got - expected).max(), np.abs(got + expected).max()) < 1e-9


def test_a_turned_imus_readings_come_out_in_the_base_frame():
    mount = Rotation.from_euler("xyz", [0.3, -0.2, -np.pi / 2])  # base <- IMU
    base = Rotation.from_euler("xyz", [0.1, 0.05, 0.7])  # world <- base
    gyro, specific_force = np.array([0.3, -1.2, 0.5]), np.array([0.4, 0.1, 9.7])
    mounted = SensorReadings.zeros(12)
    mounted.orientation[:] = (base * mount).as_quat()
    mounted.gyro[:] = mount.inv().apply(gyro)
    mounted.accelerometer[:] = mount.inv().apply(specific_force)
    mounted.joint_positions[:] = np.arange(12)
    before = mounted.orientation.copy()
    out = ImuMounting(mount.as_matrix(), 12).to_base(mounted)
    assert (Rotation.from_quat(out.orientation).inv() * base).magnitude() < 1e-12
    np.testing.assert_allclose(out.gyro, gyro, atol=1e-12)
    np.testing.assert_allclose(out.accelerometer, specific_force, atol=1e-12)
    np.testing.assert_array_equal(out.joint_positions, np.arange(12))
    np.testing.assert_array_equal(mounted.orientation, before)  # the input is left as it is
    with pytest.raises(ValueError, match="rotation matrix"):
        ImuMounting(np.diag([1.0, 1.0, 2.0]), 12)
