"""CAFE-MPC in a MuJoCo loop you wrote yourself: ``cafe_mpc.Controller`` as a library.

The loop below is plain MuJoCo: load a model, step it, read ``qpos``/``qvel``, write ``ctrl``. The only
cafe-mpc calls are ``Controller(...)``, ``reset`` and ``compute`` (plus two helpers for MuJoCo's state
layout). Run it from the repository:

    .venv/bin/python examples/mujoco_loop.py                      # trot 3 s, MPC inline
    .venv/bin/python examples/mujoco_loop.py --preset bound --duration 5
    .venv/bin/python examples/mujoco_loop.py --mode process       # MPC in its own process, loop paced to
                                                                  # the wall clock (a real-time loop)

With your own simulator or robot, replace the MuJoCo calls: give ``compute`` the measured state in the
robot's joint order (``controller.robot.joint_names``) and send back the torques it returns.
"""

from __future__ import annotations

import argparse
import time

import mujoco

import cafe_mpc


def main() -> None:
    formatter = argparse.RawDescriptionHelpFormatter
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=formatter)
    parser.add_argument("--preset", default="trot", help="a gait preset or a YAML run config")
    parser.add_argument("--duration", type=float, default=3.0, help="simulated seconds")
    parser.add_argument("--mode", choices=["inline", "process"], default="inline", help="where the MPC runs")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="config override")
    arguments = parser.parse_args()

    with cafe_mpc.Controller(arguments.preset, arguments.set, mode=arguments.mode) as controller:
        # --- your simulator: the robot's own MJCF (any model with the same joints works) -------------------
        model = mujoco.MjModel.from_xml_string(controller.robot.mjcf)
        data = mujoco.MjData(model)
        data.qpos[:] = controller.standing_qpos()
        mujoco.mj_forward(model, data)
        control_period = controller.control_period  # 2 ms: the rate the presets are tuned for
        substeps = round(control_period / model.opt.timestep)

        # --- start: the first (cold) MPC solve runs here, while the robot stands ---------------------------
        controller.reset(controller.measurement(data.qpos, data.qvel, time=data.time))
        wall_start = time.perf_counter()
        for tick in range(round(arguments.duration / control_period)):
            if arguments.mode == "process":  # a real-time loop: tick k starts k control periods after start
                delay = wall_start + tick * control_period - time.perf_counter()
                if delay > 0:
                    time.sleep(delay)
            measurement = controller.measurement(data.qpos, data.qvel, time=data.time)
            data.ctrl[:] = controller.compute(data.time, measurement)  # held for one control period
            for _ in range(substeps):
                mujoco.mj_step(model, data)
            if data.qpos[2] < 0.12:
                break

        fell = bool(data.qpos[2] < 0.12)
        print(
            f"{arguments.preset} ({arguments.mode}): {data.time:.2f} s simulated, fell: {fell}, "
            f"base x {data.qpos[0]:.2f} m, height {data.qpos[2]:.3f} m, "
            f"mean forward speed {data.qpos[0] / max(data.time, 1e-9):.2f} m/s"
        )
        print("MPC:", {key: value for key, value in controller.statistics().items() if "median" in key})


if __name__ == "__main__":
    main()
