"""The state estimator a legged robot runs at 500 Hz: IMU orientation + a kinematic linear Kalman filter.

This is the MIT Cheetah 3 / Mini Cheetah design (G. Bledt, M. J. Powell, B. Katz, J. Di Carlo, P. M. Wensing
and S. Kim, "MIT Cheetah 3: Design and Control of a Robust, Dynamic Quadruped Robot", IROS 2018, Sec. IV-B
"State estimation"; B. Katz, J. Di Carlo and S. Kim, "Mini Cheetah: A Platform for Pushing the Limits of
Dynamic Quadruped Control", ICRA 2019; implemented in MIT's ``Cheetah-Software`` as
``VectorNavOrientationEstimator`` and ``LinearKFPositionVelocityEstimator``), in two stages:

1. **Orientation and angular velocity from the IMU**: the IMU's own attitude estimate (the Mini Cheetah's
   VectorNav runs its attitude filter on board) is the base orientation ``R``; the gyro is the base angular
   velocity ``w`` (base frame).
2. **Base position and linear velocity from a linear Kalman filter** (state ``[p, v, p_foot_1..4]``, world
   frame; ``kernels``): the prediction integrates the accelerometer, ``a = R f + g``; every foot in stance
   measures its position relative to the base, ``p_foot - p = R r(q_j)``, and, being at rest, the base
   velocity ``v = -R (w x r + J(q_j) qd_j)`` (leg kinematics from Pinocchio); a stance foot's height is the
   ground's (flat ground; off it, with ``stance_height: touchdown``, the height the foot settled at; with
   ``stance_height: plan``, the height the plan in effect puts it at: a box top). Feet
   in swing or flight give nothing (their states are re-anchored at the legs'
   kinematic positions with a large variance, uncorrelated): in flight the filter runs on the IMU alone.
   A foot's trust ramps in and out over the first and last ``trust_window`` of its planned stance, scaling
   its velocity and height noise by ``1 + (1 - trust) * 100`` as MIT's filter does.

Differences from MIT's code, on purpose: the measurements are applied one scalar at a time (equal to MIT's
28-row batch update, ``R`` being diagonal) so that skipped feet cost nothing and nothing is allocated;
``p`` integrates ``dt^2 a / 2`` too; the foot's velocity is corrected for a spherical foot rolling on the
ground (``rolling_foot``: the contact point is at rest, not the sphere's centre; MIT's feet are points);
a foot in contact is not at rest vertically but sinks into a compliant floor (``foot_compliance``,
``foot_contact_frequency``: a spring-damper from its landing speed, driven by its load; MIT: rigid), which
the foot-height and vertical-velocity measurements account for;
MIT's covariance reset of the unobservable x-y position is not done (it only bounds ``P``).
Contacts come from the plan (``kernels.planned_trust``), optionally gated by the ground force the joint
torques imply (``contact_force_threshold``).

The x-y position and the yaw are not observable: they drift with the sensors' errors, as on the robot. The
estimate's x-y starts where ``reset`` says (the robot's placement: its odometry origin).
"""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin

from cafe_mpc.config.estimation import KinematicKFSettings
from cafe_mpc.core.measurement import Measurement
from cafe_mpc.core.physics import GRAVITY_VECTOR
from cafe_mpc.core.plan import KnotPlan
from cafe_mpc.core.sensors import SensorReadings
from cafe_mpc.dynamics.srb_kernels import quaternion_to_rotation
from cafe_mpc.estimation.imu_outage import ImuOutageObserver
from cafe_mpc.estimation.kernels import (
    NOISE_HEIGHT,
    NOISE_POSITION,
    NOISE_VELOCITY,
    SLIP_THRESHOLD,
    SUSPECT,
    SWING_VARIANCE,
    VERTICAL_FACTOR,
    foot_sink_step,
    kf_predict,
    kf_update_feet,
    leg_ground_forces,
    planned_trust,
)
from cafe_mpc.robots.robot import Robot

LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED


