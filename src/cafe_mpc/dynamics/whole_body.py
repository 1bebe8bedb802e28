"""Whole-body phase dynamics: KKT contact dynamics + Euler step on the state manifold (paper Eqs. (19)-(23)).

For a fixed set of stance feet, the continuous dynamics are the KKT system (21)

    [M   Jc^T] [ qdd ]   [ B^T tau - n(q, v)         ]
    [Jc  0   ] [ -Fc ] = [ -Jc_dot v - alpha Jc v    ]

i.e. the equations of motion (19) with the non-slip constraint at the acceleration level with first-order
Baumgarte stabilisation (20), ``Jc qdd + Jc_dot v = -alpha Jc v``. Contacts are points at the foot frames
with ``LOCAL_WORLD_ALIGNED`` Jacobians, so ``Fc`` stacks world-frame ground reaction forces in leg order
(stance feet only). With no stance foot the dynamics are the free-floating ABA.

The solution and its analytical derivatives come from Pinocchio: ``constraintDynamics`` (exact Cholesky of
the KKT system; proximal iterations only with ``damping > 0``) and ``computeConstraintDynamicsDerivatives``
(``d qdd / d(q, v, tau)`` and ``d Fc / d(q, v, tau)``), or ``aba`` and ``computeABADerivatives`` in flight.
No finite differences. ``calc_diff`` reuses the forward pass of ``calc`` stored in the data's Pinocchio
``Data``, so it must follow ``calc`` with the same ``(x, u)`` (``WholeBodyKnot`` guarantees it).

Time stepping (23) on the manifold, ``dt`` fixed per model:

* ``"explicit"`` (paper):  ``q+ = q ⊕ v dt``,          ``v+ = v + qdd dt``;
* ``"semi_implicit"`` (Crocoddyl's ``IntegratedActionModelEuler``): ``q+ = q ⊕ (v + qdd dt) dt``;
* ``"explicit_world"`` (free-flyer robots): Eq. (23)'s explicit step but with the base's linear velocity
  stepped in the world frame (``kernels.world_velocity_euler_step``): ``p+ = p + R v dt``, ``R+ = R exp3(w
  dt)``, ``v+ = exp3(-w dt) (v + (a_lin + w x v) dt)``. Eq. (23) steps the body-frame velocity ``v`` by
  Pinocchio's spatial acceleration, which under fast rotation inflates ``|v|`` by ``sqrt(1 + (w dt)^2)`` a
  step (a body spinning at 11 rad/s with dt = 0.01 s gains 0.6 m/s of horizontal speed in 0.45 s of
  flight); this scheme keeps a free-falling body's horizontal velocity exactly. Joints as Eq. (23).
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
import pinocchio as pin

from cafe_mpc.config import BAUMGARTE_ALPHA
from cafe_mpc.core.contacts import as_contact_flags, flags_to_string
from cafe_mpc.dynamics.kernels import (
    copy_force_derivatives,
    euler_step,
    euler_step_jacobians,
    free_flyer_euler_step_jacobians,
    world_velocity_euler_step,
    world_velocity_euler_step_jacobians,
)
from cafe_mpc.dynamics.multibody_state import MultibodyState
from cafe_mpc.robots.robot import Robot

IntegrationScheme = Literal["explicit", "semi_implicit", "explicit_world"]
INTEGRATION_SCHEMES: tuple[str, ...] = ("explicit", "semi_implicit", "explicit_world")


class ContactDynamicsError(FloatingPointError):
    """The contact dynamics produced a non-finite result (non-finite input or a singular KKT system)."""


def foot_contact_models(
    robot: Robot, stance: tuple[bool, ...], baumgarte_alpha: float
) -> pin.StdVec_RigidConstraintModel:
    """Pinocchio point-contact models (3D, ``LOCAL_WORLD_ALIGNED``) on the stance feet, in leg order,
    with the first-order Baumgarte gain ``Kd = alpha`` (Eq. (20)) and no position feedback."""
    model = robot.model
    contact_models = pin.StdVec_RigidConstraintModel()
    for leg, frame_id in enumerate(robot.foot_frame_ids):
        if not stance[leg]:
            continue
        frame = model.frames[frame_id]
        contact = pin.RigidConstraintModel(
            pin.ContactType.CONTACT_3D,
            model,
            frame.parentJoint,
            frame.placement,
            pin.ReferenceFrame.LOCAL_WORLD_ALIGNED,
        )
        contact.name = robot.leg_names[leg]
        contact.setBaumgarteCorrectorParameters(pin.BaumgarteCorrectorParameters(0.0, float(baumgarte_alpha)))
        contact_models.append(contact)
    return contact_models


def proximal_settings(damping: float) -> pin.ProximalSettings:
    """Exact KKT solve (one iteration, no regularisation) when ``damping == 0``; otherwise proximal
    iterations with regularisation ``mu = damping`` (converges to the exact solution for full-rank contact
    Jacobians and stays finite for rank-deficient ones). One object per data: Pinocchio writes into it."""
    if damping == 0.0:
        return pin.ProximalSettings(1e-12, 0.0, 1)
    return pin.ProximalSettings(1e-12, float(damping), 50)


class WholeBodyDynamicsData:
    """Per-knot workspace of ``WholeBodyDynamics`` (one Pinocchio ``Data`` each; created once, reused)."""

    def __init__(self, dynamics: WholeBodyDynamics, force_derivatives: bool = True) -> None:
        model = dynamics.model
        self.force_derivatives = force_derivatives
        """Whether ``calc_diff`` writes ``dforces_dx``/``dforces_du`` (each costs Pinocchio copies of its
        ``dlambda_*``; left zero without)."""
        nv, nu, nf = model.nv, dynamics.nu, dynamics.n_forces
        self.pinocchio = model.createData()
        self.contact_datas = pin.StdVec_RigidConstraintData()
        for contact in dynamics.contact_models:
            self.contact_datas.append(contact.createData())
        if dynamics.n_contacts:
            pin.initConstraintDynamics(model, self.pinocchio, dynamics.contact_models, self.contact_datas)
        self.proximal = proximal_settings(dynamics.damping)
        # Views into the Pinocchio data (eigenpy shares these members' memory; they keep their size once
        # the contact dynamics are initialised): read without a Python attribute lookup per call.
        # ``dlambda_*`` are not shared (each access copies) and are read from the data.
        pd = self.pinocchio
        self.lambda_c = pd.lambda_c
        self.ddq_dq = pd.ddq_dq
        self.ddq_dv = pd.ddq_dv
        self.ddq_dtau = pd.ddq_dtau
        self.Minv = pd.Minv
        self.tau = np.zeros(nv)
        self.acceleration = np.zeros(nv)
        self.forces = np.zeros(nf)
        """Stance-foot ground reaction forces (world frame, 3 per stance foot, leg order)."""
        self._actuated_tau = self.tau[nv - nu :]
        self._contact_forces = self.lambda_c if dynamics.n_contacts else self.forces
        self._integrate_blocks = np.zeros((6, 12))
        self.x_next = np.zeros(model.nq + nv)
        self.Fx = np.zeros((2 * nv, 2 * nv))
        self.Fu = np.zeros((2 * nv, nu))
        self.dforces_dx = np.zeros((nf, 2 * nv))
        self.dforces_du = np.zeros((nf, nu))
        self._step = np.zeros(nv)


class WholeBodyDynamics:
    """Discrete whole-body dynamics ``x+ = f(x, tau)`` of one contact phase (Eqs. (19)-(23)).

    Immutable after construction and shareable between knots with the same stance flags and time step;
    each knot gets its own ``WholeBodyDynamicsData``.

    Args:
        robot: the robot (its Pinocchio model is the planning model).
        stance: 4 contact flags in leg order.
        dt: integration time step (s).
        baumgarte_alpha: first-order Baumgarte gain ``alpha`` of Eq. (20) (1/s).
        integration: ``"explicit"`` (paper Eq. (23)), ``"semi_implicit"`` (Crocoddyl's Euler) or
            ``"explicit_world"`` (Eq. (23) with the base's linear velocity stepped in the world frame; a
            free-flyer robot only).
        damping: 0 for the exact KKT solve; ``> 0`` regularises a (nearly) singular contact Jacobian with
            Pinocchio's proximal algorithm. With 0, a singular system raises ``ContactDynamicsError``.
    """

    def __init__(
        self,
        robot: Robot,
        stance: tuple[bool, ...],
        dt: float,
        baumgarte_alpha: float = BAUMGARTE_ALPHA,
        integration: IntegrationScheme = "explicit",
        damping: float = 0.0,
    ) -> None:
        self.robot = robot
        self.model = robot.model
        self.state = MultibodyState(robot.model)
        self.stance = as_contact_flags(stance, "stance flags")
        if not (math.isfinite(dt) and dt > 0):
            raise ValueError(f"time step must be positive and finite, got {dt}")
        if not (math.isfinite(baumgarte_alpha) and baumgarte_alpha >= 0):
            raise ValueError(f"Baumgarte alpha must be non-negative, got {baumgarte_alpha}")
        if integration not in INTEGRATION_SCHEMES:
            raise ValueError(f"integration must be one of {INTEGRATION_SCHEMES}, got {integration!r}")
        if not (math.isfinite(damping) and damping >= 0):
            raise ValueError(f"damping must be non-negative, got {damping}")
        self.dt = float(dt)
        self.baumgarte_alpha = float(baumgarte_alpha)
        self.integration = integration
        self._explicit = integration == "explicit"
        self.damping = float(damping)
        self.nu = robot.nu
        self.contact_legs = tuple(leg for leg in range(robot.n_feet) if self.stance[leg])
        self.n_contacts = len(self.contact_legs)
        self.n_forces = 3 * self.n_contacts
        self.contact_models = foot_contact_models(robot, self.stance, self.baumgarte_alpha)
        self._nq = robot.model.nq
        self._free_flyer = self.state.free_flyer_root
        """A free flyer at the root: the step and its Jacobians are compiled (``euler_step``,
        ``free_flyer_euler_step_jacobians``) instead of ``pin.integrate`` and ``pin.dIntegrate``."""
        self._world_velocity = integration == "explicit_world"
        if self._world_velocity and not self._free_flyer:
            raise ValueError(
                f"integration 'explicit_world' needs a free-flyer root with vector joints; {robot.name!r} "
                "has another configuration space"
            )

    def __repr__(self) -> str:
        return f"WholeBodyDynamics({flags_to_string(self.stance)}, dt={self.dt}, {self.integration})"

    def create_data(self, force_derivatives: bool = True) -> WholeBodyDynamicsData:
        """A workspace; ``force_derivatives=False`` for a user of ``x_next``, ``Fx``, ``Fu`` and the forces
        only (``calc_diff`` then leaves ``dforces_dx``/``dforces_du`` zero)."""
        return WholeBodyDynamicsData(self, force_derivatives)

    def calc(self, data: WholeBodyDynamicsData, x: np.ndarray, u: np.ndarray) -> None:
        """Write ``data.acceleration``, ``data.forces`` and ``data.x_next``."""
        model, nq = self.model, self._nq
        q, v = x[:nq], x[nq:]
        data._actuated_tau[:] = u
        if self.n_contacts:
            acceleration = pin.constraintDynamics(
                model, data.pinocchio, q, v, data.tau, self.contact_models, data.contact_datas, data.proximal
            )
        else:
            # WORLD convention: what computeABADerivatives(model, data) reuses in calc_diff.
            acceleration = pin.aba(model, data.pinocchio, q, v, data.tau, pin.Convention.WORLD)
        free_flyer = self._free_flyer
        if self._world_velocity:
            if not world_velocity_euler_step(
                acceleration,
                data._contact_forces,
                x,
                self.dt,
                nq,
                data.acceleration,
                data.forces,
                data.x_next,
                data._step,
            ):
                self._raise_non_finite(x, u)
            return
        if not euler_step(
            acceleration,
            data._contact_forces,
            x,
            self.dt,
            self._explicit,
            nq,
            free_flyer,
            data.acceleration,
            data.forces,
            data.x_next,
            data._step,
        ):
            self._raise_non_finite(x, u)
        if not free_flyer:
            data.x_next[:nq] = pin.integrate(model, q, data._step)

    def calc_diff(self, data: WholeBodyDynamicsData, x: np.ndarray, u: np.ndarray) -> None:
        """Write ``data.Fx``, ``data.Fu`` (tangent Jacobians of ``x_next``) and ``data.dforces_dx``,
        ``data.dforces_du``. Assumes ``calc(data, x, u)`` ran last on this data."""
        model = self.model
        pd = data.pinocchio
        if self.n_contacts:
            pin.computeConstraintDynamicsDerivatives(
                model, pd, self.contact_models, data.contact_datas, data.proximal
            )
            da_dtau = data.ddq_dtau
            if data.force_derivatives:
                copy_force_derivatives(
                    pd.dlambda_dq, pd.dlambda_dv, pd.dlambda_dtau, data.dforces_dx, data.dforces_du
                )
        else:
            pin.computeABADerivatives(model, pd)  # reuses the WORLD-convention ABA of calc
            da_dtau = data.Minv  # d qdd / d tau; Pinocchio fills only its upper triangle
        if self._world_velocity:
            nq = self._nq
            world_velocity_euler_step_jacobians(
                data.ddq_dq,
                data.ddq_dv,
                da_dtau,
                self.n_contacts == 0,
                data._step,
                x[nq : nq + 6],
                data.x_next[nq : nq + 3],
                self.dt,
                data._integrate_blocks,
                data.Fx,
                data.Fu,
            )
            return
        if self._free_flyer:
            free_flyer_euler_step_jacobians(
                data.ddq_dq,
                data.ddq_dv,
                da_dtau,
                self.n_contacts == 0,
                data._step,
                self.dt,
                self._explicit,
                data._integrate_blocks,
                data.Fx,
                data.Fu,
            )
            return
        dintegrate_dq, dintegrate_dstep = pin.dIntegrate(model, x[: self._nq], data._step)
        euler_step_jacobians(
            data.ddq_dq,
            data.ddq_dv,
            da_dtau,
            self.n_contacts == 0,
            dintegrate_dq,
            dintegrate_dstep,
            self.dt,
            self._explicit,
            data.Fx,
            data.Fu,
        )

    def _raise_non_finite(self, x: np.ndarray, u: np.ndarray) -> None:
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(u))):
            raise ContactDynamicsError(f"{self!r}: non-finite state or torque")
        raise ContactDynamicsError(
            f"{self!r}: the contact KKT system is singular (rank-deficient contact Jacobian); "
            "construct the dynamics with damping > 0 to regularise it"
        )
