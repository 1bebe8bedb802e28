"""Knot models (``ActionModel``) of the CAFE-MPC plans and the factories that build them.

* ``WholeBodyKnot``: whole-body dynamics of one contact phase (Eqs. (19)-(23)) + cost (18) + inequality
  constraints (26), (27) as relaxed-barrier costs; with ``dynamics=None`` it is a terminal model (``nu = 0``,
  no torque term, state-only constraints).
* ``SRBKnot``: SRB dynamics (29), (30) + cost (28), unconstrained; terminal without the force term.

References (design choice). Each knot owns a small mutable reference object (``WholeBodyReference`` /
``SRBReference``) in ``knot.reference``; the MPC updates it *in place* every update (``reference.set(...)``)
without rebuilding models or data. Everything heavy (dynamics, Pinocchio contact models, cost and constraint
terms, barrier stack) is shared: a factory caches one prototype knot per (stance, running/terminal, dt) and
``prototype.with_reference(reference)`` makes a knot that shares it all but the reference (a shallow copy,
a few microseconds). Data objects (``knot.create_data()``) are per knot and hold every array and the
Pinocchio ``Data``; a data object can be reused by any knot built from the same prototype.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np
import pinocchio as pin

from cafe_mpc.config import BAUMGARTE_ALPHA, SRB_DT, WHOLE_BODY_DT
from cafe_mpc.config.weights import BaseError, SRBWeights, WholeBodyWeights
from cafe_mpc.core.contacts import ContactFlags, as_contact_flags, flags_to_string, touchdown_flags
from cafe_mpc.core.interfaces import ActionData, ActionModel, IdentityReset, ResetMap
from cafe_mpc.core.kernels import same_point
from cafe_mpc.dynamics.impact import ImpactReset
from cafe_mpc.dynamics.kinematics import FootKinematics
from cafe_mpc.dynamics.multibody_state import MultibodyState
from cafe_mpc.dynamics.srb import SRBDynamics, SRBParameters, SRBState, srb_parameters
from cafe_mpc.dynamics.srb_kernels import srb_cost, srb_cost_derivatives
from cafe_mpc.dynamics.transition import ComposedReset, WholeBodyToSRB
from cafe_mpc.dynamics.whole_body import IntegrationScheme, WholeBodyDynamics
from cafe_mpc.ocp import kernels as packed
from cafe_mpc.ocp.constraints import TouchdownFootHeight, WholeBodyConstraintSettings
from cafe_mpc.ocp.kernels import same_inputs, whole_body_cost, whole_body_derivatives
from cafe_mpc.ocp.knot_layout import constraint_layout, residual_layout
from cafe_mpc.robots.robot import Robot


def _array(value, shape: tuple[int, ...], name: str) -> np.ndarray:
    array = np.asarray(value, dtype=float)
    if array.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {array.shape}")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{name} must be finite")
    return array


# --------------------------------------------------------------------------------------------------
# Whole-body knot
# --------------------------------------------------------------------------------------------------


class WholeBodyReference:
    """Mutable per-knot reference of a whole-body knot (updated in place).

    ``state``: ``x_ref = [q_ref (19, quaternion base), v_ref (18, base-frame velocities)]``;
    ``foot_positions``/``foot_velocities``: world-frame swing-foot targets (4 x 3, leg order; only swing
    feet are used); ``torque``: torque regularisation target (12, default zero); ``contact_frame``: the
    ground's frame the friction pyramid (26) is taken in (3 x 3, rows: two tangents and the normal, world;
    the identity: flat ground, the paper's pyramid about world z).
    """

    __slots__ = ("contact_frame", "foot_positions", "foot_velocities", "state", "torque")

    def __init__(
        self,
        state: np.ndarray,
        foot_positions: np.ndarray | None = None,
        foot_velocities: np.ndarray | None = None,
        torque: np.ndarray | None = None,
    ) -> None:
        state = np.asarray(state, dtype=float)
        self.state = _array(state, state.shape, "reference state").copy()
        if self.state.ndim != 1:
            raise ValueError("reference state must be a vector")
        self.foot_positions = np.zeros((4, 3))
        self.foot_velocities = np.zeros((4, 3))
        self.torque = np.zeros(12)
        self.contact_frame = np.eye(3)
        self.set(foot_positions=foot_positions, foot_velocities=foot_velocities, torque=torque)

    def set(
        self,
        state: np.ndarray | None = None,
        foot_positions: np.ndarray | None = None,
        foot_velocities: np.ndarray | None = None,
        torque: np.ndarray | None = None,
    ) -> None:
        """Overwrite the given parts in place (shapes are checked)."""
        if state is not None:
            self.state[:] = _array(state, self.state.shape, "reference state")
        if foot_positions is not None:
            self.foot_positions[:] = _array(foot_positions, (4, 3), "reference foot positions")
        if foot_velocities is not None:
            self.foot_velocities[:] = _array(foot_velocities, (4, 3), "reference foot velocities")
        if torque is not None:
            self.torque[:] = _array(torque, (12,), "reference torque")

    def copy(self) -> WholeBodyReference:
        reference = WholeBodyReference(self.state, self.foot_positions, self.foot_velocities, self.torque)
        reference.contact_frame[:] = self.contact_frame
        return reference

    @classmethod
    def of_rows(
        cls,
        state: np.ndarray,
        foot_positions: np.ndarray,
        foot_velocities: np.ndarray,
        torque: np.ndarray,
        contact_frame: np.ndarray | None = None,
    ) -> WholeBodyReference:
        """A reference whose parts *are* the given arrays (no copies): rows of a caller's stacked storage,
        so that one write of the stack updates every knot reading it (``contact_frame``: one array shared
        by every knot; None: a frame of its own, the identity). Shapes and dtype are checked here, once,
        because the rows are then written without ``set``'s checks."""
        if contact_frame is None:
            contact_frame = np.eye(3)
        parts = (
            ("reference state", state, None),
            ("reference foot positions", foot_positions, (4, 3)),
            ("reference foot velocities", foot_velocities, (4, 3)),
            ("reference torque", torque, (12,)),
            ("reference contact frame", contact_frame, (3, 3)),
        )
        for name, array, shape in parts:
            if not isinstance(array, np.ndarray) or array.dtype != np.float64:
                raise ValueError(f"{name} must be a float64 array")
            if shape is not None and array.shape != shape:
                raise ValueError(f"{name} must have shape {shape}, got {array.shape}")
        if state.ndim != 1:
            raise ValueError("reference state must be a vector")
        reference = cls.__new__(cls)
        reference.state = state
        reference.foot_positions = foot_positions
        reference.foot_velocities = foot_velocities
        reference.torque = torque
        reference.contact_frame = contact_frame
        return reference


