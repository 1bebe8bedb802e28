"""What makes an MPC update fast must not change what it computes (issue 20)."""

from __future__ import annotations

import gc

import numpy as np
import pytest

from cafe_mpc.config import MpcSettings, VelocityCommand
from cafe_mpc.control.inline import InlineMpcLoop
from cafe_mpc.core.buffers import ArrayLender
from cafe_mpc.low_level.riccati import RiccatiController
from cafe_mpc.ocp.contact_schedule import get_gait
from cafe_mpc.ocp.knots import SRBModelFactory, WholeBodyModelFactory
from cafe_mpc.planners import collector
from cafe_mpc.planners.cafe.plan import PLAN_FIELDS, Plan, PlanBuffers
from cafe_mpc.planners.cafe.planner import RecedingHorizonMpc
from cafe_mpc.planners.cafe.problem import CafeProblemBuilder, ModelSchedule
from cafe_mpc.planners.time_grid import TIME_QUANTUM, PiecewiseTrajectory
from cafe_mpc.reference.base import ReferenceWindow
from cafe_mpc.reference.locomotion import LocomotionReference
from cafe_mpc.solver import MSiLQRSolver, SolverOptions
from cafe_mpc_lab.bench.problems import TROT_CYCLE, whole_body_problem
from cafe_mpc_lab.sim.loop import SimulationOptions, simulate
from cafe_mpc_lab.sim.mujoco_plant import MujocoPlant


def _solve(peer, **options):
    solver = MSiLQRSolver(SolverOptions(max_iterations=3, max_al_iterations=1, **options))
    return solver.solve(peer.problem, peer.initial_xs, peer.initial_us)


def test_threaded_and_fused_linearisations_equal_the_plain_one(robot) -> None:
    """``threads=2`` linearises on a pool (blocks of knots, no fused first linearisation); the result is the
    one of the single-threaded solve, whose first linearisation is fused with the evaluation, bit for bit."""
    peer = whole_body_problem(robot, TROT_CYCLE)
    single, threaded = _solve(peer), _solve(peer, threads=2)
    assert single.statistics.linearizations == threaded.statistics.linearizations == 4
    assert single.cost == threaded.cost
    for a, b in zip(single.phases, threaded.phases, strict=True):
        for name in ("xs", "us", "K", "k", "Quu", "Qux", "Qu"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))


def test_the_collector_is_paused_inside_and_restored_after() -> None:
    seen = []

    @collector.paused
    def update(fail: bool) -> None:
        seen.append(gc.isenabled())
        if fail:
            raise ValueError("failed update")

    was_enabled = gc.isenabled()
    try:
        gc.enable()
        update(False)
        assert gc.isenabled()
        with pytest.raises(ValueError):
            update(True)
        assert gc.isenabled()
        gc.disable()
        update(False)
        assert not gc.isenabled()  # a caller that had it off keeps it off
    finally:
        if was_enabled:
            gc.enable()
    assert seen == [False, False, False]


def test_plan_buffers_lend_only_arrays_no_plan_uses() -> None:
    """A set of plan arrays is lent again once nothing holds the arrays lent, one of them or a view of one;
    past the capacity, sets are new and not kept; a longer plan grows a free set."""
    buffers = PlanBuffers(capacity=2)

    def address(arrays: dict[str, np.ndarray]) -> dict[str, int]:
        return {name: array.__array_interface__["data"][0] for name, array in arrays.items()}

    lent = buffers.take(3, 5, 2, 4, 2)
    assert lent["K"].shape == (3, 2, 4) and lent["xs"].shape == (4, 5) and lent["contacts"].dtype == bool
    first = address(lent)
    assert set(address(buffers.take(3, 5, 2, 4, 2)).values()).isdisjoint(first.values())  # held
    view = lent["Qux"][1:]
    del lent
    held = buffers.take(3, 5, 2, 4, 2)
    assert set(address(held).values()).isdisjoint(first.values())  # the view keeps it busy
    assert buffers.kept == 2
    beyond = buffers.take(3, 5, 2, 4, 2)  # two sets busy: new arrays, not kept
    assert buffers.kept == 2 and not np.shares_memory(beyond["K"], held["K"])
    assert set(address(beyond).values()).isdisjoint(first.values())
    del view
    assert address(buffers.take(3, 5, 2, 4, 2)) == first
    assert buffers.take(12, 5, 2, 4, 2)["times"].shape == (12,)  # the free first set, grown
    assert buffers.kept == 2


