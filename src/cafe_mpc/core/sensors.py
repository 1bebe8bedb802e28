"""What a legged robot's own sensors give at a control tick: an IMU on the trunk and the joint encoders.

A real robot has no measurement of its base pose and velocity; it has

* an **IMU** on the trunk: a gyroscope (body angular velocity, base frame), an accelerometer (specific force
  ``R' (a - g)`` in the base frame: it reads ``+9.81`` upwards at rest) and, for an AHRS such as the Mini
  Cheetah's VectorNav, the orientation its own filter estimates;
* **joint encoders**: joint angles and rates (the motor controllers' estimates, quantised by the bus);
* **joint torques**: the motor controllers' current-based torque estimates.

The simulator (``cafe_mpc_lab.sim.sensors``) fills a ``SensorReadings`` from MuJoCo's sensors with noise, bias
and quantisation; a state estimator (``cafe_mpc.estimation``) turns readings into the ``Measurement`` the
controllers read. On a robot, fill one from the hardware drivers (``fill``: from plain arrays, as
``cafe_mpc.Controller.measurement_from_sensors`` does). Conventions are the planning model's: quaternion ``(x,
y, z, w)`` (base to world), joints in the robot's joint order. A reading may carry the time stamps of its
samples (``imu_time``, ``joint_times``: when the IMU and each encoder sampled; NaN: at the reading's
``time``), which tell a missing or late sample from a fresh one.

``SensorGuard`` is the check at the boundary, before the estimator: every tick it takes a reading apart,
sample by sample, and rejects what cannot be right (non-finite, outside the sensor's range or the joint's
limits, older than ``max_sample_age``), holding the last good value instead (a missing accelerometer sample
reads the robot at rest: gravity only), counting each rejection by kind, and timing how long each sensor
(the IMU, each joint's encoder) has been out (``outage``: longer than ``outage_limit``). Its limits are the
run config's ``recovery.sensors`` (``config.SensorLimits``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from cafe_mpc.config import SensorLimits
from cafe_mpc.core.height_map import HeightMap
from cafe_mpc.core.physics import GRAVITY


def rotation_to_quaternion(rotation: np.ndarray) -> np.ndarray:
    """The unit quaternion ``(x, y, z, w)`` of a rotation matrix (Shepperd's method: the largest of the four
    squares first, so no division by a small number)."""
    r = np.asarray(rotation, dtype=float)
    trace = r[0, 0] + r[1, 1] + r[2, 2]
    squares = (trace, r[0, 0], r[1, 1], r[2, 2])
    largest = int(np.argmax(squares))
    if largest == 0:
        w = 0.5 * math.sqrt(1.0 + trace)
        x, y, z = (r[2, 1] - r[1, 2]) / (4 * w), (r[0, 2] - r[2, 0]) / (4 * w), (r[1, 0] - r[0, 1]) / (4 * w)
    elif largest == 1:
        x = 0.5 * math.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2])
        w, y, z = (r[2, 1] - r[1, 2]) / (4 * x), (r[0, 1] + r[1, 0]) / (4 * x), (r[0, 2] + r[2, 0]) / (4 * x)
    elif largest == 2:
        y = 0.5 * math.sqrt(1.0 - r[0, 0] + r[1, 1] - r[2, 2])
        w, x, z = (r[0, 2] - r[2, 0]) / (4 * y), (r[0, 1] + r[1, 0]) / (4 * y), (r[1, 2] + r[2, 1]) / (4 * y)
    else:
        z = 0.5 * math.sqrt(1.0 - r[0, 0] - r[1, 1] + r[2, 2])
        w, x, y = (r[1, 0] - r[0, 1]) / (4 * z), (r[0, 2] + r[2, 0]) / (4 * z), (r[1, 2] + r[2, 1]) / (4 * z)
    quaternion = np.array([x, y, z, w])
    return quaternion / np.linalg.norm(quaternion)


@dataclass
class SensorReadings:
    """One tick of sensor readings (a producer may overwrite its arrays in place on its next read: copy what
    must outlive the tick). ``joint_torques`` may be all NaN when the robot has no torque estimate; the time
    stamps NaN when the samples are of ``time``."""

    time: float
    orientation: np.ndarray  # (4,) IMU orientation estimate, quaternion x, y, z, w (base -> world)
    gyro: np.ndarray  # (3,) angular velocity, base frame, rad/s
    accelerometer: np.ndarray  # (3,) specific force, base frame, m/s^2 (+g upwards at rest)
    joint_positions: np.ndarray  # (nj,) rad
    joint_velocities: np.ndarray  # (nj,) rad/s
    joint_torques: np.ndarray  # (nj,) Nm (NaN: not measured)
    imu_time: float = math.nan  # when the IMU sampled (NaN: at ``time``)
    joint_times: np.ndarray = field(default_factory=lambda: np.zeros(0))  # (nj,) when each encoder sampled
    height_map: HeightMap | None = None  # the map measured at this tick, relative to the base (or None)

    def __post_init__(self) -> None:
        if len(self.joint_times) != len(self.joint_positions):
            self.joint_times = np.full(len(self.joint_positions), np.nan)

    @classmethod
    def zeros(cls, n_joints: int) -> SensorReadings:
        orientation = np.zeros(4)
        orientation[3] = 1.0
        return cls(
            0.0,
            orientation,
            np.zeros(3),
            np.zeros(3),
            np.zeros(n_joints),
            np.zeros(n_joints),
            np.zeros(n_joints),
        )

    def copy_from(self, other: SensorReadings) -> None:
        """Overwrite this reading with ``other``'s values (no allocation)."""
        self.time = other.time
        np.copyto(self.orientation, other.orientation)
        np.copyto(self.gyro, other.gyro)
        np.copyto(self.accelerometer, other.accelerometer)
        np.copyto(self.joint_positions, other.joint_positions)
        np.copyto(self.joint_velocities, other.joint_velocities)
        np.copyto(self.joint_torques, other.joint_torques)
        self.imu_time = other.imu_time
        np.copyto(self.joint_times, other.joint_times)

    def fill(
        self,
        time: float,
        orientation: np.ndarray,
        gyro: np.ndarray,
        accelerometer: np.ndarray,
        joint_positions: np.ndarray,
        joint_velocities: np.ndarray,
        joint_torques: np.ndarray | None = None,
        scalar_first: bool = False,
        imu_time: float | None = None,
        joint_times: np.ndarray | None = None,
    ) -> None:
        """Overwrite this reading with plain arrays (sequences are taken too). ``orientation``: quaternion
        ``(x, y, z, w)``, or ``(w, x, y, z)`` with ``scalar_first``; ``joint_torques`` None: not measured
        (NaN); ``imu_time``, ``joint_times``: the samples' time stamps (None: the reading's time).
        ``ValueError`` naming the field for a value of the wrong shape or type; the values themselves are
        ``SensorGuard``'s (or ``validate``'s) to check."""
        try:
            self.time = float(time)
            quaternion = np.asarray(orientation, dtype=float)
            if quaternion.shape != (4,):
                raise ValueError(f"sensor reading orientation must have shape (4,), got {quaternion.shape}")
            if scalar_first:
                self.orientation[3] = quaternion[0]
                self.orientation[:3] = quaternion[1:]
            else:
                self.orientation[:] = quaternion
            values = {
                "gyro": gyro,
                "accelerometer": accelerometer,
                "joint_positions": joint_positions,
                "joint_velocities": joint_velocities,
            }
            if joint_torques is not None:
                values["joint_torques"] = joint_torques
            else:
                self.joint_torques[:] = np.nan
            if joint_times is not None:
                values["joint_times"] = joint_times
            else:
                self.joint_times[:] = np.nan
            for name, value in values.items():
                array = np.asarray(value, dtype=float)
                target = getattr(self, name)
                if array.shape != target.shape:
                    raise ValueError(
                        f"sensor reading {name} must have shape {target.shape}, got {array.shape}"
                    )
                target[:] = array
            self.imu_time = math.nan if imu_time is None else float(imu_time)
        except (TypeError, ValueError) as error:
            raise ValueError(str(error)) from error

    def validate(self, n_joints: int) -> None:
        """Raise ``ValueError`` naming the field when a reading has the wrong shape or is not finite
        (``joint_torques`` may be NaN: not measured). The strict check of one reading by itself; a loop's
        readings go through ``SensorGuard``, which holds the last good value instead."""
        shapes = {
            "orientation": (4,),
            "gyro": (3,),
            "accelerometer": (3,),
            "joint_positions": (n_joints,),
            "joint_velocities": (n_joints,),
            "joint_torques": (n_joints,),
        }
        for name, shape in shapes.items():
            value = getattr(self, name)
            if np.shape(value) != shape:
                raise ValueError(f"sensor reading {name} must have shape {shape}, got {np.shape(value)}")
            if name != "joint_torques" and not np.all(np.isfinite(value)):
                raise ValueError(f"sensor reading {name} contains NaN or inf: {value}")
        if np.any(np.isinf(self.joint_torques)):
            raise ValueError("sensor reading joint_torques contains inf (NaN means: not measured)")
        norm = float(np.linalg.norm(self.orientation))
        if not 0.5 < norm < 1.5:
            raise ValueError(f"sensor reading orientation is not a unit quaternion (norm {norm:.3g})")
        if not np.isfinite(self.time):
            raise ValueError(f"sensor reading time must be finite, got {self.time}")