class WholeBodyKnotData(ActionData):
    """Per-knot workspace: dynamics data (its ``x_next``/``Fx``/``Fu`` are this data's), foot kinematics, and
    the stacked residual, constraint values and barrier derivatives of the fused evaluation (views of one
    buffer, ``work``, that the compiled calls take whole)."""

    def __init__(self, model: WholeBodyKnot) -> None:
        super().__init__(model)
        ndx, nu = model.state.ndx, model.nu
        self.dynamics = (
            model.dynamics.create_data(force_derivatives=model.n_friction > 0)
            if model.dynamics is not None
            else None
        )
        if self.dynamics is not None:
            self.x_next = self.dynamics.x_next
            self.Fx = self.dynamics.Fx
            self.Fu = self.dynamics.Fu
            self.dforces_dx = self.dynamics.dforces_dx
            self.dforces_du = self.dynamics.dforces_du
            self.stance_forces = self.dynamics.forces
        else:
            self.dforces_dx = np.zeros((0, ndx))
            self.dforces_du = np.zeros((0, nu))
            self.stance_forces = np.zeros(0)
        self.kinematics = model.kinematics.create_data()
        self.work = np.zeros(model._work_size)
        section = model._work_section
        self.forces = section(self.work, packed.FORCES).reshape(model.n_feet, 3)
        """World-frame ground reaction force of every foot (zero on swing feet) at the last ``calc``."""
        self.base_rotation = section(self.work, packed.BASE_ROTATION).reshape(3, 3)
        self.base_rotation[:] = np.eye(3)
        self.rotation_error = section(self.work, packed.ROTATION_ERROR)
        """``[log3(R_ref' R), angle]`` of the ``"world"`` base error."""
        self.r = section(self.work, packed.R)
        """Stacked residual: state (``ndx``), swing-foot positions and velocities (3 each), torque."""
        self.wr = section(self.work, packed.WR)
        self.g = section(self.work, packed.G)
        """Stacked constraint values ``g >= 0``: friction rows, box rows, base height."""
        self.d1 = section(self.work, packed.D1)
        self.d2 = section(self.work, packed.D2)
        nb = len(model.base_rows)
        self.base_jacobian = section(self.work, packed.BASE_JACOBIAN).reshape(nb, nb)
        if nb == 12:
            self.base_jacobian[9:12, 9:12] = np.eye(3)
        # Derivatives over [x | u]; Lx, Lu, Lxx, Luu, Lux are views of these (the solver rebinds all of them
        # to its stacked arrays, keeping the same relation).
        self.gradient = np.zeros(ndx + nu)
        self.hessian = np.zeros((ndx + nu, ndx + nu))
        self.Lx = self.gradient[:ndx]
        self.Lu = self.gradient[ndx:]
        self.Lxx = self.hessian[:ndx, :ndx]
        self.Luu = self.hessian[ndx:, ndx:]
        self.Lux = self.hessian[ndx:, :ndx]
        self.values = section(self.work, packed.VALUES)
        self.last_x = section(self.work, packed.LAST_X)
        self.last_x[:] = np.nan
        self.last_u = section(self.work, packed.LAST_U)
        self.last_u[:] = np.nan
        self.layout = model.layout


