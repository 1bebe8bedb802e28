"""A trajectory-optimisation task as data: contact sequence, keyframes, weights, constraints, solver settings.

The offline TO of the paper's Appendix (Sec. VI-B) is a multi-phase problem whose phases come from a contact
sequence with switching times; each phase tracks one *keyframe* (the desired state at the end of the phase)
with its own running and terminal weights; touchdowns are constraints (Eq. (25)); minimum base height,
torque, joint-position, joint-speed and friction limits are inequality constraints. ``TrajOptTask`` holds all
of it as plain values so that a task is a YAML file (``cafe-mpc optimize TASK_OR_FILE --set key=value``,
read like a run config: ``config.loading``) and every written trajectory comes with the YAML that made it.

Conventions: contact codes as in ``cafe_mpc.reference.trajectory_file`` (``"FS"``, ``"FT"``, ``"FR-HR"``);
base weights in the order ``[x, y, z, yaw, pitch, roll]`` (``cafe_mpc.config.weights``); keyframe orientations
as roll, pitch, yaw (``R = Rz(yaw) Ry(pitch) Rx(roll)``) where the roll is *cumulative* (``2 pi`` = one full
turn), and orientation rates as roll, pitch, yaw rates; joint vectors as 3 values (abad, hip, knee; every
leg) or 12 (leg order FL, FR, HL, HR).
"""

from __future__ import annotations

import itertools
import math
from typing import Literal

import numpy as np
import yaml
from pydantic import Field, field_validator, model_validator

from cafe_mpc.config import DEFAULT_FRICTION
from cafe_mpc.config.loading import ConfigError, StrictModel
from cafe_mpc.config.weights import WholeBodyWeights
from cafe_mpc.core.physics import GRAVITY
from cafe_mpc.ocp.constraints import BarrierParameters, WholeBodyConstraintSettings
from cafe_mpc.reference.trajectory_file import parse_contact_code
from cafe_mpc.robots.robot import Robot
from cafe_mpc.solver.options import SolverOptions

Vector3 = tuple[float, float, float]
Vector6 = tuple[float, float, float, float, float, float]
TIME_TOLERANCE = 1e-9


class TrajOptTaskError(ConfigError):
    """A task (preset, YAML file or override) that cannot be used; the message names the key."""


def _joint_vector(values: list[float], name: str) -> list[float]:
    if len(values) not in (3, 12):
        raise ValueError(f"{name}: give 3 values (abad, hip, knee; every leg) or 12, got {len(values)}")
    if not all(math.isfinite(v) for v in values):
        raise ValueError(f"{name}: values must be finite")
    return values


def joints12(values: list[float] | tuple[float, ...]) -> np.ndarray:
    """3 values (every leg) or 12 -> 12 values in leg order."""
    array = np.asarray(values, dtype=float)
    return np.tile(array, 4) if array.shape == (3,) else array


class KeyframeSpec(StrictModel):
    """A desired whole-body state (the end of a phase, or the initial state)."""

    position: Vector3 = Field(description="base position, world (m)")
    rpy: Vector3 = Field((0.0, 0.0, 0.0), description="roll, pitch, yaw (rad); roll cumulative")
    linear_velocity: Vector3 = Field((0.0, 0.0, 0.0), description="base linear velocity, world (m/s)")
    rpy_rates: Vector3 = Field((0.0, 0.0, 0.0), description="roll, pitch, yaw rates (rad/s)")
    joint_positions: list[float] = Field(description="3 (every leg) or 12 joint angles (rad)")
    joint_velocities: list[float] = Field([0.0, 0.0, 0.0], description="3 or 12 joint rates (rad/s)")

    @field_validator("joint_positions", "joint_velocities")
    @classmethod
    def _joints(cls, values: list[float], info) -> list[float]:
        return _joint_vector(values, info.field_name)

    @field_validator("position", "rpy", "linear_velocity", "rpy_rates")
    @classmethod
    def _finite(cls, values: Vector3, info) -> Vector3:
        if not all(math.isfinite(v) for v in values):
            raise ValueError(f"{info.field_name}: values must be finite")
        return values


