"""Steer CAFE-MPC at run time: ``cafe_mpc.Controller.set_command`` from a command sequence given on the
command line, in a MuJoCo loop (a joystick or a planner would call ``set_command`` the same way).

    .venv/bin/python examples/steer.py                                    # the default sequence below
    .venv/bin/python examples/steer.py --commands "0:vx=0.3 2:vx=0.6,yaw_rate=0.4 4:vx=0.2,vy=0.2"
    .venv/bin/python examples/steer.py --preset bound --commands "0:vx=0.3 2:vx=0.8" --mode process

Each item is ``TIME:key=value,...`` (TIME in seconds from the start; keys ``vx``, ``vy`` in m/s,
``yaw_rate`` in rad/s, ``height`` in m; a key left out keeps its previous value). The controller is built
once; the commands are set while it runs. At the end the script prints, per item, the commanded and the
measured mean forward speed and yaw rate over the second half of the item's time.
"""

from __future__ import annotations

import argparse
import itertools
import math
import sys
import time

import mujoco
import numpy as np

import cafe_mpc

DEFAULT_COMMANDS = "0:vx=0.3 2:vx=0.6,yaw_rate=0.3 4:vx=0.2,yaw_rate=0"
KEYS = ("vx", "vy", "yaw_rate", "height")


def parse_commands(text: str) -> list[tuple[float, dict[str, float]]]:
    """``"0:vx=0.3 2:vx=0.6,yaw_rate=0.3"`` -> ``[(0.0, {"vx": 0.3}), (2.0, {...})]`` (ValueError if bad)."""
    items = []
    for item in text.split():
        when, separator, body = item.partition(":")
        if not separator:
            raise ValueError(f"command {item!r}: expected TIME:key=value,...")
        values = {}
        for pair in body.split(","):
            key, equals, value = pair.partition("=")
            if not equals or key not in KEYS:
                raise ValueError(f"command {item!r}: {pair!r} is not one of {', '.join(KEYS)}=VALUE")
            values[key] = float(value)
        items.append((float(when), values))
    if not items or any(later[0] <= earlier[0] for earlier, later in itertools.pairwise(items)):
        raise ValueError("give at least one command, with increasing times")
    return items


def main() -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--preset", default="trot", help="a gait preset or a YAML run config")
    parser.add_argument("--commands", default=DEFAULT_COMMANDS, help="TIME:key=value,... items")
    parser.add_argument("--duration", type=float, default=6.0, help="simulated seconds")
    parser.add_argument("--mode", choices=["inline", "process"], default="inline", help="where the MPC runs")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="config override")
    arguments = parser.parse_args()
    try:
        items = parse_commands(arguments.commands)
    except ValueError as error:
        print(f"steer.py: error: {error}", file=sys.stderr)
        return 2

    with cafe_mpc.Controller(arguments.preset, arguments.set, mode=arguments.mode) as controller:
        model = mujoco.MjModel.from_xml_string(controller.robot.mjcf)
        data = mujoco.MjData(model)
        data.qpos[:] = controller.standing_qpos()
        mujoco.mj_forward(model, data)
        period = controller.control_period
        substeps = round(period / model.opt.timestep)
        ticks = round(arguments.duration / period)
        speed = np.zeros(ticks)  # forward speed in the heading frame, m/s
        yaw_rate = np.zeros(ticks)  # rad/s
        controller.reset(controller.measurement(data.qpos, data.qvel, time=data.time))
        wall_start = time.perf_counter()
        next_item = 0
        for tick in range(ticks):
            if next_item < len(items) and data.time + 1e-9 >= items[next_item][0]:
                controller.set_command(**items[next_item][1])  # checked; ConfigError if out of range
                next_item += 1
            if arguments.mode == "process":  # a real-time loop
                delay = wall_start + tick * period - time.perf_counter()
                if delay > 0:
                    time.sleep(delay)
            measurement = controller.measurement(data.qpos, data.qvel, time=data.time)
            data.ctrl[:] = controller.compute(data.time, measurement)
            for _ in range(substeps):
                mujoco.mj_step(model, data)
            w, x, y, z = data.qpos[3:7]
            heading = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
            speed[tick] = math.cos(heading) * data.qvel[0] + math.sin(heading) * data.qvel[1]
            yaw_rate[tick] = data.qvel[5]  # base-frame z rate (close to the yaw rate when level)
            if data.qpos[2] < 0.12:
                print(f"fell at {data.time:.2f} s")
                return 1
        commanded = {key: 0.0 for key in KEYS[:3]}
        print("from (s)  commanded vx, yaw rate  ->  measured vx, yaw rate (second half of the item)")
        for index, (start, values) in enumerate(items):
            commanded.update({key: value for key, value in values.items() if key in commanded})
            end = items[index + 1][0] if index + 1 < len(items) else arguments.duration
            window = slice(round((start + end) / 2 / period), round(end / period))
            print(
                f"{start:7.2f}   {commanded['vx']:6.2f} m/s {commanded['yaw_rate']:6.2f} rad/s  ->  "
                f"{speed[window].mean():6.2f} m/s {yaw_rate[window].mean():6.2f} rad/s"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
