"""Offline multi-phase whole-body trajectory optimisation with the MS-iLQR (paper Sec. VI-B, Appendix).

* ``task``: a TO task as data (contact sequence and switching times, keyframes, weights, constraints,
  solver settings), YAML round trip and ``key=value`` overrides;
* ``multiphase``: task -> ``MultiPhaseProblem`` (keyframe costs, impacts, touchdown constraints, barriers),
  the initial guess, the solve, the flattened trajectory and its feasibility check;
* ``barrel_roll``: the in-place barrel roll with the authors' settings;
* ``presets``: the task presets (``TASKS``) and ``load_task`` (preset or YAML file, with overrides);
* ``outputs``: the files of ``cafe-mpc optimize`` (trajectory, settings, plots, video, summary).
"""
