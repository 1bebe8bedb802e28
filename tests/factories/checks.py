"""The finite-difference checks every factory case goes through.

``check_action``: for a knot at ``(x, u)``,

* ``Fx``, ``Fu`` against central differences of ``x_next`` in the next state's tangent (running knots); a
  terminal knot (``nu == 0``) leaves ``x_next``, ``Fx`` and ``Fu`` as created;
* ``Lx``, ``Lu`` against central differences of the cost;
* the Hessian ``[[Lxx, Lux'], [Lux, Luu]]`` against the Gauss-Newton Hessian the knot promises,
  ``Jz' diag(c) Jz`` with ``Jz`` the central differences of its inner functions (``cases.ActionCase``); it
  is symmetric and positive semi-definite;
* the reported ``constraint_violation`` is ``max(0, -min g)`` of its inequalities;
* further outputs' Jacobians (contact forces) against their central differences.

``check_reset``: ``Px`` against central differences of ``x_next`` in the next state's tangent.
``check_constraint``: ``Hx`` against central differences of the constraint value.

Every check also evaluates the derivatives twice on a data object first used at another point and once on a
fresh one: the results must agree (no state carried between calls).

Tolerances are relative to the size of the derivative (``numdiff.relative_error``). Over all cases the worst
errors of the library's derivatives are 5e-8 (first derivatives: the cost gradient of SRB knots far from
their reference, the dynamics Jacobian of a trajectory-optimisation knot) and 3e-9 (Hessians), twenty times
below the tolerances; a single entry off by 1e-4 of the largest shows as an error of 1e-4
(``tests/test_finite_differences.py`` checks that it fails).
"""

from __future__ import annotations

import numpy as np

from factories.cases import ActionCase, ConstraintCase, ResetCase
from factories.numdiff import probe, relative_error

FIRST_DERIVATIVES = 1e-6
"""Tolerance of Jacobians and gradients (relative to their largest entry, or absolute below one)."""
HESSIAN = 1e-6
"""Tolerance of the Gauss-Newton Hessian (a product of two finite-difference Jacobians)."""
REPEAT = 1e-12
"""Derivatives evaluated again, or on a fresh data object, agree to rounding."""


def assert_close(what: str, analytic: np.ndarray, numeric: np.ndarray, tolerance: float) -> None:
    """``AssertionError`` naming ``what``, its error and the worst entry when the relative error exceeds
    ``tolerance``."""
    error = relative_error(analytic, numeric)
    if error <= tolerance:
        return
    analytic, numeric = np.atleast_1d(analytic), np.atleast_1d(numeric)
    worst = np.unravel_index(int(np.argmax(np.abs(analytic - numeric))), analytic.shape)
    raise AssertionError(
        f"{what}: relative error {error:.2e} > {tolerance:.0e}; worst entry {tuple(int(i) for i in worst)}: "
        f"analytic {analytic[worst]:.9g}, finite differences {numeric[worst]:.9g}"
    )


def _action_derivatives(case: ActionCase, data) -> dict[str, np.ndarray]:
    """Copies of everything ``calc_diff`` writes."""
    model = case.model
    values = {name: np.array(getattr(data, name)) for name in ("Lx", "Lu", "Lxx", "Luu", "Lux")}
    if model.nu:
        values.update(Fx=np.array(data.Fx), Fu=np.array(data.Fu))
    for output in case.outputs:
        values[f"{output.name} dx"] = np.array(output.dx(data))
        values[f"{output.name} du"] = np.array(output.du(data))
    return values


def _evaluate_twice(model, case, other: tuple, derivatives) -> tuple[object, dict[str, np.ndarray]]:
    """The derivatives at the case's point on a data object used at ``other`` first, checked against a second
    evaluation on the same data and one on a fresh data object; returns that data and the derivatives."""
    point = (case.x, case.u) if isinstance(case, ActionCase) else (case.x,)
    data = model.create_data()
    model.calc(data, *other)
    model.calc_diff(data, *other)
    model.calc(data, *point)
    model.calc_diff(data, *point)
    first = derivatives(data)
    model.calc_diff(data, *point)
    again = derivatives(data)
    fresh_data = model.create_data()
    model.calc(fresh_data, *point)
    model.calc_diff(fresh_data, *point)
    fresh = derivatives(fresh_data)
    for name, value in first.items():
        scale = max(1.0, float(np.max(np.abs(value)))) if value.size else 1.0
        np.testing.assert_allclose(again[name], value, rtol=0, atol=REPEAT * scale, err_msg=f"{name} again")
        np.testing.assert_allclose(fresh[name], value, rtol=0, atol=REPEAT * scale, err_msg=f"{name} fresh")
    return data, first