IMU = "imu"
"""The IMU's name in ``SensorGuard``'s records (the encoders are named by their joints)."""


class ImuMounting:
    """An IMU mounted turned against the trunk, its readings expressed in the base frame (what every
    estimator assumes): ``rotation`` is base <- IMU (the robot description's ``imu`` frame,
    ``Robot.imu_rotation``). The gyro and accelerometer are turned by it and the orientation composed with
    its inverse (``q_world_base = q_world_imu q_imu_base``). The IMU's offset from the base origin is not
    compensated (the accelerometer's lever-arm terms: a few centimetres on the robots shipped). Writes into
    its own reading (no allocation); the input is left as it is."""

    def __init__(self, rotation: np.ndarray, n_joints: int) -> None:
        rotation = np.asarray(rotation, dtype=float)
        if rotation.shape != (3, 3) or not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-6):
            raise ValueError(f"an IMU mounting must be a 3 x 3 rotation matrix, got {rotation.tolist()}")
        self.rotation = rotation
        self._imu_from_base = rotation_to_quaternion(rotation.T)
        self.readings = SensorReadings.zeros(n_joints)

    @staticmethod
    def needed(rotation: np.ndarray) -> bool:
        """Whether an IMU turned by ``rotation`` needs the transform (not the identity)."""
        return not np.allclose(rotation, np.eye(3), atol=1e-9)

    def to_base(self, readings: SensorReadings) -> SensorReadings:
        """``readings`` with the IMU's values in the base frame (this object's reading, overwritten)."""
        out = self.readings
        out.copy_from(readings)
        np.dot(self.rotation, readings.gyro, out=out.gyro)
        np.dot(self.rotation, readings.accelerometer, out=out.accelerometer)
        x1, y1, z1, w1 = readings.orientation
        x2, y2, z2, w2 = self._imu_from_base
        orientation = out.orientation
        orientation[0] = w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2
        orientation[1] = w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2
        orientation[2] = w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2
        orientation[3] = w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2
        return out


