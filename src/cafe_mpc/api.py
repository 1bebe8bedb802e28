"""CAFE-MPC as a library: ``cafe_mpc.Controller`` for your own simulator or robot loop.

The same controller as ``cafe-mpc run`` (reference, CAFE-MPC, VWBC or Riccati low level), built from a run
config (a preset name, a YAML file or a ``RunConfig``), without the simulation around it::

    import cafe_mpc

    with cafe_mpc.Controller("trot", ["gait.commands.0.vx=0.3"]) as controller:
        controller.reset(controller.measurement(qpos, qvel, time=0.0))   # the cold solve, robot standing
        while running:
            torques = controller.compute(t, controller.measurement(qpos, qvel, time=t))
            ...                                                          # send them, advance your loop

``compute`` is meant to be called at the config's control rate (``simulation.control_rate_hz``, 500 Hz in the
presets) with the newest measurement; it returns the 12 joint torques in the robot's joint order
(``controller.robot.joint_names``), which hold until the next call. Times are seconds on your clock;
``reset`` sets time zero of the reference (the gait's commands, its start stance and ramp).

Two ways to run the MPC (``mode``):

* ``"inline"`` (default): in the calling thread, as ``cafe-mpc run`` does in simulated time
  (``control.inline``): every ``mpc.period`` of *your* time one ``compute`` call also runs
  an MPC update: with the real-time iteration (``mpc.scheme: rti``, default) the feedback phase of the update
  prepared for that call's time and the preparation of the next one (which expects its call on a multiple
  of the control period, else it falls back to a one-phase update); with ``mpc.latency: measured`` a plan
  takes effect once its wall time has passed on your clock, with ``fixed`` after ``mpc.fixed_latency``.
  Deterministic with ``fixed``; right for a simulator that waits for the controller.
* ``"process"``: in its own process, against the wall clock (``control.process``, ``cafe-mpc run
  --realtime``): ``compute`` never waits for a solve, it follows the newest plan. For a loop that runs in
  real time (a robot, or a simulator paced by the wall clock); ``reset`` starts the process (a new one on a
  later ``reset``), ``close()`` (or ``with``) stops it and frees its shared memory. If the MPC process dies
  it is restarted (``recovery.max_restarts_per_minute``), if it stalls it is taken back when it delivers
  again (or restarted after ``recovery.stall_restart_after``); meanwhile the safe ladder holds the robot
  (the last plan, the balance stance, the damped stance: docs/faults.md). Past the restart limit the robot
  stays in the damped stance and ``failure`` says why.

Either way the controller is the run config resolved once (``assembly``) and one MPC loop
(``control.loop.MpcLoop``) of the planner the config names, with the state estimator the assembly builds for
``measurement_from_sensors``.

Measurements are in the planning model's coordinates (``core.measurement.Measurement``: Pinocchio's free-flyer
``q``, ``v`` with the base linear velocity in the base frame); ``measurement(qpos, qvel, ...)`` converts
MuJoCo's free-joint state (``core.free_joint``). A robot has no such state: ``measurement_from_sensors(...)``
estimates it from the IMU and the joint encoders (``estimation.estimator.StateEstimator``, the config's
``kinematic_kf`` tuning) with the stance of the plan the controller follows; call it once per tick, before
``compute``. Every reading is checked first (``core.sensors.SensorGuard``, the config's ``recovery.sensors``):
a missing, late, non-finite or out-of-range sample is rejected and its last good value held, and a sensor
out for longer than ``outage_limit`` (or an estimate that diverged) holds the robot off its plans until it
is back; ``faults()`` reports what happened::

    measurement = controller.measurement_from_sensors(t, quaternion, gyro, accelerometer, q_joints, v_joints)
    controller.reset(measurement)          # first tick (robot standing)
    ...
    torques = controller.compute(t, controller.measurement_from_sensors(t, ...))

``set_command(vx=..., vy=..., yaw_rate=..., height=...)`` steers a gait config at run time (a joystick, a
planner, a keyboard): the command is checked as a config's is (``control.commands.check_command``), written in
place, and the MPC follows it from its next update (``control.commands``); ``set_gait(name)`` switches gait at
the next cycle boundary. ``plan`` is the plan the low level follows now (the planner's plan type:
``planners.cafe.plan.Plan`` for CAFE-MPC), e.g. to draw it (``robots.plan_overlay``).
``examples/mujoco_loop.py`` runs it against a MuJoCo loop, ``examples/steer.py`` steers it from a command
sequence given on its command line.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import ValidationError

from cafe_mpc.assembly.checks import robot_of
from cafe_mpc.assembly.controllers import build_estimator, build_mpc_loop
from cafe_mpc.assembly.resolve import resolve
from cafe_mpc.config import ConfigError, RunConfig, VelocityCommand, format_validation_error, load_config
from cafe_mpc.control.commands import GAIT_NAMES, check_command
from cafe_mpc.control.loop import MpcLoop
from cafe_mpc.core.free_joint import free_joint_measurement, free_joint_qpos
from cafe_mpc.core.measurement import Measurement
from cafe_mpc.core.plan import KnotPlan
from cafe_mpc.core.sensors import SensorReadings
from cafe_mpc.estimation.controller import SensorFrontEnd
from cafe_mpc.planners.resolved import ResolvedRun
from cafe_mpc.robots.robot import Robot

__all__ = ["Controller"]

logger = logging.getLogger(__name__)

Mode = Literal["inline", "process"]


class Controller:
    """An MPC over its low-level controller, for a loop you own (see the module docstring).

    ``config``: a preset name (``trot``, ``bound``, ...), a YAML file, or a ``RunConfig``; ``overrides``:
    ``key=value`` strings as ``cafe-mpc run --set`` takes them (not with a ``RunConfig``). ``mode``:
    ``inline`` or ``process``. Raises ``ConfigError`` (one line naming the key) for a config that cannot
    drive the robot (e.g. ``wbc: pd``, which has no MPC).
    """

    def __init__(
        self,
        config: RunConfig | str | Path = "trot",
        overrides: Sequence[str] = (),
        mode: Mode = "inline",
    ) -> None:
        if isinstance(overrides, str):
            raise ConfigError(
                f"overrides must be a list of 'key=value' strings, e.g. [{overrides!r}], not one string"
            )
        if isinstance(config, RunConfig):
            if overrides:
                raise ConfigError("overrides apply to a preset or a YAML file, not to a RunConfig")
        else:
            config = load_config(str(config), list(overrides))
        self.config = config
        self.mode: Mode = mode
        self.robot: Robot = robot_of(config)  # the config checked against the robot it names
        self.run: ResolvedRun = resolve(config, self.robot)
        """The config resolved once against the robot (``assembly.resolve``): what the controller runs."""
        # the low level without a run recorder: a loop of unknown length keeps no per-tick records
        self._loop: MpcLoop = build_mpc_loop(self.run, mode)
        self._t0 = 0.0
        self._started = False
        self._closed = False
        self._sensing: SensorFrontEnd | None = None  # built on the first measurement_from_sensors
        self._sensor_fault: tuple[str | None, bool] = (None, False)
        self._readings = SensorReadings.zeros(self.robot.nu)
        first = config.gait.commands[0] if config.gait is not None else VelocityCommand()
        self._command = (first.vx, first.vy, first.yaw_rate, first.height)
        """The last command set (initially the config's first), whose values ``set_command`` keeps."""
        self._gait: int | None = None
        """The gait set by ``set_gait`` (an index of ``control.commands.GAIT_NAMES``), None: the config's."""

    # ------------------------------------------------------------------------------------ lifecycle
    def __enter__(self) -> Controller:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Stop the MPC process (``process`` mode) and free its shared memory; idempotent."""
        self._loop.close()
        self._closed = True

    def _check_open(self) -> None:
        if self._closed:
            raise RuntimeError("this Controller is closed; create a new one")

    # -------------------------------------------------------------------------------------- control
    @property
    def control_period(self) -> float:
        """Seconds between ``compute`` calls the config is tuned for (1 / ``simulation.control_rate_hz``)."""
        return self.run.control_period

    def reset(self, measurement: Measurement, t: float | None = None) -> None:
        """Start (again) from ``measurement``: forget plans and warm starts, make ``t`` (default
        ``measurement.time``) time zero of the reference, and run the first (cold) MPC solve now, before your
        loop's clock starts, as on the robot (in ``process`` mode: start the MPC process, a new one after a
        previous ``reset``, and wait for its first plan; it follows the command and gait set so far)."""
        self._check_open()
        self._t0 = float(measurement.time if t is None else t)
        self._loop.reset()
        self._loop.start(0.0, self._relative(measurement, 0.0))
        self._started = True

    def restart_clock(self, t: float) -> None:
        """Make ``t`` (your clock) time zero again without a new solve, after a ``reset`` that took wall time
        while the robot held still (on a robot the cold solve runs while a stance holds it): the first
        ``compute`` then continues the first plan instead of jumping ahead by the time the start took."""
        self._check_open()
        self._t0 = float(t)

    def compute(self, t: float, measurement: Measurement) -> np.ndarray:
        """Joint torques (nu,) for time ``t`` (your clock) from ``measurement``; call at the control rate."""
        if not self._started:
            raise RuntimeError("call reset(measurement) before compute")
        torques = self._loop.compute(t - self._t0, self._relative(measurement, t - self._t0))
        return np.array(torques, dtype=float)

    def set_command(
        self,
        *,
        vx: float | None = None,
        vy: float | None = None,
        yaw_rate: float | None = None,
        height: float | None = None,
    ) -> None:
        """Steer: follow this velocity command from the MPC's next update on (in ``inline`` mode the next
        ``compute`` call that runs an update, in ``process`` mode the MPC process's next update).

        ``vx``, ``vy``: m/s forward and to the left in the heading frame; ``yaw_rate``: rad/s; ``height``: m
        (body height). An argument left out keeps its value from the previous ``set_command`` (initially the
        config's first command; ``height`` then stays as it was: ``None`` is the standing height). The
        command replaces the config's timed commands from then on and is approached like them
        (``gait.command_ramp``). It is checked as a config command is: ``ConfigError`` (one line) for a
        value the robot cannot follow (e.g. ``|vx| > 3 m/s``) or for a config without a gait (a composed
        reference such as the barrel roll cannot be steered). Written in place: no allocation, safe to call
        at the control rate."""
        self._check_steerable("set_command steers a gait")
        old_vx, old_vy, old_yaw_rate, old_height = self._command
        values = (
            old_vx if vx is None else vx,
            old_vy if vy is None else vy,
            old_yaw_rate if yaw_rate is None else yaw_rate,
            old_height if height is None else height,
        )
        if values != self._command:
            self._check_command(*values)
            self._command = values
        self._check_open()
        self._loop.commands.post(*self._command, self._gait)

    def set_gait(self, name: str) -> None:
        """Switch gait (``trot``, ``pace``, ``bound``, ``pronk``, ``flying_trot``, ``flying_pace``, ``stand``)
        at the current gait's next cycle boundary after the MPC's next update, so that no step is cut short;
        the velocity command stays. The config's other settings (swing height, weights, horizons) stay too:
        the gait presets differ only in their gait. ``ConfigError`` for an unknown gait or a config without a
        gait."""
        self._check_steerable("set_gait switches a gait")
        key = str(name).replace("-", "_").lower()
        if key not in GAIT_NAMES:
            raise ConfigError(f"invalid gait {name!r}; gaits: {', '.join(GAIT_NAMES)}")
        self._check_open()
        self._gait = GAIT_NAMES.index(key)
        self._loop.commands.post(*self._command, self._gait)

    def _check_steerable(self, what: str) -> None:
        if self.config.gait is None:
            name = self.config.name
            raise ConfigError(
                f"{what}; config {name!r} follows a composed reference (reference section) instead"
            )

    def _check_command(self, vx: float, vy: float, yaw_rate: float, height: float | None) -> None:
        """``ConfigError`` (one line) unless the robot can follow the command (``check_command``); a
        warning when the gait was not tested with it."""
        try:
            command = VelocityCommand(vx=vx, vy=vy, yaw_rate=yaw_rate, height=height)
        except ValidationError as error:
            raise ConfigError(f"invalid command: {format_validation_error(error, 'command')}") from error
        gait = GAIT_NAMES[self._gait] if self._gait is not None else self.config.gait.name
        try:
            untested = check_command(command, self.robot, gait)
        except ValueError as error:
            raise ConfigError(f"invalid command: {error}") from error
        if untested is not None:
            logger.warning("set_command: %s; it may not work", untested)

    def _relative(self, measurement: Measurement, t: float) -> Measurement:
        """The measurement on the controller's clock (time zero at ``reset``)."""
        return Measurement(t, measurement.q, measurement.v, measurement.contacts, measurement.foot_forces)

    # ---------------------------------------------------------------------------------- inspection
    @property
    def plan(self) -> KnotPlan | None:
        """The plan the low-level controller follows now (None before the first solve). Its times are on the
        controller's clock (zero at ``reset``)."""
        return self._loop.plan

    @property
    def failure(self) -> str | None:
        """``process`` mode: why the MPC process stopped delivering plans (None while all is well)."""
        return self._loop.failure

    def faults(self) -> dict:
        """What went wrong so far and what the controller did: ``ladder`` (the safe ladder's steps with
        their times, the episodes off the plans and how long until a fresh plan took the robot back) and, in
        ``process`` mode, ``mpc`` (the MPC process's exits, stalls and restarts, each restart's duration);
        ``sensors`` (rejected samples by kind, outages, estimator restarts) once ``measurement_from_sensors``
        is in use. Empty sections are left out."""
        record = dict(self._loop.fault_record(self.control_period) or {})
        if self._sensing is not None and self._sensing.eventful:
            record["sensors"] = self._sensing.record()
        return record

    def statistics(self) -> dict:
        """The MPC's update statistics so far (``MpcLoop.summary``: solves, failures, update and latency
        medians, ...); in ``process`` mode the plans received here (the MPC process's own records arrive when
        it stops)."""
        return self._loop.summary()

    # ---------------------------------------------------------------------------- measurements
    def measurement(
        self,
        qpos: np.ndarray,
        qvel: np.ndarray,
        time: float = 0.0,
        contacts: Sequence[bool] | None = None,
    ) -> Measurement:
        """A ``Measurement`` from MuJoCo's free-joint state (``qpos``: position, quaternion w x y z, joints;
        ``qvel``: world-frame linear velocity, base-frame angular velocity, joint rates), joints in the
        robot's order (``core.free_joint.free_joint_measurement``). ``contacts``: feet in contact (leg order;
        only ``vwbc.stance_source: intersect`` uses them; default none)."""
        robot = self.robot
        try:
            return free_joint_measurement(qpos, qvel, robot.nv, robot.n_feet, time, contacts)
        except ValueError as error:
            raise ValueError(f"measurement: {error}") from error

    def measurement_from_sensors(
        self,
        time: float,
        orientation: Sequence[float] | np.ndarray,
        gyro: Sequence[float] | np.ndarray,
        accelerometer: Sequence[float] | np.ndarray,
        joint_positions: Sequence[float] | np.ndarray,
        joint_velocities: Sequence[float] | np.ndarray,
        joint_torques: Sequence[float] | np.ndarray | None = None,
        scalar_first: bool = False,
        imu_time: float | None = None,
        joint_times: Sequence[float] | np.ndarray | None = None,
    ) -> Measurement:
        """The ``Measurement`` the state estimator makes of a robot's sensor readings at ``time`` (your
        clock).

        ``orientation``: the IMU's attitude estimate, base to world, quaternion ``(x, y, z, w)`` (``(w, x,
        y, z)`` with ``scalar_first``; e.g. MuJoCo's ``framequat``); ``gyro``: base-frame angular velocity
        (rad/s); ``accelerometer``: base-frame specific force (m/s^2, +9.81 up at rest); joint angles, rates
        and (optional, for the foot-load compensation) torques in the robot's joint order; ``imu_time`` and
        ``joint_times``: when the IMU and each encoder took the samples given (your clock; None: at ``time``),
        which tells a driver's repeated old sample from a new one. The IMU is assumed at the base frame's
        origin with the base's axes. Call once per control tick, before ``compute``: the
        estimator (``estimation.estimator.StateEstimator``, the config's ``kinematic_kf`` section) integrates
        from one call to the next and uses the stance of the plan followed now. Its first call (or the first
        after ``reset_estimator``) starts it with the robot standing at x-y ``(0, 0)``. Each reading is
        checked at the boundary (module docstring): a bad sample is held at its last good value and counted
        (``faults()``), a sensor out for too long holds the robot off its plans; a value of the wrong shape
        raises ``ValueError`` naming the field (``core.sensors.SensorReadings.fill``), as does a bad sample
        in the very first reading (there is nothing to hold yet). The returned object is reused by the next
        call."""
        sensing = self._sensing_front_end()
        readings = self._readings
        readings.fill(
            time,
            orientation,
            gyro,
            accelerometer,
            joint_positions,
            joint_velocities,
            joint_torques,
            scalar_first,
            imu_time,
            joint_times,
        )
        plan_time = readings.time - self._t0
        measurement = sensing.measure(readings, self.plan, plan_time=plan_time)
        fault = sensing.fault(readings.time)
        reported = (fault, fault is not None and sensing.modelled(readings.time))
        if reported != self._sensor_fault:
            self._loop.report_sensors(plan_time, *reported)
            self._sensor_fault = reported
        return measurement

    def _sensing_front_end(self) -> SensorFrontEnd:
        if self._sensing is None:
            estimator = build_estimator(self.run)
            self._sensing = SensorFrontEnd(estimator, self.run.config.recovery.sensors)
        return self._sensing

    def reset_estimator(self, position_xy: Sequence[float] = (0.0, 0.0)) -> None:
        """Restart the state estimator: its next ``measurement_from_sensors`` starts it with the robot
        standing at ``position_xy`` (the odometry origin)."""
        self._sensing_front_end().reset(np.asarray(position_xy, dtype=float))

    def standing_qpos(self) -> np.ndarray:
        """MuJoCo ``qpos`` of the robot standing (where the presets start), for ``robot.mjcf``'s model."""
        return free_joint_qpos(self.robot.q_standing)
