"""The MuJoCo plant: the simulated robot that every controller is tested against.

The plant is built from ``Robot.mjcf`` (same kinematics and inertias as the planning model, plus rotor
armature, joint damping and friction, torque saturation, foot spheres and elliptic cones). It never
shares an object with a controller: it reads and writes plain arrays in the planning model's
coordinates (Pinocchio's free-flyer convention):

* ``q = [base position, base quaternion (x, y, z, w), joint angles]``
* ``v = [base linear velocity (base frame), base angular velocity (base frame), joint rates]``

MuJoCo's free joint stores the quaternion as ``(w, x, y, z)`` and the linear velocity in the world frame;
the conversion happens here and only here.

The scene carries the robot's sensors (``sim.sensors``): ``sim.sensors.SensorSuite`` reads them as a robot
would (IMU and encoders with noise, bias and quantisation). A ``PlantVariation`` (``sim.randomization``)
changes the plant's friction, masses and motor strengths after the model is loaded (domain randomisation), and
terrain (``sim.terrain``) adds slopes and steps to the scene; the ``Robot``, and so every controller, stays
nominal (it plans on flat ground).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import mujoco
import numpy as np

from cafe_mpc.core.free_joint import planning_state
from cafe_mpc.core.measurement import Measurement
from cafe_mpc.robots.robot import Robot
from cafe_mpc_lab.sim.bar import BAR_NAME, Bar, with_bar
from cafe_mpc_lab.sim.randomization import PlantVariation, apply_variation
from cafe_mpc_lab.sim.sensors import with_sensors
from cafe_mpc_lab.sim.terrain import Terrain, with_terrain

_DIVERGENCE_WARNINGS = (
    mujoco.mjtWarning.mjWARN_BADQPOS,
    mujoco.mjtWarning.mjWARN_BADQVEL,
    mujoco.mjtWarning.mjWARN_BADQACC,
)


def scene_mjcf(robot: Robot, terrain: Sequence[Terrain] = (), bar: Bar | None = None) -> str:
    """The plant's MJCF: the robot's, with the scene's terrain (``sim.terrain``) on the floor and the bar
    (``sim.bar``), if any."""
    return with_bar(with_terrain(robot.mjcf, terrain, robot.plant.floor_friction), bar)


class SimulationDiverged(RuntimeError):
    """The simulator produced a non-finite state."""


class MujocoPlant:
    """MuJoCo simulation of a ``Robot`` with torque inputs and planning-coordinate read-out."""

    def __init__(
        self,
        robot: Robot,
        timestep: float | None = None,
        variation: PlantVariation | None = None,
        terrain: Sequence[Terrain] = (),
        bar: Bar | None = None,
    ) -> None:
        self.robot = robot
        self.terrain = tuple(terrain)
        self.bar = bar
        # the robot's sensors (sim.sensors: IMU and joint sensors) instrument the plant; they do not change
        # its dynamics
        self.model = mujoco.MjModel.from_xml_string(
            with_sensors(scene_mjcf(robot, self.terrain, bar), robot.joint_names)
        )
        if timestep is not None:
            if not timestep > 0:
                raise ValueError(f"plant timestep must be positive, got {timestep}")
            self.model.opt.timestep = timestep
        self.variation = variation or PlantVariation()
        self.motor_strength = np.ones(robot.nu)
        """Torque the motor applies per unit commanded (the actuator gear; 1 unless varied)."""
        if variation is not None:
            variation.check(robot)
            if not variation.is_nominal:
                self.motor_strength = apply_variation(self.model, robot, variation)
        self.data = mujoco.MjData(self.model)
        names = [self.model.joint(i).name for i in range(1, self.model.njnt)]
        if tuple(names) != robot.joint_names:
            raise ValueError(f"plant joint order {names} differs from the robot's {robot.joint_names}")
        self.base_body = self.model.body("base").id
        self.floor_geom = self.model.geom("floor").id
        # the trunk: the robot's collision geoms on the base body (a generated plant's box "trunk"; a model
        # file's own trunk geoms)
        self.trunk_geoms = frozenset(
            g
            for g in range(self.model.ngeom)
            if self.model.geom_bodyid[g] == self.base_body
            and (self.model.geom_contype[g] or self.model.geom_conaffinity[g])
        )
        self._world_geom = self.model.geom_bodyid == 0
        self.foot_geoms = np.array([self.model.geom(name).id for name in robot.foot_frame_names])
        self._foot_index = {int(g): i for i, g in enumerate(self.foot_geoms)}
        self.torque_limits = np.array(robot.plant.motor_torque_limits)
        self._state = Measurement.zeros(robot.nq, robot.nv, robot.n_feet)
        self._rotation = np.zeros(9)
        self._contact_wrench = np.zeros(6)
        self._contact_frame = np.zeros((3, 3))
        self.trunk_touched_floor = False
        self.bar_geom = self.model.geom(BAR_NAME).id if bar is not None else -1
        self.bar_in_contact = False
        """A robot geom touched the bar at the last ``read_state`` (``sim.bar``)."""
        self.bar_contact_geoms: set[int] = set()
        """Every robot geom that touched the bar since ``reset``."""
        self.after_step: Callable[[mujoco.MjData], None] | None = None
        """Called after every physics step (``sim.sensors.SensorSuite`` averages the IMU over the steps)."""

    @property
    def timestep(self) -> float:
        return float(self.model.opt.timestep)

    @property
    def time(self) -> float:
        return float(self.data.time)

    def reset(self, q: np.ndarray, v: np.ndarray | None = None) -> None:
        """Set the plant to ``(q, v)`` given in planning coordinates."""
        q = np.asarray(q, dtype=float)
        v = np.zeros(self.robot.nv) if v is None else np.asarray(v, dtype=float)
        if q.shape != (self.robot.nq,) or v.shape != (self.robot.nv,):
            raise ValueError(f"reset expects q ({self.robot.nq},) and v ({self.robot.nv},)")
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(v))):
            raise ValueError("reset state contains NaN or inf")
        mujoco.mj_resetData(self.model, self.data)
        quaternion_xyzw = q[3:7] / np.linalg.norm(q[3:7])
        self.data.qpos[:3] = q[:3]
        self.data.qpos[3:7] = [quaternion_xyzw[3], *quaternion_xyzw[:3]]
        self.data.qpos[7:] = q[7:]
        mujoco.mju_quat2Mat(self._rotation, self.data.qpos[3:7])
        self.data.qvel[:3] = self._rotation.reshape(3, 3) @ v[:3]
        self.data.qvel[3:] = v[3:]
        self.data.ctrl[:] = 0.0
        self.trunk_touched_floor = False
        self.bar_in_contact = False
        self.bar_contact_geoms.clear()
        mujoco.mj_forward(self.model, self.data)

    def set_external_force(self, force_world: np.ndarray) -> None:
        """Apply a world-frame force (N) at the base's centre of mass until changed."""
        self.data.xfrc_applied[self.base_body, :3] = force_world

    def step(self, torques: np.ndarray, n_steps: int = 1) -> None:
        """Hold ``torques`` (saturated by the actuators' ``ctrlrange``) for ``n_steps`` physics steps."""
        self.data.ctrl[:] = torques
        for _ in range(n_steps):
            mujoco.mj_step(self.model, self.data)
            if self.after_step is not None:
                self.after_step(self.data)
            # MuJoCo resets itself (and only warns) when the state blows up; turn that into an error.
            for warning in _DIVERGENCE_WARNINGS:
                if self.data.warning[warning].number > 0:
                    raise SimulationDiverged(
                        f"MuJoCo state became non-finite or huge ({warning.name}) "
                        f"at t = {self.data.time:.4f} s"
                    )
        if not (np.all(np.isfinite(self.data.qpos)) and np.all(np.isfinite(self.data.qvel))):
            raise SimulationDiverged(f"MuJoCo state became non-finite at t = {self.data.time:.4f} s")

    def applied_torques(self) -> np.ndarray:
        """Torques the motors actually apply (after saturation)."""
        return self.applied(self.data.ctrl)

    def applied(self, torques: np.ndarray) -> np.ndarray:
        """Torques the motors apply for commanded ``torques``: saturated at the command limits
        (``ctrlrange``), times each motor's strength."""
        return self.motor_strength * np.clip(torques, -self.torque_limits, self.torque_limits)

    def read_state(self) -> Measurement:
        """Current state in planning coordinates, feet contacts and ground reaction forces (the arrays are
        the plant's, overwritten on the next read)."""
        state = self._state
        state.time = float(self.data.time)
        mujoco.mju_quat2Mat(self._rotation, self.data.qpos[3:7])
        planning_state(self.data.qpos, self.data.qvel, state.q, state.v, self._rotation)
        state.contacts[:] = False
        state.foot_forces[:] = 0.0
        self.bar_in_contact = False
        for i in range(self.data.ncon):
            contact = self.data.contact[i]
            geom1, geom2 = int(contact.geom1), int(contact.geom2)
            if self.bar_geom in (geom1, geom2):  # the bar is neither floor nor foothold
                self.bar_in_contact = True
                self.bar_contact_geoms.add(geom2 if geom1 == self.bar_geom else geom1)
                continue
            if (geom1 in self.trunk_geoms and self._world_geom[geom2]) or (
                geom2 in self.trunk_geoms and self._world_geom[geom1]
            ):  # the trunk on the floor or terrain (a model file's legs may also touch it)
                self.trunk_touched_floor = True
            foot = self._foot_index.get(geom1, self._foot_index.get(geom2, -1))
            if foot < 0:
                continue
            mujoco.mj_contactForce(self.model, self.data, i, self._contact_wrench)
            self._contact_frame[:] = contact.frame.reshape(3, 3)
            force_world = self._contact_frame.T @ self._contact_wrench[:3]
            # mj_contactForce gives the force of geom1 on geom2 along the normal (geom1 -> geom2).
            if geom1 == self.foot_geoms[foot]:
                force_world = -force_world
            state.foot_forces[foot] += force_world
            state.contacts[foot] = True
        return state
