"""Where the 500 Hz loop and the MPC processes run (``cafe_mpc.control.scheduling``): separate cores, every
thread of an MPC process (a standby's too) away from the loop's core, real-time priority granted or refused
with a reason, memory locked or said why not."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

from cafe_mpc.assembly.controllers import process_planner
from cafe_mpc.assembly.resolve import resolve
from cafe_mpc.config import RecoveryConfig, load_config
from cafe_mpc.control.ipc.channels import ControlBlock
from cafe_mpc.control.process import ProcessMpcLoop
from cafe_mpc.control.scheduling import (
    CpuPlan,
    RealTimePriority,
    host_steal_seconds,
    lock_memory,
    unlock_memory,
)
from cafe_mpc.core.measurement import Measurement
from cafe_mpc.planners.cafe.plan import plan_format
from cafe_mpc_lab.experiments.controllers import build_recorder

TWO_CPUS = len(os.sched_getaffinity(0)) >= 2 if hasattr(os, "sched_getaffinity") else False


def test_the_loop_and_the_mpc_get_different_cores_or_none():
    plan = CpuPlan.of_this_process()
    if TWO_CPUS:
        assert plan.loop_cpu != plan.mpc_cpu
        assert {plan.loop_cpu, plan.mpc_cpu} <= os.sched_getaffinity(0)
    else:
        assert plan == CpuPlan(None, None)


@pytest.mark.skipif(not TWO_CPUS, reason="needs two CPUs")
def test_pinning_every_thread_moves_threads_that_were_already_running():
    """A thread started before the pin (as a numerical library's workers are) ends on the pinned CPU too;
    ``os.sched_setaffinity(0, ...)`` alone would leave it where it was."""
    cpu = max(os.sched_getaffinity(0))
    script = textwrap.dedent(
        f"""
        import os, threading, time
        from cafe_mpc.control.scheduling import pin_every_thread
        ready, done = threading.Event(), threading.Event()
        ids = []
        def worker():
            ids.append(threading.get_native_id()); ready.set(); done.wait()
        thread = threading.Thread(target=worker); thread.start(); ready.wait()
        pin_every_thread({cpu})
        print(sorted(os.sched_getaffinity(ids[0])), sorted(os.sched_getaffinity(0)))
        done.set(); thread.join()
        """
    )
    output = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True)
    assert output.stdout.split("] [") == [f"[{cpu}", f"{cpu}]\n"]


def test_real_time_priority_is_granted_and_released_or_refused_with_a_reason():
    with pytest.raises(ValueError, match="0 \\(off\\) to 99"):
        RealTimePriority(100)
    off = RealTimePriority(0)
    assert not off.acquire() and off.description.startswith("normal")
    before = os.sched_getscheduler(0)
    priority = RealTimePriority(10)
    if priority.acquire():
        reset_on_fork = getattr(os, "SCHED_RESET_ON_FORK", 0)
        assert os.sched_getscheduler(0) & ~reset_on_fork == os.SCHED_FIFO
        assert priority.description == "SCHED_FIFO 10"
        try:  # a process it starts (an MPC standby) begins in the normal class, not the loop's
            child = subprocess.run(
                [sys.executable, "-c", "import os; print(os.sched_getscheduler(0))"],
                capture_output=True,
                text=True,
                check=True,
            )
            assert int(child.stdout) == os.SCHED_OTHER
        finally:
            priority.release()
    else:
        assert priority.description.startswith("normal (SCHED_FIFO 10 refused")
    assert os.sched_getscheduler(0) == before


def test_memory_is_locked_or_the_reason_is_given_and_steal_is_read():
    status = lock_memory()
    try:
        assert status == "locked" or status.startswith("not locked (")
    finally:
        unlock_memory()
    steal = host_steal_seconds()
    assert steal is None or steal >= 0.0


@pytest.mark.slow
@pytest.mark.realtime
@pytest.mark.skipif(not TWO_CPUS, reason="needs two CPUs")
def test_the_mpc_process_and_its_standby_run_off_the_loops_core(robot):
    """The standby is started after the caller pinned itself to the loop's core: it must not inherit it; one
    built while the robot runs waits in the idle scheduling class."""
    config = load_config("trot", ["output.plots=false"])
    plans = plan_format(25, robot.nq + robot.nv, robot.nu, 2 * robot.nv, robot.n_feet)
    loop = ProcessMpcLoop(
        robot,
        _factory(config),
        build_recorder(resolve(config, robot)),
        plans,
        0.02,
        recovery=RecoveryConfig(standby=True),
    )
    cpus = CpuPlan.of_this_process()
    with loop:
        loop.start(0.0, Measurement.of_state(robot.q_standing, np.zeros(robot.nv), np.ones(4, bool)))
        assert os.sched_getaffinity(0) == {cpus.loop_cpu}
        for process in (loop.process, loop.standby):
            assert process is not None and process.is_alive()
            for task in os.listdir(f"/proc/{process.pid}/task"):
                assert os.sched_getaffinity(int(task)) == {cpus.mpc_cpu}
        if hasattr(os, "SCHED_IDLE"):  # a standby built while the robot runs waits in the idle class
            loop._discard_standby()
            loop._spawn_standby(background=True)
            deadline = time.perf_counter() + 60.0  # until it has started and switched (not a timing check)
            while loop._control.array[ControlBlock.STANDBY_READY] != 1.0 and time.perf_counter() < deadline:
                time.sleep(0.05)
            for process, policy in ((loop.standby, os.SCHED_IDLE), (loop.process, os.SCHED_OTHER)):
                for task in os.listdir(f"/proc/{process.pid}/task"):
                    assert os.sched_getscheduler(int(task)) == policy
                    assert os.sched_getaffinity(int(task)) == {cpus.mpc_cpu}


def _factory(config):
    import functools

    return functools.partial(process_planner, config.model_dump(mode="json"))


@pytest.mark.skipif(not hasattr(os, "SCHED_IDLE"), reason="needs SCHED_IDLE")
def test_a_process_goes_to_the_background_and_back_with_every_thread():
    """A standby MPC process builds and waits in ``SCHED_IDLE`` (every thread, also one started before),
    and takes over in the normal class; where leaving the idle class is refused it says so."""
    script = textwrap.dedent(
        """
        import os, threading
        from cafe_mpc.control.scheduling import background_priority, foreground_priority
        ready, done = threading.Event(), threading.Event()
        ids = []
        def worker():
            ids.append(threading.get_native_id()); ready.set(); done.wait()
        thread = threading.Thread(target=worker); thread.start(); ready.wait()
        granted = background_priority()
        idle = [os.sched_getscheduler(i) == os.SCHED_IDLE for i in (0, ids[0])]
        back = foreground_priority()
        normal = [os.sched_getscheduler(i) == os.SCHED_OTHER for i in (0, ids[0])]
        print(granted, idle, back, normal)
        done.set(); thread.join()
        """
    )
    output = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True).stdout
    granted, rest = output.split(" ", 1)
    assert granted == "SCHED_IDLE" and rest.startswith("[True, True]"), output
    if os.geteuid() == 0:  # leaving the idle class needs root or CAP_SYS_NICE
        assert rest.strip().endswith("normal [True, True]"), output
    else:
        assert "normal [True, True]" in rest or "refused" in rest, output
