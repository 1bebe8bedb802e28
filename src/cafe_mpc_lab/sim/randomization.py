"""Plant variations and sensor imperfections: the simulated robot differs from the one the controller plans
with, and the controller sees the state through noisy, late sensors.

This is the simulation layer's half of domain randomisation (the paper's reliability test, Sec. VII-C3 and
Fig. 17, repeats a task on hardware whose friction, masses, motors and sensors are never exactly the
model's). Everything here changes only the MuJoCo model of ``sim.mujoco_plant.MujocoPlant`` and the
``Measurement`` handed to the controller; the controller's ``Robot`` (Pinocchio model, SRB parameters,
torque limits) is never touched, because the mismatch between the two is the point.

* ``PlantVariation``: floor (and terrain) and foot friction, the whole robot's mass, trunk mass, the mass
  of every leg link, the strength of every motor. Masses scale with their inertia tensors (same shape,
  different density); motor strength scales the actuator gear, so a motor at 0.9 delivers 0.9 x the
  commanded torque and saturates at 0.9 x its limit.
* ``SensorModel``: zero-mean Gaussian noise on the measured base pose, base twist, joint angles and rates,
  and a latency jitter: at each control tick the controller sees the state of a random earlier tick, at most
  ``delay_max`` seconds old and never older than what it saw at the previous tick (measurements arrive in
  order). The delay is extra to the MPC's own latency (``mpc.latency``): the low-level controller and the
  MPC's measurement both come late.

Sampling ranges live with the experiments (``cafe-mpc experiment reliability``); a sampled plant is plain
data in the run config's ``plant`` section, so a trial's ``config.yaml`` re-runs it alone.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import mujoco
import numpy as np

from cafe_mpc.config import PlantConfig, SensorNoise
from cafe_mpc.core.measurement import Measurement
from cafe_mpc.robots.robot import Robot

if TYPE_CHECKING:
    from cafe_mpc_lab.sim.plant import Plant


@dataclass(frozen=True)
class PlantVariation:
    """How the simulated robot differs from its robot table; the defaults change nothing.

    ``link_mass_scales`` and ``motor_strength_scales`` hold one value per actuated joint in the robot's joint
    order (the link a joint moves; the motor that drives it) or a single value for all.
    """

    floor_friction: float | None = None
    """Sliding friction of the floor and of the foot spheres (None: the robot table's)."""
    body_mass_scale: float = 1.0
    link_mass_scales: float | tuple[float, ...] = 1.0
    motor_strength_scales: float | tuple[float, ...] = 1.0
    mass_scale: float = 1.0
    """Every body's mass and inertia (the whole robot), on top of the trunk and link factors."""

    def per_joint(self, values: float | tuple[float, ...], n: int, name: str) -> np.ndarray:
        array = np.full(n, float(values)) if np.isscalar(values) else np.asarray(values, dtype=float)
        if array.shape != (n,) or not np.all(np.isfinite(array)) or np.any(array <= 0.0):
            raise ValueError(f"{name}: one positive value or {n} (one per joint), got {values!r}")
        return array

    def check(self, robot: Robot) -> None:
        """Raise ``ValueError`` naming the field when a value does not fit ``robot``."""
        if self.floor_friction is not None and not 0.0 < self.floor_friction <= 10.0:
            raise ValueError(f"floor_friction must be in (0, 10], got {self.floor_friction}")
        if not 0.0 < self.body_mass_scale <= 10.0:
            raise ValueError(f"body_mass_scale must be in (0, 10], got {self.body_mass_scale}")
        if not 0.0 < self.mass_scale <= 10.0:
            raise ValueError(f"mass_scale must be in (0, 10], got {self.mass_scale}")
        self.per_joint(self.link_mass_scales, robot.nu, "link_mass_scales")
        self.per_joint(self.motor_strength_scales, robot.nu, "motor_strength_scales")

    @property
    def is_nominal(self) -> bool:
        return (
            self.floor_friction is None
            and self.body_mass_scale == 1.0
            and self.mass_scale == 1.0
            and np.all(np.asarray(self.link_mass_scales) == 1.0)
            and np.all(np.asarray(self.motor_strength_scales) == 1.0)
        )


def plant_variation(plant: PlantConfig) -> PlantVariation:
    """The ``PlantVariation`` of a config's ``plant`` section."""

    def scales(value: float | list[float]) -> float | tuple[float, ...]:
        return tuple(value) if isinstance(value, list) else value

    return PlantVariation(
        plant.floor_friction,
        plant.body_mass_scale,
        scales(plant.link_mass_scales),
        scales(plant.motor_strength_scales),
        mass_scale=plant.mass_scale,
    )


def apply_variation(model: mujoco.MjModel, robot: Robot, variation: PlantVariation) -> np.ndarray:
    """Change a freshly loaded plant model in place; returns the per-motor strength (gear) factors.

    Bodies are found through the model: the trunk is body ``base``, the link of actuated joint ``j`` is the
    body that joint moves (``jnt_bodyid``), the feet are the geoms named after the robot's foot frames.
    """
    variation.check(robot)
    if variation.floor_friction is not None:
        geoms = [model.geom("floor").id, *(model.geom(name).id for name in robot.foot_frame_names)]
        geoms += terrain_geoms(model)  # sim.terrain's slopes and steps are floor too
        for geom in geoms:  # MuJoCo takes the larger friction of the two geoms in contact: set both
            model.geom_friction[geom, 0] = variation.floor_friction
    if variation.mass_scale != 1.0:
        model.body_mass[1:] *= variation.mass_scale  # body 0 is the world
        model.body_inertia[1:] *= variation.mass_scale
    base = model.body("base").id
    model.body_mass[base] *= variation.body_mass_scale
    model.body_inertia[base] *= variation.body_mass_scale
    link_scales = variation.per_joint(variation.link_mass_scales, robot.nu, "link_mass_scales")
    for index, name in enumerate(robot.joint_names):
        body = model.jnt_bodyid[model.joint(name).id]
        model.body_mass[body] *= link_scales[index]
        model.body_inertia[body] *= link_scales[index]
    strength = variation.per_joint(variation.motor_strength_scales, robot.nu, "motor_strength_scales")
    if model.nu != robot.nu:
        raise ValueError(f"plant has {model.nu} actuators, the robot {robot.nu} joints")
    model.actuator_gear[:, 0] *= strength
    data = mujoco.MjData(model)
    mujoco.mj_setConst(model, data)  # subtree masses and constraint scalings follow the new inertias
    return strength


TERRAIN_PREFIX = "terrain_"
"""Name prefix of the terrain geoms (``sim.terrain``)."""


def terrain_geoms(model: mujoco.MjModel) -> list[int]:
    """Ids of the scene's terrain geoms (named ``terrain_*``)."""
    return [i for i in range(model.ngeom) if (model.geom(i).name or "").startswith(TERRAIN_PREFIX)]


def _quaternion_times_rotation_vector(q_xyzw: np.ndarray, rotation_vector: np.ndarray) -> np.ndarray:
    """``q * exp(rotation_vector)`` for a quaternion (x, y, z, w) and a body-frame rotation vector."""
    angle = float(np.linalg.norm(rotation_vector))
    if angle < 1e-12:
        return q_xyzw.copy()
    axis = rotation_vector / angle
    dx, dy, dz = np.sin(angle / 2.0) * axis
    dw = np.cos(angle / 2.0)
    x, y, z, w = q_xyzw
    return np.array(
        [
            w * dx + x * dw + y * dz - z * dy,
            w * dy - x * dz + y * dw + z * dx,
            w * dz + x * dy - y * dx + z * dw,
            w * dw - x * dx - y * dy - z * dz,
        ]
    )


class SensorModel:
    """What the controller measures: the plant's state, late (latency jitter) and noisy.

    ``observe(tick, state)`` is called once per control tick with the plant's true state and returns the
    measurement the controller gets (its own arrays; the log keeps the truth). With ``delay_max_ticks`` = 0
    and zero noise it returns ``state`` itself. Random numbers come from ``numpy.random.default_rng(seed)``:
    a seed gives the same noise and delays on every run.
    """

    def __init__(self, noise: SensorNoise | None = None, delay_max_ticks: int = 0, seed: int = 0) -> None:
        if delay_max_ticks < 0:
            raise ValueError(f"delay_max_ticks must be >= 0, got {delay_max_ticks}")
        self.noise = noise if noise is not None else SensorNoise()
        self.delay_max_ticks = int(delay_max_ticks)
        self.seed = int(seed)
        self.rng = np.random.default_rng(self.seed)
        self._history: list[Measurement] = []
        self._last_source = -1
        self.delays: list[int] = []
        """Delay (control ticks) of every measurement handed out."""

    @property
    def is_identity(self) -> bool:
        return self.delay_max_ticks == 0 and self.noise.is_zero

    def reset(self) -> None:
        self.rng = np.random.default_rng(self.seed)
        self._history.clear()
        self._last_source = -1
        self.delays.clear()

    def observe(self, tick: int, state: Measurement) -> Measurement:
        if self.is_identity:
            return state
        snapshot = Measurement(
            state.time, state.q.copy(), state.v.copy(), state.contacts.copy(), state.foot_forces.copy()
        )
        self._history.append(snapshot)
        if len(self._history) > self.delay_max_ticks + 1:
            self._history.pop(0)
        first = tick - (len(self._history) - 1)  # tick of the oldest snapshot kept
        delay = int(self.rng.integers(0, self.delay_max_ticks + 1)) if self.delay_max_ticks else 0
        source = max(tick - delay, self._last_source, first)
        self._last_source = source
        self.delays.append(tick - source)
        seen = self._history[source - first]
        measured = Measurement(
            seen.time, seen.q.copy(), seen.v.copy(), seen.contacts.copy(), seen.foot_forces.copy()
        )
        noise, rng = self.noise, self.rng
        if not noise.is_zero:
            measured.q[:3] += noise.base_position * rng.standard_normal(3)
            rotation = noise.base_orientation * rng.standard_normal(3)
            quaternion = _quaternion_times_rotation_vector(measured.q[3:7], rotation)
            measured.q[3:7] = quaternion / np.linalg.norm(quaternion)
            measured.q[7:] += noise.joint_position * rng.standard_normal(len(measured.q) - 7)
            measured.v[:3] += noise.base_linear_velocity * rng.standard_normal(3)
            measured.v[3:6] += noise.base_angular_velocity * rng.standard_normal(3)
            measured.v[6:] += noise.joint_velocity * rng.standard_normal(len(measured.v) - 6)
        return measured

    def measure(self, tick: int, plant: Plant, state: Measurement) -> Measurement:
        """``sim.plant.PlantSensors``: the controller's measurement of the plant's true ``state``."""
        return self.observe(tick, state)

    def log_extra(self) -> dict[str, dict]:
        """The run log's ``sensor`` block (delay statistics), none when the measurement is the truth."""
        return {} if self.is_identity else {"sensor": self.summary()}

    def summary(self) -> dict:
        """Delay statistics of the run (ticks)."""
        delays = np.asarray(self.delays)
        return {
            "delay_max_ticks": self.delay_max_ticks,
            "delay_ticks_mean": float(np.mean(delays)) if delays.size else 0.0,
            "delay_ticks_max": int(np.max(delays)) if delays.size else 0,
        }


def sensor_model(plant: PlantConfig, control_rate_hz: float) -> SensorModel:
    """The controller's ``SensorModel`` of a config's ``plant`` section (delays in whole control ticks,
    rounded down)."""
    ticks = math.floor(plant.measurement_delay_max * control_rate_hz + 1e-9)
    return SensorModel(plant.sensor_noise, ticks, plant.seed)
