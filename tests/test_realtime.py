"""Real-time mode (``--realtime``): the MPC in its own process, faults, and that nothing is left behind.

Nothing here asserts timing (machines differ); the tests check that the run starts, delivers plans through
the shared-memory channels, records its real-time metrics, holds a stance when the MPC process dies or
stalls and no restart is allowed, ends with one clear error that leaves the run's record, and stops its
processes and frees its shared memory on success, on errors and on Ctrl-C. The MPC process's restarts and
injected faults: tests/test_faults.py.
"""

from __future__ import annotations

import json
import multiprocessing
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from cafe_mpc.assembly.controllers import process_planner
from cafe_mpc.assembly.resolve import resolve
from cafe_mpc.config import RecoveryConfig, load_config
from cafe_mpc.control.ipc.shared import shared_block_prefix
from cafe_mpc.control.process import ProcessMpcLoop
from cafe_mpc.core.measurement import Measurement
from cafe_mpc.planners.cafe.plan import plan_format
from cafe_mpc_lab.experiments.controllers import build_recorder
from cafe_mpc_lab.experiments.run import run
from cafe_mpc_lab.sim.loop import SimulationOptions, WallClockPacer, simulate
from cafe_mpc_lab.sim.mujoco_plant import MujocoPlant

pytestmark = pytest.mark.realtime
"""Every test here runs the MPC in its own process on the wall clock."""

SHM = Path("/dev/shm")


def _shared_memory_blocks() -> set[str]:
    """This test process's shared-memory blocks (other programs' and other test sessions' are not ours)."""
    return {path.name for path in SHM.glob(shared_block_prefix() + "*")} if SHM.exists() else set()


def _children(pid: int) -> set[int]:
    """Live child processes of ``pid`` (from /proc)."""
    children = set()
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid and fields[0] != "Z":
            children.add(int(entry.name))
    return children


@pytest.mark.slow
def test_realtime_run_starts_records_and_cleans_up(tmp_path):
    before = _shared_memory_blocks()
    config = load_config(
        "trot", ["simulation.duration=1.0", "output.plots=false", "simulation.realtime=true"]
    )
    result = run(config, tmp_path / "run")
    metrics = result.metrics
    assert metrics["timing"]["mode"] == "realtime"
    assert metrics["realtime"]["ticks"] == 500
    assert {"missed_ticks", "tick_lateness_ms_p99", "tick_control_ms_p99", "tick_step_ms_max"} <= set(
        metrics["realtime"]
    )
    mpc = metrics["mpc"]
    assert mpc["plans_received"] > 5 and mpc["rate_hz"] > 0
    assert mpc["latency_ms_median"] is not None and mpc["update_ms_median"] is not None
    assert mpc["worker_error"] is None
    # nothing compiled after the clock started, in either process (core.compilation)
    assert metrics["compiles_during_run"] == 0 and mpc["mpc_process_compiles_during_run"] == 0
    assert mpc["mpc_process_kernels_loaded_during_run"] == []
    assert np.all(np.isfinite(result.log.torque_command))
    assert not multiprocessing.active_children()
    assert _shared_memory_blocks() <= before


# ------------------------------------------------------------------------------------------ faults
class CrashingMpc:
    """Delegates to the real MPC, then dies (``os._exit``) or stalls after ``after`` updates (one-phase
    updates or real-time-iteration feedbacks)."""

    def __init__(self, inner, after: int, mode: str) -> None:
        self.inner, self.after, self.mode, self.count = inner, after, mode, 0

    def __getattr__(self, name):
        return getattr(self.inner, name)

    def _count(self) -> None:
        self.count += 1
        if self.count > self.after:
            if self.mode == "crash":
                os._exit(3)
            while True:  # stall: never deliver again
                time.sleep(1.0)

    def update(self, t, q, v):
        self._count()
        return self.inner.update(t, q, v)

    def feedback(self, t, q, v):
        self._count()
        return self.inner.feedback(t, q, v)


def crashing_mpc(config_data: dict, after: int, mode: str) -> CrashingMpc:
    return CrashingMpc(process_planner(config_data), after, mode)


