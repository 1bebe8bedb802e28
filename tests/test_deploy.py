"""A deployment (``cafe_mpc.deploy``) from lying to lying: against our plant in the same process (simulated
time, deterministic: the start-up refusals, the sequence, link loss) and, over Unitree's DDS topics on the
loopback interface, against ``cafe-mpc sim-robot`` in another process."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from cafe_mpc import Controller
from cafe_mpc.deploy.runner import Deployment
from cafe_mpc.deploy.settings import DeploySettings
from cafe_mpc.deploy.startup import StartupRefused
from cafe_mpc.robot_io.inprocess import InProcessRobot
from cafe_mpc.robot_io.interface import Clock, JointCommand, LinkHealth, RobotInterface, RobotState
from cafe_mpc_lab.sim.motor_plant import MujocoMotorPlant

SOURCES = Path(__file__).resolve().parents[1] / "src"
QUICK = {
    "link_window": 0.2,
    "stand_duration": 0.6,
    "hold_duration": 0.2,
    "lie_duration": 0.5,
    "damp_duration": 0.2,
    "resume_after": 0.2,
}
"""Short motions (the robot file's gains still hold it): a test's seconds, not a robot's."""


class RecordingPlant(MujocoMotorPlant):
    """Our plant at the motor level, keeping the true base height and tilt of every physics step."""

    def __init__(self, robot) -> None:
        super().__init__(robot)
        self.record: list[tuple[float, float, float]] = []

    def step(self, torques: np.ndarray) -> None:
        super().step(torques)
        self.record.append((self.time, self.base_height(), self.tilt()))

    def between(self, start: float, end: float) -> np.ndarray:
        rows = np.array(self.record)
        return rows[(rows[:, 0] >= start) & (rows[:, 0] < end)]


@pytest.fixture(scope="module")
def trot_controller():
    """The trot preset on the Go2, its MPC inline with a fixed latency (deterministic in simulated time)."""
    overrides = ["robot=go2", "mpc.latency=fixed", "mpc.fixed_latency=0.02"]
    with Controller("trot", overrides, mode="inline") as controller:
        yield controller


def lying_robot(controller: Controller, **options) -> tuple[InProcessRobot, RecordingPlant]:
    plant = RecordingPlant(controller.robot)
    plant.lie_down()
    return InProcessRobot(plant, controller.robot.nu, controller.robot.n_feet, **options), plant


def test_startup_refuses_and_commands_nothing(trot_controller):
    """A joint outside its range, the trunk upside down, a link below 400 Hz, no state at all: one line,
    nothing sent."""
    robot = trot_controller.robot
    settings = DeploySettings(**QUICK)
    cases = []
    interface, plant = lying_robot(trot_controller)
    plant.model.jnt_range[1 + 2] = (-4.0, 4.0)  # the plant lets a calf rest where the robot file forbids
    plant.data.qpos[7 + 2] = robot.position_lower[2] - 0.3  # (a bad offset or calibration on a robot)
    cases.append((interface, f"joint outside its range: {robot.joint_names[2]}"))
    interface, plant = lying_robot(trot_controller)
    plant.data.qpos[3:7] = (0.0, 1.0, 0.0, 0.0)  # rolled over: MuJoCo's w, x, y, z
    plant.data.qpos[2] += 0.3
    cases.append((interface, "upside down"))
    interface, _ = lying_robot(trot_controller, state_rate_hz=250.0)
    cases.append((interface, "arrives at 2[45][0-9] Hz"))
    interface, _ = lying_robot(trot_controller, outages=[(0.0, 10.0)])
    cases.append((interface, "no state from the robot within 0.3 s"))
    for interface, message in cases:
        with pytest.raises(StartupRefused, match=message):
            Deployment(interface, trot_controller, settings.model_copy(update={"state_timeout": 0.3})).run()
        assert interface.commands_sent == 0
    interface, _ = lying_robot(trot_controller)
    report = Deployment(interface, trot_controller, settings, say=lambda _: None).run(dry_run=True)
    assert report.outcome == "dry-run" and interface.commands_sent == 0


@pytest.mark.slow
def test_stand_trot_link_loss_resume_and_lie_down(trot_controller):
    """Stand up from lying, trot, lose the link for 0.2 s (damped stance, no fall), resume the MPC, lie
    down: in simulated time, every command through the limits."""
    settings = DeploySettings(**QUICK, duration=1.4)
    mpc_start = QUICK["link_window"] + QUICK["stand_duration"] + QUICK["hold_duration"]
    outage = (mpc_start + 0.4, 0.2)
    interface, plant = lying_robot(trot_controller, outages=[outage])
    lines: list[str] = []
    report = Deployment(interface, trot_controller, settings, say=lines.append).run()
    assert report.outcome == "completed", report.message
    assert report.link_losses == 1 and report.mpc_starts == 2, lines
    assert [name for name, _ in report.phases] == [
        "wait",
        "check",
        "stand",
        "hold",
        "mpc-start",
        "mpc",
        "mpc-start",
        "mpc",
        "lie",
        "damp",
    ]
    phase_times = dict(report.phases[:3])
    lying_height = plant.between(0.0, 0.1)[:, 1].mean()
    lie_start = report.phases[-2][1]
    upright = plant.between(phase_times["stand"] + QUICK["stand_duration"], lie_start)
    assert upright[:, 1].min() > lying_height + 0.08, "the robot sagged to the floor while standing"
    assert upright[:, 2].max() < 0.3, "the trunk tilted as in a fall"
    outage_rows = plant.between(outage[0], outage[0] + outage[1] + settings.resume_after)
    assert outage_rows[:, 1].min() > lying_height + 0.08  # the damped stance held it up
    assert plant.record[-1][1] < lying_height + 0.04  # lying again at the end
    assert report.mpc_ticks > 0.5 * (settings.duration - outage[1] - settings.resume_after) / 0.002


@pytest.mark.slow
def test_a_link_that_stays_lost_lies_the_robot_down(trot_controller):
    """No state for longer than max_link_loss while the MPC runs: the deployment gives up and lies down."""
    settings = DeploySettings(**QUICK, duration=5.0, max_link_loss=0.3)
    mpc_start = QUICK["link_window"] + QUICK["stand_duration"] + QUICK["hold_duration"]
    interface, plant = lying_robot(trot_controller, outages=[(mpc_start + 0.3, 30.0)])
    report = Deployment(interface, trot_controller, settings, say=lambda _: None).run()
    assert report.outcome == "link-lost" and report.link_losses == 1 and report.mpc_starts == 1
    assert [name for name, _ in report.phases][-2:] == ["lie", "damp"]
    lying_height = plant.between(0.0, 0.1)[:, 1].mean()
    assert plant.between(mpc_start + 0.3, mpc_start + 0.6)[:, 1].min() > lying_height + 0.08
    assert plant.record[-1][1] < lying_height + 0.04


def _alive(group: int) -> bool:
    try:
        os.killpg(group, 0)
    except ProcessLookupError:
        return False
    return True


def _gone(group: int, timeout: float = 10.0) -> bool:
    """Whether every process of ``group`` has exited within ``timeout`` s (multiprocessing's resource
    tracker leaves shortly after its parent)."""
    deadline = time.monotonic() + timeout
    while _alive(group):
        if time.monotonic() > deadline:
            return False
        time.sleep(0.1)
    return True


def _stop_group(process: subprocess.Popen) -> None:
    """SIGTERM the process's group, then SIGKILL what is left after 10 s."""
    if process.poll() is None or _alive(process.pid):
        try:
            os.killpg(process.pid, signal.SIGTERM)
        except ProcessLookupError:
            return
        deadline = time.monotonic() + 10.0
        while _alive(process.pid) and time.monotonic() < deadline:
            time.sleep(0.1)
        if _alive(process.pid):
            os.killpg(process.pid, signal.SIGKILL)
    process.wait(timeout=10)


@pytest.mark.slow
@pytest.mark.realtime
def test_deploy_over_dds_against_sim_robot(tmp_path):
    """``cafe-mpc sim-robot`` and ``cafe-mpc deploy`` as two processes on the loopback interface: the Go2
    stands up and trots (0.3 m/s); the link is cut for 0.3 s (SIGUSR1 to the simulator): the deployment holds
    the damped stance, restarts the MPC once states flow again, and lies the robot down at the end. No
    process is left behind."""
    pytest.importorskip("cyclonedds")
    env = dict(os.environ, PYTHONPATH=str(SOURCES))
    domain = "41"  # away from the robots' 0 and a simulator's default 1
    cli = [sys.executable, "-m", "cafe_mpc_lab.cli"]
    wire = ["--network-interface", "lo", "--domain", domain]
    sim_out, deploy_out = tmp_path / "sim.json", tmp_path / "deploy.json"
    sim_robot = subprocess.Popen(
        [*cli, "sim-robot", "--robot", "go2", *wire, "--out", str(sim_out)],
        env=env,
        start_new_session=True,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.STDOUT,
    )
    options = [f"--deploy-set={key}={value}" for key, value in QUICK.items()]
    # a loaded 2-core machine runs three processes here: no spinning, and a link judged more leniently
    options += ["--deploy-set=min_link_rate_hz=200", "--deploy-set=stale_after=0.1", "--deploy-set=spin=0"]
    options += ["--set=gait.commands.0.vx=0.3", "--duration=4", f"--out={deploy_out}", "-q"]
    lines: list[str] = []
    deploy = None
    try:
        deploy = subprocess.Popen(
            [*cli, "deploy", "trot", "--robot", "go2", *wire, *options],
            env=env,
            start_new_session=True,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        cut = False
        deadline = time.monotonic() + 600.0
        for line in deploy.stdout:  # ends when the deployment exits
            lines.append(line)
            if "MPC running" in line and not cut:
                time.sleep(1.5)  # trot a while, then cut the link
                os.kill(sim_robot.pid, signal.SIGUSR1)
                cut = True
            assert time.monotonic() < deadline, "the deployment took over 10 minutes"
        deploy.wait(timeout=60)
        assert _gone(deploy.pid), "the deployment left a process behind (its MPC process?)"
    finally:
        if deploy is not None:
            _stop_group(deploy)
        _stop_group(sim_robot)
    assert _gone(sim_robot.pid)
    output = "".join(lines)
    report = json.loads(deploy_out.read_text())
    assert report["outcome"] == "completed", output
    assert report["link_losses"] == 1 and report["mpc_starts"] == 2, output
    assert report["mpc_ticks"] > 0 and report["link"]["crc_errors"] == 0
    summary = json.loads(sim_out.read_text())
    assert summary["crc_errors"] == 0 and summary["commands_received"] > 1000
    assert len(summary["outages"]) == 1
    trace = {name: np.array(values) for name, values in summary["trace"].items()}
    held = np.flatnonzero(trace["kp_mean"] > 0)  # stand-up, hold, link loss, lie-down: the stance's PD
    mpc = np.arange(held[0], held[-1])
    mpc = mpc[trace["kp_mean"][mpc] == 0.0]  # between them with no stiffness: the MPC's torques
    assert len(mpc) > 0, output
    lying = trace["z"][0]
    assert trace["z"][mpc].min() > lying + 0.08, "the robot sagged or fell while the MPC ran"
    assert trace["tilt"][mpc].max() < 0.3
    start, end = summary["outages"][0]
    around = (trace["t"] >= start) & (trace["t"] < end + 0.5)
    assert trace["z"][around].min() > lying + 0.08, "the robot sagged while the link was cut"
    assert trace["z"][-1] < lying + 0.04  # lying again


def test_terminal_teleop_steers_and_refuses():
    """The deployment's terminal commands: steps of speed and yaw rate, a gait switch, a refusal, the stop."""
    from cafe_mpc_lab.cli import DeployTeleop

    stopped = []
    with Controller("trot", ["robot=go2"]) as controller:  # its own: the commands stay with it
        teleop = DeployTeleop(controller, lambda: stopped.append(True))
        _steer(teleop)
    assert stopped == [True]


def _steer(teleop) -> None:
    start = teleop.vx
    assert teleop.handle("w") == f"vx {start + 0.1:+.2f} m/s, yaw rate +0.00 rad/s"
    assert teleop.handle("d").endswith("yaw rate -0.10 rad/s")
    assert teleop.handle("x") == "vx +0.00 m/s, yaw rate +0.00 rad/s"
    assert teleop.handle("g bound") == "gait bound from the next cycle"
    assert teleop.handle("g cartwheel").startswith("refused: invalid gait")
    for _ in range(40):  # 4 m/s: beyond what the robot can be commanded
        answer = teleop.handle("w")
    assert answer.startswith("refused") and teleop.vx < 4.0
    assert teleop.handle("?").startswith("commands:")
    assert teleop.handle("q") == "stopping: lying down"


class _ScriptedClock(Clock):
    """A wall clock in name (``realtime``) whose time moves only when the loop sleeps: deterministic."""

    realtime = True

    def __init__(self) -> None:
        self.t = 0.0

    def now(self) -> float:
        return self.t

    def sleep_until(self, t: float) -> None:
        self.t = max(self.t, t)


class _PeriodicRobot(RobotInterface):
    """States arriving every ``period`` s from ``phase`` s on; each command written records how long after
    the newest state's arrival it left."""

    def __init__(self, robot, period: float, phase: float) -> None:
        self.n_joints = robot.nu
        self.clock = _ScriptedClock()
        self.period, self.phase = period, phase
        self.state = RobotState.zeros(robot.nu, robot.n_feet)
        self.answered: list[tuple[int, float]] = []

    def read(self) -> RobotState:
        arrived = int(np.floor((self.clock.t - self.phase) / self.period + 1e-9)) + 1
        self.state.sequence = arrived
        self.state.received = self.phase + (arrived - 1) * self.period
        return self.state

    def write(self, command: JointCommand) -> None:
        state = self.read()
        self.answered.append((state.sequence, self.clock.t - state.received))

    def health(self) -> LinkHealth:
        raise NotImplementedError

    def open(self) -> None: ...

    def close(self) -> None: ...


@pytest.mark.parametrize("sync", [True, False])
def test_ticks_lock_onto_the_robots_states(trot_controller, sync):
    """With ``sync_to_state`` each command leaves as soon as the state it answers arrived (the robot's
    states 1.3 ms out of phase with the loop's start); a free-running loop answers it 0.7 ms later."""
    robot = _PeriodicRobot(trot_controller.robot, trot_controller.control_period, phase=0.0013)
    deployment = Deployment(robot, trot_controller, DeploySettings(sync_to_state=sync), say=lambda _: None)
    command = JointCommand.zeros(robot.n_joints)
    for _ in range(60):
        deployment._tick(lambda now, state, stale: command)
    sequences, delays = zip(*robot.answered[10:], strict=True)
    assert np.all(np.diff(sequences) == 1)  # every state answered once, none skipped
    if sync:
        assert max(delays) < 0.2e-3
    else:
        assert min(delays) > 0.6e-3
