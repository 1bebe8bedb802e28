"""Every knot, reset map and switching constraint of the library against finite differences (the factory in
``tests/factories``): dynamics and reset Jacobians in the tangent spaces, exact cost gradients, the
Gauss-Newton Hessians the knots promise, constraint Jacobians and contact-force Jacobians. One test per case,
named after it; a further test checks that the factory covers every such class the library defines, and
one that the checks catch a single wrong entry."""

from __future__ import annotations

import importlib
import pkgutil

import numpy as np
import pytest

import cafe_mpc
from cafe_mpc.core.interfaces import ActionModel, ResetMap, SwitchingConstraint
from factories.actions import ACTION_CASES
from factories.cases import ActionCase, CaseSpec, Library
from factories.checks import check_action, check_constraint, check_reset
from factories.resets import CONSTRAINT_CASES, RESET_CASES


@pytest.fixture(scope="module")
def library(reference_robot) -> Library:
    return Library({reference_robot.name: reference_robot})


def _ids(specs: list[CaseSpec]) -> list[str]:
    return [spec.name for spec in specs]


@pytest.mark.parametrize("spec", ACTION_CASES, ids=_ids(ACTION_CASES))
def test_knot_derivatives(library, spec):
    case = spec.build(library)
    assert type(case.model) is spec.model_type
    check_action(case)


@pytest.mark.parametrize("spec", RESET_CASES, ids=_ids(RESET_CASES))
def test_reset_map_jacobian(library, spec):
    case = spec.build(library)
    assert type(case.reset) is spec.model_type
    check_reset(case)


@pytest.mark.parametrize("spec", CONSTRAINT_CASES, ids=_ids(CONSTRAINT_CASES))
def test_switching_constraint_jacobian(library, spec):
    case = spec.build(library)
    assert type(case.constraint) is spec.model_type
    check_constraint(case)


def _subclasses(base: type) -> set[type]:
    found = set()
    for cls in base.__subclasses__():
        found |= {cls} | _subclasses(cls)
    return found


def test_the_factory_covers_every_model_of_the_library():
    """Every ``ActionModel``, ``ResetMap`` and ``SwitchingConstraint`` class of ``cafe_mpc`` has a case."""
    for module in pkgutil.walk_packages(cafe_mpc.__path__, "cafe_mpc."):
        importlib.import_module(module.name)
    covered = {spec.model_type for spec in (*ACTION_CASES, *RESET_CASES, *CONSTRAINT_CASES)}
    for base in (ActionModel, ResetMap, SwitchingConstraint):
        library_classes = {cls for cls in _subclasses(base) if cls.__module__.startswith("cafe_mpc.")}
        missing = sorted(cls.__qualname__ for cls in library_classes - covered)
        assert not missing, f"no factory case for {', '.join(missing)}"


class WrongEntry:
    """A model of the factory whose ``calc_diff`` writes one entry of one derivative off by ``RELATIVE`` times
    the derivative's largest entry (both entries of a symmetric pair for a Hessian block): what a slip in an
    analytic derivative looks like. Everything else is the model's own."""

    RELATIVE = 1e-4

    def __init__(self, model, field: str, index: tuple[int, int] | int) -> None:
        self._model, self.field, self.index = model, field, index

    def __getattr__(self, name: str):
        return getattr(self._model, name)

    def calc_diff(self, data, *point) -> None:
        self._model.calc_diff(data, *point)
        array = getattr(data, self.field)
        delta = self.RELATIVE * max(1.0, float(np.max(np.abs(array))))
        array[self.index] += delta
        if self.field in ("Lxx", "Luu"):
            array[self.index[::-1]] += delta


@pytest.mark.parametrize(
    ("case_name", "field", "index", "message"),
    [
        ("whole-body-running-1001", "Fx", (20, 4), "Fx"),
        ("whole-body-running-1001", "Fu", (30, 2), "Fu"),
        ("whole-body-running-1001", "Lx", 7, "Lx"),
        ("whole-body-running-1001", "Lu", 11, "Lu"),
        ("whole-body-running-1001", "Lxx", (3, 25), "Gauss-Newton Hessian"),
        ("whole-body-running-1001", "Lux", (5, 30), "Gauss-Newton Hessian"),
        ("whole-body-running-1001", "dforces_dx", (2, 9), "contact forces dx"),
        ("whole-body-terminal-0110", "Lxx", (0, 0), "Gauss-Newton Hessian"),
        ("srb-running-1111", "Fx", (9, 4), "Fx"),
        ("template-srb-running-1111", "Luu", (2, 5), "Gauss-Newton Hessian"),
        ("impact-1111", "Px", (20, 3), "Px"),
        ("transition-to-srb-1001-to-1111", "Px", (7, 3), "Px"),
        ("touchdown-0110-step", "Hx", (1, 4), "Hx"),
    ],
)
def test_a_wrong_entry_fails_the_check(library, case_name, field, index, message):
    specs = {spec.name: spec for spec in (*ACTION_CASES, *RESET_CASES, *CONSTRAINT_CASES)}
    case = specs[case_name].build(library)
    if isinstance(case, ActionCase):
        wrong, check = (
            ActionCase(**{**vars(case), "model": WrongEntry(case.model, field, index)}),
            check_action,
        )
    elif hasattr(case, "reset"):
        wrong, check = type(case)(WrongEntry(case.reset, field, index), case.x, case.other), check_reset
    else:
        wrong, check = (
            type(case)(WrongEntry(case.constraint, field, index), case.x, case.other),
            check_constraint,
        )
    with pytest.raises(AssertionError, match=message):
        check(wrong)