def check_action(case: ActionCase) -> None:
    model, x, u = case.model, case.x, case.u
    state, nu = model.state, model.nu
    data, analytic = _evaluate_twice(model, case, case.other, lambda d: _action_derivatives(case, d))
    z, curvature = case.gauss_newton(model, data, x, u)
    z, curvature = np.array(z), np.array(curvature)
    g = np.array(case.inequalities(model, data, x, u))
    violation = max(0.0, -float(np.min(g))) if g.size else 0.0
    assert abs(data.constraint_violation - violation) <= REPEAT * max(1.0, violation), (
        f"constraint_violation {data.constraint_violation} != max(0, -min g) = {violation}"
    )
    if nu == 0:
        for name in ("x_next", "Fx", "Fu"):
            assert not np.any(getattr(data, name)), f"a terminal knot wrote {name}"

    probe_data = model.create_data()

    def evaluate(x_: np.ndarray, u_: np.ndarray) -> list:
        model.calc(probe_data, x_, u_)
        inner, _ = case.gauss_newton(model, probe_data, x_, u_)
        outputs = [np.array([probe_data.cost]), inner, probe_data.x_next]
        return outputs + [output.value(probe_data) for output in case.outputs]

    numeric = probe(evaluate, state, x, u)
    gradient = numeric.jacobian(0)[0]
    assert_close("Lx", analytic["Lx"], gradient[: state.ndx], FIRST_DERIVATIVES)
    assert_close("Lu", analytic["Lu"], gradient[state.ndx :], FIRST_DERIVATIVES)
    hessian = np.block([[analytic["Lxx"], analytic["Lux"].T], [analytic["Lux"], analytic["Luu"]]])
    jz = numeric.jacobian(1)
    assert_close("Gauss-Newton Hessian", hessian, jz.T @ (curvature[:, None] * jz), HESSIAN)
    scale = max(1.0, float(np.max(np.abs(hessian))))
    np.testing.assert_allclose(hessian, hessian.T, rtol=0, atol=REPEAT * scale, err_msg="Hessian symmetry")
    lowest = float(np.min(np.linalg.eigvalsh(0.5 * (hessian + hessian.T))))
    assert lowest >= -1e-9 * scale, (
        f"Gauss-Newton Hessian not positive semi-definite (eigenvalue {lowest:.3g})"
    )
    if nu:
        fx, fu = numeric.split(numeric.jacobian(2, model.next_state))
        assert_close("Fx", analytic["Fx"], fx, FIRST_DERIVATIVES)
        assert_close("Fu", analytic["Fu"], fu, FIRST_DERIVATIVES)
    for index, output in enumerate(case.outputs):
        dx, du = numeric.split(numeric.jacobian(3 + index))
        assert_close(f"{output.name} dx", analytic[f"{output.name} dx"], dx, FIRST_DERIVATIVES)
        assert_close(f"{output.name} du", analytic[f"{output.name} du"], du, FIRST_DERIVATIVES)


def check_reset(case: ResetCase) -> None:
    reset = case.reset
    _, analytic = _evaluate_twice(reset, case, (case.other,), lambda d: {"Px": np.array(d.Px)})
    probe_data = reset.create_data()

    def evaluate(x_: np.ndarray, u_: np.ndarray) -> list:
        reset.calc(probe_data, x_)
        return [probe_data.x_next]

    numeric = probe(evaluate, reset.state, case.x, np.zeros(0))
    assert_close("Px", analytic["Px"], numeric.jacobian(0, reset.next_state), FIRST_DERIVATIVES)


def check_constraint(case: ConstraintCase) -> None:
    constraint = case.constraint
    _, analytic = _evaluate_twice(constraint, case, (case.other,), lambda d: {"Hx": np.array(d.Hx)})
    probe_data = constraint.create_data()

    def evaluate(x_: np.ndarray, u_: np.ndarray) -> list:
        constraint.calc(probe_data, x_)
        return [probe_data.value]

    numeric = probe(evaluate, constraint.state, case.x, np.zeros(0))
    assert_close("Hx", analytic["Hx"], numeric.jacobian(0), FIRST_DERIVATIVES)
