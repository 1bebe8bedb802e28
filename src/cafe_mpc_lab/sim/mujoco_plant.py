"""Our MuJoCo plant (``plant.kind: mujoco``): the simulated robot that every controller is tested against.

The plant is built from ``Robot.mjcf`` (same kinematics and inertias as the planning model, plus rotor
armature, joint damping and friction, torque saturation, foot spheres and elliptic cones). It never
shares an object with a controller: it reads and writes plain arrays in the planning model's coordinates
(``sim.plant``). MuJoCo's free joint stores the quaternion as ``(w, x, y, z)`` and the linear velocity in the
world frame; the conversion happens here (``core.free_joint``).

The model carries the robot's sensors (``sim.sensors``): ``sim.sensors.SensorSuite`` reads them as a robot
would (IMU and encoders with noise, bias and quantisation). A ``PlantVariation`` (``sim.randomization``)
changes the plant's friction, masses and motor strengths after the model is loaded (domain randomisation),
and the scene (``sim.scene``) adds terrain and a bar; a height-map sensor (``sim.height_map``) measures the
ground around the robot. The ``Robot``, and so every controller, stays nominal (it plans on flat ground or
on the plane of its stance feet, ``terrain: blind``).
"""

from __future__ import annotations

from collections.abc import Callable

import mujoco
import numpy as np

from cafe_mpc.config import RunConfig
from cafe_mpc.config.run import HeightMapConfig
from cafe_mpc.core.free_joint import planning_state
from cafe_mpc.core.measurement import Measurement
from cafe_mpc.robots.robot import Robot
from cafe_mpc_lab.sim.bar import BAR_NAME, geom_label
from cafe_mpc_lab.sim.height_map import HeightMapSensor
from cafe_mpc_lab.sim.plant import Plant, PlantSensors, checked_timestep
from cafe_mpc_lab.sim.randomization import PlantVariation, apply_variation, plant_variation
from cafe_mpc_lab.sim.scene import Scene, scene_of
from cafe_mpc_lab.sim.sensors import with_sensors


class MujocoPlant(Plant):
    """MuJoCo simulation of a ``Robot`` from its robot file, varied by a ``PlantVariation``.

    ``timestep``: the physics step (None: the robot file's); ``scene``: terrain and bar (None: the flat
    floor); ``sensors``: what the controller reads (``sim.plant.PlantSensors``; the true state by default);
    ``height_map``: the height-map sensor's settings (None or not ``enabled``: no sensor), its noise drawn
    from ``seed``.
    """

    kind = "mujoco"

    def __init__(
        self,
        robot: Robot,
        timestep: float | None = None,
        variation: PlantVariation | None = None,
        scene: Scene | None = None,
        sensors: PlantSensors | None = None,
        height_map: HeightMapConfig | None = None,
        seed: int = 0,
    ) -> None:
        super().__init__(robot, sensors)
        self.scene = scene = scene if scene is not None else Scene()
        self.bar = scene.bar
        # the robot's sensors (sim.sensors: IMU and joint sensors) instrument the plant; they do not change
        # its dynamics
        self.model = mujoco.MjModel.from_xml_string(with_sensors(scene.mjcf(robot), robot.joint_names))
        if timestep is not None:
            self.model.opt.timestep = checked_timestep(timestep)
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
        self.bar_geom = self.model.geom(BAR_NAME).id if self.bar is not None else -1
        self.bar_contact_geoms: set[int] = set()
        """Every robot geom that touched the bar since ``reset``."""
        self.after_step: Callable[[mujoco.MjData], None] | None = None
        """Called after every physics step (``sim.sensors.SensorSuite`` averages the IMU over the steps)."""
        if height_map is not None and height_map.enabled:
            self.height_map = HeightMapSensor(self.model, self.data, height_map, self.base_body, seed)

    @classmethod
    def from_config(cls, config: RunConfig, robot: Robot, sensors: PlantSensors | None = None) -> MujocoPlant:
        """The plant of a run config: its ``simulation.plant_timestep``, ``plant`` variation, ``scene`` and
        height-map sensor (``plant.height_map``)."""
        return cls(
            robot,
            config.simulation.plant_timestep,
            plant_variation(config.plant),
            scene_of(config.scene),
            sensors,
            config.plant.height_map,
            config.plant.seed,
        )

    def _reset(self, q: np.ndarray, v: np.ndarray) -> None:
        mujoco.mj_resetData(self.model, self.data)
        quaternion_xyzw = q[3:7] / np.linalg.norm(q[3:7])
        self.data.qpos[:3] = q[:3]
        self.data.qpos[3:7] = [quaternion_xyzw[3], *quaternion_xyzw[:3]]
        self.data.qpos[7:] = q[7:]
        mujoco.mju_quat2Mat(self._rotation, self.data.qpos[3:7])
        self.data.qvel[:3] = self._rotation.reshape(3, 3) @ v[:3]
        self.data.qvel[3:] = v[3:]
        self.data.ctrl[:] = 0.0
        self.bar_contact_geoms.clear()
        mujoco.mj_forward(self.model, self.data)

    def step(self, torques: np.ndarray, n_steps: int = 1) -> None:
        """Hold ``torques`` (saturated by the actuators' ``ctrlrange``) for ``n_steps`` physics steps."""
        self.data.ctrl[:] = torques
        for _ in range(n_steps):
            mujoco.mj_step(self.model, self.data)
            if self.after_step is not None:
                self.after_step(self.data)
            self._check_warnings()
        self._check_finite()

    def applied_torques(self) -> np.ndarray:
        return self.applied(self.data.ctrl)

    def applied(self, torques: np.ndarray) -> np.ndarray:
        """Torques the motors apply for commanded ``torques``: saturated at the command limits
        (``ctrlrange``), times each motor's strength."""
        return self.motor_strength * np.clip(torques, -self.torque_limits, self.torque_limits)

    def close(self) -> None:
        """Nothing to release: the model and data are freed with the plant."""

    def bar_touched_by(self) -> list[str]:
        return [geom_label(self.model, geom) for geom in sorted(self.bar_contact_geoms)]

    def read_state(self) -> Measurement:
        """Also notes the trunk touching the floor or terrain (``trunk_touched_floor``) and the bar's
        contacts."""
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
