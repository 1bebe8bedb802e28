"""Touchdown impact reset map (paper Eqs. (22), (24)).

When feet touch down, the velocity jumps so that the constrained feet stop (perfectly inelastic impact):

    [M   Jc^T] [ v+  ]   [ M v- ]
    [Jc  0   ] [ -Λc ] = [ 0    ],        x+ = [q-, v+]   (24)

solved by ``pin.impulseDynamics`` (point contacts, ``LOCAL_WORLD_ALIGNED``, restitution 0), with the
Jacobian from ``pin.computeImpulseDynamicsDerivatives`` (``d v+ / dq`` and ``d(v+ - v-) / dv-``).

The constrained set is chosen by the caller (``WholeBodyModelFactory.reset_map`` uses every foot in stance
after the switch: the new touchdowns and the feet that stay down, so that the impulse does not make a
standing foot slip). Take-off is the identity map (``IdentityReset``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import pinocchio as pin

from cafe_mpc.core.contacts import as_contact_flags, flags_to_string
from cafe_mpc.core.interfaces import ResetData, ResetMap
from cafe_mpc.core.kernels import same_point
from cafe_mpc.dynamics.multibody_state import MultibodyState
from cafe_mpc.dynamics.whole_body import ContactDynamicsError, foot_contact_models, proximal_settings
from cafe_mpc.robots.robot import Robot


class ImpactData(ResetData):
    """Workspace of ``ImpactReset`` (own Pinocchio ``Data``)."""

    def __init__(self, reset: ImpactReset) -> None:
        super().__init__(reset)
        model = reset.model
        self.pinocchio = model.createData()
        self.contact_datas = pin.StdVec_RigidConstraintData()
        for contact in reset.contact_models:
            self.contact_datas.append(contact.createData())
        pin.initConstraintDynamics(model, self.pinocchio, reset.contact_models, self.contact_datas)
        self.proximal = proximal_settings(reset.damping)
        self.impulses = np.zeros(3 * reset.n_contacts)
        """Contact impulses Λc (world frame, 3 per constrained foot, leg order)."""
        nv = model.nv
        self.Px[:nv, :nv] = np.eye(nv)
        self.last_x = np.full(model.nq + nv, np.nan)


class ImpactReset(ResetMap):
    """``x+ = [q, v+(q, v-)]`` with the feet in ``impact_feet`` brought to rest (Eqs. (22), (24))."""

    def __init__(self, robot: Robot, impact_feet: Sequence[bool], damping: float = 0.0) -> None:
        self.impact_feet = as_contact_flags(impact_feet, "impact feet")
        if not any(self.impact_feet):
            raise ValueError(
                "an impact map needs at least one constrained foot (use IdentityReset otherwise)"
            )
        if not (math.isfinite(damping) and damping >= 0):
            raise ValueError(f"damping must be non-negative, got {damping}")
        self.robot = robot
        self.model = robot.model
        self.state = MultibodyState(robot.model)
        self.next_state = self.state
        self.damping = float(damping)
        self.n_contacts = sum(self.impact_feet)
        self.contact_models = foot_contact_models(robot, self.impact_feet, 0.0)
        self._eye_nv = np.eye(robot.model.nv)

    def __repr__(self) -> str:
        return f"ImpactReset({flags_to_string(self.impact_feet)})"

    def create_data(self) -> ImpactData:
        return ImpactData(self)

    def calc(self, data: ImpactData, x: np.ndarray) -> None:
        nq = self.model.nq
        v_after = pin.impulseDynamics(
            self.model,
            data.pinocchio,
            x[:nq],
            x[nq:],
            self.contact_models,
            data.contact_datas,
            0.0,
            data.proximal,
        )
        if not math.isfinite(float(np.dot(v_after, v_after))):
            raise ContactDynamicsError(
                f"{self!r}: non-finite post-impact velocity (non-finite state or singular)"
            )
        data.x_next[:nq] = x[:nq]
        data.x_next[nq:] = v_after
        data.impulses[:] = data.pinocchio.impulse_c
        data.last_x[:] = x

    def calc_diff(self, data: ImpactData, x: np.ndarray) -> None:
        if not same_point(x, data.last_x):
            self.calc(data, x)  # the derivatives reuse the forward pass of calc
        nv = self.model.nv
        pd = data.pinocchio
        # Pinocchio 4.0.0 accumulates into ``dvc_dq`` instead of overwriting it: without this reset every
        # call after the first on the same Data returned a wrong d v+ / dq (errors of order 1 in our tests;
        # a solver evaluates each impact many times).
        pd.dvc_dq[:] = 0.0
        pin.computeImpulseDynamicsDerivatives(
            self.model, pd, self.contact_models, data.contact_datas, 0.0, data.proximal
        )
        data.Px[nv:, :nv] = pd.ddq_dq  # d v+ / dq
        np.add(pd.ddq_dv, self._eye_nv, out=data.Px[nv:, nv:])  # Pinocchio gives d(v+ - v-) / dv-