@pytest.mark.parametrize("mode", ["crash", "stall"])
@pytest.mark.slow
def test_a_dead_or_stalled_mpc_process_without_restarts_holds_a_stance_and_ends_with_one_error(mode, robot):
    """``recovery.max_restarts_per_minute: 0``: the loop gives up at once and holds the damped stance."""
    import functools

    before = _shared_memory_blocks()
    config = load_config("trot", ["simulation.duration=3.0", "output.plots=false"])
    factory = functools.partial(crashing_mpc, config.model_dump(mode="json"), 5, mode)
    plans = plan_format(25, robot.nq + robot.nv, robot.nu, 2 * robot.nv, robot.n_feet)
    wait = 0.3 if mode == "stall" else 10.0  # a crash: a slow process on a loaded machine is no stall
    recovery = RecoveryConfig(
        stall_timeout=wait, stall_restart_after=wait, max_restarts_per_minute=0, standby=False
    )
    controller = ProcessMpcLoop(
        robot, factory, build_recorder(resolve(config, robot)), plans, 0.02, recovery=recovery
    )
    with controller:
        controller.start(0.0, Measurement.of_state(robot.q_standing, np.zeros(robot.nv), np.ones(4, bool)))
        assert len(_shared_memory_blocks() - before) == 3  # measurements, plans, control: named as ours
        options = SimulationOptions(3.0, pacer=WallClockPacer(), stop=controller.should_stop)
        log = simulate(MujocoPlant(robot), controller, options)
    assert controller.failure is not None
    assert ("exited" in controller.failure) if mode == "crash" else ("no plan" in controller.failure)
    assert controller.received.fallback_ticks > 0  # the safe ladder held the robot after the plan ran out
    assert controller.follower.step == "damped"
    assert log.time[-1] < 2.9  # the run ended early, soon after the failure
    assert not log.fell
    assert not controller.process.is_alive()
    assert not multiprocessing.active_children()
    assert _shared_memory_blocks() <= before


@pytest.mark.slow
def test_the_command_line_reports_a_dead_mpc_process(monkeypatch, tmp_path, capsys):
    """``cafe-mpc run --realtime`` ends with one line and a non-zero status when the MPC process dies and
    may not be restarted; the run's record (config, metrics.json saying it failed, the log) is written."""
    import cafe_mpc.assembly.controllers as controllers
    from cafe_mpc_lab.cli import main

    original = controllers.process_planner
    monkeypatch.setattr(controllers, "process_planner", _crashing_process_planner)
    try:
        command = ["run", "trot", "--realtime", "--duration", "2", "--out", str(tmp_path / "out")]
        status = main(
            [*command, "--set", "recovery.max_restarts_per_minute=0", "--set", "recovery.standby=false"]
        )
    finally:
        monkeypatch.setattr(controllers, "process_planner", original)
    assert status == 1
    lines = capsys.readouterr().err.strip().splitlines()
    errors = [line for line in lines if line.startswith("cafe-mpc: error:")]
    # the run's stage lines (issue 22) come first; the error is one line, the last
    assert errors == [lines[-1]] and "MPC process" in lines[-1]
    record = tmp_path / "out"
    metrics = json.loads((record / "metrics.json").read_text())
    assert metrics["status"] == "failed" and "MPC process" in metrics["error"]
    assert metrics["faults"]["mpc"]["events"][0]["event"] == "mpc_exited"
    assert metrics["faults"]["ladder"]["failure"] is not None
    assert {"config.yaml", "run.log", "log.npz"} <= {path.name for path in record.iterdir()}
    assert not multiprocessing.active_children()


def _crashing_process_planner(config_data: dict) -> CrashingMpc:
    return crashing_mpc(config_data, 5, "crash")


def test_an_interrupt_swallowed_before_the_loop_stops_the_run_at_its_next_tick(tmp_path):
    """A SIGINT that lands while numba compiles or loads a kernel is swallowed in llvmlite's ctypes callback;
    the command line's handler also sets ``sim.loop.INTERRUPT``, so the closed loop raises it again at its
    next tick: exit status 130, and the flag cleared for the next command."""
    from cafe_mpc_lab.cli import main
    from cafe_mpc_lab.sim.loop import INTERRUPT

    INTERRUPT.set()  # as the handler leaves it when its KeyboardInterrupt was swallowed
    assert main(["run", "stand", "--duration", "0.2", "--out", str(tmp_path / "out")]) == 130
    assert not INTERRUPT.is_set()