class WeightsSpec(StrictModel):
    """Diagonal weights of one phase's running or terminal cost (Eq. (18); running cost times dt)."""

    base_position: Vector6 = Field(description="x, y, z, yaw, pitch, roll")
    base_velocity: Vector6 = Field(description="vx, vy, vz (world), yaw, pitch, roll rates")
    joint_position: list[float] = Field(description="3 (abad, hip, knee; every leg) or 12")
    joint_velocity: list[float] = Field(description="3 or 12")
    torque: float = Field(0.0, ge=0.0, description="torque regularisation (running knots only)")

    @field_validator("joint_position", "joint_velocity")
    @classmethod
    def _joints(cls, values: list[float], info) -> list[float]:
        _joint_vector(values, info.field_name)
        if any(v < 0 for v in values):
            raise ValueError(f"{info.field_name}: weights must be non-negative")
        return values

    @field_validator("base_position", "base_velocity")
    @classmethod
    def _non_negative(cls, values: Vector6, info) -> Vector6:
        if not all(math.isfinite(v) and v >= 0 for v in values):
            raise ValueError(f"{info.field_name}: weights must be finite and non-negative")
        return values

    def weights(self) -> WholeBodyWeights:
        """The knot weights (foot terms off: the TO tracks keyframes only, paper Appendix)."""
        return WholeBodyWeights(
            base_position=tuple(self.base_position),
            base_velocity=tuple(self.base_velocity),
            joint_position=tuple(joints12(self.joint_position)),
            joint_velocity=tuple(joints12(self.joint_velocity)),
            torque=self.torque,
            swing_foot_position=0.0,
            swing_foot_velocity=0.0,
        )


class PhaseSpec(StrictModel):
    """One phase: its contacts, the keyframe it ends on, its weights, its minimum base height and the least
    normal force of its stance feet."""

    name: str
    contacts: str = Field(description="contact code: FS, FT or stance legs joined by '-' (FR-HR)")
    keyframe: KeyframeSpec
    running: WeightsSpec
    terminal: WeightsSpec
    minimum_height: float | None = Field(None, ge=0.0, le=1.0, description="minimum base height (m)")
    minimum_normal_force: float = Field(
        0.0,
        ge=0.0,
        le=2.0,
        description="least normal force of every stance foot, x m g / n_feet (the robot's weight share; "
        "0: the pyramid (26) as is). A stance foot planned at no load floats just above the floor in closed "
        "loop and cannot push at once when the next phase loads it",
    )
    surface_height: float | None = Field(
        None,
        ge=-1.0,
        le=1.0,
        description="world z of the surface the phase's stance feet stand on, m (a box top); the touchdown "
        "constraint that enters the phase uses it (null: the task's surface_height)",
    )

    @field_validator("contacts")
    @classmethod
    def _code(cls, code: str) -> str:
        parse_contact_code(code)
        return code.strip().upper()

    @property
    def stance(self) -> tuple[bool, bool, bool, bool]:
        return parse_contact_code(self.contacts)


class BarrierSpec(StrictModel):
    """Relaxed barrier ``eps * B(g)`` with threshold ``delta`` (Sec. III-B-2)."""

    delta: float = Field(gt=0.0)
    eps: float = Field(ge=0.0)

    def parameters(self) -> BarrierParameters:
        return BarrierParameters(self.delta, self.eps)


class BarrierSetSpec(StrictModel):
    """Barrier parameters of every inequality (GRF in N, torque in Nm, joints in rad, rad/s, height in m)."""

    friction: BarrierSpec
    torque: BarrierSpec
    joint_position: BarrierSpec
    joint_speed: BarrierSpec
    height: BarrierSpec


def _authors_to_barriers() -> BarrierSetSpec:
    """Authors' barrel-roll TO barriers (ROAM-Lab-ND/CAFE-MPC,
    ``MHPC/MHPC-Trajopt/BarrelRoll/setting/br_constraint_params.info``)."""
    return BarrierSetSpec(
        friction=BarrierSpec(delta=0.02, eps=0.1),
        torque=BarrierSpec(delta=0.01, eps=0.1),
        joint_position=BarrierSpec(delta=0.01, eps=0.1),
        joint_speed=BarrierSpec(delta=0.1, eps=0.1),
        height=BarrierSpec(delta=0.01, eps=0.1),
    )


def _mpc_barriers() -> BarrierSetSpec:
    """This package's MPC defaults (``WholeBodyConstraintSettings``): much softer."""
    defaults = WholeBodyConstraintSettings()
    return BarrierSetSpec(
        friction=BarrierSpec(delta=defaults.friction_barrier.delta, eps=defaults.friction_barrier.eps),
        torque=BarrierSpec(delta=defaults.torque_barrier.delta, eps=defaults.torque_barrier.eps),
        joint_position=BarrierSpec(
            delta=defaults.joint_position_barrier.delta, eps=defaults.joint_position_barrier.eps
        ),
        joint_speed=BarrierSpec(
            delta=defaults.joint_velocity_barrier.delta, eps=defaults.joint_velocity_barrier.eps
        ),
        height=BarrierSpec(delta=defaults.base_height_barrier.delta, eps=defaults.base_height_barrier.eps),
    )


