"""The bottom layer: what every other layer may use and which uses nothing of the package.

* ``interfaces``: the per-knot interface between optimal-control problems and the solver;
* ``contacts``: contact flags (one bool per foot, leg order);
* ``measurement``: ``Measurement``, what a controller reads at a control tick;
* ``plan``: ``KnotPlan``, what every plan is (the planners' own plan types follow it), and ``PlanFormat``,
  how a plan type's arrays travel;
* ``controller``: the ``LowLevelController[PlanT]`` and closed-loop ``Controller`` interfaces.
"""