def leg_velocity_indices(robot: Robot) -> np.ndarray:
    """Velocity indices (``n_feet x 3``) of the joints that move each foot, root to foot."""
    model = robot.model
    rows = []
    for frame_id in robot.foot_frame_ids:
        joint = model.frames[frame_id].parentJoint
        chain = []
        while joint > 1:  # joint 1 is the free flyer
            chain.append(model.joints[joint].idx_v)
            joint = model.parents[joint]
        rows.append(sorted(chain))
    lengths = {len(row) for row in rows}
    if lengths != {3}:
        raise ValueError(f"the estimator needs 3 joints per leg, got {sorted(lengths)}")
    return np.array(rows, dtype=np.int64)


PLANNED_LEVEL_DEADBAND = 0.005
"""m; with ``stance_height: plan`` a planned foot within this of the floor (z = 0) stands on it: a stored
trajectory's feet touch a flat floor within a millimetre or two (the solver's tolerance), a gait's exactly."""


class LegKinematics:
    """Foot positions and velocities relative to the base from the joint readings and the IMU (Pinocchio).

    With the base at the origin, oriented by the IMU and turning at the gyro's rate, a foot frame's placement
    is ``R r`` and its velocity (``LOCAL_WORLD_ALIGNED``) is ``R (w x r + J qd)``, its angular velocity the
    foot link's (world). Preallocated; Pinocchio's data is this object's own.
    """

    def __init__(self, robot: Robot, foot_radius: float) -> None:
        self.model = robot.model
        self.data = self.model.createData()
        self.frame_ids = tuple(robot.foot_frame_ids)
        self.foot_radius = float(foot_radius)
        n_feet = len(self.frame_ids)
        self.q = pin.neutral(self.model)
        self.v = np.zeros(self.model.nv)
        self.relative = np.zeros((n_feet, 3))
        """World-frame foot (sphere centre) minus base position."""
        self.velocity = np.zeros((n_feet, 3))
        """World-frame velocity of the foot's point on the ground relative to the base."""
        self.jacobians = np.zeros((n_feet, 3, 3))
        """World-frame Jacobians of each foot w.r.t. its own leg's joints."""
        self.leg_indices = leg_velocity_indices(robot)

    def compute(self, readings: SensorReadings, rolling_foot: bool, jacobians: bool) -> None:
        q, v = self.q, self.v
        q[3:7] = readings.orientation
        q[3:7] /= np.linalg.norm(q[3:7])
        q[7:] = readings.joint_positions
        v[3:6] = readings.gyro
        v[6:] = readings.joint_velocities
        model, data = self.model, self.data
        pin.forwardKinematics(model, data, q, v)
        if jacobians:
            pin.computeJointJacobians(model, data, q)
        radius = self.foot_radius
        for leg, frame_id in enumerate(self.frame_ids):
            placement = pin.updateFramePlacement(model, data, frame_id)
            self.relative[leg] = placement.translation
            motion = pin.getFrameVelocity(model, data, frame_id, LWA)
            velocity = self.velocity[leg]
            velocity[:] = motion.linear
            if (
                rolling_foot
            ):  # the ground contact point, r_c = centre - radius z, is at rest: add w x (-radius z)
                angular = motion.angular
                velocity[0] -= radius * angular[1]
                velocity[1] += radius * angular[0]
            if jacobians:
                full = pin.getFrameJacobian(model, data, frame_id, LWA)
                self.jacobians[leg] = full[:3, self.leg_indices[leg]]


class PlannedContacts:
    """Which feet the plan has in stance now, and how much each is trusted (``kernels.planned_trust``).

    Without a plan (before the first one, PD standing) every foot is in stance and trusted.
    """

    def __init__(self, n_feet: int, trust_window: float) -> None:
        self.window = float(trust_window)
        self.flags = np.ones(n_feet, dtype=np.bool_)
        self.trust = np.ones(n_feet)
        self.touchdown = np.zeros(n_feet)
        self.settled = np.ones(n_feet, dtype=np.bool_)

    def reset(self, t: float = 0.0) -> None:
        self.flags[:] = True
        self.trust[:] = 1.0
        self.touchdown[:] = t
        self.settled[:] = True

    def update(self, t: float, plan: KnotPlan | None) -> None:
        if plan is None:
            self.flags[:] = True
            self.trust[:] = 1.0
            self.settled[:] = True
            return
        planned_trust(
            plan.times,
            plan.dt,
            plan.contacts,
            t,
            self.window,
            self.flags,
            self.touchdown,
            self.settled,
            self.trust,
        )


