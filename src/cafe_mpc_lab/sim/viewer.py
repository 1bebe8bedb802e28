"""Watch a run live: MuJoCo's own viewer (passive mode) on the plant, with the MPC's current plan drawn in it.

``LiveViewer`` is a ``sim.loop.Observer`` (``SimulationOptions(observer=LiveViewer.following(robot,
controller))``): it opens ``mujoco.viewer.launch_passive`` on the plant's model and data before the first
tick and, after the ticks that fall on its frame rate, draws the plan (``robots.plan_overlay.draw_plan``
into the viewer's ``user_scn``), with the plant's newest height map when it has a height-map sensor (green
points at the measured heights: ``sim.height_map.draw_height_map``), and calls ``sync()``. The simulation
stays in charge of time: the viewer never steps physics. By default the run is held to the wall clock
(``realtime``: never faster than real time, so a fast simulation can be watched; a slower one is shown as
fast as it runs). Closing the window ends the run early (the run still writes its results). The camera
follows the base.

The viewer needs a display (X11 or Wayland: ``DISPLAY``, ``WAYLAND_DISPLAY``; on a headless machine e.g.
``xvfb-run``). ``check_display()`` raises ``ViewerUnavailable`` with one line saying so before anything
starts (GLFW's own failure inside the viewer's thread would otherwise leave the caller waiting forever).
Drawing costs CPU (software OpenGL under Xvfb especially), which the MPC shares in measured-latency runs.

Keyboard teleop (``KeyboardTeleop``, gait runs): the arrow keys change the forward speed (up, down) and the
yaw rate (left, right), Home stops (zero speed and yaw rate), End switches to the next gait of
``TELEOP_GAITS`` (at the gait's next cycle boundary); each key press is checked like a config command and
posted to the MPC (``control.commands``), which follows it from its next update. The key list
and the current command are shown in the window.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable

import numpy as np

from cafe_mpc.config import VelocityCommand
from cafe_mpc.control.commands import GAIT_NAMES, CommandChannel, check_command
from cafe_mpc.core.plan import KnotPlan
from cafe_mpc.robots.plan_overlay import PlanOverlay, draw_plan
from cafe_mpc.robots.robot import Robot
from cafe_mpc_lab.sim.height_map import draw_height_map
from cafe_mpc_lab.sim.plant import Plant


class ViewerUnavailable(RuntimeError):
    """The live viewer cannot open here (no display, no GLFW)."""


def check_display() -> None:
    """Raise ``ViewerUnavailable`` (one line) unless a window can be opened."""
    if not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        raise ViewerUnavailable(
            "--viewer needs a display (DISPLAY is not set); on a headless machine run it under xvfb-run, "
            "or use --render for a video"
        )
    try:
        import glfw
    except Exception as error:  # the wheel's GLFW library missing or broken
        raise ViewerUnavailable(f"--viewer needs GLFW ({type(error).__name__}: {error})") from error
    errors: list[str] = []
    previous = glfw.set_error_callback(lambda code, message: errors.append(_text(message)))
    try:
        ok = glfw.init()
    except Exception as error:
        ok = False
        errors.append(str(error))
    finally:
        glfw.set_error_callback(previous)
    if not ok:
        detail = errors[-1] if errors else "glfw.init() failed"
        display = os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")
        raise ViewerUnavailable(f"--viewer cannot open a window on display {display!r}: {detail}")


def _text(message: bytes | str) -> str:
    return message.decode(errors="replace") if isinstance(message, bytes) else str(message)


KEY_RIGHT, KEY_LEFT, KEY_DOWN, KEY_UP, KEY_HOME, KEY_END = 262, 263, 264, 265, 268, 269
"""GLFW key codes (what MuJoCo's viewer passes to its ``key_callback``); keys MuJoCo's viewer does not use."""

SPEED_STEP = 0.1
"""m/s of forward speed per arrow-key press."""
YAW_RATE_STEP = 0.1
"""rad/s of yaw rate per arrow-key press."""
TELEOP_GAITS = ("trot", "flying_trot", "pace", "bound", "pronk", "stand")
"""The gaits End cycles through (``ocp.contact_schedule.GAITS``)."""


class KeyboardTeleop:
    """Arrow keys -> velocity commands for a gait run (module docstring).

    ``channel``: the MPC's command channel; ``command``: the command to start from (the config's first).
    ``key(code)`` is MuJoCo's ``key_callback`` (the viewer's thread calls it); it returns whether the key
    was one of ours. A command the robot cannot follow (``validate_command``) is refused and said on screen.
    """

    KEYS = (
        ("Up / Down", f"forward speed +- {SPEED_STEP} m/s"),
        ("Left / Right", f"yaw rate +- {YAW_RATE_STEP} rad/s"),
        ("Home", "stop (speed and yaw rate 0)"),
        ("End", "next gait (" + ", ".join(TELEOP_GAITS) + ")"),
    )

    def __init__(
        self, robot: Robot, channel: CommandChannel, command: VelocityCommand, gait: str = "trot"
    ) -> None:
        self.robot = robot
        self.channel = channel
        self.command = command.model_copy(update={"start": 0.0})
        self.gait = gait
        self._gait_posted = False
        self.message = ""
        self.presses = 0

    @classmethod
    def of_controller(cls, robot: Robot, controller: object) -> KeyboardTeleop | None:
        """Teleop for a run's controller (its ``inner`` controllers searched), or None when it takes no
        commands (PD standing, a composed reference such as the barrel roll)."""
        channel = reference = None
        seen = controller
        while seen is not None and (channel is None or reference is None):
            channel = channel if channel is not None else getattr(seen, "commands", None)
            reference = reference if reference is not None else getattr(seen, "reference", None)
            seen = getattr(seen, "inner", None)
        commands = getattr(reference, "commands", None)
        if not isinstance(channel, CommandChannel) or not hasattr(reference, "set_command") or not commands:
            return None
        gait = getattr(getattr(reference, "gait", None), "name", "trot")
        return cls(robot, channel, commands[0], gait)

    def key(self, code: int) -> bool:
        command = self.command
        if code == KEY_UP:
            changes = {"vx": round(command.vx + SPEED_STEP, 6)}
        elif code == KEY_DOWN:
            changes = {"vx": round(command.vx - SPEED_STEP, 6)}
        elif code == KEY_LEFT:
            changes = {"yaw_rate": round(command.yaw_rate + YAW_RATE_STEP, 6)}
        elif code == KEY_RIGHT:
            changes = {"yaw_rate": round(command.yaw_rate - YAW_RATE_STEP, 6)}
        elif code == KEY_HOME:
            changes = {"vx": 0.0, "vy": 0.0, "yaw_rate": 0.0}
        elif code == KEY_END:
            index = TELEOP_GAITS.index(self.gait) + 1 if self.gait in TELEOP_GAITS else 0
            self.gait, self._gait_posted = TELEOP_GAITS[index % len(TELEOP_GAITS)], True
            changes = {}
        else:
            return False
        wanted = command.model_copy(update=changes)
        try:
            untested = check_command(wanted, self.robot, self.gait)
        except ValueError as error:
            self.message = f"refused: {error}"
            return True
        self.command, self.message = wanted, f"untested: {untested}" if untested else ""
        self.presses += 1
        gait = GAIT_NAMES.index(self.gait) if self._gait_posted else None
        self.channel.post(wanted.vx, wanted.vy, wanted.yaw_rate, wanted.height, gait)
        return True

    def texts(self) -> tuple[str, str]:
        """The key list and the current command, as two columns for the viewer's overlay."""
        keys = "\n".join(key for key, _ in self.KEYS)
        actions = "\n".join(action for _, action in self.KEYS)
        command = self.command
        status = f"{self.gait}: vx {command.vx:+.2f} m/s, yaw rate {command.yaw_rate:+.2f} rad/s"
        return f"{keys}\n", f"{actions}\n{status}" + (f"\n{self.message}" if self.message else "")