class ConstraintSpec(StrictModel):
    """Limits and barrier parameters.

    ``barriers`` are used by the final solve; ``warm_up_barriers`` (or ``null``) by a first solve from the
    keyframe guess (a barrier continuation: the stiff barriers, far outside their ``delta`` at the guess,
    stall the line search when they are used from the start).
    """

    torque_limit: float | None = Field(
        None,
        gt=0.0,
        description="|tau| limit of every joint, Nm (null: the robot's limits named by torque_limit_source)",
    )
    torque_limit_source: Literal["joints", "motor"] = Field(
        "joints",
        description="with torque_limit null: joints (the robot table's joints.torque_limits, 17 Nm on every "
        "Mini Cheetah joint) or motor (the motors' saturation, plant.motor_torque_limits: 17/17/26 Nm), the "
        "limits a run with torque_limits: motor plans and acts with",
    )
    torque_limit_fraction: float = Field(
        1.0,
        gt=0.0,
        le=1.0,
        description="the limits the trajectory may use as a fraction of the torque limits above: a margin "
        "that the closed loop's feedback (and a motor weaker than its datasheet) can draw on",
    )
    joint_speed_limit: float | None = Field(
        20.0, gt=0.0, description="|qdot| limit of every joint, rad/s (null: the robot's velocity_limits)"
    )
    friction_coefficient: float = Field(DEFAULT_FRICTION, gt=0.0)
    barriers: BarrierSetSpec = Field(default_factory=_authors_to_barriers)
    warm_up_barriers: BarrierSetSpec | None = Field(default_factory=_mpc_barriers)

    def torque_limits(self, robot: Robot) -> tuple[float, ...]:
        """Per-joint ``|tau|`` limits the trajectory may use, Nm: ``torque_limit`` on every joint, or the
        robot's own limits (``torque_limit_source``), times ``torque_limit_fraction``."""
        if self.torque_limit is not None:
            limits = np.full(robot.nu, float(self.torque_limit))
        elif self.torque_limit_source == "motor":
            limits = np.asarray(robot.plant.motor_torque_limits, dtype=float)
        else:
            limits = np.asarray(robot.torque_limits, dtype=float)
        return tuple(float(limit) for limit in limits * self.torque_limit_fraction)

    def settings(
        self,
        minimum_height: float | None,
        barriers: BarrierSetSpec,
        robot: Robot,
        minimum_normal_force: float = 0.0,
    ) -> WholeBodyConstraintSettings:
        """Knot constraint settings (joint speed limits come from the planning robot, see ``multiphase``);
        ``minimum_normal_force`` as a fraction of the robot's weight share ``m g / n_feet``."""
        return WholeBodyConstraintSettings(
            friction_coefficient=self.friction_coefficient,
            minimum_base_height=minimum_height,
            minimum_normal_force=minimum_normal_force * robot.total_mass * GRAVITY / robot.n_feet,
            friction_barrier=barriers.friction.parameters(),
            torque_barrier=barriers.torque.parameters(),
            joint_position_barrier=barriers.joint_position.parameters(),
            joint_velocity_barrier=barriers.joint_speed.parameters(),
            base_height_barrier=barriers.height.parameters(),
            torque_limit_values=self.torque_limits(robot),
        )