class WholeBodyKnot(ActionModel):
    """Whole-body knot: ``x+ = f(x, tau)`` (Eqs. (19)-(23)), cost (18) and barrier-penalised (26), (27).

    One fused evaluation: one dynamics call, one set of foot-kinematics calls, then every cost residual and
    constraint value stacked into ``r`` (weights ``w``) and ``g`` and priced in one compiled pass; the
    derivatives are the Gauss-Newton ``J' W r`` and ``J' W J`` (plus the barrier's ``G' B'``, ``G' B'' G``)
    formed in one compiled pass as well (``cafe_mpc.ocp.kernels``).

    Args:
        robot: the robot.
        dynamics: the phase dynamics (sets ``nu`` and the time step), or ``None`` for a terminal knot.
        weights: the cost weights of Eq. (18) (``WholeBodyWeights``); the torque term only on running knots.
        constraints: which inequalities are priced (``None``: none). Terminal knots keep only the state ones
            (joint position and speed limits, base height).
        reference: this knot's mutable reference.
        stance: stance flags of a terminal knot (a running knot takes the dynamics').
        base_error: ``"tangent"`` or ``"world"`` base residual (see ``BaseError``).
    """

    def __init__(
        self,
        robot: Robot,
        dynamics: WholeBodyDynamics | None,
        weights: WholeBodyWeights,
        constraints: WholeBodyConstraintSettings | None,
        reference: WholeBodyReference,
        stance: Sequence[bool] | None = None,
        base_error: BaseError = "tangent",
    ) -> None:
        if base_error not in ("tangent", "world"):
            raise ValueError(f"base_error must be 'tangent' or 'world', got {base_error!r}")
        self.robot = robot
        self.model = robot.model
        self.dynamics = dynamics
        self.state = dynamics.state if dynamics is not None else MultibodyState(robot.model)
        self.next_state = self.state
        self.nu = dynamics.nu if dynamics is not None else 0
        self.cost_scale = dynamics.dt if dynamics is not None else 1.0
        if dynamics is not None:
            self.stance = dynamics.stance
            if stance is not None and as_contact_flags(stance) != dynamics.stance:
                raise ValueError("stance flags differ from the dynamics' stance flags")
        else:
            if stance is None:
                raise ValueError("a terminal whole-body knot needs its phase's stance flags")
            self.stance = as_contact_flags(stance)
        self.weights = weights
        self.base_error = base_error
        nq, nv = robot.model.nq, robot.model.nv
        self.n_feet = len(robot.foot_frame_ids)
        residual = residual_layout(robot, weights, self.stance, self.nu, base_error)
        limits = constraint_layout(robot, constraints, self.stance, self.nu)
        self.residual_layout, self.constraint_layout = residual, limits
        # The layouts' fields as plain attributes: the compiled calls read them on every evaluation.
        self.residual_weights = residual.weights
        self.residual_dim = residual.dim
        self.position_legs, self.velocity_legs = residual.position_legs, residual.velocity_legs
        self.feet_row, self.torque_row, self.nu_torque = (
            residual.feet_row,
            residual.torque_row,
            residual.nu_torque,
        )
        self.tracks_state = residual.tracks_state
        self.base_rows, self.base_mask = residual.base_rows, residual.base_mask
        self.kinematics = FootKinematics(robot, self.position_legs.tolist(), self.velocity_legs.tolist())
        self.n_friction, self.friction_coefficient = limits.n_friction, limits.friction_coefficient
        self.minimum_normal_force = limits.minimum_normal_force
        self.box_on_control, self.box_index, self.box_column = (
            limits.box_on_control,
            limits.box_index,
            limits.box_column,
        )
        self.box_sign, self.box_offset = limits.box_sign, limits.box_offset
        self.minimum_height, self.height_index = limits.minimum_height, limits.height_index
        self.barrier_delta, self.barrier_eps = limits.barrier_delta, limits.barrier_eps
        self.constraint_dim = limits.dim
        self._stance_legs = np.array([leg for leg in range(self.n_feet) if self.stance[leg]], dtype=np.int64)
        self._nq, self._nv = nq, nv
        self._x_shape, self._u_shape = (nq + nv,), (self.nu,)
        self._has_kinematics = not self.kinematics.empty
        self._has_velocity_kinematics = bool(self.kinematics.velocity_legs)
        self._pack_parameters()
        self.layout = object()
        """Identity token shared by every knot made from this one with ``with_reference``: a data object
        created by one of them can be reused by any other (``data.layout is knot.layout``)."""
        self.reference = self._check_reference(reference)

    def _check_reference(self, reference: WholeBodyReference) -> WholeBodyReference:
        if not isinstance(reference, WholeBodyReference):
            raise ValueError(f"reference must be a WholeBodyReference, got {type(reference).__name__}")
        if reference.state.shape != (self.state.nx,):
            raise ValueError(
                f"reference state must have shape ({self.state.nx},), got {reference.state.shape}"
            )
        return reference

    def __repr__(self) -> str:
        kind = f"dt={self.cost_scale}" if self.dynamics is not None else "terminal"
        return f"WholeBodyKnot({flags_to_string(self.stance)}, {kind})"

    @property
    def is_terminal(self) -> bool:
        return self.dynamics is None

    def with_reference(self, reference: WholeBodyReference) -> WholeBodyKnot:
        """A knot sharing everything with this one except the reference."""
        knot = copy.copy(self)
        knot.reference = self._check_reference(reference)
        return knot

    def create_data(self) -> WholeBodyKnotData:
        return WholeBodyKnotData(self)

    def _check_sizes(self, x: np.ndarray, u: np.ndarray) -> None:
        """The ``ValueError`` naming the wrong size (``calc`` calls it on an unexpected shape)."""
        if x.shape != (self.state.nx,):
            raise ValueError(f"{self!r}: x must have shape ({self.state.nx},), got {x.shape}")
        if u.shape != (self.nu,):
            raise ValueError(f"{self!r}: u must have shape ({self.nu},), got {u.shape}")

    def _pack_parameters(self) -> None:
        """The knot's constants in two arrays and the layout of its data's workspace (``ocp.kernels``: the
        header, the sections), for the compiled calls."""
        nq, nv = self._nq, self._nv
        if not self.tracks_state:
            base_error = packed.NO_STATE
        elif self.base_error == "world":
            base_error = packed.WORLD
        elif self.state.free_flyer_root:
            base_error = packed.TANGENT_FREE_FLYER
        else:
            base_error = packed.TANGENT_GENERIC
        self._generic_base_error = base_error == packed.TANGENT_GENERIC
        velocity_rows_from = nv if self.base_error == "tangent" else nv + 3
        header = np.zeros(packed.HEADER, dtype=np.int64)
        header[packed.FEET_ROW] = self.feet_row
        header[packed.TORQUE_ROW] = self.torque_row
        header[packed.N_FRICTION] = self.n_friction
        header[packed.HEIGHT_INDEX] = self.height_index
        header[packed.VELOCITY_ROWS_FROM] = velocity_rows_from if self.tracks_state else 2 * nv
        header[packed.NQ], header[packed.NV] = nq, nv
        header[packed.NU_TORQUE] = self.nu_torque
        header[packed.BASE_ERROR] = base_error
        integers = packed.pack_sections(
            header,
            packed.INT_SECTIONS,
            [
                self.position_legs,
                self.velocity_legs,
                self.box_on_control,
                self.box_index,
                self.box_column,
                self._stance_legs,
                self.base_rows,
                self.base_mask,
            ],
            np.int64,
        )
        floats = packed.pack_sections(
            header,
            packed.FLOAT_SECTIONS,
            [self.residual_weights, self.box_sign, self.box_offset, self.barrier_delta, self.barrier_eps],
            float,
        )
        nb = len(self.base_rows)
        sizes = [self.residual_dim] * 2 + [self.constraint_dim] * 3
        sizes += [2, nq + nv, self.nu, 3 * self.n_feet, 9, 4, nb * nb]
        self._work_size = int(np.sum(sizes))
        packed.pack_sections(header, packed.WORK_SECTIONS, [np.zeros(size) for size in sizes], float)
        self._integers = np.concatenate([header, integers])
        self._floats = np.concatenate(
            [
                [self.friction_coefficient, self.minimum_height, self.cost_scale, self.minimum_normal_force],
                floats,
            ]
        )

    def _work_section(self, work: np.ndarray, section: int) -> np.ndarray:
        """The view of a data's workspace ``work`` holding ``section`` (``ocp.kernels.R`` etc.)."""
        first = self._integers[packed.WORK_SECTIONS + section]
        return work[first : self._integers[packed.WORK_SECTIONS + section + 1]]

    def calc(self, data: WholeBodyKnotData, x: np.ndarray, u: np.ndarray) -> None:
        if x.shape != self._x_shape or u.shape != self._u_shape:
            self._check_sizes(x, u)
        if self.dynamics is not None:
            self.dynamics.calc(data.dynamics, x, u)
        kinematics = data.kinematics
        if self._has_kinematics:
            nq = self._nq
            self.kinematics.calc(kinematics, x[:nq], x[nq:])
        reference = self.reference
        if self._generic_base_error:
            nq = self._nq
            data.r[: self._nv] = pin.difference(self.model, reference.state[:nq], x[:nq])
        data.cost, data.constraint_violation = whole_body_cost(
            x,
            u,
            reference.state,
            reference.foot_positions,
            reference.foot_velocities,
            reference.torque,
            self._integers,
            self._floats,
            data.work,
            data.stance_forces,
            kinematics.positions,
            kinematics.velocities,
            reference.contact_frame,
        )

    def calc_diff(self, data: WholeBodyKnotData, x: np.ndarray, u: np.ndarray) -> None:
        if not same_inputs(x, u, data.last_x, data.last_u):
            self.calc(data, x, u)  # keep the forward pass consistent with (x, u)
        if self.dynamics is not None:
            self.dynamics.calc_diff(data.dynamics, x, u)
        kinematics = data.kinematics
        if self._has_velocity_kinematics:
            nq = self._nq
            self.kinematics.calc_diff(kinematics, x[:nq], x[nq:])
        reference = self.reference
        if self._generic_base_error:
            nq = self._nq
            data.base_jacobian[:, :] = pin.dDifference(
                self.model, reference.state[:nq], x[:nq], pin.ArgumentPosition.ARG1
            )[:6, :6]
        whole_body_derivatives(
            data.gradient,
            data.hessian,
            x,
            reference.state,
            self._integers,
            self._floats,
            data.work,
            kinematics.position_jacobians,
            kinematics.velocity_dq,
            data.dforces_dx,
            data.dforces_du,
            reference.contact_frame,
        )