class LiveViewer:
    """MuJoCo's passive viewer following a run, with the plan overlay (see the module docstring).

    ``plan_source()`` returns the plan the controller follows now (or None); ``fps``: frames per second of
    simulated time; ``realtime``: hold the run to the wall clock; ``teleop``: keyboard steering (arrow keys),
    or None.
    """

    def __init__(
        self,
        robot: Robot,
        plan_source: Callable[[], KnotPlan | None],
        fps: float = 30.0,
        realtime: bool = True,
        teleop: KeyboardTeleop | None = None,
    ) -> None:
        if not fps > 0:
            raise ValueError(f"viewer fps must be positive, got {fps}")
        self.robot = robot
        self.plan_source = plan_source
        self.period = 1.0 / fps
        self.realtime = realtime
        self.stop_reason = ""
        self.frames = 0
        self.overlay_geoms_max = 0
        self.height_map_points_max = 0
        self._plant: Plant | None = None
        self._handle = None
        self._next_frame = 0.0
        self._wall_start = 0.0
        self._threads: list[threading.Thread] = []
        self._overlay: PlanOverlay | None = None
        self._overlay_of: object | None = None
        self.teleop = teleop

    def key_callback(self, code: int) -> None:
        """MuJoCo's viewer calls this with each key press (GLFW key code), in its own thread."""
        if self.teleop is not None:
            self.teleop.key(code)

    @classmethod
    def following(cls, robot: Robot, controller: object, realtime: bool = True) -> LiveViewer:
        """The viewer of a run's controller: it draws the plan the controller follows now (its ``plan``) and,
        for a gait run, the arrow keys steer it (``KeyboardTeleop.of_controller``)."""
        teleop = KeyboardTeleop.of_controller(robot, controller)
        return cls(robot, lambda: getattr(controller, "plan", None), realtime=realtime, teleop=teleop)

    def start(self, plant: Plant) -> None:
        check_display()
        import mujoco
        import mujoco.viewer

        before = set(threading.enumerate())
        self._handle = mujoco.viewer.launch_passive(
            plant.model, plant.data, key_callback=self.key_callback, show_left_ui=False, show_right_ui=False
        )
        # the viewer's own thread: ``close`` waits for it, so that it has destroyed its window before the
        # interpreter's exit terminates GLFW (terminating under a live window crashed the process)
        self._threads = [thread for thread in threading.enumerate() if thread not in before]
        camera = self._handle.cam
        camera.type = mujoco.mjtCamera.mjCAMERA_TRACKING
        camera.trackbodyid = plant.base_body
        camera.distance, camera.elevation, camera.azimuth = 1.4, -20.0, 120.0
        self._next_frame = 0.0
        self._wall_start = time.perf_counter()
        self.frames = 0
        self._plant = plant
        self._draw(0.0)

    def update(self, t: float, plant: Plant) -> bool:
        handle = self._handle
        if handle is None:
            return True
        if not handle.is_running():
            self.stop_reason = "the viewer window was closed"
            return False
        if t + 1e-9 < self._next_frame:
            return True
        if self.realtime:
            ahead = self._wall_start + t - time.perf_counter()
            if ahead > 0:
                time.sleep(ahead)
        self._draw(t)
        self._next_frame = t + self.period
        return True

    def _draw(self, t: float) -> None:
        handle = self._handle
        plan = self.plan_source()
        if plan is not None and plan is not self._overlay_of:
            overlay = PlanOverlay.of_plan(self.robot, plan)  # None for a plan without configurations
            if overlay is not None:
                self._overlay, self._overlay_of = overlay, plan
        with handle.lock():
            scene = handle.user_scn
            scene.ngeom = 0
            if self._overlay is not None:
                self.overlay_geoms_max = max(self.overlay_geoms_max, draw_plan(scene, self._overlay, t))
            sensor = self._plant.height_map if self._plant is not None else None
            if sensor is not None and sensor.latest is not None:
                points = draw_height_map(scene, sensor.latest)
                self.height_map_points_max = max(self.height_map_points_max, points)
        if self.teleop is not None:
            import mujoco

            keys, actions = self.teleop.texts()
            handle.set_texts(
                (mujoco.mjtFontScale.mjFONTSCALE_150, mujoco.mjtGridPos.mjGRID_TOPLEFT, keys, actions)
            )
        handle.sync()
        self.frames += 1

    def close(self, timeout: float = 10.0) -> None:
        """Close the window and wait (up to ``timeout`` s) for the viewer's thread to end; idempotent."""
        if self._handle is not None:
            self._handle.close()
            self._handle = None
        for thread in self._threads:
            thread.join(timeout)
        self._threads = []

    def summary(self) -> dict:
        """What the viewer showed (``metrics.json``'s ``viewer`` block)."""
        return {
            "frames": int(self.frames),
            "overlay_geoms_max": int(self.overlay_geoms_max),
            "height_map_points_max": int(self.height_map_points_max),
            "closed_by_user": bool(self.stop_reason),
            "fps": float(np.round(1.0 / self.period, 3)),
            "teleop_key_presses": int(self.teleop.presses) if self.teleop is not None else None,
        }
