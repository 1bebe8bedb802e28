"""The safe ladder's stop step (docs/faults.md): an IMU out too long while the estimator stands in for it
stops the robot on the plans (the MPC's commands rest, the gait's steps go on) before the balance stance
holds it; a bound at 0.85 m/s caught by the balance stance at once fell.
"""

from __future__ import annotations

import numpy as np
import pytest

from cafe_mpc.config import RecoveryConfig, load_config
from cafe_mpc.control.loop import GaitRestart
from cafe_mpc.control.plan_follower import NewestPlanFollower
from cafe_mpc.core.measurement import Measurement
from cafe_mpc.low_level.riccati import RiccatiController
from cafe_mpc.low_level.synthetic import synthetic_plan
from cafe_mpc.ocp.contact_schedule import get_gait
from cafe_mpc.reference.base import STANCE_TIME_EPS
from cafe_mpc.reference.locomotion import LocomotionReference, VelocityCommand
from cafe_mpc_lab.experiments.run import run


def _moving(robot, vx: float) -> Measurement:
    v = np.zeros(robot.nv)
    v[0] = vx
    return Measurement.of_state(robot.q_standing, v, np.ones(robot.n_feet, dtype=bool))


def test_a_stop_follows_the_plans_until_the_base_is_slow_then_balances_until_fresh_plans(robot):
    recovery = RecoveryConfig(take_back_plans=1, stop_speed=0.2, stop_timeout=0.5)
    follower = NewestPlanFollower(robot, RiccatiController(robot), recovery)
    plan = synthetic_plan(robot, knots=50, dt=0.02)  # 1 s
    follower.new_plan(0.0, 0.0)
    follower.compute(0.01, _moving(robot, 0.8), plan)
    follower.stop(0.02, "sensors", "imu out since t = 0.000 s")
    torques = follower.compute(0.03, _moving(robot, 0.8), plan)
    assert follower.step == "stop" and follower.following and follower.stopping
    assert np.all(np.isfinite(torques))
    follower.new_plan(0.04, 0.04)
    follower.compute(0.05, _moving(robot, 0.5), plan)  # still fast: on the plans
    assert follower.step == "stop"
    follower.compute(0.06, _moving(robot, 0.1), plan)  # slow: the balance stance holds it
    assert follower.step == "balance" and not follower.following and not follower.stopping
    assert follower.steps[-1]["reason"].endswith("the base has slowed down")
    follower.new_plan(0.07, 0.07)  # fresh, but the IMU is still out
    follower.compute(0.08, _moving(robot, 0.0), plan)
    assert follower.step == "balance"
    follower.stop(0.09, "sensors", None)  # the IMU is back: plans measured since take the robot back
    follower.new_plan(0.10, 0.08)
    follower.compute(0.11, _moving(robot, 0.0), plan)
    assert follower.step == "balance"
    follower.new_plan(0.12, 0.10)
    follower.compute(0.13, _moving(robot, 0.0), plan)
    assert follower.step == "plan"
    [episode] = follower.record(0.002)["episodes"]
    assert episode["lowest"] == "balance" and episode["off_at"] == 0.03 and episode["back_at"] == 0.13
    # a stop that does not slow the robot hands over after stop_timeout
    follower.stop(0.2, "sensors", "imu out")
    follower.compute(0.21, _moving(robot, 0.8), plan)
    follower.compute(0.70, _moving(robot, 0.8), plan)
    assert follower.step == "stop"
    follower.compute(0.72, _moving(robot, 0.8), plan)
    assert follower.step == "balance"


def test_a_stop_rests_the_commands_on_the_gait_and_its_end_ramps_them_back(robot):
    reference = LocomotionReference(
        robot, get_gait("bound"), [VelocityCommand(vx=0.5)], start_stance=0.2, command_ramp=0.5
    )
    reference.update(0.0, robot.q_standing, np.zeros(robot.nv))
    flags = [reference.stance_at(t + STANCE_TIME_EPS) for t in np.arange(1.0, 2.0, 0.01)]
    restart = GaitRestart(reference, None)
    assert restart.observe(1.0, False, stopping=True) and reference.restarts == []
    assert reference.command_at(1.01).vx == 0.0 and reference.command_at(1.5).vx == 0.0
    assert [reference.stance_at(t + STANCE_TIME_EPS) for t in np.arange(1.0, 2.0, 0.01)] == flags
    assert not restart.observe(1.02, False, stopping=True)
    assert restart.observe(1.2, False, stopping=False)  # the stop lifted on the plans: ramped back
    assert reference.command_at(1.45).vx == pytest.approx(0.25)
    assert reference.command_at(1.8).vx == pytest.approx(0.5)
    # stopped, then held in the balance stance: the gait stands, and restarts from stance when taken back
    restart.observe(2.0, False, stopping=True)
    restart.observe(2.2, True, stopping=False)
    assert reference.restarts == [(2.2, float("inf"))] and reference.command_at(2.1).vx == 0.0
    restart.observe(2.6, False)
    assert reference.command_at(2.6 + reference.start_stance + 0.25).vx == pytest.approx(0.25)


@pytest.mark.slow
def test_a_bound_whose_imu_goes_out_500ms_in_flight_is_stopped_on_its_steps_and_stays_up(tmp_path):
    """IMU out 500 ms from 2.0 s: the outage is long enough at 2.12 s, in flight at 0.85 m/s. The balance
    stance at once (``imu_outage_response: balance``) did not slow the base and it rolled over its front
    feet (fell at 2.56 s); stopped on the plans it slows in one front stance, then balances."""
    config = load_config(
        "bound",
        [
            "simulation.duration=2.9",
            "mpc.latency=fixed",
            "mpc.fixed_latency=0.02",
            "output.plots=false",
            "plant.faults=[{kind: imu_dropout, start: 2.0, duration: 0.5}]",
        ],
    )
    result = run(config, tmp_path / "run")
    assert not result.log.fell
    steps = [change["step"] for change in result.metrics["faults"]["ladder"]["steps"]]
    assert steps[:2] == ["stop", "balance"]


def test_the_mpc_process_hears_of_a_stop_through_the_measurement_ring_and_rests_the_commands(robot):
    from cafe_mpc.control.ipc.channels import MeasurementRing
    from cafe_mpc.control.process import STOPPING, _Worker

    ring = MeasurementRing(robot.nq, robot.nv, robot.n_feet)
    try:
        out = np.zeros(ring.slot - 2)
        contacts = np.ones(robot.n_feet)
        ring.write(3, 0.006, robot.q_standing, np.zeros(robot.nv), contacts, held=STOPPING)
        assert ring.read(3, out) and out[ring.HELD] == STOPPING
    finally:
        ring.close(unlink=True)
    reference = LocomotionReference(
        robot, get_gait("bound"), [VelocityCommand(vx=0.5)], start_stance=0.2, command_ramp=0.5
    )
    worker = _Worker.__new__(_Worker)
    worker.planner = type("Planner", (), {"started": True})()
    worker.ring = type("Ring", (), {"HELD": 0})()
    worker.buffer = np.array([STOPPING])
    worker.gait_restart = GaitRestart(reference, None)
    worker._warm_from_gait = False
    assert worker._observe_hold(1.0) is True  # stopping, not held: the commands rest, the gait goes on
    assert reference.restarts == [] and reference.command_at(1.1).vx == 0.0
    worker.buffer[0] = 0.0
    assert worker._observe_hold(1.3) is True and reference.command_at(1.9).vx == pytest.approx(0.5)
