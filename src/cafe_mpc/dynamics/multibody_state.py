"""The whole-body state manifold ``x = [q, v]`` of a floating-base robot (paper Sec. IV-A).

The paper writes the base orientation as ZYX Euler angles; here it is Pinocchio's free-flyer
configuration (position and unit quaternion) so that any orientation, e.g. a 2*pi barrel roll, is
representable without a singularity. The tangent space (``ndx = 2 * nv = 36``) is

    [base linear (base frame, 3), base angular (base frame, 3), joints (12), v (18)]

and ``integrate``/``difference`` are Pinocchio's (SE(3) exponential/logarithm on the base, plain
addition on the joints and on the velocity), so the tangent of ``q`` has the same coordinates as ``v``. For
the usual floating-base robot (a free flyer at the root, vector-space joints after it) the in-place versions
are compiled kernels equal to Pinocchio's to round-off (``dynamics.kernels``; a fifth of the time of the
Python call with its slicing, on the solver's hot path), which the manifold also hands to the solver's
compiled kernels (``FREE_FLYER_OPERATIONS``).
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from cafe_mpc.core.interfaces import CompiledStateOperations, StateManifold, own_operations
from cafe_mpc.core.kernels import stack_columns_left_multiplied
from cafe_mpc.dynamics.kernels import (
    free_flyer_difference,
    free_flyer_difference_jacobian,
    free_flyer_difference_jacobian_product_stacked,
    free_flyer_integrate,
    free_flyer_state_difference,
    free_flyer_state_integrate,
    free_flyer_state_integrate_rows,
)

FREE_FLYER_OPERATIONS = CompiledStateOperations(
    free_flyer_integrate, free_flyer_difference, free_flyer_difference_jacobian_product_stacked
)
"""The compiled operations of ``MultibodyState`` with a free flyer at the root (``dynamics.kernels``)."""


class MultibodyState(StateManifold):
    """``x = [q (nq), v (nv)]`` on ``Q x R^nv`` with Pinocchio's Lie-group operations on ``Q``."""

    def __init__(self, model: pin.Model) -> None:
        self.model = model
        self.nq = model.nq
        self.nv = model.nv
        self.nx = model.nq + model.nv
        self.ndx = 2 * model.nv
        # Velocity rows [0, _lie_rows) of joints whose configuration lives on a Lie group (nq != nv, e.g. the
        # free-flyer); every later joint must be a vector-space joint (nq == nv), whose difference Jacobian
        # is the identity. Otherwise the full Jacobian is used (_lie_rows = nv).
        self._lie_rows = 0
        for joint in model.joints[1:]:
            if joint.nq != joint.nv:
                self._lie_rows = joint.idx_v + joint.nv
        if self._lie_rows:
            later = [j for j in model.joints[1:] if j.idx_v >= self._lie_rows]
            if any(j.nq != j.nv for j in later) or any(
                j.idx_v < self._lie_rows and j.nq == j.nv for j in model.joints[1:] if j.idx_v > 0
            ):
                self._lie_rows = model.nv
        root = model.joints[1] if model.njoints > 1 else None
        self.free_flyer_root = (
            root is not None
            and root.shortname() == "JointModelFreeFlyer"
            and root.idx_q == 0
            and all(joint.nq == joint.nv for joint in model.joints[2:])
        )
        """A free flyer at the root and vector-space joints after it: the compiled operations apply."""
        compiled = self.free_flyer_root and own_operations(self, MultibodyState)
        self.compiled = FREE_FLYER_OPERATIONS if compiled else None

    def zero(self) -> np.ndarray:
        return np.concatenate([pin.neutral(self.model), np.zeros(self.nv)])

    def check(self, x: np.ndarray, name: str = "x") -> np.ndarray:
        """``x`` as a float array of the right size, or a ``ValueError`` naming the mismatch."""
        x = np.asarray(x, dtype=float)
        if x.shape != (self.nx,):
            raise ValueError(
                f"{name} must have shape ({self.nx},) = [q ({self.nq}), v ({self.nv})], got {x.shape}"
            )
        return x

    def integrate(self, x: np.ndarray, dx: np.ndarray) -> np.ndarray:
        out = np.empty(self.nx)
        self.integrate_into(x, dx, out)
        return out

    def difference(self, x0: np.ndarray, x1: np.ndarray) -> np.ndarray:
        out = np.empty(self.ndx)
        self.difference_into(x0, x1, out)
        return out

    def jacobian_difference(self, x0: np.ndarray, x1: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        nq, nv = self.nq, self.nv
        d0, d1 = pin.dDifference(self.model, x0[:nq], x1[:nq])
        j0 = np.zeros((self.ndx, self.ndx))
        j1 = np.zeros((self.ndx, self.ndx))
        j0[:nv, :nv] = d0
        j1[:nv, :nv] = d1
        j0[nv:, nv:] = -np.eye(nv)
        j1[nv:, nv:] = np.eye(nv)
        return j0, j1

    def difference_into(self, x0: np.ndarray, x1: np.ndarray, out: np.ndarray) -> None:
        nq, nv = self.nq, self.nv
        if self.free_flyer_root:
            free_flyer_state_difference(x0, x1, nq, nv, out)
            return
        out[:nv] = pin.difference(self.model, x0[:nq], x1[:nq])
        np.subtract(x1[nq:], x0[nq:], out=out[nv:])

    def integrate_into(self, x: np.ndarray, dx: np.ndarray, out: np.ndarray) -> None:
        nq, nv = self.nq, self.nv
        if self.free_flyer_root:
            free_flyer_state_integrate(x, dx, nq, nv, out)
            return
        out[:nq] = pin.integrate(self.model, x[:nq], dx[:nv])
        np.add(x[nq:], dx[nv:], out=out[nq:])

    def integrate_rows_into(self, xs: np.ndarray, dxs: np.ndarray, out: np.ndarray) -> None:
        if self.free_flyer_root:
            free_flyer_state_integrate_rows(xs, dxs, self.nq, self.nv, out)
            return
        super().integrate_rows_into(xs, dxs, out)

    def difference_jacobian_product_stacked(
        self, x0: np.ndarray, x1: np.ndarray, left: np.ndarray, right: np.ndarray, out: np.ndarray
    ) -> None:
        if self.free_flyer_root:
            free_flyer_difference_jacobian_product_stacked(x0, x1, left, right, out)
            return
        rows = self._lie_rows or self.nv
        nq = self.nq
        jacobian = pin.dDifference(self.model, x0[:nq], x1[:nq], pin.ArgumentPosition.ARG1)
        stack_columns_left_multiplied(jacobian[:rows, :rows], rows, left, right, out)

    def difference_jacobian_product(
        self, x0: np.ndarray, x1: np.ndarray, matrix: np.ndarray, out: np.ndarray
    ) -> None:
        """``∂(x1 ⊖ x0)/∂x1 @ matrix``: only the configuration rows of Lie-group joints (the free-flyer's 6)
        differ from the identity, so only those rows are multiplied."""
        nq = self.nq
        out[:] = matrix
        if self.free_flyer_root:
            jacobian = np.empty((6, 6))
            free_flyer_difference_jacobian(x0, x1, jacobian)
            np.matmul(jacobian, matrix[:6], out=out[:6])
        elif self._lie_rows:
            rows = self._lie_rows
            jacobian = pin.dDifference(self.model, x0[:nq], x1[:nq], pin.ArgumentPosition.ARG1)
            np.matmul(jacobian[:rows, :rows], matrix[:rows], out=out[:rows])

    def jacobian_integrate(self, x: np.ndarray, dx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        nq, nv = self.nq, self.nv
        d0, d1 = pin.dIntegrate(self.model, x[:nq], dx[:nv])
        j0 = np.zeros((self.ndx, self.ndx))
        j1 = np.zeros((self.ndx, self.ndx))
        j0[:nv, :nv] = d0
        j1[:nv, :nv] = d1
        j0[nv:, nv:] = np.eye(nv)
        j1[nv:, nv:] = np.eye(nv)
        return j0, j1