class SolverSpec(StrictModel):
    """MS-iLQR settings of each solve (``SolverOptions``; paper Sec. III, offline values)."""

    max_iterations: int = Field(10, ge=1, le=10000, description="inner iterations per AL iteration")
    max_al_iterations: int = Field(30, ge=1, le=1000)
    cost_change_tolerance: float = Field(1e-2, gt=0.0)
    expected_decrease_tolerance: float = Field(1e-3, gt=0.0)
    defect_tolerance: float = Field(1e-3, gt=0.0)
    switching_tolerance: float = Field(1e-3, gt=0.0)
    regularization_initial: float = Field(1e-3, ge=0.0)
    regularization_min: float = Field(1e-6, ge=0.0)
    merit_feasibility_weight: float = Field(
        0.2,
        ge=0.0,
        lt=1.0,
        description="share of the line search's merit weight that rewards closing the defects "
        "(SolverOptions); near 1 a step that closes large defects of an inconsistent guess is accepted "
        "although it raises the cost",
    )

    def options(self, verbose: bool = False) -> SolverOptions:
        return SolverOptions(
            max_iterations=self.max_iterations,
            max_al_iterations=self.max_al_iterations,
            cost_change_tolerance=self.cost_change_tolerance,
            expected_decrease_tolerance=self.expected_decrease_tolerance,
            defect_tolerance=self.defect_tolerance,
            switching_tolerance=self.switching_tolerance,
            regularization_initial=self.regularization_initial,
            regularization_min=self.regularization_min,
            merit_feasibility_weight=self.merit_feasibility_weight,
            verbose=verbose,
        )


class TrajOptTask(StrictModel):
    """A multi-phase whole-body TO task (see the module docstring)."""

    name: str
    robot: str = "mini_cheetah"
    keyframes_robot: str | None = Field(
        None,
        description="the robot the keyframes, heights, speeds and timings are written for (null: robot); "
        "another robot's task is retargeted to robot before the solve (trajopt.retarget)",
    )
    keyframe_feet: Literal["as-given", "stance-ik"] = Field(
        "as-given",
        description="stance-ik: the stance legs of the initial state and of every keyframe are solved by "
        "inverse kinematics onto their footholds (trajopt.retarget.place_stance_feet)",
    )
    dt: float = Field(0.01, gt=0.0, le=0.1, description="knot spacing (s)")
    integration: Literal["explicit", "semi_implicit", "explicit_world"] = Field(
        "explicit",
        description="time stepping of the planning model (whole_body.WholeBodyDynamics): explicit (the "
        "paper's Eq. (23)), semi_implicit, or explicit_world (the base's linear velocity stepped in the "
        "world frame: keeps a spinning body's momentum in flight)",
    )
    surface_height: float = Field(0.0, description="ground height for touchdowns (m; phases may override)")
    switching_times: list[float] = Field(description="phase boundaries (s), one more than phases")
    initial: KeyframeSpec = Field(description="initial state (velocities are used as given)")
    phases: list[PhaseSpec]
    constraints: ConstraintSpec = Field(default_factory=ConstraintSpec)
    solver: SolverSpec = Field(default_factory=SolverSpec)
    initial_controls: Literal["static", "zero"] = Field(
        "static", description="torque guess: static stance torques (zero in flight), or zero"
    )
    initial_guess: Literal["keyframes", "kinematic"] = Field(
        "keyframes",
        description="state guess: keyframes, every part interpolated linearly (velocities too); kinematic, "
        "the same configurations with the velocities that move each knot's configuration to the next one's "
        "in dt (no configuration defect, the rotation's rate consistent with its angle)",
    )

    @model_validator(mode="after")
    def _timing(self) -> TrajOptTask:
        times, phases = self.switching_times, self.phases
        if not phases:
            raise ValueError("phases: a task needs at least one phase")
        if len(times) != len(phases) + 1:
            raise ValueError(
                f"switching_times: need {len(phases) + 1} times for {len(phases)} phases, got {len(times)}"
            )
        for index, (start, end) in enumerate(itertools.pairwise(times)):
            if not (math.isfinite(start) and math.isfinite(end)) or end - start <= TIME_TOLERANCE:
                raise ValueError(f"switching_times: phase {index} has no duration ({start} -> {end})")
            knots = (end - start) / self.dt
            if abs(knots - round(knots)) > 1e-6:
                raise ValueError(
                    f"switching_times: phase {index} lasts {end - start:g} s, not a multiple of dt {self.dt}"
                )
        return self

    def phase_surface_heights(self) -> list[float]:
        """World z of each phase's contact surface (``PhaseSpec.surface_height`` or the task's)."""
        return [
            self.surface_height if phase.surface_height is None else phase.surface_height
            for phase in self.phases
        ]

    @property
    def knots_per_phase(self) -> list[int]:
        return [round((end - start) / self.dt) for start, end in itertools.pairwise(self.switching_times)]

    def to_yaml(self, header: str = "") -> str:
        text = yaml.safe_dump(
            self.model_dump(mode="json"), sort_keys=False, default_flow_style=None, width=110
        )
        lines = "".join(f"# {line}\n" if line else "#\n" for line in header.splitlines())
        return lines + text
