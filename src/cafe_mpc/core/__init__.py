"""The bottom layer: what every other layer may use and which uses nothing of the package.

* ``interfaces``: the per-knot interface between optimal-control problems and the solver;
* ``contacts``: contact flags (one bool per foot, leg order);
* ``measurement``: ``Measurement``, what a controller reads at a control tick;
* ``plan``: ``Plan``, the message from the MPC to the low-level controller;
* ``controller``: the ``LowLevelController`` and closed-loop ``Controller`` interfaces.
"""