# --------------------------------------------------------------------------------------------------
# SRB knot
# --------------------------------------------------------------------------------------------------


class SRBReference:
    """Mutable per-knot reference and parameters of an SRB knot (updated in place).

    ``state``: ``[c, quat, c_dot (world), omega (body)]`` (13); ``foot_positions``: world foot positions
    (4 x 3, Raibert footholds; parameters of the dynamics); ``contacts``: stance flags as floats (4);
    ``forces``: GRF regularisation target (12), by default ``weight / n_stance`` vertical on stance feet and
    zero on swing feet (Eq. (28)).
    """

    __slots__ = ("contacts", "foot_positions", "forces", "state", "weight")

    def __init__(
        self,
        state: np.ndarray,
        foot_positions: np.ndarray,
        contacts: Sequence[bool],
        weight: float,
        forces: np.ndarray | None = None,
    ) -> None:
        if not (math.isfinite(weight) and weight > 0):
            raise ValueError(f"weight (m g) must be positive, got {weight}")
        self.weight = float(weight)
        self.state = _array(state, (13,), "SRB reference state").copy()
        self.foot_positions = _array(foot_positions, (4, 3), "SRB foot positions").copy()
        self.contacts = np.zeros(4)
        self.forces = np.zeros(12)
        self.set(contacts=contacts, forces=forces)

    def set(
        self,
        state: np.ndarray | None = None,
        foot_positions: np.ndarray | None = None,
        contacts: Sequence[bool] | None = None,
        forces: np.ndarray | None = None,
    ) -> None:
        """Overwrite the given parts in place. New ``contacts`` without ``forces`` reset the force target to
        the weight split over the stance feet."""
        if state is not None:
            self.state[:] = _array(state, (13,), "SRB reference state")
        if foot_positions is not None:
            self.foot_positions[:] = _array(foot_positions, (4, 3), "SRB foot positions")
        if contacts is not None:
            self.contacts[:] = as_contact_flags(contacts, "SRB contact flags")
            if forces is None:
                self.forces[:] = weight_split_forces(self.contacts, self.weight)
        if forces is not None:
            self.forces[:] = _array(forces, (12,), "SRB reference forces")

    @classmethod
    def of_rows(
        cls,
        state: np.ndarray,
        foot_positions: np.ndarray,
        contacts: np.ndarray,
        forces: np.ndarray,
        weight: float,
    ) -> SRBReference:
        """A reference whose parts *are* the given arrays (no copies): rows of a caller's stacked storage,
        written in place by its owner. Shapes and dtype are checked here, once."""
        if not (math.isfinite(weight) and weight > 0):
            raise ValueError(f"weight (m g) must be positive, got {weight}")
        parts = (
            ("SRB reference state", state, (13,)),
            ("SRB foot positions", foot_positions, (4, 3)),
            ("SRB contact flags", contacts, (4,)),
            ("SRB reference forces", forces, (12,)),
        )
        for name, array, shape in parts:
            if not isinstance(array, np.ndarray) or array.dtype != np.float64 or array.shape != shape:
                raise ValueError(f"{name} must be a float64 array of shape {shape}")
        reference = cls.__new__(cls)
        reference.weight = float(weight)
        reference.state = state
        reference.foot_positions = foot_positions
        reference.contacts = contacts
        reference.forces = forces
        return reference


