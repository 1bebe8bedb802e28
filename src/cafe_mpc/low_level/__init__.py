"""The low-level controllers at the control rate: PD standing (``pd``), the Riccati feedback (33)
(``riccati``), the VWBC QP (34) (``vwbc``), the contact dynamics they share (``contact_dynamics``),
synthetic plans for tests (``synthetic``) and the ``wbc`` key's registry (``registry``). A planner whose
plan type none of them follows brings its own (``planners.template.low_level``).
"""