def test_array_lender_lends_only_sets_nothing_refers_to() -> None:
    """A set of buffers is lent again once no row view of it is alive; a short buffer grows; past the
    capacity, sets are new and not kept."""
    lender = ArrayLender(capacity=2)
    first = lender.take()
    rows = first.rows(("xs", 0), 3, (5,))
    assert rows.shape == (3, 5) and rows.base.shape == (8, 5)
    flags = first.rows(("rollout", 0), 4, (), bool)
    assert flags.dtype == bool
    second = lender.take()  # ``rows`` and ``flags`` keep the first set busy
    other = second.rows(("xs", 0), 3, (5,))
    assert not np.shares_memory(other, rows)
    beyond = lender.take().rows(("xs", 0), 3, (5,))  # two sets busy: a new one, not kept
    assert lender.kept == 2 and not np.shares_memory(beyond, rows) and not np.shares_memory(beyond, other)
    buffer = rows.base
    del rows
    assert not np.shares_memory(lender.take().rows(("xs", 0), 3, (5,)), buffer)  # ``flags`` still held
    address = buffer.__array_interface__["data"][0]
    del flags, buffer
    reused = lender.take().rows(("xs", 0), 3, (5,))
    assert reused.__array_interface__["data"][0] == address  # the first set again
    del reused
    grown = lender.take().rows(("xs", 0), 20, (5,))
    assert grown.shape == (20, 5) and grown.__array_interface__["data"][0] != address


class _CheckingRiccati(RiccatiController):
    """Keeps a copy of the arrays of each plan it is given (not the plan: it holds the one in effect only,
    as a low level does); each tick, the plan must still equal its copy."""

    def __init__(self, robot) -> None:
        super().__init__(robot)
        self.plan: Plan | None = None
        self.copies: list[dict[str, np.ndarray]] = []
        self.array_addresses: set[int] = set()
        self.torques: list[np.ndarray] = []

    def compute(self, t, measurement, plan):
        if plan is not self.plan:
            self.plan = plan
            self.copies.append({name: getattr(plan, name).copy() for name in PLAN_FIELDS})
            self.array_addresses.add(plan.K.__array_interface__["data"][0])
        for name, values in self.copies[-1].items():
            np.testing.assert_array_equal(getattr(plan, name), values, err_msg=f"{name} at t = {t}")
        torques = super().compute(t, measurement, plan)
        self.torques.append(torques.copy())
        return torques


def _trot_loop(robot) -> tuple[InlineMpcLoop, _CheckingRiccati]:
    """A trotting real-time-iteration loop whose plans are in flight for 2.5 periods and read by the delay
    predictor (``carry``), its low level checking that no plan changes while in use."""
    reference = LocomotionReference(robot, get_gait("trot"), [VelocityCommand(start=0.0, vx=0.4)])
    low_level = _CheckingRiccati(robot)
    controller = InlineMpcLoop(
        robot,
        RecedingHorizonMpc(
            robot,
            reference,
            CafeProblemBuilder(
                WholeBodyModelFactory(robot), SRBModelFactory(robot=robot), ModelSchedule.named("S1")
            ),
            MpcSettings(
                period=0.02, latency="fixed", fixed_latency=0.05, scheme="rti", delay_compensation=True
            ),
        ),
        low_level,
    )
    return controller, low_level


def _closed_loop_with_plan_buffers(robot, capacity: int) -> _CheckingRiccati:
    controller, low_level = _trot_loop(robot)
    controller.planner.plan_buffers = PlanBuffers(capacity)
    simulate(MujocoPlant(robot), controller, SimulationOptions(0.3))
    assert controller.planner.plan_buffers.kept <= capacity
    return low_level


def test_reused_plan_arrays_never_change_a_plan_in_use(robot) -> None:
    """Closed loop with several plans in flight: no plan changes while the low level follows it, and the
    run with reused plan arrays is the run with new arrays for every plan, bit for bit."""
    reused = _closed_loop_with_plan_buffers(robot, capacity=6)
    fresh = _closed_loop_with_plan_buffers(robot, capacity=0)
    assert len(reused.copies) == len(fresh.copies) >= 10
    assert len(reused.array_addresses) <= 6  # the plans' arrays were reused
    for a, b in zip(reused.copies, fresh.copies, strict=True):
        for name in PLAN_FIELDS:
            np.testing.assert_array_equal(a[name], b[name])
    np.testing.assert_array_equal(np.array(reused.torques), np.array(fresh.torques))


def _closed_loop_with_lent_results(robot, lend: bool) -> tuple[_CheckingRiccati, int]:
    """The trot loop with the solvers' results lent (``SolverOptions.lend_results``) or new; before and
    after every call to the MPC, the solution it keeps (``previous``: read by ``predict`` and by the next
    warm start) must equal what it was when it was made. Returns the low level and the number of checks."""
    controller, low_level = _trot_loop(robot)
    mpc = controller.planner
    for solver in (mpc.solver, mpc.prepare_solver):
        solver.options.lend_results = lend
    kept: list[list[np.ndarray]] = []
    checks = [0]

    def snapshot() -> list[np.ndarray]:
        _, result = mpc.previous
        return [getattr(phase, name).copy() for phase in result.phases for name in ("xs", "us")]

    def checked(method):
        def call(t, q, v):
            if kept:
                for array, before in zip(snapshot(), kept[-1], strict=True):
                    np.testing.assert_array_equal(array, before, err_msg=f"kept solution at t = {t}")
                checks[0] += 1
            outcome = method(t, q, v)
            kept.append(snapshot())
            return outcome

        return call

    for name in ("update", "prepare", "feedback"):
        setattr(mpc, name, checked(getattr(mpc, name)))
    simulate(MujocoPlant(robot), controller, SimulationOptions(0.3))
    return low_level, checks[0]


