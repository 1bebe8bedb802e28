"""A run config -> the plant its closed loop runs against, and what the loop does to it.

``build_plant(run)`` builds the plant of a resolved run's ``plant.kind`` (``PLANTS``) with its scene (terrain,
the bar), its variation (``sim.randomization``), its sensors (what the controller reads: the state through
``plant.sensor_noise`` and the latency jitter, or the robot's sensor readings when an estimator runs,
``sim.sensors``, with the sensor faults of ``plant.faults``, ``sim.faults``) and its height-map sensor
(``plant.height_map``, ``sim.height_map``), and the ``SimulationOptions`` of the config: duration, control
rate, the start state, pushes, fall criteria (from the terrain under the base) and, in real time, the
wall-clock pacer. The controller's ``Robot`` stays nominal.

A new plant is one module with a ``sim.plant.Plant`` and one line in ``PLANTS`` (and its name among the
config's ``plant.kind`` values).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass

from cafe_mpc.config import SENSOR_FAULTS, ConfigError, RunConfig
from cafe_mpc.planners.resolved import ResolvedRun
from cafe_mpc.robots.robot import Robot
from cafe_mpc_lab.sim.faults import FaultySensors, joint_index
from cafe_mpc_lab.sim.gym_plant import GymQuadrupedPlant
from cafe_mpc_lab.sim.loop import FallCriteria, Push, SimulationOptions, WallClockPacer
from cafe_mpc_lab.sim.mujoco_plant import MujocoPlant
from cafe_mpc_lab.sim.plant import Plant, PlantSensors
from cafe_mpc_lab.sim.randomization import sensor_model
from cafe_mpc_lab.sim.scene import Scene, scene_of
from cafe_mpc_lab.sim.sensors import SensorSuite, sensor_spec
from cafe_mpc_lab.sim.terrain import support_height

PlantFactory = Callable[[RunConfig, Robot, PlantSensors], Plant]
"""Builds a plant from a run config, the robot and the sensors the controller reads."""

PLANTS: dict[str, PlantFactory] = {
    MujocoPlant.kind: MujocoPlant.from_config,
    GymQuadrupedPlant.kind: GymQuadrupedPlant.from_config,  # imports gym-quadruped when built
}
"""``plant.kind`` -> the plant's factory."""


def plant_factory(kind: str) -> PlantFactory:
    """The factory of ``plant.kind`` ``kind``; ``ValueError`` (one line) for an unknown kind."""
    try:
        return PLANTS[kind]
    except KeyError:
        raise ValueError(f"plant.kind {kind!r} is not a plant; plants: {', '.join(PLANTS)}") from None


def plant_sensors(config: RunConfig, robot: Robot) -> PlantSensors:
    """What the controller reads: the robot's sensor readings for a state estimator
    (``plant.sensors``, with ``plant.faults``' sensor faults), else the true state through
    ``plant.sensor_noise`` and the latency jitter. ``ConfigError`` naming the key for a fault's unknown
    joint."""
    rate = config.simulation.control_rate_hz
    if config.estimator != "ground_truth":
        suite = SensorSuite(robot.nu, sensor_spec(config.plant, rate), rate)
        faults = [fault for fault in config.plant.faults if fault.kind in SENSOR_FAULTS]
        if not faults:
            return suite
        for index, fault in enumerate(config.plant.faults):
            try:
                joint_index(fault.joint, robot.joint_names)
            except ValueError as error:
                raise ConfigError(f"plant.faults.{index}.joint: {error}") from error
        return FaultySensors(suite, faults, robot.joint_names)
    return sensor_model(config.plant, rate)


def simulation_options(run: ResolvedRun) -> SimulationOptions:
    """The run's ``simulation`` and ``pushes``: duration, rate, the start state (standing,
    ``initial_height_offset`` higher), pushes (their forces in N for this robot), fall criteria (the fall
    height scaled to the robot, measured from the terrain under the base, gaps bridged) and, for
    ``simulation.realtime``, the wall-clock pacer."""
    config, robot = run.config, run.robot
    simulation = config.simulation
    terrain = scene_of(config.scene).terrain
    q0 = robot.q_standing.copy()
    q0[2] += simulation.initial_height_offset
    return SimulationOptions(
        duration=simulation.duration,
        control_rate_hz=simulation.control_rate_hz,
        initial_q=q0,
        pushes=tuple(Push(p.start, p.duration, p.force_on(robot.total_mass)) for p in config.pushes),
        fall=FallCriteria(
            run.scale.distance(simulation.fall.min_base_height),
            simulation.fall.max_tilt_rad,
            functools.partial(support_height, terrain) if terrain else None,
        ),
        stop_on_fall=simulation.stop_on_fall,
        pacer=WallClockPacer(priority=simulation.realtime_priority, lock_pages=simulation.lock_memory)
        if simulation.realtime
        else None,
    )


@dataclass(frozen=True)
class PlantSetup:
    """A run's plant (built: scene, variation, sensors), its scene (for videos) and the loop's options."""

    plant: Plant
    scene: Scene
    options: SimulationOptions


def build_plant(run: ResolvedRun) -> PlantSetup:
    """The plant of a resolved run (its config's, for its robot) and the options to simulate it with (module
    docstring)."""
    config, robot = run.config, run.robot
    plant = plant_factory(config.plant.kind)(config, robot, plant_sensors(config, robot))
    return PlantSetup(plant, scene_of(config.scene), simulation_options(run))
