"""The MPC's warm-up: after it, the preparations of a closed loop create no solver data and no impact map.

Knot data made inside an update cost it their construction and the page faults of their first writes (a
whole-body knot's data hold two Pinocchio ``Data``: a few hundred kB). The warm-up builds the problems of
the updates of its window from every start an update can have (``RecedingHorizonMpc.problem_start``: on the
knot grid with delay compensation) and evaluates each new data object once."""

from __future__ import annotations

import pytest

from cafe_mpc.config import load_config
from cafe_mpc.planners.cafe.planner import RecedingHorizonMpc
from cafe_mpc.solver import workspace


@pytest.mark.slow
def test_no_data_is_created_inside_a_preparation(monkeypatch):
    """The spin at a fixed 20 ms latency (deterministic): its updates' problems start on the knot grid, and
    a warm-up that built them only at off-grid starts missed one knot object every 0.2 s, whose data the
    update at 0.2, 0.4, ... s then made."""
    from cafe_mpc_lab.experiments.run import simulate_run

    made: list[tuple[float, str]] = []
    now: dict[str, float | None] = {"t": None}
    planners: list[RecedingHorizonMpc] = []
    get = workspace._DataPool.get

    def counting_get(self, owner, create):
        def make():
            if now["t"] is not None:
                made.append((now["t"], type(owner).__name__))
            return create()

        return get(self, owner, make)

    prepare = RecedingHorizonMpc.prepare

    def watched_prepare(self, t, q, v):
        if not planners:
            planners.append(self)
            planners.append(len(self._projections))
        now["t"] = t
        try:
            return prepare(self, t, q, v)
        finally:
            now["t"] = None

    monkeypatch.setattr(workspace._DataPool, "get", counting_get)
    monkeypatch.setattr(RecedingHorizonMpc, "prepare", watched_prepare)
    config = load_config(
        "spin", ["mpc.latency=fixed", "simulation.duration=1.1", "mpc.warm_up=1.2", "output.plots=false"]
    )
    _, _, log = simulate_run(config)
    assert not log.fell
    assert made == []
    planner, projections_after_warm_up = planners
    assert len(planner._projections) == projections_after_warm_up  # landings' impact maps made before
