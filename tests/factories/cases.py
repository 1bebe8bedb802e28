"""What a factory case is: a model at a point, with what the model promises about its derivatives.

* ``ActionCase``: an ``ActionModel`` at ``(x, u)``. Every knot of the library promises (``ActionModel.
  calc_diff``): ``Fx``/``Fu`` are the Jacobians of ``x_next`` in the tangent spaces, ``Lx``/``Lu`` the exact
  cost gradient, and ``Lxx``/``Luu``/``Lux`` the Gauss-Newton Hessian. The case states that Hessian's
  structure (``gauss_newton``): the cost is ``sum_i phi_i(z_i(x, u))`` with inner functions ``z`` (residuals
  and constraint values) and outer functions of curvature ``c_i = phi_i''(z_i)``, and the promised Hessian is
  ``Jz' diag(c) Jz`` with ``Jz`` the Jacobian of ``z``. Inequality constraint values (``inequalities``) give
  the reported worst violation; ``outputs`` are further derivatives a model writes (contact forces).
* ``ResetCase``: a ``ResetMap`` at ``x`` (``Px`` tangent to tangent).
* ``ConstraintCase``: a ``SwitchingConstraint`` at ``x`` (``Hx``).

Each case also carries another point, ``other``: its data object is first evaluated there, so that a model
keeping state between calls (a Pinocchio ``Data`` that accumulates) shows.

A ``CaseSpec`` names a case and the type of its model, and builds it on demand from a ``Library`` (the
robots and the built problems that cases share).
"""

from __future__ import annotations

import zlib
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from cafe_mpc.core.interfaces import ActionData, ActionModel, ResetMap, SwitchingConstraint
from cafe_mpc.robots.robot import Robot, load_robot

GaussNewton = Callable[[ActionModel, ActionData, np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]
"""``(model, data, x, u) -> (z, c)`` after ``model.calc(data, x, u)``: the inner functions' values and the
outer functions' curvatures (see the module docstring)."""

Inequalities = Callable[[ActionModel, ActionData, np.ndarray, np.ndarray], np.ndarray]
"""``(model, data, x, u) -> g`` after ``model.calc(data, x, u)``: the priced inequalities ``g >= 0``."""


@dataclass(frozen=True)
class OutputDerivative:
    """A further output of ``calc`` and its Jacobians written by ``calc_diff`` (e.g. contact forces)."""

    name: str
    value: Callable[[ActionData], np.ndarray]
    dx: Callable[[ActionData], np.ndarray]
    du: Callable[[ActionData], np.ndarray]


@dataclass(frozen=True)
class ActionCase:
    model: ActionModel
    x: np.ndarray
    u: np.ndarray
    other: tuple[np.ndarray, np.ndarray]
    gauss_newton: GaussNewton
    inequalities: Inequalities
    outputs: tuple[OutputDerivative, ...] = ()


@dataclass(frozen=True)
class ResetCase:
    reset: ResetMap
    x: np.ndarray
    other: np.ndarray


@dataclass(frozen=True)
class ConstraintCase:
    constraint: SwitchingConstraint
    x: np.ndarray
    other: np.ndarray


@dataclass
class Library:
    """What cases share: robots (loaded once) and expensive objects built once (``shared``)."""

    robots: dict[str, Robot] = field(default_factory=dict)
    built: dict[Any, Any] = field(default_factory=dict)

    def robot(self, name: str) -> Robot:
        if name not in self.robots:
            self.robots[name] = load_robot(name)
        return self.robots[name]

    def shared(self, key: Any, make: Callable[[], Any]) -> Any:
        """``make()`` the first time ``key`` is asked for, the same object afterwards."""
        if key not in self.built:
            self.built[key] = make()
        return self.built[key]


@dataclass(frozen=True)
class CaseSpec:
    """A named case: ``build(library, rng)`` makes it; its model is a ``model_type`` (exactly)."""

    name: str
    model_type: type
    make: Callable[[Library, np.random.Generator], ActionCase | ResetCase | ConstraintCase]

    def build(self, library: Library) -> ActionCase | ResetCase | ConstraintCase:
        """The case, at points drawn from a generator seeded by the case's name (the same every run)."""
        return self.make(library, np.random.default_rng(zlib.crc32(self.name.encode())))