def weight_split_forces(contacts: Sequence[float], weight: float) -> np.ndarray:
    """``[0, 0, weight / n_stance]`` on each stance foot, zero on swing feet (12)."""
    contacts = np.asarray(contacts, dtype=float)
    forces = np.zeros((4, 3))
    n_stance = float(contacts.sum())
    if n_stance > 0:
        forces[:, 2] = contacts * weight / n_stance
    return forces.reshape(-1)


class SRBKnotData(ActionData):
    def __init__(self, model: SRBKnot) -> None:
        super().__init__(model)
        self.dynamics = model.dynamics.create_data() if model.dynamics is not None else None
        if self.dynamics is not None:
            self.x_next = self.dynamics.x_next
            self.Fx = self.dynamics.Fx
            self.Fu = self.dynamics.Fu
        self.r = np.zeros(12)
        self.weighted_r = np.zeros(12)
        self.rotation_error = np.eye(3)
        self.force_residual = np.zeros(model.nu)
        self.rotation_angle = np.zeros(1)
        self.last_x = np.full(13, np.nan)
        self.last_u = np.full(model.nu, np.nan)
        self.layout = model.layout


class SRBKnot(ActionModel):
    """SRB knot: dynamics (29), (30), cost (28) (base tracking + GRF regularisation), no constraints.

    The tracking residual is ``SRBState.difference(x_ref, x)`` = ``[c - c_ref, log3(R_ref' R), c_dot -
    c_dot_ref, omega - omega_ref]``; the force residual ``u - forces_ref``. ``dynamics=None``: terminal knot
    (``nu = 0``, tracking only, not scaled by a time step).
    """

    def __init__(self, dynamics: SRBDynamics | None, weights: SRBWeights, reference: SRBReference) -> None:
        self.dynamics = dynamics
        self.state = SRBState()
        self.next_state = self.state
        reference = self._check_reference(reference)
        n_feet = len(reference.foot_positions)
        self.nu = 3 * n_feet if dynamics is not None else 0
        self.cost_scale = dynamics.dt if dynamics is not None else 1.0
        self.weights = weights
        self.state_weights = weights.state_weights()
        self.force_weights = weights.force_weights(n_feet) if dynamics is not None else np.zeros(3 * n_feet)
        self._diagonal = np.arange(12)
        self.layout = object()
        """Shared by knots made with ``with_reference``; data with the same layout is interchangeable."""
        self.reference = reference

    @staticmethod
    def _check_reference(reference: SRBReference) -> SRBReference:
        if not isinstance(reference, SRBReference):
            raise ValueError(f"reference must be an SRBReference, got {type(reference).__name__}")
        return reference

    def __repr__(self) -> str:
        return f"SRBKnot({'dt=' + str(self.cost_scale) if self.dynamics is not None else 'terminal'})"

    def with_reference(self, reference: SRBReference) -> SRBKnot:
        knot = copy.copy(self)
        knot.reference = self._check_reference(reference)
        return knot

    def create_data(self) -> SRBKnotData:
        return SRBKnotData(self)

    def calc(self, data: SRBKnotData, x: np.ndarray, u: np.ndarray) -> None:
        if x.shape != (13,) or u.shape != (self.nu,):
            raise ValueError(
                f"{self!r}: x must have shape (13,) and u ({self.nu},), got {x.shape}, {u.shape}"
            )
        reference = self.reference
        if self.dynamics is not None:
            self.dynamics.calc(data.dynamics, x, u, reference.foot_positions, reference.contacts)
        data.cost = srb_cost(
            x,
            u,
            reference.state,
            reference.forces,
            self.state_weights,
            self.force_weights,
            self.cost_scale,
            data.r,
            data.weighted_r,
            data.force_residual,
            data.rotation_angle,
        )
        data.constraint_violation = 0.0
        data.last_x[:] = x
        data.last_u[:] = u

    def calc_diff(self, data: SRBKnotData, x: np.ndarray, u: np.ndarray) -> None:
        if not (same_point(x, data.last_x) and same_point(u, data.last_u)):
            self.calc(data, x, u)
        reference = self.reference
        if self.dynamics is not None:
            self.dynamics.calc_diff(data.dynamics, x, u, reference.foot_positions, reference.contacts)
        srb_cost_derivatives(
            data.r,
            data.weighted_r,
            data.force_residual,
            self.state_weights,
            self.force_weights,
            float(data.rotation_angle[0]),
            self.cost_scale,
            data.Lx,
            data.Lu,
            data.Lxx,
            data.Luu,
            data.Lux,
        )


