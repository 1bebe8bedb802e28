"""gym-quadruped's ``QuadrupedEnv`` as the plant (``plant.kind: gym-quadruped``): an external test bed.

The environment simulates the robot with its *own* model file and contact settings (gym-quadruped 1.1.8,
the environment Quadruped-PyMPC uses; ``pip install 'cafe-mpc[gym]'``); nothing of its physics is changed.
One ``env.step(torques)`` is one ``mj_step``; the run's control tick holds the torques for
``control period / plant time step`` steps. The robot file names the environment's robot
(``gym_quadruped.robot``) and the controller's model is Pinocchio's reading of the same model file.

What is mapped (``GymQuadrupedPlant``), and the environment's traps avoided:

* state: the environment's ``qpos``/``qvel`` (MuJoCo's free joint: quaternion ``w, x, y, z``, world-frame
  linear velocity) -> planning coordinates (``core.free_joint.planning_state``), minus the **joint offsets**:
  gym-quadruped sets ``qpos0`` of the Mini Cheetah's thighs to -pi/2 (front) and +pi/2 (hind) after
  loading, and MuJoCo's kinematics use ``qpos - qpos0``, so its joint angles are the model file's plus that
  offset (``JointOffsets``, read from the environment: nothing is hard-coded);
* contacts and ground reaction forces: the environment's ``feet_contact_state`` (world frame, force on the
  foot), feet matched by the model file's foot geom names; the trunk touching the ground: the environment's
  termination (any non-leg body on the ground);
* torques: planning joint order -> the environment's actuator order (``actuator_trnid``), divided by the gear;
  ``applied`` saturates like its actuators (``ctrlrange``, ``forcerange``, the joints' ``actuatorfrcrange``:
  23.7 Nm on every Go1 joint);
* reset: ``env.reset(qpos, qvel)`` with the standing state (never ``random=True``, which puts the robot at a
  random place of a kilometre-wide terrain), then the state is set again at time 0 (the environment's reset
  takes one physics step);
* creating an environment writes ``<robot>-<scene>.xml`` into gym-quadruped's package folder and reads it
  back: parallel workers on one robot would read each other's half-written files, so construction holds an
  exclusive file lock (``fcntl``) in the temporary folder;
* the robot's sensors (for a state estimator, ``estimator: kinematic_kf``, the default): the environment's
  model carries none of ours, so ``sim.sensors.StateSensors`` computes them from its state (IMU from the
  trunk's rate and acceleration, encoders from the joints with the offsets removed, torques from the applied
  command); ``after_step`` lets the IMU average over the physics steps as in our plant.

Not supported here (the run config says so before anything runs): terrain, the bar and plant variations other
than the floor friction (the environment's model is not ours to change). The floor friction is passed as
``ground_friction_coeff``, and the environment's reset writes it (torsional 0.005, rolling 0) into the floor
*and the four foot geoms*: contact friction inside the environment is that coefficient for every robot, while
our plant keeps the model file's foot friction (MuJoCo uses the larger of floor and foot friction, or the
foot's where its geom has priority: 0.8 for Go1 and Spot, 1.3 for A2). Where the two agree (Go2, B2, the Mini
Cheetah: foot friction <= 0.6, no priority) our plant built from the model file and the environment simulate
the same trajectories (Go2: identical; Mini Cheetah: within 1e-9 m over 10 s).
"""

from __future__ import annotations

import contextlib
import fcntl
import io
import os
import tempfile
import warnings
from collections.abc import Callable
from dataclasses import dataclass

import mujoco
import numpy as np

from cafe_mpc.config import RunConfig
from cafe_mpc.core.free_joint import planning_state
from cafe_mpc.core.measurement import Measurement
from cafe_mpc.robots.robot import Robot
from cafe_mpc_lab.sim.plant import Plant, PlantSensors, checked_timestep