@pytest.mark.slow
def test_ctrl_c_stops_the_run_and_leaves_no_process(tmp_path):
    """SIGINT (Ctrl-C) during a real-time run: exit status 130 and no MPC process left behind."""
    command = [sys.executable, "-m", "cafe_mpc_lab.cli", "run", "trot", "--realtime", "--duration", "30"]
    process = subprocess.Popen(
        [*command, "--out", str(tmp_path / "out")], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    children: set[int] = set()
    deadline = time.time() + 60
    while time.time() < deadline and process.poll() is None and not children:
        children |= _children(process.pid)
        time.sleep(0.2)
    assert children, "the real-time run started no MPC process"
    time.sleep(3.0)  # cold solve, then the run itself
    process.send_signal(signal.SIGINT)
    _, stderr = process.communicate(timeout=30)
    assert process.returncode == 130, stderr
    deadline = time.time() + 5.0  # the resource tracker exits once it has seen its parent go
    while time.time() < deadline and any(Path(f"/proc/{pid}").exists() for pid in children):
        time.sleep(0.1)
    alive = {pid: _command_line(pid) for pid in children if Path(f"/proc/{pid}").exists()}
    assert not alive, f"processes left behind: {alive}"


def _command_line(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return "?"


def test_bench_mpc_reports_each_gait_as_json(capsys):
    """``cafe-mpc bench mpc --json``: one object per gait with the fields BENCHMARKS.md is made from (no
    timing is asserted)."""

    from cafe_mpc_lab.cli import main

    assert main(["bench", "mpc", "--gaits", "trot", "--duration", "0.4", "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert [row["gait"] for row in rows] == ["trot"]
    for key in (
        "update_ms_median",
        "update_ms_p99",
        "iteration_ms_median",
        "fell",
        "vx_mean",
        "timing_mode",
        "prepare_ms_median",
        "prepare_ms_p99",
        "feedback_ms_median",
        "feedback_ms_p99",
        "knots",
    ):
        assert key in rows[0]
    assert rows[0]["timing_mode"] == "measured"
    assert main(["bench", "mpc", "--gaits", "walk"]) == 2  # unknown preset: one clear error


class RobotClock:
    """A controller seen through a robot's clock: every tick's time a little off the control grid."""

    def __init__(self, inner, offset: float) -> None:
        self.inner, self.offset = inner, offset

    def reset(self) -> None:
        self.inner.reset()

    def compute(self, t, measurement):
        return self.inner.compute(t + self.offset, measurement)


@pytest.mark.slow
@pytest.mark.realtime
def test_a_prepared_update_is_fed_back_when_the_robots_clock_is_off_the_grid(robot):
    """Over a robot's wire the measurements carry the robot's time stamps, never exactly ``tick * period``:
    the MPC process must still feed back the update it prepared for that tick (it refused every one)."""
    import functools

    config = load_config("trot", ["output.plots=false"])
    factory = functools.partial(process_planner, config.model_dump(mode="json"))
    plans = plan_format(25, robot.nq + robot.nv, robot.nu, 2 * robot.nv, robot.n_feet)
    controller = ProcessMpcLoop(
        robot,
        factory,
        build_recorder(resolve(config, robot)),
        plans,
        0.02,
        recovery=RecoveryConfig(standby=False),
    )
    with controller:
        controller.start(0.0, Measurement.of_state(robot.q_standing, np.zeros(robot.nv), np.ones(4, bool)))
        options = SimulationOptions(1.5, pacer=WallClockPacer())
        simulate(MujocoPlant(robot), RobotClock(controller, 0.0004), options)
    assert controller.scheme == "rti"
    assert controller.statistics.failures == 0
    assert controller.summary(1.5)["plans_received"] >= 10