# --------------------------------------------------------------------------------------------------
# Factories
# --------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class WholeBodySettings:
    """Everything that configures whole-body knots (settings facts defaults)."""

    dt: float = WHOLE_BODY_DT
    baumgarte_alpha: float = BAUMGARTE_ALPHA
    integration: IntegrationScheme = "explicit"
    contact_damping: float = 0.0
    running_weights: WholeBodyWeights = field(default_factory=WholeBodyWeights.regular_running)
    terminal_weights: WholeBodyWeights = field(default_factory=WholeBodyWeights.regular_terminal)
    constraints: WholeBodyConstraintSettings = field(default_factory=WholeBodyConstraintSettings)
    terminal_constraints: bool = True
    """State-only inequalities (joint limits, joint speeds, base height) also on terminal knots."""
    base_error: BaseError = "tangent"
    """Base residual of the state-tracking cost (see ``StateTrackingCost``)."""
    impact_on_all_stance_feet: bool = True
    """Impact map constrains every post-switch stance foot (True) or only the new touchdowns (False)."""


class WholeBodyModelFactory:
    """Builds whole-body knots, reset maps, touchdown constraints and the WB -> SRB transition for a robot,
    sharing dynamics and term objects between knots (cached per stance and time step)."""

    def __init__(self, robot: Robot, settings: WholeBodySettings | None = None) -> None:
        self.robot = robot
        self.settings = settings or WholeBodySettings()
        self.state = MultibodyState(robot.model)
        self._dynamics: dict[tuple, WholeBodyDynamics] = {}
        self._prototypes: dict[tuple, WholeBodyKnot] = {}
        self._standing_feet = robot.foot_positions(robot.q_standing)

    def default_reference(self, state: np.ndarray | None = None) -> WholeBodyReference:
        """Standing state and standing foot positions, zero foot velocities and torque target."""
        x_ref = self.robot.x_standing if state is None else self.state.check(state, "reference state")
        return WholeBodyReference(x_ref, self._standing_feet)

    def dynamics(self, stance: Sequence[bool], dt: float | None = None) -> WholeBodyDynamics:
        stance = as_contact_flags(stance, "stance flags")
        dt = self.settings.dt if dt is None else float(dt)
        key = (stance, dt)
        if key not in self._dynamics:
            self._dynamics[key] = WholeBodyDynamics(
                self.robot,
                stance,
                dt,
                baumgarte_alpha=self.settings.baumgarte_alpha,
                integration=self.settings.integration,
                damping=self.settings.contact_damping,
            )
        return self._dynamics[key]

    def _prototype(self, stance: ContactFlags, running: bool, dt: float | None) -> WholeBodyKnot:
        key = (stance, running, dt)
        if key not in self._prototypes:
            settings = self.settings
            weights = settings.running_weights if running else settings.terminal_weights
            constraints = settings.constraints if running or settings.terminal_constraints else None
            dynamics = self.dynamics(stance, dt) if running else None
            self._prototypes[key] = WholeBodyKnot(
                self.robot,
                dynamics,
                weights,
                constraints,
                self.default_reference(),
                stance=stance,
                base_error=settings.base_error,
            )
        return self._prototypes[key]

    def running_knot(
        self, stance: Sequence[bool], reference: WholeBodyReference | None = None, dt: float | None = None
    ) -> WholeBodyKnot:
        """A running knot of a phase with these stance flags (``dt`` defaults to the settings')."""
        stance = as_contact_flags(stance, "stance flags")
        dt = self.settings.dt if dt is None else float(dt)
        return self._prototype(stance, True, dt).with_reference(reference or self.default_reference())

    def terminal_knot(
        self, stance: Sequence[bool], reference: WholeBodyReference | None = None
    ) -> WholeBodyKnot:
        """The terminal knot of a phase with these stance flags (``nu = 0``)."""
        stance = as_contact_flags(stance, "stance flags")
        return self._prototype(stance, False, None).with_reference(reference or self.default_reference())

    def reset_map(self, stance_before: Sequence[bool], stance_after: Sequence[bool]) -> ResetMap:
        """Impact map (22), (24) when a foot touches down, identity otherwise (take-off, Sec. IV-A-2)."""
        before = as_contact_flags(stance_before, "stance before")
        after = as_contact_flags(stance_after, "stance after")
        touchdown = touchdown_flags(before, after)
        if not any(touchdown):
            return IdentityReset(self.state)
        impact_feet = after if self.settings.impact_on_all_stance_feet else touchdown
        return ImpactReset(self.robot, impact_feet, damping=self.settings.contact_damping)

    def touchdown_constraint(
        self, stance_before: Sequence[bool], stance_after: Sequence[bool], surface_height: float = 0.0
    ) -> TouchdownFootHeight | None:
        """Eq. (25) on the feet touching down at the switch (``None`` when none does)."""
        touchdown = touchdown_flags(stance_before, stance_after)
        if not any(touchdown):
            return None
        return TouchdownFootHeight(self.robot, touchdown, surface_height)

    def transition_to_srb(
        self, stance_before: Sequence[bool], stance_after: Sequence[bool], srb_state: SRBState | None = None
    ) -> ResetMap:
        """Eq. (31): the reset map of the switch (impact or identity) followed by the projection (32)."""
        projection = WholeBodyToSRB(self.state, srb_state)
        reset = self.reset_map(stance_before, stance_after)
        if isinstance(reset, IdentityReset):
            return projection
        return ComposedReset(reset, projection)


