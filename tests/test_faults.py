"""Faults on the robot's side (docs/faults.md): each fault the plant injects (``plant.faults``), in a short
run, keeps the robot up with finite torques and leaves the run's record; a run that ends in an error or is
interrupted still writes its record; the MPC process killed or stopped is restarted or taken back and no
process is left behind.

No test asserts a time: the sensor faults run with fixed latency (deterministic), the MPC-process faults in
real time, where only what happened (not when) is checked.
"""

from __future__ import annotations

import json
import multiprocessing
import time
from pathlib import Path

import numpy as np
import pytest

from cafe_mpc.config import ConfigError, load_config
from cafe_mpc_lab.experiments.run import run

RECORD = {"config.yaml", "run.log", "metrics.json", "log.npz"}
"""The files every run leaves, also one that ended early."""

SENSOR_FAULTS = {
    "imu_dropout": ("{kind: imu_dropout, start: 0.6, duration: 0.3}", "imu_late"),
    "encoder_freeze": ("{kind: encoder_freeze, start: 0.6, duration: 0.3, joint: FR_knee}", "encoder_late"),
    "nan_sample": ("{kind: nan_sample, start: 0.6, sensor: gyro, period: 0.2}", "gyro"),
    "out_of_range": ("{kind: out_of_range, start: 0.6, sensor: accelerometer, period: 0.2}", "accelerometer"),
}
"""Each sensor fault, and the kind of rejected sample the sensing front end must count for it."""


def _record(path: Path) -> dict:
    assert {item.name for item in path.iterdir()} >= RECORD
    return json.loads((path / "metrics.json").read_text())


