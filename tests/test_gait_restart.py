"""The gait restarted from the stance the robot stands in after the safe ladder held it (docs/faults.md):
the locomotion reference's ``restart_gait`` (a stand until further notice while the robot is held, then a
short stand and the gait from its first phase, the commands ramped in from rest), the MPC loops' side of it
(``control.loop.GaitRestart``, the held flag in the MPC process's measurement ring) and, closed loop with a
fixed latency, a bound whose plans are withheld (``mpc_pause``): taken back standing, it bounds again from
the gait's first phase and stays up. No test asserts a time.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from cafe_mpc.config import load_config
from cafe_mpc.control.ipc.channels import MeasurementRing
from cafe_mpc.control.loop import GaitRestart
from cafe_mpc.ocp.contact_schedule import get_gait
from cafe_mpc.reference.base import STANCE_TIME_EPS, ReferenceWindow
from cafe_mpc.reference.locomotion import LocomotionReference, VelocityCommand
from cafe_mpc_lab.experiments.faults import stepping_again
from cafe_mpc_lab.experiments.run import run

ALL_FEET = (True, True, True, True)


def _bound(robot) -> LocomotionReference:
    reference = LocomotionReference(
        robot, get_gait("bound"), [VelocityCommand(vx=0.5)], start_stance=0.2, command_ramp=0.5
    )
    reference.update(0.0, robot.q_standing, np.zeros(robot.nv))
    return reference


def test_a_restart_stands_until_released_then_starts_the_gait_from_its_first_phase(robot):
    reference = _bound(robot)
    gait = reference.gait
    held_at, released_at, stand = 1.03, 1.31, 0.2
    assert reference.stance_at(held_at + STANCE_TIME_EPS) != ALL_FEET  # mid-cycle: a flight or two feet
    reference.restart_gait(held_at, math.inf)
    for t in np.arange(held_at, held_at + 3.0, 0.01):
        assert reference.stance_at(float(t) + STANCE_TIME_EPS) == ALL_FEET
    assert reference.command_at(held_at + 0.1).vx == 0.0  # held: at rest
    assert reference.switch_times(held_at, held_at + 3.0) == []

    reference.restart_gait(released_at, stand)
    gait_start = released_at + stand
    for t in np.arange(released_at, gait_start - 0.005, 0.01):
        assert reference.stance_at(float(t) + STANCE_TIME_EPS) == ALL_FEET
    # from the stand's end the gait's phases in their order, a whole cycle from the first
    ends = np.cumsum([duration for _, duration in gait.cycle])
    for (flags, _), end in zip(gait.cycle, ends, strict=True):
        assert reference.stance_at(gait_start + end - 0.05) == flags
    switches = reference.switch_times(released_at, gait_start + gait.period - 0.01)
    np.testing.assert_allclose(switches, gait_start + np.r_[0.0, ends[:-1]], atol=1e-9)
    # the commands rest during the stand and ramp in from rest after it, as at the start
    assert reference.command_at(gait_start - 0.01).vx == 0.0
    assert reference.command_at(gait_start + 0.25).vx == pytest.approx(0.25)
    assert reference.command_at(gait_start + 0.6).vx == pytest.approx(0.5)
    # the compiled sampling (the MPC's) agrees: stance and the stand's load
    window = ReferenceWindow(40, robot.nq, robot.nv, robot.nu, robot.n_feet)
    reference.update(released_at, robot.q_standing, np.zeros(robot.nv))
    window.set_times(released_at + 0.02 * np.arange(40))
    reference.sample(window)
    for i, t in enumerate(window.times.tolist()):
        assert tuple(window.stance[i]) == reference.stance_at(t + STANCE_TIME_EPS)
        factor = reference.support_factor(t)
        assert window.forces[i, 0, 2] == pytest.approx(
            window.stance[i, 0] * factor * robot.total_mass * 9.81, rel=1e-3
        )
    assert reference.support_factor(released_at + 0.1) == 1.0 / robot.n_feet


def test_a_gait_switch_during_the_stand_starts_after_it_and_the_commanded_path_starts_again(robot):
    reference = _bound(robot)
    reference.path_origin = (0.0, np.zeros(2), 0.0)
    reference.restart_gait(2.0, 0.2)
    assert reference.path_origin is None  # the next measured pose starts the path: no pull back
    at = reference.set_gait(2.1, "trot")
    assert at == pytest.approx(2.2)
    assert reference.stance_at(2.2 + STANCE_TIME_EPS) == get_gait("trot").cycle[0][0]
    with pytest.raises(ValueError, match="stand >= 0"):
        reference.restart_gait(3.0, -0.1)


def test_the_loops_restart_the_gait_when_the_robot_is_held_and_when_it_is_taken_back(robot):
    reference = _bound(robot)
    restart = GaitRestart(reference, None)
    assert restart.stand == reference.start_stance
    assert not restart.observe(1.0, False)  # following plans: nothing changes
    assert restart.observe(1.02, True) and reference.restarts == [(1.02, math.inf)]
    assert not restart.observe(1.04, True)
    assert restart.observe(1.5, False) and reference.restarts[-1] == (1.5, reference.start_stance)
    off = GaitRestart(_bound(robot), 0.3, enabled=False)
    assert not off.observe(1.0, True)
    # the MPC process reads the held flag with each measurement
    ring = MeasurementRing(robot.nq, robot.nv, robot.n_feet)
    try:
        out = np.zeros(ring.slot - 2)
        contacts = np.ones(robot.n_feet)
        ring.write(7, 0.014, robot.q_standing, np.zeros(robot.nv), contacts, held=True)
        assert (
            ring.read(7, out)
            and out[ring.HELD] == 1.0
            and np.all(out[ring.HELD - robot.n_feet : ring.HELD] == 1)
        )
        ring.write(8, 0.016, robot.q_standing, np.zeros(robot.nv), contacts)
        assert ring.read(8, out) and out[ring.HELD] == 0.0
    finally:
        ring.close(unlink=True)


@pytest.mark.slow
def test_a_bound_taken_back_after_withheld_plans_restarts_from_stance_and_stays_up(tmp_path):
    """Plans withheld for 0.5 s mid-bound (``mpc_pause``, fixed latency): the last plan, then the balance
    stance; the plans that take the robot back stand, then the bound starts from its first phase, every
    foot steps again and the robot stays up."""
    config = load_config(
        "bound",
        [
            "simulation.duration=2.8",
            "mpc.latency=fixed",
            "mpc.fixed_latency=0.02",
            "output.plots=false",
            "plant.faults=[{kind: mpc_pause, start: 1.03, duration: 0.5}]",
        ],
    )
    result = run(config, tmp_path / "run")
    faults = result.metrics["faults"]
    assert not result.log.fell
    assert faults["applied"][0]["kind"] == "mpc_pause"
    [episode] = faults["ladder"]["episodes"]
    assert episode["lowest"] == "balance" and episode["back_at"] is not None
    reference = result.controller.reference
    (held_at, forever), (released_at, stand) = reference.restarts
    assert forever == math.inf and episode["off_at"] <= held_at < episode["back_at"] <= released_at
    assert stand == pytest.approx(0.2)
    gait = reference.gait
    assert reference.stance_at(released_at + stand + STANCE_TIME_EPS) == gait.cycle[0][0]
    assert reference.stance_at(released_at + 0.5 * stand) == ALL_FEET
    tick = int(np.searchsorted(result.log.time, episode["back_at"] - 1e-9))
    assert result.log.extra["planned_stance"][tick].all()  # taken back by a plan that stands
    assert stepping_again(result.log, episode["back_at"]) is not None


class _Planner:
    """What ``_Worker._observe_hold`` looks at of a planner: started, reset, settings, statistics."""

    def __init__(self, reference) -> None:
        self.reference, self.started, self.statistics = reference, True, object()
        self.settings = type("Settings", (), {"warm_up": 1.0})()

    def reset(self) -> None:
        self.started = False


class _Reference:
    def __init__(self) -> None:
        self.restarts: list[tuple[float, float]] = []
        self.start_stance = 0.2

    def restart_gait(self, t: float, stand: float) -> None:
        self.restarts.append((t, stand))


def test_a_process_that_solved_cold_on_the_gait_solves_again_from_the_held_stance_once():
    """A standby that took over solved cold from a measurement of the gait (feet in the air); when the robot
    is held off the plans its warm start is dropped (the next update solves cold from the stance), once:
    held again later, the warm start (now from the stance) is kept."""
    from cafe_mpc.control.process import _Worker

    reference = _Reference()
    worker = _Worker.__new__(_Worker)
    worker.planner = planner = _Planner(reference)
    worker.ring = type("Ring", (), {"HELD": 3})()
    worker.buffer = np.zeros(4)
    worker.gait_restart = GaitRestart(reference, None)
    worker._warm_from_gait = True  # its cold solve was on the gait
    assert worker._observe_hold(1.0) is False and planner.started
    worker.buffer[3] = 1.0  # held off the plans
    assert worker._observe_hold(1.1) is True
    assert not planner.started and planner.settings.warm_up == 0.0  # the next update solves cold
    assert worker._observe_hold(1.2) is False and worker._warm_from_gait is False
    planner.started = True  # that cold solve, from the held stance
    worker.buffer[3] = 0.0
    assert worker._observe_hold(1.5) is True  # taken back: the gait restarts
    worker.buffer[3] = 1.0
    assert worker._observe_hold(2.0) is True and planner.started  # held again: the warm start is kept
    assert reference.restarts == [(1.1, math.inf), (1.5, 0.2), (2.0, math.inf)]


class _RecordingPlanner:
    """What ``_Worker.prepare_standby`` uses of a planner: update, reset, settings."""

    def __init__(self) -> None:
        self.calls: list[tuple] = []
        self.settings = type("Settings", (), {"warm_up": 1.0})()

    def update(self, t, q, v):
        self.calls.append(("update", t, q.copy(), v.copy()))

    def reset(self) -> None:
        self.calls.append(("reset",))


def test_a_standby_makes_its_first_solve_while_it_waits_and_forgets_it():
    """A standby solves once on the newest measurement (kernels and solver data made then, not at its
    takeover), drops that warm start and the warm-up (its takeover is a cold solve alone); told to stop
    first, it stops; made the active one before any measurement, it goes straight to work."""
    import os

    from cafe_mpc.control.ipc.channels import ControlBlock, MeasurementRing
    from cafe_mpc.control.process import _Worker

    nq, nv = 3, 2
    ring, control = MeasurementRing(nq, nv, 1), ControlBlock()
    try:
        worker = _Worker.__new__(_Worker)
        worker.planner = planner = _RecordingPlanner()
        worker.ring, worker.control = ring, control
        worker.buffer = np.zeros(ring.slot - 2)
        worker.nq, worker.nv = nq, nv
        worker.parent_pid, worker.generation = os.getppid(), 2.0
        control.array[ControlBlock.ACTIVE] = 2.0  # made active before a measurement came: no solve here
        assert worker.prepare_standby() and planner.calls == []
        control.array[ControlBlock.ACTIVE] = 1.0
        control.array[ControlBlock.STOP] = 1.0  # told to stop while waiting for a measurement
        assert not worker.prepare_standby() and planner.calls == []
        control.array[ControlBlock.STOP] = 0.0
        ring.write(4, 0.008, np.arange(3.0), np.ones(2), np.ones(1, bool))
        ring.write(5, 0.010, np.arange(3.0) + 1, 2 * np.ones(2), np.ones(1, bool))
        assert worker.prepare_standby()
        (update, t, q, v), (reset,) = planner.calls
        assert (update, reset) == ("update", "reset") and t == 0.010  # the newest measurement
        np.testing.assert_array_equal(q, np.arange(3.0) + 1)
        np.testing.assert_array_equal(v, 2 * np.ones(2))
        assert planner.settings.warm_up == 0.0
    finally:
        for channel in (ring, control):
            channel.close(unlink=True)


def test_a_plan_older_than_the_stale_window_is_not_followed():
    """A plan received more than ``recovery.stale_after`` after its measurement (a cold solve after a takeover
    or a stall) is counted and not followed; the process still counts as delivering; a fresh one is
    followed."""
    from cafe_mpc.config import RecoveryConfig
    from cafe_mpc.control.process import ProcessMpcLoop
    from cafe_mpc.planners.base import MpcStatistics

    class Plans:
        def __init__(self) -> None:
            self.queue: list[tuple] = []

        def receive(self):
            return self.queue.pop(0) if self.queue else None

    class Follower:
        def __init__(self) -> None:
            self.heard: list[tuple[float, float]] = []

        def new_plan(self, t, measured_at) -> None:
            self.heard.append((t, measured_at))

    loop = ProcessMpcLoop.__new__(ProcessMpcLoop)
    loop.recovery = RecoveryConfig()
    loop._plans, loop.follower, loop.received = Plans(), Follower(), MpcStatistics()
    loop._plan, loop._restarting, loop._stalled_at, loop._last_plan_time = "last", None, None, 0.0
    loop._cold_hold = False
    stale = loop.recovery.stale_after
    loop._plans.queue.append(("cold", 1.0, 0.2))
    loop._poll_plan(1.0 + stale + 0.07, record=True)
    assert loop._plan == "last" and loop.follower.heard == [] and loop.received.stale_plans == 1
    assert loop._last_plan_time == 1.0 + stale + 0.07  # delivering: no stall
    loop._plans.queue.append(("fresh", 1.2, 0.01))
    loop._poll_plan(1.21, record=True)
    assert loop._plan == "fresh" and loop.follower.heard == [(1.21, 1.2)]