GYM_SCENES = ("flat", "perlin", "random_boxes", "random_pyramids", "stairs", "ramp", "slippery")
"""gym-quadruped's scene names (``QuadrupedEnv(scene=...)``)."""
MASS_TOLERANCE = 1e-6
"""Relative difference of total mass above which the environment's robot is not the robot file's model."""


class GymQuadrupedUnavailable(RuntimeError):
    """gym-quadruped is not installed, or cannot simulate this robot."""


@dataclass(frozen=True)
class JointOffsets:
    """Environment joint angle = planning (model file) joint angle + ``offsets`` (robot joint order)."""

    offsets: np.ndarray

    def to_environment(self, joints: np.ndarray) -> np.ndarray:
        return np.asarray(joints, dtype=float) + self.offsets

    def to_planning(self, joints: np.ndarray) -> np.ndarray:
        return np.asarray(joints, dtype=float) - self.offsets


@contextlib.contextmanager
def _environment_lock():
    """Exclusive lock around ``QuadrupedEnv(...)``, which writes and reads an XML in its package folder."""
    path = os.path.join(tempfile.gettempdir(), "cafe_mpc_gym_quadruped.lock")
    with open(path, "a") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


def make_environment(robot: Robot, timestep: float, floor_friction: float, scene: str = "flat"):
    """A ``QuadrupedEnv`` of the robot file's gym-quadruped robot (see the module docstring)."""
    if robot.gym_quadruped is None:
        raise GymQuadrupedUnavailable(
            f"robot {robot.name!r} names no gym-quadruped model (robot file key gym_quadruped.robot)"
        )
    if scene not in GYM_SCENES:
        raise GymQuadrupedUnavailable(
            f"unknown gym-quadruped scene {scene!r}; scenes: {', '.join(GYM_SCENES)}"
        )
    try:
        from gym_quadruped.quadruped_env import QuadrupedEnv
    except ImportError as error:
        raise GymQuadrupedUnavailable(
            f"plant.kind gym-quadruped needs gym-quadruped (pip install 'cafe-mpc[gym]'): {error}"
        ) from error
    # it prints the qpos0 change and gymnasium warns that its action-space bounds are float32: neither matters
    with _environment_lock(), contextlib.redirect_stdout(io.StringIO()), warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*precision lowered by casting to float32.*")
        return QuadrupedEnv(
            robot=robot.gym_quadruped,
            scene=scene,
            sim_dt=timestep,
            ground_friction_coeff=floor_friction,
            base_vel_command_type="forward",
            state_obs_names=("qpos", "qvel"),
        )


