"""The base's attitude and rates without the IMU (``estimation.imu_outage``; docs/estimation.md "Without the
IMU"): in flight the angular momentum about the centre of mass is kept whatever the joints do; standing on
four feet the feet's plane levels a wrong attitude and the feet at rest stop a wrong rate; the outage starts
from the last good sample at its own time and replays the ticks since; while the IMU is in nothing changes.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
from scipy.spatial.transform import Rotation

from cafe_mpc.core.sensors import SensorReadings
from cafe_mpc.estimation.imu_outage import ImuOutageObserver

DT = 0.002


def _readings(robot, t: float, joint_velocities: np.ndarray | None = None) -> SensorReadings:
    readings = SensorReadings.zeros(robot.nu)
    readings.time = t
    readings.joint_positions[:] = robot.q_standing[7:]
    if joint_velocities is not None:
        readings.joint_velocities[:] = joint_velocities
    readings.joint_torques[:] = np.nan  # not measured: the feet's kinematics alone on the ground
    return readings


def test_in_flight_the_observer_keeps_the_angular_momentum_whatever_the_joints_do(robot):
    observer = ImuOutageObserver(robot)
    start = Rotation.from_euler("xyz", [0.05, -0.1, 0.3])
    gyro = np.array([0.3, 2.0, -0.4])
    observer.start(np.nan, start.as_quat(), gyro, np.zeros(3), 0.6)
    flight = np.zeros(robot.n_feet, dtype=bool)
    rng = np.random.default_rng(0)
    model, data = robot.model, robot.model.createData()
    momentum = None
    for tick in range(50):
        rates = rng.uniform(-5.0, 5.0, robot.nu)
        observer.step(_readings(robot, tick * DT, rates), flight, np.zeros(3), 0.6)
        q = observer.q.copy()
        v = np.concatenate([np.zeros(3), observer.angular_velocity, rates])
        angular = pin.computeCentroidalMap(model, data, q)[3:6] @ v
        if momentum is None:
            momentum = angular
        np.testing.assert_allclose(angular, momentum, atol=1e-9)
    assert not np.allclose(observer.angular_velocity, gyro)  # the legs' swings turned the base


def test_standing_on_four_feet_the_feet_level_a_wrong_attitude_and_stop_a_wrong_rate(robot):
    observer = ImuOutageObserver(robot)
    tilted = Rotation.from_euler("xyz", [0.04, 0.08, 0.5])  # the truth: level, heading 0.5 rad
    observer.start(np.nan, tilted.as_quat(), np.array([0.0, 0.5, 0.0]), np.zeros(3), robot.q_standing[2])
    stance = np.ones(robot.n_feet, dtype=bool)
    for tick in range(200):
        observer.step(_readings(robot, tick * DT), stance, np.zeros(3), robot.q_standing[2])
    roll, pitch, _ = Rotation.from_matrix(observer.rotation).as_euler("xyz")
    assert abs(roll) < 0.005 and abs(pitch) < 0.005, (roll, pitch)
    assert np.linalg.norm(observer.angular_velocity) < 0.01


def test_an_outage_starts_from_the_last_good_sample_and_replays_the_ticks_since(robot):
    """Noticed 10 ticks late, the outage starts at the sample's time: the same estimate as an observer that
    started at once."""
    flight = np.zeros(robot.n_feet, dtype=bool)
    rng = np.random.default_rng(1)
    rates = rng.uniform(-5.0, 5.0, (20, robot.nu))
    attitude, gyro = Rotation.from_euler("xyz", [0.0, 0.1, 0.0]).as_quat(), np.array([0.0, 1.5, 0.0])
    at_once, late = ImuOutageObserver(robot), ImuOutageObserver(robot)
    at_once.start(np.nan, attitude, gyro, np.zeros(3), 0.6)
    for tick in range(20):
        readings = _readings(robot, tick * DT, rates[tick])
        at_once.step(readings, flight, np.zeros(3), 0.6)
        if tick < 10:
            late.remember(readings, flight)
        else:
            if tick == 10:
                late.start(0.0, attitude, gyro, np.zeros(3), 0.6)
            late.step(readings, flight, np.zeros(3), 0.6)
    np.testing.assert_allclose(late.rotation, at_once.rotation, atol=1e-12)
    np.testing.assert_allclose(late.angular_velocity, at_once.angular_velocity, atol=1e-12)


def test_an_outage_noticed_late_in_flight_takes_back_the_held_push_off_the_filter_integrated(robot):
    """The driver repeats a push-off sample (20 m/s^2 up, level) for 10 ticks before the outage is noticed;
    the position filter integrated it in flight, where the model reads free fall: the start says how much
    velocity and height that put in (the bound fell when the height estimate drifted up 3 cm and every foot
    planned in stance looked above the ground)."""
    flight = np.zeros(robot.n_feet, dtype=bool)
    observer = ImuOutageObserver(robot)
    level = np.array([0.0, 0.0, 0.0, 1.0])
    for tick in range(11):
        readings = _readings(robot, tick * DT)
        readings.orientation[:] = level
        readings.accelerometer[:] = (0.0, 0.0, 20.0)
        observer.remember(readings, flight)
    observer.start(0.0, level, np.zeros(3), np.zeros(3), 0.6)
    elapsed = 10 * DT
    np.testing.assert_allclose(observer.velocity_change, [0.0, 0.0, -20.0 * elapsed], atol=1e-9)
    np.testing.assert_allclose(observer.position_change, [0.0, 0.0, -10.0 * elapsed**2], atol=1e-9)
    observer.start(np.nan, level, np.zeros(3), np.zeros(3), 0.6)  # noticed at once: nothing to take back
    assert not observer.velocity_change.any() and not observer.position_change.any()