class StateEstimator:
    """Sensor readings -> ``Measurement`` (see the module docstring); one ``update`` per control tick.

    ``reset(position_xy)`` before a run: the next ``update`` starts the filter from the robot standing (base
    height and feet from the leg kinematics, velocity zero, x-y at ``position_xy``). Arrays are preallocated;
    ``update`` returns the estimator's own ``Measurement`` (overwritten on the next update).
    """

    def __init__(
        self, robot: Robot, settings: KinematicKFSettings | None = None, flat_ground: bool = True
    ) -> None:
        settings = settings if settings is not None else KinematicKFSettings()
        self.robot = robot
        self.flat_ground = flat_ground
        """Whether the ground is flat at z = 0 (``terrain: flat``). Off it (``blind``) a foot planned in
        stance is not dropped for standing above z = 0 (``contact_height_threshold``): on a step every foot
        would be, the filter would lose its legs and drift on the IMU; with them it holds its stance feet at
        z = 0, a frame that follows the ground (which the blind controller's ground plane expects), unless
        ``stance_height: touchdown`` (``touchdown_level``)."""
        self.hold_touchdown = not flat_ground and settings.stance_height == "touchdown"
        """Off flat ground with ``stance_height: touchdown``: each stance foot's height is measured at the
        height its foot state had when it touched down (``touchdown_level``), not at z = 0."""
        self.settings = settings
        n_feet, nj = robot.n_feet, robot.nu
        self.n_feet = n_feet
        self.foot_height = float(robot.foot_radius)
        """Height of a foot frame (the foot sphere's centre) standing on the ground, unloaded."""
        self.ground_height = np.full(n_feet, self.foot_height)
        """Height of each foot frame standing on the ground under its estimated load (``foot_compliance``;
        with ``foot_contact_frequency``: below it by the foot's sink, ``sink``)."""
        self.touchdown_level = np.zeros(n_feet)
        """Height of the ground under each foot, as the filter put the foot frame when it touched down
        (``hold_touchdown``; 0 for a foot standing since the filter started): added to ``ground_height``."""
        self._anchored = np.zeros(n_feet, dtype=np.bool_)
        self.follow_plan = settings.stance_height == "plan"
        """``stance_height: plan``: each stance foot's ground is the height the plan in effect puts the foot
        at (``planned_level``)."""
        self.planned_level = np.zeros(n_feet)
        """Height of the ground under each foot where the plan landed it (``follow_plan``: the plan's
        configuration at the foot's touchdown knot, held through the stance; 0 otherwise, within
        ``PLANNED_LEVEL_DEADBAND`` of the floor, and for a foot standing since the start): added to
        ``ground_height``."""
        self._plan_data = robot.model.createData() if self.follow_plan else None
        self._level_held = np.ones(n_feet, dtype=np.bool_)
        self.legs = LegKinematics(robot, robot.foot_radius)
        self.contacts = PlannedContacts(n_feet, settings.trust_window)
        self.imu_outage = (
            ImuOutageObserver(robot, settings.contact_height_threshold if flat_ground else None)
            if settings.imu_outage == "dynamics"
            else None
        )
        """The attitude and rates while the IMU is out (``update``'s ``imu_out``); None: its last sample
        held."""
        bias = settings.accelerometer_bias is True or (settings.accelerometer_bias == "flat" and flat_ground)
        self.feet_start = 9 if bias else 6
        n = self.feet_start + 3 * n_feet
        self.x = np.zeros(n)
        self.P = np.zeros((n, n))
        self.rotation = np.eye(3)
        self._specific_force = np.zeros(3)
        self.acceleration = np.zeros(3)
        """World-frame base acceleration the last prediction used (IMU, gravity removed)."""
        self.base_velocity = np.zeros((n_feet, 3))
        self.trust = np.zeros(n_feet)
        """Trust of each foot's measurements at the last update (0: not used)."""
        self.in_contact = np.zeros(n_feet, dtype=np.bool_)
        self.slipping = np.zeros(n_feet, dtype=np.bool_)
        """Trusted feet the slip test left out at the last update (``KinematicKFSettings.slip_threshold``)."""
        self.forces = np.zeros((n_feet, 3))
        self.sink = np.zeros(n_feet)
        """How far each foot in contact has sunk into the floor (m; ``foot_contact_frequency``)."""
        self.sink_rate = np.zeros(n_feet)
        """How fast (m/s, down positive)."""
        self._touching = np.zeros(n_feet, dtype=np.bool_)
        self._start_sink = np.zeros(n_feet)
        self._start_rate = np.zeros(n_feet)
        self._q_feet = np.zeros(n_feet)
        self._slip_streak = np.zeros(1, dtype=np.int64)
        self._slip_patience = 0  # ticks; set from the tick period at the first prediction
        self._scratch = np.zeros((2, n))
        self._parameters = np.zeros(7)
        self._parameters[NOISE_POSITION] = settings.foot_sensor_noise_position
        self._parameters[NOISE_VELOCITY] = settings.foot_sensor_noise_velocity
        self._parameters[VERTICAL_FACTOR] = settings.vertical_velocity_factor
        self._parameters[NOISE_HEIGHT] = settings.foot_height_sensor_noise
        self._parameters[SUSPECT] = settings.suspect_factor
        self._parameters[SWING_VARIANCE] = settings.swing_foot_variance
        self._parameters[SLIP_THRESHOLD] = (
            settings.slip_threshold if settings.slip_threshold is not None else 0.0
        )
        self._position_xy = np.zeros(2)
        self._last_time = 0.0
        self._started = False
        self._moving = False
        self.measurement = Measurement.zeros(robot.nq, robot.nv, n_feet)
        if len(self.measurement.q) - 7 != nj:
            raise ValueError("the estimator expects a floating base with 7 configuration coordinates")
        self._compile_kernels()

    def _compile_kernels(self) -> None:
        """Call each compiled kernel a tick of the running filter calls, once, on scratch copies of the
        filter's arrays (the same argument types; nothing of the filter changes): the first update only
        initialises the filter, so without this a run's second tick would compile them (a first run's
        tick stalled for seconds after the clock started; ``core.compilation``)."""
        settings, n_feet, dt = self.settings, self.n_feet, 0.002
        x, P = self.x.copy(), np.eye(len(self.x)) * 1e-3
        kf_predict(x, P, np.zeros(3), dt, 1e-4, 1e-4, 1e-4, self.feet_start, np.full(n_feet, 1e-4))
        kf_update_feet(
            x,
            P,
            self.feet_start,
            self.legs.relative.copy(),
            self.base_velocity.copy(),
            np.ones(n_feet),
            self.ground_height.copy(),
            settings.foot_height,
            self._parameters.copy(),
            1,
            np.zeros(1, dtype=np.int64),
            np.zeros(n_feet, dtype=np.bool_),
            np.zeros_like(self._scratch),
        )
        knots = 3
        planned_trust(
            np.arange(knots) * 0.01,
            np.full(knots, 0.01),
            np.ones((knots, n_feet), dtype=np.bool_),
            0.0,
            self.contacts.window,
            np.ones(n_feet, dtype=np.bool_),
            np.zeros(n_feet),
            np.ones(n_feet, dtype=np.bool_),
            np.ones(n_feet),
        )
        if settings.foot_compliance > 0.0 and settings.foot_contact_frequency is not None:
            forces = np.zeros((n_feet, 3))
            foot_sink_step(
                np.zeros(n_feet),
                np.zeros(n_feet),
                np.zeros(n_feet, dtype=np.bool_),
                forces[:, 2],
                np.ones(n_feet, dtype=np.bool_),
                np.zeros(n_feet),
                np.zeros(n_feet),
                dt,
                settings.foot_compliance,
                settings.foot_contact_frequency,
                settings.foot_contact_damping,
            )

    @property
    def started(self) -> bool:
        return self._started

    def reset(self, position_xy: tuple[float, float] | np.ndarray = (0.0, 0.0), moving: bool = False) -> None:
        """Forget the run; the next ``update`` initialises the filter with its base at ``position_xy``.
        ``moving``: a restart during a run (the sensing front end's): the velocity starts from the legs'
        kinematics of the feet on the ground, not at zero (a wrong start would make every foot disagree
        with the prediction, taken for slipping, and the error would stay)."""
        self._position_xy[:] = position_xy
        self._started = False
        self._moving = moving
        self.contacts.reset()
        if not moving:  # a restart keeps the levels the robot stands on until the next plan
            self.planned_level[:] = 0.0
            self._level_held[:] = True
        if self.imu_outage is not None:
            self.imu_outage.stop()
            if not moving:
                self.imu_outage.reset()

    # ------------------------------------------------------------------------------------------ update
    def update(
        self,
        readings: SensorReadings,
        plan: KnotPlan | None = None,
        plan_time: float | None = None,
        imu_out: bool = False,
        imu_sample_time: float = math.nan,
    ) -> Measurement:
        """The estimate at ``readings.time`` from the readings and the plan in effect (its stance flags,
        looked up at ``plan_time``, default ``readings.time``: the plan's clock if it is not the sensors').
        ``imu_out``: the readings' IMU values are a held sample (taken at ``imu_sample_time``); with
        ``imu_outage: dynamics`` the attitude, rates and specific force come from ``ImuOutageObserver``."""
        settings = self.settings
        t = float(readings.time)
        self.contacts.update(t if plan_time is None else float(plan_time), plan)
        if self.follow_plan and plan is not None:
            self._follow_plan_levels(plan, t if plan_time is None else float(plan_time))
        observer = self.imu_outage
        if observer is not None:
            if imu_out and self._started:
                if not observer.active:
                    observer.start(
                        imu_sample_time,
                        readings.orientation,
                        readings.gyro,
                        self.x[3:6],
                        self.x[2],
                    )
                    # the held sample integrated since it was taken, in flight: the model's force instead
                    self.x[0:3] += observer.position_change
                    self.x[3:6] += observer.velocity_change
                observer.step(readings, self.contacts.flags, self.x[3:6], float(self.x[2]))
                readings = observer.write(readings)
            else:
                observer.stop()
                observer.remember(readings, self.contacts.flags)
        quaternion_to_rotation(readings.orientation, self.rotation)
        need_forces = (
            settings.contact_force_threshold is not None or settings.foot_compliance > 0.0
        ) and bool(np.all(np.isfinite(readings.joint_torques)))
        self.legs.compute(readings, settings.rolling_foot, need_forces)
        np.copyto(self.trust, self.contacts.trust)
        np.copyto(self.in_contact, self.contacts.flags)
        np.add(self.planned_level, self.foot_height, out=self.ground_height)
        if need_forces:
            leg_ground_forces(self.legs.jacobians, readings.joint_torques, 3, self.forces)
            threshold = settings.contact_force_threshold
            for foot in range(self.n_feet):
                normal = self.forces[foot, 2]
                if threshold is not None and normal < threshold:
                    self.in_contact[foot] = False
                    self.trust[foot] = 0.0
                if normal > 0.0:  # a loaded foot sinks in (compliant foot and floor)
                    self.ground_height[foot] -= settings.foot_compliance * normal
        else:
            self.forces[:] = 0.0
        height_limit = settings.contact_height_threshold
        if height_limit is not None and self._started and self.flat_ground:
            # a foot planned in stance that the legs put well above the ground is not on it (a missed or late
            # touchdown); flat ground, as the foot-height measurement assumes
            for foot in range(self.n_feet):
                clearance = self.x[2] + self.legs.relative[foot, 2] - self.ground_height[foot]
                if self.in_contact[foot] and clearance > height_limit:
                    self.in_contact[foot] = False
                    self.trust[foot] = 0.0
        np.negative(self.legs.velocity, out=self.base_velocity)
        if need_forces and settings.foot_compliance > 0.0 and settings.foot_contact_frequency is not None:
            self._sink_dynamics(t)
        if not self._started:
            self._initialise(t)
        else:
            dt = t - self._last_time
            if dt > 0.0:
                self._slip_patience = max(round(settings.slip_patience / dt), 1)
                # The accelerometer's mean over the last dt, rotated with the attitude of the interval's
                # middle, R(t - dt/2) = R(t) (I - [w] dt/2): at a 10 rad/s roll R(t) alone turns a 50 m/s^2
                # push-off 0.01 rad, a 0.5 m/s^2 error (the first-order sculling correction).
                f, w, mid = readings.accelerometer, readings.gyro, self._specific_force
                half = 0.5 * dt
                mid[0] = f[0] - half * (w[1] * f[2] - w[2] * f[1])
                mid[1] = f[1] - half * (w[2] * f[0] - w[0] * f[2])
                mid[2] = f[2] - half * (w[0] * f[1] - w[1] * f[0])
                np.matmul(self.rotation, mid, out=self.acceleration)
                self.acceleration += GRAVITY_VECTOR
                for foot in range(self.n_feet):
                    self._q_feet[foot] = (
                        dt
                        * settings.foot_process_noise_position
                        * (1.0 + (1.0 - self.trust[foot]) * settings.suspect_factor)
                    )
                kf_predict(
                    self.x,
                    self.P,
                    self.acceleration,
                    dt,
                    dt / 20.0 * settings.imu_process_noise_position,
                    dt * 9.8 / 20.0 * settings.imu_process_noise_velocity,
                    dt * settings.bias_process_noise,
                    self.feet_start,
                    self._q_feet,
                )
                if self.hold_touchdown:
                    self._hold_touchdown_levels()
                kf_update_feet(
                    self.x,
                    self.P,
                    self.feet_start,
                    self.legs.relative,
                    self.base_velocity,
                    self.trust,
                    self.ground_height,
                    settings.foot_height,
                    self._parameters,
                    self._slip_patience,
                    self._slip_streak,
                    self.slipping,
                    self._scratch,
                )
        self._last_time = t
        return self._write(readings)

    def _follow_plan_levels(self, plan: KnotPlan, t: float) -> None:
        """``stance_height: plan``: when a foot's planned stance begins, ``planned_level`` is taken from the
        plan's configuration at the knot that stance starts at (forward kinematics; the touchdown
        constraint (25) puts the foot there on the reference's surface), and held until the foot leaves the
        ground. Not from the plan's current knot: a stance foot's planned height is where the estimate put
        it, so its level would follow the estimate's drift. 0 within ``PLANNED_LEVEL_DEADBAND`` of the
        floor; a plan without configurations keeps the floor."""
        flags, contacts = self.contacts.flags, plan.contacts
        for foot in range(self.n_feet):
            if not flags[foot]:
                self._level_held[foot] = False
                continue
            if self._level_held[foot]:
                continue
            self._level_held[foot] = True
            configurations = plan.knot_configurations(self.robot.nq)
            if configurations is None:
                self.planned_level[foot] = 0.0
                continue
            k = plan.knot_at(t)
            while k > 0 and contacts[k - 1, foot]:
                k -= 1
            model, data = self.robot.model, self._plan_data
            pin.framesForwardKinematics(model, data, configurations[k])
            level = float(data.oMf[self.legs.frame_ids[foot]].translation[2]) - self.foot_height
            self.planned_level[foot] = level if abs(level) >= PLANNED_LEVEL_DEADBAND else 0.0

    def _hold_touchdown_levels(self) -> None:
        """``stance_height: touchdown``: while a foot's trust ramps in after its touchdown (until
        ``PlannedContacts.settled``) its ground is where the predicted base and its leg put it (less its sink
        under ``ground_height``): a landing foot still moves (it lands late or early, it sinks), and its
        height measurement then says nothing of the base's. Once settled the level is held until the foot
        leaves the ground: every used foot's height measurement is its level (plus its sink's change), so a
        foot at rest stays where it landed, whatever level it landed on."""
        height = self.x[2]
        settled = self.contacts.settled
        for foot in range(self.n_feet):
            if self.trust[foot] <= 0.0:
                self._anchored[foot] = False
                self.touchdown_level[foot] = 0.0
                continue
            if not self._anchored[foot]:
                self.touchdown_level[foot] = height + self.legs.relative[foot, 2] - self.ground_height[foot]
                self._anchored[foot] = settled[foot]
            self.ground_height[foot] += self.touchdown_level[foot]

    def _sink_dynamics(self, t: float) -> None:
        """The feet's sink as a spring-damper driven by their load (``kernels.foot_sink_step``): the height
        each foot in contact stands at and the legs' vertical velocity measurement (the foot moves down at
        the sink's rate: ``v = -R (w x r + J qd) - s' z``)."""
        settings = self.settings
        relative, velocity = self.legs.relative, self.legs.velocity
        if not self._started:  # standing: each foot settled under its load
            for foot in range(self.n_feet):
                self._touching[foot] = self.in_contact[foot]
                self.sink[foot] = settings.foot_compliance * max(self.forces[foot, 2], 0.0)
                self.sink_rate[foot] = 0.0
        else:
            dt = t - self._last_time
            if dt <= 0.0:
                return
            height, vertical = self.x[2] + dt * self.x[5], self.x[5]
            for foot in range(self.n_feet):  # where and how fast a foot touching down now hits the floor
                # (held at touchdown the floor's height is not known: the static sink of the foot's load)
                self._start_sink[foot] = (
                    settings.foot_compliance * self.forces[foot, 2]
                    if self.hold_touchdown
                    else self.foot_height + self.planned_level[foot] - (height + relative[foot, 2])
                )
                self._start_rate[foot] = -(vertical + velocity[foot, 2])
            foot_sink_step(
                self.sink,
                self.sink_rate,
                self._touching,
                self.forces[:, 2],
                self.in_contact,
                self._start_sink,
                self._start_rate,
                dt,
                settings.foot_compliance,
                settings.foot_contact_frequency,
                settings.foot_contact_damping,
            )
        for foot in range(self.n_feet):
            if self.in_contact[foot]:
                self.ground_height[foot] = self.foot_height + self.planned_level[foot] - self.sink[foot]
                self.base_velocity[foot, 2] -= self.sink_rate[foot]
            else:
                self.ground_height[foot] = self.foot_height + self.planned_level[foot]

    def _initialise(self, t: float) -> None:
        """The robot standing: base height from the feet in planned stance (all if none), velocity zero (or,
        restarted ``moving``, the stance legs' mean)."""
        settings = self.settings
        relative = self.legs.relative
        stance = self.in_contact if np.any(self.in_contact) else np.ones(self.n_feet, dtype=np.bool_)
        height = float(np.mean(self.ground_height[stance] - relative[stance, 2]))
        self.x[:] = 0.0
        self.x[:2] = self._position_xy
        self.x[2] = height
        if self._moving:
            self.x[3:6] = self.base_velocity[stance].mean(axis=0)
        start = self.feet_start
        for foot in range(self.n_feet):
            self.x[start + 3 * foot : start + 3 + 3 * foot] = self.x[:3] + relative[foot]
        self.P[:] = 0.0
        diagonal = np.einsum("ii->i", self.P)
        diagonal[:] = settings.initial_position_variance
        diagonal[3:6] = settings.initial_velocity_variance
        if start == 9:
            diagonal[6:9] = settings.initial_bias_variance
        self.acceleration[:] = 0.0
        self.touchdown_level[:] = 0.0
        np.copyto(self._anchored, self.trust > 0.0)
        self._slip_streak[0] = 0
        self._started = True
        self._last_time = t

    def _write(self, readings: SensorReadings) -> Measurement:
        measurement = self.measurement
        measurement.time = float(readings.time)
        q, v = measurement.q, measurement.v
        q[:3] = self.x[:3]
        q[3:7] = readings.orientation
        q[3:7] /= np.linalg.norm(q[3:7])
        q[7:] = readings.joint_positions
        np.matmul(self.rotation.T, self.x[3:6], out=v[:3])  # base-frame linear velocity
        v[3:6] = readings.gyro
        v[6:] = readings.joint_velocities
        np.copyto(measurement.contacts, self.in_contact)
        np.copyto(measurement.foot_forces, self.forces)
        return measurement

    @property
    def world_velocity(self) -> np.ndarray:
        """The estimated base velocity, world frame (a view of the filter state)."""
        return self.x[3:6]