def test_lent_solver_results_never_change_a_solution_in_use(robot) -> None:
    """Closed loop with the MPC's solver results lent: the solution the MPC keeps never changes while it is
    kept, and the run equals the one with new result arrays, plan for plan and torque for torque."""
    lent, lent_checks = _closed_loop_with_lent_results(robot, lend=True)
    new, new_checks = _closed_loop_with_lent_results(robot, lend=False)
    assert lent_checks == new_checks >= 20
    assert len(lent.copies) == len(new.copies) >= 10
    for a, b in zip(lent.copies, new.copies, strict=True):
        for name in PLAN_FIELDS:
            np.testing.assert_array_equal(a[name], b[name])
    np.testing.assert_array_equal(np.array(lent.torques), np.array(new.torques))


@pytest.mark.parametrize("field", ["state", "torque", "forces", "foot_positions", "foot_velocities"])
@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf])
def test_reference_window_check_finds_any_non_finite_entry(field: str, value: float) -> None:
    """The window check (compiled, no temporaries) flags a NaN or an infinity anywhere in its rows, and
    nothing past them (rows beyond the window's ``n`` are not the references of this update)."""
    window = ReferenceWindow(6, 19, 18, 12, 4)
    window.set_times(np.linspace(0.0, 0.1, 4))
    window.check_finite("test")
    rows = getattr(window, field)
    rows[-1].reshape(-1)[-1] = value
    with pytest.raises(ValueError, match=field):
        window.check_finite("test")
    rows[-1].reshape(-1)[-1] = 0.0
    getattr(window, f"_{field}")[5].reshape(-1)[0] = value  # a row past ``n``
    window.check_finite("test")


def test_trajectory_state_written_in_place_is_the_knot_or_the_interpolation() -> None:
    """``PiecewiseTrajectory.state_into`` (the warm start's, into its guess buffers): a knot's own state
    within half a quantum of its time, the tangent-space interpolation between knots, the ends past them;
    ``out`` is fully written and no knot state changes."""
    times = np.array([0.0, 0.01, 0.025, 0.03])
    xs = np.arange(12.0).reshape(4, 3) ** 2
    trajectory = PiecewiseTrajectory(times, xs, np.zeros((3, 2)), lambda a, b: b - a, lambda x, d: x + d)
    kept = xs.copy()
    out = np.full(3, np.nan)
    for t, expected in [
        (0.01 + 0.4 * TIME_QUANTUM, xs[1]),
        (-0.02, xs[0]),
        (0.5, xs[3]),
        (0.0175, xs[1] + (0.0175 - 0.01) / (0.025 - 0.01) * (xs[2] - xs[1])),
    ]:
        out[:] = np.nan
        trajectory.state_into(t, out)
        np.testing.assert_array_equal(out, expected)
        np.testing.assert_array_equal(trajectory.state_at(t), expected)
    np.testing.assert_array_equal(xs, kept)


def test_a_later_cold_solve_leaves_the_frozen_objects_frozen(monkeypatch) -> None:
    """The run's first cold solve collects once and freezes what lives (before the clock starts); a cold
    solve after ``reset`` (a resumed or restarted MPC, the robot waiting for its plan) does not again."""
    from cafe_mpc.planners.base import MpcStatistics, RecedingHorizonPlanner

    calls: list[str] = []
    monkeypatch.setattr(collector, "thaw", lambda: calls.append("thaw"))
    monkeypatch.setattr(collector, "freeze_live_objects", lambda: calls.append("freeze"))

    class Solved(RecedingHorizonPlanner):
        def _solve_at(self, t, q, v, solver):
            calls.append("solve")
            return "built", "result"

        def _plan(self, built, result):
            return "plan"

    planner = Solved.__new__(Solved)
    planner.previous = planner.prepared = None
    planner._collected = False
    planner.settings = MpcSettings(warm_up=0.0)
    planner.statistics = MpcStatistics()
    planner.first_solver = planner.solver = None
    state = np.zeros(3)
    assert planner.update(0.0, state, state) == "plan"
    assert calls == ["thaw", "solve", "freeze"]
    planner.update(0.02, state, state)  # warm
    planner.reset()
    planner.update(0.5, state, state)  # cold again
    assert calls == ["thaw", "solve", "freeze", "solve", "solve"]
