"""A finite-difference test factory (after Crocoddyl's ``unittest/factory``): every knot, reset map and
switching constraint of the library, built at random points on its manifolds, and the one check each goes
through (``checks``).

* ``actions.ACTION_CASES``, ``resets.RESET_CASES``, ``resets.CONSTRAINT_CASES``: named ``CaseSpec`` s;
  ``spec.build(library)`` makes the case (a ``cases.Library`` holds the robots and problems they share);
* ``checks.check_action``, ``check_reset``, ``check_constraint``: the derivatives against central differences
  on the manifold (``numdiff``) and the Gauss-Newton structure each knot promises.

``tests/test_finite_differences.py`` runs every case.
"""
