"""The planners: measured (or predicted) state -> plan of the planner's own type, one vertical slice each.

* ``base``: the ``Planner[PlanT]`` protocol the MPC loops see, the receding-horizon update the planners share
  (``RecedingHorizonPlanner``), ``MpcStatistics``, ``PlannerSlice`` (how a run config builds a planner) and
  the ``Registry`` of a config key;
* ``registry``: the ``planner`` key's slices, one line each;
* ``cafe/``: CAFE-MPC (paper Sec. IV, VI): the problem, its config and scaling, the planner with the real-time
  iteration, ``Plan`` and ``PlanBuffers``, the delay predictor;
* ``template/``: the SRB-only baseline (Sec. VII-C): its problem, planner, ``TemplatePlan`` and its own low
  level;
* ``time_grid``, ``collector``: the knot time grid and the garbage-collector pause both planners use.
"""