def _alive(pid: int) -> bool:
    """Whether process ``pid`` exists and is not a zombie."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


@pytest.mark.slow
@pytest.mark.parametrize("kind", list(SENSOR_FAULTS))
def test_a_sensor_fault_is_rejected_at_the_boundary_and_the_robot_walks_on(kind, tmp_path):
    fault, rejected = SENSOR_FAULTS[kind]
    config = load_config(
        "trot",
        [
            "simulation.duration=1.6",
            "mpc.latency=fixed",
            "mpc.fixed_latency=0.02",
            "output.plots=true",
            f"plant.faults=[{fault}]",
        ],
    )
    result = run(config, tmp_path / "run")
    metrics = _record(tmp_path / "run")
    assert not result.log.fell and "status" not in metrics
    assert np.all(np.isfinite(result.log.torque_command))
    faults = metrics["faults"]
    assert faults["injected"][0]["kind"] == kind
    assert faults["applied"] and faults["applied"][0]["kind"] == kind
    assert faults["sensors"]["rejected"].get(rejected, 0) > 0, faults["sensors"]
    for episode in (faults.get("ladder") or {}).get("episodes", []):
        assert episode["back_at"] is not None, episode  # every episode off the plans ended on a plan
    assert (tmp_path / "run" / "faults.png").exists()


@pytest.mark.slow
def test_an_imu_out_for_long_holds_the_balance_stance_until_fresh_plans_take_the_robot_back(tmp_path):
    config = load_config(
        "trot",
        [
            "simulation.duration=1.6",
            "mpc.latency=fixed",
            "mpc.fixed_latency=0.02",
            "output.plots=false",
            "plant.faults=[{kind: imu_dropout, start: 0.5, duration: 0.4}]",
        ],
    )
    result = run(config, tmp_path / "run")
    faults = result.metrics["faults"]
    assert not result.log.fell
    [outage] = faults["sensors"]["outages"]
    assert outage["sensor"] == "imu" and outage["end"] is not None
    [episode] = faults["ladder"]["episodes"]
    assert episode["lowest"] == "balance" and "imu" in episode["reason"]
    assert episode["back_at"] is not None and episode["back_at"] > outage["end"]
    steps = result.log.extra["safety_step"]
    assert steps.max() == 3 and steps[-1] == 0  # balance during the outage, the plan again at the end


@pytest.mark.slow
def test_a_bound_whose_imu_drops_out_bounds_on_with_the_attitude_of_its_model(tmp_path):
    """The IMU out for 50 ms in the bound: with its last sample held (``kinematic_kf.imu_outage: hold``) the
    low level acted on a pitch rate several rad/s off and the robot fell 0.8 s later; with the attitude and
    rates integrated from the model (``dynamics``, ``estimation.imu_outage``) it bounds on."""
    config = load_config(
        "bound",
        [
            "simulation.duration=3.2",
            "mpc.latency=fixed",
            "mpc.fixed_latency=0.02",
            "output.plots=false",
            "plant.faults=[{kind: imu_dropout, start: 2.13, duration: 0.05}]",
        ],
    )
    result = run(config, tmp_path / "run")
    log = result.log
    assert not log.fell
    assert result.metrics["faults"]["sensors"]["rejected"].get("imu_late", 0) > 0
    after = log.time > 2.3
    assert np.all((~log.contacts[after]).any(axis=0)), "every foot lifts off again after the dropout"
    assert np.all(log.contacts[after].any(axis=0)), "and lands again"


@pytest.mark.parametrize("ending", [RuntimeError, KeyboardInterrupt])
def test_a_run_that_ends_in_an_error_or_ctrl_c_writes_its_record(ending, tmp_path, monkeypatch):
    """An error (or Ctrl-C) inside the loop: the record of the ticks so far, marked failed (interrupted),
    then the error again."""
    from cafe_mpc.low_level.pd import PDController

    original = PDController.compute

    def failing(self, t, *args):
        if t >= 0.2:
            raise ending("injected by the test")
        return original(self, t, *args)

    monkeypatch.setattr(PDController, "compute", failing)
    config = load_config("stand", ["simulation.duration=1.0", "output.plots=true"])
    with pytest.raises(ending, match="injected by the test"):
        run(config, tmp_path / "run")
    metrics = _record(tmp_path / "run")
    assert metrics["status"] == ("interrupted" if ending is KeyboardInterrupt else "failed")
    assert "injected by the test" in metrics["error"]
    assert metrics["sim_time_s"] == pytest.approx(0.2, abs=0.01)  # the ticks simulated before the error
    assert (tmp_path / "run" / "base_height.png").exists()
    assert not list(tmp_path.glob(".*partial"))


def test_a_fault_that_does_not_fit_the_run_is_one_config_error():
    with pytest.raises(ConfigError, match=r"plant\.faults\.0.*ground_truth"):
        load_config("trot", ["estimator=ground_truth", "plant.faults=[{kind: imu_dropout, duration: 0.1}]"])
    with pytest.raises(ConfigError, match=r"plant\.faults\.0.*realtime"):
        load_config("trot", ["plant.faults=[{kind: mpc_kill, start: 1}]"])
    with pytest.raises(ConfigError, match="needs 'joint'"):
        load_config("trot", ["plant.faults=[{kind: encoder_freeze, duration: 0.1}]"])
    with pytest.raises(ConfigError, match=r"plant\.faults\.0.*mpc_pause.*not real time"):
        load_config(
            "trot", ["simulation.realtime=true", "plant.faults=[{kind: mpc_pause, start: 1, duration: 0.5}]"]
        )
    with pytest.raises(ConfigError, match="needs 'duration'"):
        load_config("trot", ["plant.faults=[{kind: mpc_pause, start: 1}]"])


# ------------------------------------------------------------------------------------ MPC process
def _realtime_fault(fault: str, tmp_path: Path) -> tuple[dict, object]:
    config = load_config(
        "trot",
        [
            "simulation.duration=3.0",
            "simulation.realtime=true",
            "output.plots=true",
            f"plant.faults=[{fault}]",
        ],
    )
    result = run(config, tmp_path / "run")
    return _record(tmp_path / "run"), result


@pytest.mark.slow
@pytest.mark.realtime
def test_a_killed_mpc_process_is_replaced_by_its_standby_and_leaves_no_process(tmp_path):
    metrics, result = _realtime_fault("{kind: mpc_kill, start: 0.5}", tmp_path)
    assert not result.log.fell and "status" not in metrics
    assert np.all(np.isfinite(result.log.torque_command))
    mpc = metrics["faults"]["mpc"]
    events = [event["event"] for event in mpc["events"]]  # a loaded machine may add stalls
    exited = events.index("mpc_exited")
    assert events[exited + 1] == "mpc_restarting", events
    assert "code -9" in mpc["events"][exited]["detail"]
    [restart] = mpc["restarts"]
    assert restart["standby"]  # the standby took over: no process was built from scratch
    # held in the balance stance through the cold solve, taken back by plans that stand (the gait restarts)
    episodes = metrics["faults"]["ladder"]["episodes"]
    assert episodes and episodes[0]["off_at"] <= restart["t"] + 0.01, episodes
    for episode in episodes:
        if episode["back_at"] is not None:
            tick = int(np.searchsorted(result.log.time, episode["back_at"] - 1e-9))
            assert result.log.extra["planned_stance"][tick].all(), episode
    assert mpc["processes"] >= 2 and mpc["failure"] is None
    killed = [item["pid"] for item in metrics["faults"]["applied"] if item["kind"] == "mpc_kill"]
    assert killed and not any(_alive(pid) for pid in killed)
    assert not multiprocessing.active_children()  # the MPC process and its standby are gone
    assert (tmp_path / "run" / "faults.png").exists()


@pytest.mark.slow
@pytest.mark.realtime
def test_a_stopped_mpc_process_is_continued_and_the_run_keeps_its_record(tmp_path):
    metrics, result = _realtime_fault("{kind: mpc_stall, start: 0.5, duration: 1.0}", tmp_path)
    assert not result.log.fell and "status" not in metrics
    assert np.all(np.isfinite(result.log.torque_command))
    faults = metrics["faults"]
    applied = [item["kind"] for item in faults["applied"]]
    assert applied == ["mpc_stall", "mpc_continue"]
    assert "mpc_stalled" in [event["event"] for event in faults["mpc"]["events"]]
    assert faults["ladder"]["episodes"], "the safe ladder never left the plans during a 1 s stall"
    for episode in faults["ladder"]["episodes"]:  # taken back by plans that stand (the gait restarts)
        if episode["back_at"] is not None:
            tick = int(np.searchsorted(result.log.time, episode["back_at"] - 1e-9))
            assert result.log.extra["planned_stance"][tick].all(), episode
    assert not multiprocessing.active_children()


@pytest.mark.slow
@pytest.mark.realtime
def test_the_api_in_process_mode_restarts_a_killed_mpc_process_and_leaves_no_process():
    """``Controller(mode="process")`` in a user's own MuJoCo loop: the MPC process killed by its id, the
    loop goes on (finite torques, the robot up), the standby takes over and its plans take the robot back
    (or keep it: its first plan may come before the last one ran out);
    ``faults()`` says so; ``close`` leaves no process. The loop runs until that happened (at most 40 s of
    simulated time: a bound on a loaded machine, not a timing check)."""
    import os
    import signal

    import mujoco

    from cafe_mpc.api import Controller

    with Controller("trot", mode="process") as controller:
        model = mujoco.MjModel.from_xml_string(controller.robot.mjcf)
        data = mujoco.MjData(model)
        data.qpos[:] = controller.standing_qpos()
        mujoco.mj_forward(model, data)
        substeps = round(controller.control_period / model.opt.timestep)
        controller.reset(controller.measurement(data.qpos, data.qvel, time=0.0))
        loop = controller._loop
        killed = loop.process.pid
        taken_back = False
        start = time.perf_counter()
        for tick in range(round(40.0 / controller.control_period)):
            delay = start + tick * controller.control_period - time.perf_counter()
            if delay > 0:  # against the wall clock, as on a robot
                time.sleep(delay)
            t = data.time
            if tick == round(0.3 / controller.control_period):
                os.kill(killed, signal.SIGKILL)
            torques = controller.compute(t, controller.measurement(data.qpos, data.qvel, time=t))
            assert np.all(np.isfinite(torques)), t
            data.ctrl[:] = torques
            for _ in range(substeps):
                mujoco.mj_step(model, data)
            assert data.qpos[2] > 0.15, f"the robot fell at t = {t:.2f} s"
            faults = controller.faults()
            episodes = faults.get("ladder", {}).get("episodes", [])
            # on the plans again: every episode off them ended (none, when the standby's first plan came
            # before the last plan ran out)
            taken_back = all(episode["back_at"] is not None for episode in episodes)
            restarted = (faults.get("mpc", {}).get("restarts") or [{}])[0].get("first_plan_at") is not None
            if taken_back and restarted:
                break
        assert taken_back, controller.faults()
        mpc = controller.faults()["mpc"]
        events = [event["event"] for event in mpc["events"]]  # a loaded machine may add stalls
        assert "mpc_exited" in events and events[events.index("mpc_exited") + 1] == "mpc_restarting", events
        assert mpc["restarts"][0]["standby"] and controller.failure is None
        processes = [loop.process, loop.standby]
    assert not _alive(killed)
    assert not any(process is not None and process.is_alive() for process in processes)
    assert not [child for child in multiprocessing.active_children() if child.name == "cafe-mpc-solver"]


def test_the_fault_experiment_plans_each_fault_and_runs_the_mpc_faults_in_real_time():
    from cafe_mpc_lab.experiments.sweep import prepare

    prepared = prepare("faults", None, [], {"task": "trot", "times": "2,3"})
    names = [variant.name for variant in prepared.plan.variants]
    assert len(names) == 2 * 14 and len(set(names)) == len(names)  # 14 faults at each of 2 times
    for name, config in prepared.configs.items():
        [fault] = config.plant.faults
        assert fault.start in (2.0, 3.0) and name.startswith(fault.kind)
        assert config.simulation.realtime == (fault.kind in ("mpc_kill", "mpc_stall"))
        assert config.mpc.latency == "fixed"
    stalls = sorted(
        c.plant.faults[0].duration for c in prepared.configs.values() if c.plant.faults[0].kind == "mpc_stall"
    )
    assert stalls == [0.2, 0.2, 0.5, 0.5, 2.0, 2.0]
    assert prepared.command == "cafe-mpc experiment faults --duration 7 --task trot --times 2,3"
    with pytest.raises(ConfigError, match="--task PRESET is required"):
        prepare("faults", None, [], {})


# ------------------------------------------------------------------------------ the pieces, alone
def test_the_safe_ladder_steps_down_and_only_fresh_plans_take_the_robot_back(robot):
    """plan -> last_plan (stale) -> balance (plan ran out) -> plan again only after ``take_back_plans``
    fresh plans in a row measured since; a hold (sensors) keeps it off; ``fail`` is the damped stance for
    good; no step returns a non-finite torque, also for a non-finite measurement."""
    from cafe_mpc.config import RecoveryConfig
    from cafe_mpc.control.plan_follower import NewestPlanFollower
    from cafe_mpc.core.measurement import Measurement
    from cafe_mpc.low_level.riccati import RiccatiController
    from cafe_mpc.low_level.synthetic import synthetic_plan

    recovery = RecoveryConfig(stale_after=0.05, take_back_plans=2)
    follower = NewestPlanFollower(robot, RiccatiController(robot), recovery)
    plan = synthetic_plan(robot, knots=10, dt=0.02)  # 0.2 s
    stand = Measurement.of_state(robot.q_standing, np.zeros(robot.nv), np.ones(robot.n_feet, dtype=bool))
    follower.new_plan(0.0, 0.0)
    assert np.all(np.isfinite(follower.compute(0.01, stand, plan))) and follower.step == "plan"
    follower.compute(0.08, stand, plan)
    assert follower.step == "last_plan" and follower.following
    torques = follower.compute(0.25, stand, plan)  # past the plan's end
    assert follower.step == "balance" and np.all(np.isfinite(torques))
    later = synthetic_plan(robot, knots=10, dt=0.02, t0=0.2)
    follower.new_plan(0.26, 0.19)  # measured before the robot left the plans: not fresh
    follower.compute(0.27, stand, later)
    assert follower.step == "balance"
    follower.new_plan(0.28, 0.26)  # one fresh plan of the two asked for
    follower.compute(0.29, stand, later)
    assert follower.step == "balance"
    follower.new_plan(0.30, 0.28)
    follower.compute(0.31, stand, later)
    assert follower.step == "plan"
    follower.hold(0.32, "sensors", "imu out")
    follower.compute(0.33, stand, later)
    assert follower.step == "balance" and "imu out" in follower.steps[-1]["reason"]
    follower.hold(0.34, "sensors", None)
    follower.fail(0.35, "gave up")
    follower.new_plan(0.36, 0.36)
    follower.new_plan(0.37, 0.37)
    nonfinite = Measurement.of_state(robot.q_standing, np.full(robot.nv, np.nan), np.ones(4, dtype=bool))
    assert np.all(np.isfinite(follower.compute(0.38, nonfinite, later)))
    assert follower.step == "damped"
    record = follower.record(0.002)
    assert [episode["lowest"] for episode in record["episodes"]] == ["balance", "damped"]
    assert record["episodes"][0]["back_at"] == 0.31 and record["episodes"][1]["back_at"] is None
    assert record["failure"] == "gave up"


def test_the_sensor_guard_holds_bad_samples_counts_them_and_reports_an_outage(robot):
    from cafe_mpc.config import SensorLimits
    from cafe_mpc.core.sensors import SensorGuard, SensorReadings

    guard = SensorGuard(
        SensorLimits(), robot.position_lower, robot.position_upper, robot.velocity_limits, robot.joint_names
    )
    readings = SensorReadings.zeros(robot.nu)
    readings.joint_positions[:] = robot.q_standing[7:]
    readings.accelerometer[2] = 9.81
    bad_first = SensorReadings.zeros(robot.nu)
    bad_first.gyro[0] = np.nan
    with pytest.raises(ValueError, match="gyro"):
        guard.check(bad_first)  # nothing to hold yet
    guard.check(readings)
    for tick in range(1, 100):
        readings.time = tick * 0.002
        readings.gyro[:] = 0.1 if tick < 10 else np.nan  # out from tick 10 on
        readings.joint_positions[2] = 50.0 if tick == 5 else robot.q_standing[9]
        readings.imu_time = readings.time
        checked = guard.check(readings)
        assert np.all(np.isfinite(checked.gyro)) and abs(checked.joint_positions[2]) < 10.0
    assert checked.gyro[0] == 0.1  # the last good sample, held
    assert guard.counts == {"gyro": 90, "joint_position": 1}
    assert guard.outage(readings.time).startswith("imu out since t = 0.020 s")
    readings.time += 0.002
    readings.gyro[:] = 0.0
    guard.check(readings)
    [imu] = [outage for outage in guard.outages if outage["sensor"] == "imu"]
    assert guard.outage(readings.time) is None and imu["end"] == pytest.approx(readings.time)
    assert [outage["sensor"] for outage in guard.outages] == [f"encoder {robot.joint_names[2]}", "imu"]


def test_the_balance_controller_stands_by_itself(tmp_path):
    """``wbc: balance``: the safe ladder's balance controller holds the standing robot (torques finite and
    within the limits)."""
    config = load_config("stand", ["wbc=balance", "simulation.duration=1.0", "output.plots=false"])
    result = run(config, None)
    assert not result.log.fell and np.all(np.isfinite(result.log.torque_command))
    assert abs(result.metrics["base_height_mean"] - 0.25) < 0.03
    assert result.metrics["torque_limit_ticks"] == 0
