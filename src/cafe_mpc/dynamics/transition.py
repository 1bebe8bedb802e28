"""Whole-body -> SRB model transition (paper Sec. IV-C, Eqs. (31), (32)) and reset-map composition.

Eq. (31) is ``x_s+ = T_{w->s} P_R(x_w-)``: the phase's reset map ``P_R`` (impact (24) if feet touch down at
the transition, identity otherwise) followed by the projection (32) that keeps the base pose and its
velocity and drops the joints. ``ComposedReset(P_R, WholeBodyToSRB(...))`` builds it.

The two state conventions differ in the base linear velocity: the whole-body state has it in the base frame
(Pinocchio free flyer), the SRB state in the world frame, so the projection is
``[c, quat, R v_lin, omega]`` and its Jacobian (tangent to tangent) is

    d c      / d dq_lin = R          d c_dot / d dq_ang = -R [v_lin]x     d c_dot / d v_lin = R
    d theta  / d dq_ang = I          d omega / d omega  = I
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from cafe_mpc.core.interfaces import ResetData, ResetMap
from cafe_mpc.dynamics.multibody_state import MultibodyState
from cafe_mpc.dynamics.srb import SRBState, quaternion_to_rotation


def whole_body_to_srb_state(
    x: np.ndarray, nq: int | None = None, out: np.ndarray | None = None
) -> np.ndarray:
    """The projection (32): ``[q, v]`` (whole body) -> ``[c, quat, c_dot (world), omega (body)]``.

    ``nq``: size of ``q`` (default: a free-flyer model with one-dof joints, ``nv = nq - 1``). ``out``: a
    (13,) array to write into (a new one by default).
    """
    x = np.asarray(x, dtype=float)
    nq = (len(x) + 1) // 2 if nq is None else int(nq)
    out = np.empty(13) if out is None else out
    rotation = quaternion_to_rotation(x[3:7])
    out[0:7] = x[0:7]
    out[7:10] = rotation @ x[nq : nq + 3]
    out[10:13] = x[nq + 3 : nq + 6]
    return out


class WholeBodyToSRB(ResetMap):
    """Projection (32) of a whole-body state onto the SRB state (position, orientation, velocities)."""

    def __init__(self, whole_body_state: MultibodyState, srb_state: SRBState | None = None) -> None:
        self.state = whole_body_state
        self.next_state = srb_state or SRBState()
        self.nq, self.nv = whole_body_state.nq, whole_body_state.nv

    def create_data(self) -> ResetData:
        data = ResetData(self)
        nv = self.nv
        data.Px[3:6, 3:6] = np.eye(3)
        data.Px[9:12, nv + 3 : nv + 6] = np.eye(3)
        return data

    def calc(self, data: ResetData, x: np.ndarray) -> None:
        whole_body_to_srb_state(x, self.nq, data.x_next)

    def calc_diff(self, data: ResetData, x: np.ndarray) -> None:
        nq, nv = self.nq, self.nv
        rotation = quaternion_to_rotation(x[3:7])
        data.Px[0:3, 0:3] = rotation
        data.Px[6:9, 3:6] = -rotation @ pin.skew(x[nq : nq + 3])
        data.Px[6:9, nv : nv + 3] = rotation


class ComposedReset(ResetMap):
    """``second(first(x))`` with ``Px = Px_second @ Px_first`` (e.g. impact then WB -> SRB, Eq. (31))."""

    def __init__(self, first: ResetMap, second: ResetMap) -> None:
        if first.next_state.nx != second.state.nx or first.next_state.ndx != second.state.ndx:
            raise ValueError("composed reset maps: the first map's target is not the second map's source")
        self.first = first
        self.second = second
        self.state = first.state
        self.next_state = second.next_state

    def create_data(self) -> ResetData:
        data = ResetData(self)
        data.first = self.first.create_data()
        data.second = self.second.create_data()
        return data

    def calc(self, data: ResetData, x: np.ndarray) -> None:
        self.first.calc(data.first, x)
        self.second.calc(data.second, data.first.x_next)
        data.x_next[:] = data.second.x_next

    def calc_diff(self, data: ResetData, x: np.ndarray) -> None:
        self.first.calc_diff(data.first, x)
        self.second.calc_diff(data.second, data.first.x_next)
        np.matmul(data.second.Px, data.first.Px, out=data.Px)
