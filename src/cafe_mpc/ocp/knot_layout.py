"""Where each term of a whole-body knot lives in its stacked arrays: frozen layouts built once per prototype.

A ``WholeBodyKnot`` evaluates its cost (18) and its inequality constraints (26), (27) in one compiled pass
over two stacked vectors (``cafe_mpc.ocp.kernels``):

* the residual ``r`` with weights ``w``: the state error (``ndx`` rows), then 3 rows per tracked swing-foot
  position, 3 per tracked swing-foot velocity, then the torque (running knots with a torque weight only);
* the constraints ``g >= 0``: 5 friction-pyramid rows per stance foot (26), then the box rows (torque, joint
  position and joint speed limits (27), two per bounded coordinate), then the base height.

``ResidualLayout`` and ``ConstraintLayout`` record these row blocks and the index arrays the kernels read.
They are built from the robot, the stance, the weights and the constraint settings (``residual_layout``,
``constraint_layout``), once per prototype knot, and never change afterwards: every knot made from the
prototype with ``with_reference`` shares them. The index arrays stay writeable only because the compiled
kernels take plain arrays; nothing writes to them.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from cafe_mpc.config import DEFAULT_FRICTION
from cafe_mpc.config.weights import BaseError, WholeBodyWeights
from cafe_mpc.ocp.constraints import BarrierParameters, WholeBodyConstraintSettings
from cafe_mpc.robots.robot import Robot

FRICTION_ROWS = 5
"""Rows of the friction pyramid of one stance foot (26): four faces and ``f_z >= 0``."""


@dataclass(frozen=True)
class ResidualLayout:
    """Row blocks of the stacked residual ``r`` of cost (18), and which legs and rows each term uses.

    ``weights``: the weight of every row; ``position_legs``/``velocity_legs``: the swing legs whose foot
    position/velocity is tracked (a non-zero weight); ``feet_row``: the first foot row (after the ``ndx``
    state rows); ``torque_row``: the first torque row (-1: no torque term); ``nu_torque``: its rows;
    ``tracks_state``: whether any state weight is non-zero; ``base_rows``/``base_mask``: the state rows of
    the base error whose Jacobian is not the identity (6 for the tangent error, 12 for the world one).
    """

    weights: np.ndarray
    position_legs: np.ndarray
    velocity_legs: np.ndarray
    feet_row: int
    torque_row: int
    nu_torque: int
    tracks_state: bool
    base_rows: np.ndarray
    base_mask: np.ndarray

    @property
    def dim(self) -> int:
        return len(self.weights)


def residual_layout(
    robot: Robot,
    weights: WholeBodyWeights,
    stance: Sequence[bool],
    nu: int,
    base_error: BaseError,
) -> ResidualLayout:
    """The residual rows of a knot of ``robot`` in ``stance`` with ``nu`` controls (0: terminal)."""
    nv = robot.model.nv
    ndx = 2 * nv
    n_feet = len(robot.foot_frame_ids)
    swing = [leg for leg in range(n_feet) if not stance[leg]]
    position_weights = weights.foot_position_weights(n_feet).reshape(n_feet, 3)
    velocity_weights = weights.foot_velocity_weights(n_feet).reshape(n_feet, 3)
    position_legs = np.array([leg for leg in swing if np.any(position_weights[leg] > 0)], dtype=np.int64)
    velocity_legs = np.array([leg for leg in swing if np.any(velocity_weights[leg] > 0)], dtype=np.int64)
    torque_weights = weights.torque_weights(robot.nu)
    with_torque = nu > 0 and bool(np.any(torque_weights > 0))
    state_weights = weights.state_weights(robot.nu)
    pieces = [state_weights]
    pieces += [position_weights[leg] for leg in position_legs]
    pieces += [velocity_weights[leg] for leg in velocity_legs]
    if with_torque:
        pieces.append(torque_weights)
    base_rows = np.r_[0:6] if base_error == "tangent" else np.r_[0:6, nv : nv + 6]
    base_mask = np.zeros(ndx, dtype=bool)
    base_mask[base_rows] = True
    return ResidualLayout(
        weights=np.concatenate(pieces),
        position_legs=position_legs,
        velocity_legs=velocity_legs,
        feet_row=ndx,
        torque_row=ndx + 3 * (len(position_legs) + len(velocity_legs)) if with_torque else -1,
        nu_torque=nu if with_torque else 0,
        tracks_state=bool(np.any(state_weights > 0)),
        base_rows=base_rows,
        base_mask=base_mask,
    )


@dataclass(frozen=True)
class ConstraintLayout:
    """Row blocks of the stacked constraints ``g >= 0`` and their barrier parameters.

    ``n_friction`` stance feet priced by the pyramid (26) with ``friction_coefficient`` and its unilateral
    row raised to ``minimum_normal_force`` (rows ``0 .. FRICTION_ROWS n_friction``); then one box row per
    bound: ``box_on_control`` (a control or a state coordinate), ``box_index`` (the coordinate in ``u`` or
    ``x``), ``box_column`` (its tangent column),
    ``box_sign`` and ``box_offset`` (``g = sign * value + offset``); then the base height row at
    ``height_index`` (-1: none) with ``minimum_height``. ``barrier_delta``/``barrier_eps``: the relaxed
    barrier of every row.
    """

    n_friction: int
    friction_coefficient: float
    minimum_normal_force: float
    box_on_control: np.ndarray
    box_index: np.ndarray
    box_column: np.ndarray
    box_sign: np.ndarray
    box_offset: np.ndarray
    minimum_height: float
    height_index: int
    barrier_delta: np.ndarray
    barrier_eps: np.ndarray

    @property
    def dim(self) -> int:
        return len(self.barrier_delta)


def constraint_layout(
    robot: Robot,
    settings: WholeBodyConstraintSettings | None,
    stance: Sequence[bool],
    nu: int,
) -> ConstraintLayout:
    """The constraint rows of a knot of ``robot`` in ``stance`` with ``nu`` controls (0: terminal, which
    keeps only the state constraints: joint position and speed limits, base height)."""
    nq, nv = robot.model.nq, robot.model.nv
    ndx = 2 * nv
    running = nu > 0
    deltas: list[np.ndarray] = []
    epsilons: list[np.ndarray] = []
    n_friction = 0
    friction_coefficient = DEFAULT_FRICTION
    minimum_normal_force = 0.0
    n_contacts = sum(stance)
    if settings is not None and running and settings.friction_cone and n_contacts:
        n_friction = n_contacts
        friction_coefficient = float(settings.friction_coefficient)
        minimum_normal_force = float(settings.minimum_normal_force)
        deltas.append(np.full(FRICTION_ROWS * n_contacts, settings.friction_barrier.delta))
        epsilons.append(np.full(FRICTION_ROWS * n_contacts, settings.friction_barrier.eps))
    on_control, index, column, sign, offset = [], [], [], [], []

    def box(lower, upper, control: bool, coordinates, columns, barrier: BarrierParameters) -> None:
        lower, upper = np.asarray(lower, dtype=float), np.asarray(upper, dtype=float)
        if lower.shape != upper.shape or np.any(lower >= upper):
            raise ValueError("box constraint: need lower < upper element-wise")
        for bound_sign, bounds in ((-1.0, upper), (1.0, lower)):
            for i, (coordinate, tangent) in enumerate(zip(coordinates, columns, strict=True)):
                on_control.append(control)
                index.append(coordinate)
                column.append(tangent)
                sign.append(bound_sign)
                offset.append(bounds[i] if bound_sign < 0 else -bounds[i])
        deltas.append(np.full(2 * len(lower), barrier.delta))
        epsilons.append(np.full(2 * len(lower), barrier.eps))

    joints = range(6, nv)
    if settings is not None and running and settings.torque_limits:
        limits = (
            np.asarray(settings.torque_limit_values, dtype=float)
            if settings.torque_limit_values is not None
            else robot.torque_limits
        )
        box(-limits, limits, True, range(nu), range(ndx, ndx + nu), settings.torque_barrier)
    if settings is not None and settings.joint_position_limits:
        box(
            robot.position_lower,
            robot.position_upper,
            False,
            [j + 1 for j in joints],
            list(joints),
            settings.joint_position_barrier,
        )
    if settings is not None and settings.joint_velocity_limits:
        box(
            -robot.velocity_limits,
            robot.velocity_limits,
            False,
            [nq + j for j in joints],
            [nv + j for j in joints],
            settings.joint_velocity_barrier,
        )
    minimum_height, height_index = 0.0, -1
    if settings is not None and settings.minimum_base_height is not None:
        minimum_height = float(settings.minimum_base_height)
        height_index = FRICTION_ROWS * n_friction + len(index)
        deltas.append(np.array([settings.base_height_barrier.delta]))
        epsilons.append(np.array([settings.base_height_barrier.eps]))
    return ConstraintLayout(
        n_friction=n_friction,
        friction_coefficient=friction_coefficient,
        minimum_normal_force=minimum_normal_force,
        box_on_control=np.array(on_control, dtype=np.bool_),
        box_index=np.array(index, dtype=np.int64),
        box_column=np.array(column, dtype=np.int64),
        box_sign=np.array(sign, dtype=float),
        box_offset=np.array(offset, dtype=float),
        minimum_height=minimum_height,
        height_index=height_index,
        barrier_delta=np.concatenate(deltas) if deltas else np.zeros(0),
        barrier_eps=np.concatenate(epsilons) if epsilons else np.zeros(0),
    )
