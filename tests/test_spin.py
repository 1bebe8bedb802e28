"""The spin: the composed reference (stand -> the half-turn jump -> trot) turns pi about the vertical once and
trots on in the new heading, continuous at the joins; the closed loop gets through the take-off turning."""

import numpy as np
import pytest

from cafe_mpc.assembly import build_reference, load_run_config, resolve
from cafe_mpc.reference.base import ReferenceWindow
from cafe_mpc.reference.composition import heading
from cafe_mpc_lab.report.task_metrics import task_from_reference

DT = 0.005


def _states(reference, robot, times: np.ndarray) -> np.ndarray:
    window = ReferenceWindow(len(times), robot.nq, robot.nv, robot.nu, robot.n_feet)
    window.set_times(times)
    reference.sample(window)
    return window.state


def test_spin_reference_turns_pi_and_trots_on_in_the_new_heading(robot):
    reference = build_reference(resolve(load_run_config("spin"), robot))
    task = task_from_reference(reference)
    assert task is not None and task.rotation_axis == 2
    assert task.roll_target == pytest.approx(np.pi)
    assert task.approach_speed is None and task.resume_speed == pytest.approx(0.5)
    for index in (1, 2):  # continuous at the joins: position (mm), orientation, velocity
        join = reference.segments[index].start
        before, after = _states(reference, robot, np.array([join - 1e-4, join + 1e-4]))
        assert np.linalg.norm(after[:3] - before[:3]) < 0.02, index
        assert abs(float(np.dot(before[3:7], after[3:7]))) > np.cos(0.05), index
        np.testing.assert_allclose(after[robot.nq :][:6], before[robot.nq :][:6], atol=0.1)
    times = np.arange(0.0, 4.5, DT)
    state = _states(reference, robot, times)
    headings = np.unwrap([heading(q[3:7]) for q in state])
    assert headings[0] == pytest.approx(0.0, abs=1e-6)
    assert headings[-1] == pytest.approx(np.pi, abs=0.1)
    assert headings.min() > -0.35  # the push winds up against the turn first (0.20 rad), then one way round
    # the trot after the spin moves along the new heading (-x in the world) at its 0.5 m/s
    late = times[1:] > task.end + 1.0
    assert np.median(np.diff(state[:, 0])[late] / DT) == pytest.approx(-0.5, abs=0.05)


@pytest.mark.slow
def test_closed_loop_spin_takes_off_turning():
    """Fixed latency (20 ms, deterministic), VWBC: the stand, the push and 0.15 s of the flight: all feet off
    the floor, the base above its standing height and turning about the vertical, no fall."""
    from cafe_mpc.config import load_config
    from cafe_mpc_lab.experiments.run import simulate_run

    takeoff = 0.5 + 0.20
    config = load_config(
        "spin", ["mpc.latency=fixed", f"simulation.duration={takeoff + 0.15}", "mpc.warm_up=0.2"]
    )
    _, _, log = simulate_run(config)
    assert not log.fell and log.time[-1] >= takeoff + 0.14
    flight = log.time > takeoff + 0.05
    assert np.any(~log.contacts[flight].any(axis=1))
    assert log.q[flight, 2].max() > 0.35
    assert np.mean(log.v[flight, 5]) > 4.0  # rad/s about the body z axis
    assert np.sum(log.v[:, 5]) * (log.time[1] - log.time[0]) > 0.8