class GymQuadrupedPlant(Plant):
    """A ``sim.plant.Plant`` around a gym-quadruped environment (see the module docstring).

    ``timestep``: the physics step (None: the robot file's); ``floor_friction``: the environment's
    ``ground_friction_coeff`` (None: the robot file's); ``scene``: gym-quadruped's scene (``GYM_SCENES``);
    ``sensors``: what the controller reads (the true state unless given; the robot's sensors,
    ``sim.sensors.SensorSuite``, computed from the environment's state: ``sim.sensors.StateSensors``).
    """

    kind = "gym-quadruped"

    def __init__(
        self,
        robot: Robot,
        timestep: float | None = None,
        floor_friction: float | None = None,
        scene: str = "flat",
        sensors: PlantSensors | None = None,
    ) -> None:
        super().__init__(robot, sensors)
        timestep = checked_timestep(robot.plant.timestep if timestep is None else timestep)
        friction = robot.plant.floor_friction if floor_friction is None else float(floor_friction)
        self.gym_scene = scene
        self.env = make_environment(robot, timestep, friction, scene)
        self.model, self.data = self.env.mjModel, self.env.mjData
        self.base_body = 1
        """The trunk: the environment's first body after the world (its free-floating base)."""
        model = self.model
        env_mass = float(np.sum(model.body_mass))
        if abs(env_mass - robot.total_mass) > MASS_TOLERANCE * robot.total_mass:
            raise GymQuadrupedUnavailable(
                f"gym-quadruped's {robot.gym_quadruped!r} weighs {env_mass:.4f} kg, robot {robot.name!r} "
                f"{robot.total_mass:.4f} kg: the robot file's model_file is not that environment's model"
            )
        joints = [model.joint(name) for name in robot.joint_names]
        self.qpos_index = np.array([int(joint.qposadr[0]) for joint in joints])
        self.qvel_index = np.array([int(joint.dofadr[0]) for joint in joints])
        if not (
            np.array_equal(self.qpos_index, np.arange(7, 7 + robot.nu))
            and np.array_equal(self.qvel_index, np.arange(6, 6 + robot.nu))
        ):
            raise GymQuadrupedUnavailable(
                f"gym-quadruped's {robot.gym_quadruped!r} orders its joints differently from robot "
                f"{robot.name!r}"
            )
        self.offsets = JointOffsets(np.array(model.qpos0[self.qpos_index], dtype=float))
        self.actuator_index, self.gear, self.torque_limits = self._actuators()
        self.foot_legs = self._foot_legs()
        self._state = Measurement.zeros(robot.nq, robot.nv, robot.n_feet)
        self._rotation = np.zeros(9)
        self._ctrl = np.zeros(model.nu)
        self.termination: dict = {}
        """The environment's invalid contacts at its first termination (body pairs)."""
        self.after_step: Callable[[mujoco.MjData], None] | None = None
        """Called after every physics step (``sim.sensors.SensorSuite`` averages the IMU over the steps)."""

    @classmethod
    def from_config(
        cls, config: RunConfig, robot: Robot, sensors: PlantSensors | None = None
    ) -> GymQuadrupedPlant:
        """The plant of a run config: its ``simulation.plant_timestep``, ``plant.floor_friction`` and
        ``plant.gym_scene``."""
        return cls(
            robot,
            config.simulation.plant_timestep,
            config.plant.floor_friction,
            config.plant.gym_scene,
            sensors,
        )

    def _actuators(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """For each robot joint: the environment's actuator, its gear and the torque it can apply."""
        model, robot = self.model, self.robot
        index = np.full(robot.nu, -1)
        for actuator in range(model.nu):
            if model.actuator_trntype[actuator] != mujoco.mjtTrn.mjTRN_JOINT:
                continue
            name = model.joint(int(model.actuator_trnid[actuator, 0])).name
            if name in robot.joint_names:
                motor = (
                    model.actuator_gaintype[actuator] == mujoco.mjtGain.mjGAIN_FIXED
                    and model.actuator_biastype[actuator] == mujoco.mjtBias.mjBIAS_NONE
                    and model.actuator_gainprm[actuator, 0] == 1.0
                )
                if not motor:
                    raise GymQuadrupedUnavailable(
                        f"actuator {model.actuator(actuator).name!r} is not a torque motor"
                    )
                index[robot.joint_names.index(name)] = actuator
        if np.any(index < 0):
            missing = [robot.joint_names[i] for i in np.flatnonzero(index < 0)]
            raise GymQuadrupedUnavailable(f"no motor drives {', '.join(missing)} in gym-quadruped's model")
        gear = model.actuator_gear[index, 0].astype(float)
        limits = np.full(robot.nu, np.inf)
        for joint_index, actuator in enumerate(index):
            if model.actuator_ctrllimited[actuator]:
                limits[joint_index] = min(
                    limits[joint_index],
                    abs(gear[joint_index]) * np.max(np.abs(model.actuator_ctrlrange[actuator])),
                )
            if model.actuator_forcelimited[actuator]:
                limits[joint_index] = min(
                    limits[joint_index], float(np.max(np.abs(model.actuator_forcerange[actuator])))
                )
            joint_id = model.joint(robot.joint_names[joint_index]).id
            if model.jnt_actfrclimited[joint_id]:
                limits[joint_index] = min(
                    limits[joint_index], float(np.max(np.abs(model.jnt_actfrcrange[joint_id])))
                )
        return index, gear, limits

    def _foot_legs(self) -> list[str]:
        """The environment's leg name of each robot foot, matched by the model file's foot geom names."""
        robot = self.robot
        if robot.plant_foot_geoms is None:
            raise GymQuadrupedUnavailable(f"robot {robot.name!r} names no foot geoms (plant.foot_geoms)")
        by_geom = {geom: leg for leg, geom in self.env.robot_cfg.feet_geom_names.items()}
        legs = []
        for geom in robot.plant_foot_geoms:
            if geom not in by_geom:
                raise GymQuadrupedUnavailable(
                    f"foot geom {geom!r} is not one of gym-quadruped's feet {sorted(by_geom)}"
                )
            legs.append(by_geom[geom])
        return legs

    def environment_state(self, q: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Planning ``(q, v)`` -> the environment's ``(qpos, qvel)``."""
        qpos = np.zeros(self.model.nq)
        qvel = np.zeros(self.model.nv)
        quaternion = np.asarray(q[3:7], dtype=float) / np.linalg.norm(q[3:7])
        qpos[:3] = q[:3]
        qpos[3:7] = [quaternion[3], *quaternion[:3]]
        qpos[self.qpos_index] = self.offsets.to_environment(q[7:])
        mujoco.mju_quat2Mat(self._rotation, qpos[3:7])
        qvel[:3] = self._rotation.reshape(3, 3) @ v[:3]
        qvel[3:6] = v[3:6]
        qvel[self.qvel_index] = v[6:]
        return qpos, qvel

    def _reset(self, q: np.ndarray, v: np.ndarray) -> None:
        """Through ``env.reset(qpos, qvel)``, then the state set again at time 0."""
        qpos, qvel = self.environment_state(q, v)
        self.env.reset(qpos=qpos.copy(), qvel=qvel.copy(), random=False)
        mujoco.mj_resetData(self.model, self.data)  # undo the reset's physics step: start exactly at (q, v)
        self.data.qpos[:] = qpos
        self.data.qvel[:] = qvel
        mujoco.mj_forward(self.model, self.data)
        self._ctrl[:] = 0.0
        self.termination = {}

    def step(self, torques: np.ndarray, n_steps: int = 1) -> None:
        """``n_steps`` environment steps with the joint torques held."""
        self._ctrl[:] = 0.0
        self._ctrl[self.actuator_index] = np.asarray(torques, dtype=float) / self.gear
        for _ in range(n_steps):
            _, _, terminated, _, info = self.env.step(self._ctrl)
            if self.after_step is not None:
                self.after_step(self.data)
            if terminated and not self.trunk_touched_floor:
                self.trunk_touched_floor = True
                self.termination = {
                    "time": float(self.data.time),
                    "contacts": sorted(info["invalid_contacts"]),
                }
            self._check_warnings()
        self._check_finite()

    def applied(self, torques: np.ndarray) -> np.ndarray:
        """Torques the environment's actuators apply for commanded ``torques`` (saturated)."""
        return np.clip(torques, -self.torque_limits, self.torque_limits)

    def applied_torques(self) -> np.ndarray:
        return self.applied(self._ctrl[self.actuator_index] * self.gear)

    def read_state(self) -> Measurement:
        """Planning coordinates (joint offsets removed), the environment's feet contacts and forces."""
        state = self._state
        state.time = float(self.data.time)
        mujoco.mju_quat2Mat(self._rotation, self.data.qpos[3:7])
        planning_state(self.data.qpos, self.data.qvel, state.q, state.v, self._rotation)
        state.q[7:] = self.offsets.to_planning(self.data.qpos[self.qpos_index])
        state.v[6:] = self.data.qvel[self.qvel_index]
        contact, _, forces = self.env.feet_contact_state(frame="world", ground_reaction_forces=True)
        for foot, leg in enumerate(self.foot_legs):
            state.contacts[foot] = bool(contact[leg])
            state.foot_forces[foot] = forces[leg]
        return state

    def close(self) -> None:
        self.env.close()