class SensorGuard:
    """The check of every reading at the boundary (module docstring).

    ``check(readings)`` returns the guard's own reading (overwritten on the next call): the good samples of
    ``readings`` and the last good value of every rejected one. ``counts``: rejected samples by kind
    (``gyro``, ``accelerometer``, ``orientation``, ``imu_late``, ``joint_position``, ``joint_velocity``,
    ``encoder_late``, ``joint_torque``, ``time``); ``outages``: each time a sensor was out (``sensor``,
    ``start``, ``end``: the first good sample again, None while out). The very first reading has nothing to
    hold: a bad sample in it raises ``ValueError`` naming the field.
    """

    def __init__(
        self,
        limits: SensorLimits,
        position_lower: np.ndarray,
        position_upper: np.ndarray,
        velocity_limits: np.ndarray,
        joint_names: Sequence[str] | None = None,
    ) -> None:
        n_joints = len(position_lower)
        self.limits = limits
        self.lower = np.asarray(position_lower, dtype=float) - limits.joint_position_margin
        self.upper = np.asarray(position_upper, dtype=float) + limits.joint_position_margin
        self.velocity_max = limits.joint_velocity_factor * np.asarray(velocity_limits, dtype=float)
        self.joint_names = tuple(joint_names) if joint_names is not None else tuple(map(str, range(n_joints)))
        self.good = SensorReadings.zeros(n_joints)
        self._position_ok = np.zeros(n_joints, dtype=bool)
        self._velocity_ok = np.zeros(n_joints, dtype=bool)
        self._joint_late = np.zeros(n_joints, dtype=bool)
        self._joint_out = np.zeros(n_joints, dtype=bool)
        self._out_since = np.full(n_joints + 1, np.nan)  # the IMU, then each joint
        self.reset()

    def reset(self) -> None:
        """Forget the last good values and the records (a new run)."""
        self.started = False
        self.imu_out = False
        """Whether the last reading's IMU sample was held (late, or a value rejected)."""
        self.imu_sample_time = math.nan
        """When the last good IMU sample was taken (its time stamp, else the reading's time)."""
        self.counts: dict[str, int] = {}
        self.outages: list[dict] = []
        self._out_since[:] = np.nan
        self._open: dict[int, dict] = {}

    def _count(self, kind: str, number: int = 1) -> None:
        if number:
            self.counts[kind] = self.counts.get(kind, 0) + number

    def check(self, readings: SensorReadings) -> SensorReadings:
        """The reading with every bad sample replaced by its last good value (class docstring)."""
        good, limits = self.good, self.limits
        t = readings.time
        if not self.started:
            readings.validate(len(good.joint_positions))
            good.copy_from(readings)
            self.started = True
            self.imu_out = False
            self.imu_sample_time = t if math.isnan(readings.imu_time) else float(readings.imu_time)
            return good
        if not (math.isfinite(t) and t >= good.time):
            self._count("time")
            return good  # a reading out of time order: all of it held
        good.time = t
        imu_late = t - readings.imu_time > limits.max_sample_age  # NaN stamp: not late
        imu_out = imu_late
        if imu_late:
            self._count("imu_late")
        else:
            orientation = readings.orientation
            norm = math.sqrt(float(np.dot(orientation, orientation)))
            if abs(norm - 1.0) < 0.1:  # NaN fails too
                np.copyto(good.orientation, orientation)
            else:
                self._count("orientation")
                imu_out = True
            if np.all(np.abs(readings.gyro) <= limits.gyro_max):
                np.copyto(good.gyro, readings.gyro)
            else:
                self._count("gyro")
                imu_out = True
        if not imu_late and np.all(np.abs(readings.accelerometer) <= limits.accelerometer_max):
            np.copyto(good.accelerometer, readings.accelerometer)
        else:
            if not imu_late:
                self._count("accelerometer")
                imu_out = True
            self._at_rest(good.orientation, good.accelerometer)
        self._track(0, imu_out, t)
        self.imu_out = imu_out
        if not imu_out:
            self.imu_sample_time = t if math.isnan(readings.imu_time) else float(readings.imu_time)
        self._check_joints(readings, t)
        torques = readings.joint_torques
        if np.all(np.isfinite(torques)) or np.all(np.isnan(torques)):
            np.copyto(good.joint_torques, torques)
        else:
            self._count("joint_torque")
            good.joint_torques[:] = np.nan  # a torque reading with a bad value: not measured this tick
        return good

    def _check_joints(self, readings: SensorReadings, t: float) -> None:
        good = self.good
        position_ok, velocity_ok, late, out = (
            self._position_ok,
            self._velocity_ok,
            self._joint_late,
            self._joint_out,
        )
        np.greater(t - readings.joint_times, self.limits.max_sample_age, out=late)
        np.logical_and(
            readings.joint_positions >= self.lower, readings.joint_positions <= self.upper, out=position_ok
        )
        np.less_equal(np.abs(readings.joint_velocities), self.velocity_max, out=velocity_ok)
        if late.any() or not (position_ok.all() and velocity_ok.all()):
            self._count("encoder_late", int(late.sum()))
            position_ok &= ~late
            velocity_ok &= ~late
            self._count("joint_position", int((~position_ok & ~late).sum()))
            self._count("joint_velocity", int((~velocity_ok & ~late).sum()))
            np.copyto(good.joint_positions, readings.joint_positions, where=position_ok)
            np.copyto(good.joint_velocities, readings.joint_velocities, where=velocity_ok)
            np.logical_not(position_ok & velocity_ok, out=out)
        else:
            np.copyto(good.joint_positions, readings.joint_positions)
            np.copyto(good.joint_velocities, readings.joint_velocities)
            out[:] = False
        if out.any() or self._open:
            for joint in range(len(out)):
                self._track(joint + 1, bool(out[joint]), t)

    @staticmethod
    def _at_rest(orientation: np.ndarray, out: np.ndarray) -> None:
        """The specific force of the robot at rest in the base frame, ``R' (0, 0, g)`` (the third row of
        ``R`` for the quaternion x, y, z, w), into ``out``."""
        x, y, z, w = orientation
        out[0] = GRAVITY * 2.0 * (x * z - w * y)
        out[1] = GRAVITY * 2.0 * (y * z + w * x)
        out[2] = GRAVITY * (1.0 - 2.0 * (x * x + y * y))

    def _track(self, index: int, out: bool, t: float) -> None:
        """Open or close the outage record of sensor ``index`` (0: the IMU, ``j + 1``: joint ``j``)."""
        since = self._out_since[index]
        if out and math.isnan(since):
            self._out_since[index] = t
            record = {"sensor": self._name(index), "start": round(float(t), 6), "end": None}
            self._open[index] = record
            self.outages.append(record)
        elif not out and not math.isnan(since):
            self._out_since[index] = np.nan
            self._open.pop(index)["end"] = round(float(t), 6)

    def _name(self, index: int) -> str:
        return IMU if index == 0 else f"encoder {self.joint_names[index - 1]}"

    def imu_out_for(self, t: float) -> float:
        """How long the IMU has been out at ``t`` (0 while it is in)."""
        since = float(self._out_since[0])
        return 0.0 if math.isnan(since) else t - since

    def outage(self, t: float, imu_limit: float | None = None) -> str | None:
        """The sensor out for longest of those out for longer than ``outage_limit`` at ``t`` (the IMU:
        ``imu_limit``, default ``outage_limit``), what and since when; else None."""
        if not self._open:
            return None
        limit = self.limits.outage_limit
        longest = None
        for index in self._open:
            since = float(self._out_since[index])
            allowed = imu_limit if index == 0 and imu_limit is not None else limit
            if t - since > allowed and (longest is None or since < self._out_since[longest]):
                longest = index
        if longest is None:
            return None
        return f"{self._name(longest)} out since t = {float(self._out_since[longest]):.3f} s"

    def encoders_out(self, t: float) -> bool:
        """Whether any encoder has been out for longer than ``outage_limit`` at ``t``."""
        limit = self.limits.outage_limit
        return any(index > 0 and t - float(self._out_since[index]) > limit for index in self._open)

    def summary(self) -> dict:
        """Rejected samples by kind and every outage (``metrics.json``'s ``faults.sensors``)."""
        return {"rejected": dict(self.counts), "outages": [dict(record) for record in self.outages]}