@dataclass(frozen=True)
class SRBSettings:
    """Configuration of SRB knots (docs/settings.md). ``parameters``: the SRB's mass and inertia; ``None``:
    from the robot given to ``SRBModelFactory`` (``dynamics.srb.srb_parameters``: legs lumped, rotors
    included); one of the two is needed."""

    dt: float = SRB_DT
    parameters: SRBParameters | None = None
    running_weights: SRBWeights = field(default_factory=SRBWeights.regular_running)
    terminal_weights: SRBWeights = field(default_factory=SRBWeights.regular_terminal)


class SRBModelFactory:
    """Builds SRB knots sharing one ``SRBDynamics`` per time step (one prototype per running/terminal and
    ``dt``; knots differ only by their reference)."""

    def __init__(self, settings: SRBSettings | None = None, robot: Robot | None = None) -> None:
        settings = settings or SRBSettings()
        if settings.parameters is None:
            if robot is None:
                raise ValueError("SRBModelFactory needs the robot or SRBSettings.parameters (mass, inertia)")
            settings = replace(settings, parameters=srb_parameters(robot))
        self.settings = settings
        assert settings.parameters is not None
        self.n_feet = settings.parameters.n_feet
        self.state = SRBState()
        self._dynamics: dict[float, SRBDynamics] = {}
        self._prototypes: dict[tuple, SRBKnot] = {}
        parameters = self.settings.parameters
        self.weight = parameters.mass * parameters.gravity

    def dynamics(self, dt: float | None = None) -> SRBDynamics:
        dt = self.settings.dt if dt is None else float(dt)
        if dt not in self._dynamics:
            self._dynamics[dt] = SRBDynamics(self.settings.parameters, dt)
        return self._dynamics[dt]

    def reference(
        self, state: np.ndarray, foot_positions: np.ndarray, contacts: Sequence[bool]
    ) -> SRBReference:
        return SRBReference(state, foot_positions, contacts, self.weight)

    def _default_reference(self) -> SRBReference:
        return SRBReference(self.state.zero(), np.zeros((self.n_feet, 3)), (True,) * self.n_feet, self.weight)

    def running_knot(self, reference: SRBReference, dt: float | None = None) -> SRBKnot:
        dt = self.settings.dt if dt is None else float(dt)
        key = ("running", dt)
        if key not in self._prototypes:
            self._prototypes[key] = SRBKnot(
                self.dynamics(dt), self.settings.running_weights, self._default_reference()
            )
        return self._prototypes[key].with_reference(reference)

    def terminal_knot(self, reference: SRBReference) -> SRBKnot:
        key = ("terminal",)
        if key not in self._prototypes:
            self._prototypes[key] = SRBKnot(None, self.settings.terminal_weights, self._default_reference())
        return self._prototypes[key].with_reference(reference)
