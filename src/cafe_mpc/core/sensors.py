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
y, z, w)`` (base to world), joints in the robot's joint order.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class SensorReadings:
    """One tick of sensor readings (a producer may overwrite its arrays in place on its next read: copy what
    must outlive the tick). ``joint_torques`` may be all NaN when the robot has no torque estimate."""

    time: float
    orientation: np.ndarray  # (4,) IMU orientation estimate, quaternion x, y, z, w (base -> world)
    gyro: np.ndarray  # (3,) angular velocity, base frame, rad/s
    accelerometer: np.ndarray  # (3,) specific force, base frame, m/s^2 (+g upwards at rest)
    joint_positions: np.ndarray  # (nj,) rad
    joint_velocities: np.ndarray  # (nj,) rad/s
    joint_torques: np.ndarray  # (nj,) Nm (NaN: not measured)

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
    ) -> None:
        """Overwrite this reading with plain arrays (sequences are taken too), then ``validate`` it.
        ``orientation``: quaternion ``(x, y, z, w)``, or ``(w, x, y, z)`` with ``scalar_first``;
        ``joint_torques`` None: not measured (NaN). ``ValueError`` naming the field for a value that does
        not fit."""
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
            for name, value in values.items():
                array = np.asarray(value, dtype=float)
                target = getattr(self, name)
                if array.shape != target.shape:
                    raise ValueError(
                        f"sensor reading {name} must have shape {target.shape}, got {array.shape}"
                    )
                target[:] = array
        except (TypeError, ValueError) as error:
            raise ValueError(str(error)) from error
        self.validate(len(self.joint_positions))

    def validate(self, n_joints: int) -> None:
        """Raise ``ValueError`` naming the field when a reading has the wrong shape or is not finite
        (``joint_torques`` may be NaN: not measured). Not on the 500 Hz path of the simulation; the library
        entry point (``Controller.measurement_from_sensors``) calls it on every user reading."""
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
