"""The state estimator: time per update, memory per update, and how much a height bias matters.

* ``--timing``: median and p99 wall time of one ``StateEstimator.update`` (500 Hz path) on a standing robot
  with a plan that lifts two feet, and the memory ``tracemalloc`` sees retained after 1000 updates (0 is
  allocation-free; the temporaries of one update are reported as the peak).
* ``--height-bias MM [MM ...]``: the bound push test (``bound-push``, fixed latency) with the ground-truth
  measurement whose base height is raised by each bias: how sensitive the closed loop is to the height
  offset that a stance foot sinking into MuJoCo's soft floor gives the estimator (docs/estimation.md,
  ``foot_compliance``).

Usage: ``python benchmarks/bench_estimator.py --timing``;
``python benchmarks/bench_estimator.py --height-bias 0 4 7``.
"""

from __future__ import annotations

import argparse
import time
import tracemalloc
from dataclasses import dataclass

import numpy as np

from cafe_mpc.assembly import build_controller, resolve
from cafe_mpc.config import load_config
from cafe_mpc.core.measurement import Measurement
from cafe_mpc.core.sensors import SensorReadings
from cafe_mpc.estimation.estimator import StateEstimator
from cafe_mpc.robots.robot import load_robot
from cafe_mpc_lab.sim.loop import Push, SimulationOptions, simulate
from cafe_mpc_lab.sim.mujoco_plant import MujocoPlant


@dataclass
class TwoFeetPlan:
    times: np.ndarray
    dt: np.ndarray
    contacts: np.ndarray


def timing(updates: int = 3000) -> None:
    robot = load_robot("mini_cheetah")
    estimator = StateEstimator(robot)
    estimator.reset()
    readings = SensorReadings.zeros(robot.nu)
    readings.orientation[:] = robot.q_standing[3:7]
    readings.joint_positions[:] = robot.q_standing[7:]
    readings.accelerometer[:] = (0.0, 0.0, 9.81)
    readings.joint_torques[:] = 1.0
    contacts = np.ones((50, robot.n_feet), dtype=bool)
    contacts[25:, :2] = False
    plan = TwoFeetPlan(np.arange(50) * 0.01, np.full(50, 0.01), contacts)
    for k in range(200):  # compile, settle
        readings.time = k * 0.002
        estimator.update(readings, plan)
    times = np.zeros(updates)
    for k in range(updates):
        readings.time = (200 + k) * 0.002
        start = time.perf_counter()
        estimator.update(readings, plan)
        times[k] = time.perf_counter() - start
    print(f"update: median {np.median(times) * 1e6:.1f} us, p99 {np.percentile(times, 99) * 1e6:.1f} us")
    tracemalloc.start()
    before = tracemalloc.get_traced_memory()[0]
    for k in range(1000):
        readings.time = (200 + updates + k) * 0.002
        estimator.update(readings, plan)
    current, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    print(f"memory retained after 1000 updates: {current - before} B (peak of the temporaries {peak} B)")


class HeightBias:
    """The ground-truth measurement with its base height raised by ``offset`` m."""

    def __init__(self, inner, offset: float) -> None:
        self.inner, self.offset = inner, offset

    def reset(self) -> None:
        self.inner.reset()

    def compute(self, t: float, measurement: Measurement) -> np.ndarray:
        biased = Measurement(
            measurement.time,
            measurement.q.copy(),
            measurement.v,
            measurement.contacts,
            measurement.foot_forces,
        )
        biased.q[2] += self.offset
        return self.inner.compute(t, biased)


def height_bias(offsets_mm: list[float], duration: float = 3.5) -> None:
    config = load_config("bound-push", ["estimator=ground_truth", "mpc.latency=fixed"])
    robot = load_robot(config.robot)
    pushes = [Push(p.start, p.duration, p.force_on(robot.total_mass)) for p in config.pushes]
    for offset in offsets_mm:
        controller = HeightBias(build_controller(resolve(config, robot)), offset * 1e-3)
        log = simulate(MujocoPlant(robot), controller, SimulationOptions(duration, pushes=tuple(pushes)))
        outcome = f"fell at {log.fall_time:.3f} s ({log.fall_reason})" if log.fell else "stood"
        print(f"bound-push, ground truth + {offset:g} mm height bias, {duration:g} s: {outcome}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--timing", action="store_true")
    parser.add_argument("--height-bias", type=float, nargs="*", metavar="MM")
    arguments = parser.parse_args()
    if arguments.timing:
        timing()
    if arguments.height_bias:
        height_bias(arguments.height_bias)
    if not arguments.timing and not arguments.height_bias:
        parser.print_help()


if __name__ == "__main__":
    main()
