"""Contact detection: which feet are on the ground, from what the robot senses and what the plan expects.

The paper's VWBC takes its stance set from the plan's contact schedule and names seeding it with contact
detection as future work (Sec. VIII-A): a foot that lands before its planned touchdown is then driven along
its swing curve into the ground (it scuffs, and the body picks up the moment of that push), and a foot planned
in stance that has not landed yet is given forces it cannot produce. The detector fuses, per foot and tick, as
Bledt et al. ("Contact Model Fusion for Event-Based Locomotion in Unstructured Terrains", ICRA 2018) do:

* the **schedule's prior**: a touchdown only counts in planned stance or in the last ``early_window`` seconds
  of a swing before its planned touchdown (a foot still loaded just after a planned lift-off is lifting off,
  not landing); one within ``on_time`` of its planned time is on time (the plan's knots are 10 ms apart: its
  impact lands the foot then, and the plan's swing torques for those few milliseconds are what the paper's
  VWBC applies). A foot taken into the stance set early is driven by the swing knot's policy (torques planned
  for a foot in the air) while the ground holds it. In the nominal bound the front feet meet the ground 15-20
  ms before their planned touchdown; counted early (a 15 ms margin), those feet raised the trunk by 1.5 cm
  and its speed by 0.03 m/s, so the default margin is 25 ms (docs/robustness.md);
* the **ground force** the measurement carries (``Measurement.foot_forces``: from the joint torques through
  the leg Jacobians on a robot, ``estimation``; the plant's contact force in a ground-truth run): the foot
  pushes on something. That estimate takes the legs as massless and static, so a leg that the low level
  accelerates through the air reads its own torques as a load (the end of a bound's swing: 25 N against a
  7.1 N threshold, a foot 6.6 cm above the floor taken in as landed; docs/terrain-notes.md). With
  ``force_estimate: momentum`` the detector estimates it itself with a
  generalized-momentum observer (De Luca and Mattone, ICRA 2005) on the torques the low level applied at
  the previous tick: ``r = K_O (p - p(0) - integral(S' tau + C' v - g + r))`` with ``p = M(q) v`` tends
  to the generalized force the ground adds, ``sum_f J_f' F_f``, at bandwidth ``K_O``
  (``momentum_gain``); each foot's force is its leg's rows, ``F_f = J_f,leg'^-1 r_leg``, so the motion of
  a leg in the air is no load;
* the **foot height** above the ground (forward kinematics of the measured state): the foot is where the
  ground is. The ground is flat at ``ground_height`` (the paper's world), or, with ``ground_plane``, the
  plane through the feet's latest detected contact points (``core.ground.GroundPlane``: a blind robot's
  estimate of steps and slopes, ``terrain: blind``), its slope limited to ``ground_max_slope`` when that is
  set (the reference's plane takes the same limit: through feet 10 cm apart on two treads an unlimited fit
  tilted 0.6 and lay 10 cm under the tread a swing was aimed at; docs/terrain-notes.md), and along a direction
  its points spread less than ``ground_min_span`` along, held from the last fit (both planes: a bound's hind
  feet land 7 cm ahead of the front feet's last points, and a centimetre between them tilted the planes 0.3).

In planned stance a foot is in contact once it is within ``touchdown_height`` of the ground or loaded (a foot
still higher and unloaded is a late touchdown: in the air, out of the stance set, its leg reaching for the
planned foothold); on a ground plane with ``force_estimate: momentum`` only once loaded, since the plane is
an estimate and the observer's force a measurement: going down steps, a late foot passes under the plane
through feet on the upper tread before it meets the lower one, and taken in by its height it was put in the
stance set in the air, its point in the plane (docs/terrain-notes.md, "The momentum observer"). In
the early window of a swing it needs both, a normal force above ``touchdown_force``
and the ground within ``touchdown_height``. With a ground plane a loaded foot may be up to ``step_height``
above the plane (a step up the plane does not know yet): the force is the evidence there, and it is the
ground's. Off flat ground, with ``landing_speed`` set (off by default), a touchdown, early or late, counts
only while the foot's vertical speed is below it: the plane is an estimate (through feet on two treads it
lies above the lower one, and a descending foot passes under it before it meets the ground), and a foot out
of the stance set still gets torques near the plan's (the VWBC's cost pulls toward them: stance torques
for a late foot, swing torques for a swinging one), so a leg pushing its foot through the air shows a
load; a foot that met the ground has stopped (on the way down a slope or steps a swinging foot passes under
the plane, loaded by the torques that swing it, before it lands). A foot leaves contact when its force
drops below ``release_force`` with the foot higher than ``release_height``, or when its planned swing
begins (the schedule decides lift-off). With the static estimate the force is not asked for in planned
stance: on a robot it is estimated from the joint torques, which there are the stance torques this
controller commands, so it would only echo the schedule. Forces are thresholds on the robot's weight share
(``mg / n_feet``), so one setting holds for every robot.

With ``late_reach_speed`` set (off by default; a ground plane and the observer), a late foot whose leg throws
it down faster than that is from then on a swing reaching down at that speed (``reaching``,
``reach_torques``: a position-controlled foot, not the plan's stance torques, until it lands; the VWBC puts
those torques on its leg, ``VWBCController._reach_with_late_feet``; docs/terrain-notes.md, "Late feet reach
down").

With ``early_force`` set (off by default; a ground plane), an early foot (in the stance set before its
planned touchdown, still driven by its swing knot's policy) may push the ground with at most that normal
force (``early_force_cap``): the VWBC bounds its row of (34e) above (``_StanceQP.cap_normal_forces``), so a
front foot that meets an incline at the start of a flight does not tip the trunk over (docs/terrain-notes.md,
"Early feet on the incline").

With ``stumble_force`` set (off by default; a ground plane and the observer), a stumble reflex (Bledt et al.,
"Contact Model Fusion", 2018; ANYmal's and Cheetah 3's blind stair climbing): a foot in its planned swing
that the observer reads pushed back, against the trunk's horizontal travel, by more than that force (a
riser's face in the way) is from then on position-controlled until it lands (``stumbling``; its torques in
``reach_torques``, put on its leg as a reaching foot's): it rises ``stumble_lift``, moves ``stumble_forward``
along the travel, then reaches down, at ``stumble_speed`` (docs/terrain-notes.md, "A stumble reflex"). With
``stumble_to_plan`` set (a share ``a``) it moves at least as far along the travel as the point ``a`` of the
way from the plan's base to the plan's foot at the foot's planned touchdown (``_planned_step``; 0: under
the trunk's centre; a hind foot, behind the base, to its planned foothold at most): held where it lands
until its planned stance, a foot stepped 5 cm past a riser had been left 7-28 cm behind the base by then,
and the trunk pitched over (docs/terrain-notes.md).

With ``early_hold_height`` set (off by default; a ground plane and the observer), a foot taken in early (in
the early window of its swing) with its sole more than that above the plane, on a tread higher than the one
the plan lands it on, is held where it landed until its planned stance (``holding``; its leg position-
controlled as a landed stumbling foot's, through ``reach_torques``): in the stance set the VWBC would
otherwise take its swing knot's policy (7) in (34a), whose feedback drives it on down its swing curve into
the tread and pushes the trunk up (docs/terrain-notes.md, "Early feet on the next tread"). With
``early_hold_rise`` also set, only a foot whose sole landed more than that above its sole at its planned
lift-off is held: a plane tilted down ahead (through one pair on a tread and the other's points below it) can
lie under a foot landing early on lower ground, which held carried nothing while the other pair lifted off
(docs/terrain-notes.md, "Early feet on lower ground"). Such a foot stays in the stance set unheld
(``lowered``), driven by its swing knot's policy; with ``early_low_force`` the VWBC caps its normal force in
(34e) at that until its planned stance (unheld and uncapped, it was driven into the floor at 150 N).

``update(t, measurement, plan)`` returns the detected stance flags (an array the detector owns); counters of
early and late touchdowns and of the ticks where detection and plan disagree feed the run's statistics.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from cafe_mpc.config import ContactDetectionSettings
from cafe_mpc.core.ground import GroundPlane
from cafe_mpc.core.measurement import Measurement
from cafe_mpc.core.physics import GRAVITY
from cafe_mpc.core.plan import KnotPlan
from cafe_mpc.robots.robot import Robot


class ContactDetector:
    """Detected stance per foot (module docstring); preallocated, one Pinocchio data of its own.

    ``ground_plane``: heights above the plane through the feet's latest contact points (``ground``) instead
    of above the flat ``settings.ground_height``. ``on_time``: the settings' on-time margin (null: the flat
    ground's, or with a ground plane the margin off flat ground; ``ContactDetectionSettings.on_time_for``)."""

    def __init__(
        self, robot: Robot, settings: ContactDetectionSettings | None = None, ground_plane: bool = False
    ) -> None:
        self.robot = robot
        self.settings = settings or ContactDetectionSettings()
        self.ground = (
            GroundPlane(robot.n_feet, self.settings.ground_height, **self.settings.ground_plane_limits())
            if ground_plane
            else None
        )
        self.on_time = self.settings.on_time_for(flat=not ground_plane)
        self.force_estimate = self.settings.force_estimate_for(flat=not ground_plane)
        """``static`` or ``momentum`` (``ContactDetectionSettings.force_estimate_for``)."""
        self.soles = np.zeros((robot.n_feet, 3))
        self.data = robot.model.createData()
        weight_share = robot.total_mass * GRAVITY / robot.n_feet
        self.touchdown_force = self.settings.touchdown_force * weight_share
        self.release_force = self.settings.release_force * weight_share
        self.in_contact = np.zeros(robot.n_feet, dtype=bool)
        self.heights = np.zeros(robot.n_feet)
        self.vertical_speeds = np.zeros(robot.n_feet)
        """With a ground plane and ``landing_speed``, each foot's world vertical velocity (m/s) at the last
        update (else zeros)."""
        self.leg_descent_speeds = np.zeros(robot.n_feet)
        """With ``late_descent_speed`` acting, how fast each leg's joints move its foot down (m/s, world z,
        the trunk held still: ``-(J_f,leg qdot_leg)_z``) at the last update (else zeros)."""
        self.late_descent_speed = (
            self.settings.late_descent_speed if ground_plane and self.force_estimate == "momentum" else None
        )
        """``late_descent_speed`` where it acts (a ground plane and the momentum observer), else None: the
        VWBC takes a late foot's planned ground force off its leg when it descends faster
        (``leg_torque``)."""
        self.late_reach_speed = (
            self.settings.late_reach_speed if ground_plane and self.force_estimate == "momentum" else None
        )
        """``late_reach_speed`` where it acts (a ground plane and the momentum observer), else None: a late
        foot reaches down as a position-controlled swing (``reaching``, ``reach_torques``)."""
        self.early_force_cap = (
            None
            if self.settings.early_force is None or not ground_plane
            else self.settings.early_force * weight_share
        )
        """``early_force`` (N) where it acts (a ground plane), else None: the VWBC caps an early foot's normal
        force at it."""
        self.reaching = np.zeros(robot.n_feet, dtype=bool)
        """With ``late_reach_speed`` acting, the late feet (planned in stance, not in contact) whose legs
        moved them down faster than the reach speed since they became late (``leg_descent_speeds``: the
        stance torques are throwing them down; a foot that is late by the observer's lag on the ground, or
        whose trunk comes down on it out of a flight, is not): the VWBC drives their legs with
        ``reach_torques`` until they land."""
        self.reach_torques = np.zeros((robot.n_feet, 3))
        """Each reaching foot's leg torques (its three joints) at the last update: ``J_f,leg' Lambda_f
        (w^2 (p_d - p) + 2 w (v_d - v)) + h_leg`` (``_reach``)."""
        self.stumble_force = (
            None
            if self.settings.stumble_force is None or not ground_plane or self.force_estimate != "momentum"
            else self.settings.stumble_force * weight_share
        )
        """The stumble reflex's threshold (N) where it acts (a ground plane and the momentum observer), else
        None."""
        self.stumbling = np.zeros(robot.n_feet, dtype=bool)
        """With ``stumble_force`` acting, the feet whose swing was pushed back (module docstring), until they
        land: the VWBC drives their legs with ``reach_torques``."""
        self.early_hold_height = (
            self.settings.early_hold_height if ground_plane and self.force_estimate == "momentum" else None
        )
        """``early_hold_height`` where it acts (a ground plane and the momentum observer), else None."""
        self.holding = np.zeros(robot.n_feet, dtype=bool)
        """With ``early_hold_height`` acting, the feet that landed early on ground that far above the plane,
        until their planned stance: the VWBC drives their legs with ``reach_torques`` (held where they
        landed)."""
        self.early_hold_rise = self.settings.early_hold_rise if self.early_hold_height is not None else None
        """``early_hold_rise`` where it acts (with ``early_hold_height``), else None."""
        self.early_low_force_cap = (
            None
            if self.settings.early_low_force is None or self.early_hold_rise is None
            else self.settings.early_low_force * weight_share
        )
        """``early_low_force`` (N) where it acts (with ``early_hold_rise``), else None: the VWBC caps a
        ``lowered`` foot's normal force at it."""
        self.lowered = np.zeros(robot.n_feet, dtype=bool)
        """With ``early_hold_rise`` acting, the feet taken in early more than ``early_hold_height`` above the
        plane but not above their lift-off (lower ground under a plane tilted past them), not held, until
        their planned stance."""
        self._liftoff_soles = np.zeros(robot.n_feet)
        """With ``early_hold_rise`` acting, each foot's sole height (the measurement's frame) at its last
        planned lift-off."""
        self._stumble_since = np.zeros(robot.n_feet)
        self._stumble_origin = np.zeros((robot.n_feet, 3))
        self._stumble_direction = np.zeros((robot.n_feet, 2))
        self._stumble_held = np.zeros(robot.n_feet, dtype=bool)
        self._plan_data = robot.model.createData() if self.settings.stumble_to_plan is not None else None
        self._planned_touchdowns = np.zeros((robot.n_feet, 3))
        self._planned_footholds = np.zeros((robot.n_feet, 3))
        self._planned_known = np.zeros(robot.n_feet, dtype=bool)
        self._stumble_forward = np.zeros(robot.n_feet)
        self._target_velocity = np.zeros(3)
        self.reach_targets = np.zeros((robot.n_feet, 3))
        """Each reaching foot's target position (world, foot frame's origin) at the last update."""
        self._late_since = np.full(robot.n_feet, np.nan)
        self._late_origin = np.zeros((robot.n_feet, 3))
        self._late_floor = np.zeros(robot.n_feet)
        self._foot_jacobians = np.zeros((robot.n_feet, 3, robot.nv))
        self._foot_velocity = np.zeros(3)
        self._leg_inertia = np.zeros((3, 3))
        self._bias = np.zeros(robot.nv)
        self.estimated_forces = np.zeros((robot.n_feet, 3))
        """With ``force_estimate: momentum``, each foot's ground force (world, N) from the momentum observer
        at the last update."""
        nv, n_feet = robot.nv, robot.n_feet
        self._momentum_start = np.zeros(nv)
        self._momentum_integral = np.zeros(nv)
        self._residual = np.zeros(nv)
        self._generalized_torque = np.zeros(nv)
        self._mass = np.zeros((nv, nv))  # M(q), both triangles (CRBA fills the upper one)
        self._upper = np.triu(np.ones((nv, nv), dtype=bool))
        self._lower = ~self._upper
        self._coriolis = np.zeros((nv, nv))  # C(q, v), row-major as the bindings' copies (the same sums)
        self._momentum = np.zeros(nv)
        self._rate = np.zeros(nv)
        self._step = np.zeros(nv)
        self._leg_transposes = np.zeros((n_feet, 3, 3))  # J_f,leg' per foot
        self._leg_residuals = np.zeros((n_feet, 3))
        first_leg_column = nv - robot.nu
        self._leg_columns = [
            slice(first_leg_column + 3 * f, first_leg_column + 3 * f + 3) for f in range(n_feet)
        ]
        self._plan: KnotPlan | None = None
        self._next_touchdown = np.zeros((0, robot.n_feet))
        self.reset()

    def reset(self) -> None:
        self.in_contact[:] = True  # a robot starts standing
        self._observer_time: float | None = None
        if self.ground is not None:
            self.ground.reset()
        self.early_touchdowns = 0
        self.early_lead_sum = 0.0
        self.late_touchdown_ticks = 0
        self.early_ticks = 0
        self._was_planned = np.ones(self.robot.n_feet, dtype=bool)
        self.reaching[:] = False
        self.stumbling[:] = False
        self.holding[:] = False
        self._liftoff_soles[:] = 0.0
        self.lowered[:] = False
        self.stumbles = 0
        self._late_since[:] = np.nan

    def _index_plan(self, plan: KnotPlan) -> None:
        """Per knot and foot, the time the foot's next planned stance starts (its own time if the knot is a
        stance knot; inf if no stance follows within the plan)."""
        n = len(plan.times)
        self._next_touchdown = np.full((n, self.robot.n_feet), np.inf)
        for k in range(n - 1, -1, -1):
            later = self._next_touchdown[k + 1] if k + 1 < n else self._next_touchdown[k]
            self._next_touchdown[k] = np.where(plan.contacts[k], plan.times[k], later)
        self._plan = plan
        self._planned_known[:] = False

    def _planned_step(self, t: float, foot: int) -> float:
        """With ``stumble_to_plan`` (``a``), how far along the stumble's direction ``d`` from where it
        stumbled (``p_0``) the plan puts the point between its base and the foot, or the foot if that is
        nearer (a hind foot, behind the base): ``min((1 - a) r* + a p_f* - p_0, p_f* - p_0) . d``
        (horizontal), with the base position ``r*`` and the foot's ``p_f*`` (forward kinematics)
        of the plan's ``q*`` at the first knot from ``t`` on that plans the foot in stance, or at the
        whole-body part's last knot when none does (the touchdown lies beyond it); ``stumble_forward``
        when the plan has no configurations. Computed once per plan and foot."""
        plan = self._plan
        assert plan is not None and self._plan_data is not None
        if not self._planned_known[foot]:
            configurations = plan.knot_configurations(self.robot.model.nq)
            if configurations is None:
                return self.settings.stumble_forward
            k = plan.knot_at(t)
            stance = np.flatnonzero(plan.contacts[k:, foot])
            knot = k + int(stance[0]) if len(stance) else len(configurations) - 1
            q = configurations[knot]
            pin.framesForwardKinematics(self.robot.model, self._plan_data, q)
            foothold = self._plan_data.oMf[self.robot.foot_frame_ids[foot]].translation
            share = self.settings.stumble_to_plan
            self._planned_touchdowns[foot] = (1.0 - share) * q[:3] + share * foothold
            self._planned_footholds[foot] = foothold
            self._planned_known[foot] = True
        origin, direction = self._stumble_origin[foot, :2], self._stumble_direction[foot]
        between = float((self._planned_touchdowns[foot, :2] - origin) @ direction)
        return min(between, float((self._planned_footholds[foot, :2] - origin) @ direction))

    def _observe_momentum(self, t: float, measurement: Measurement, torques: np.ndarray) -> np.ndarray:
        """Each foot's ground force (world) from the generalized-momentum observer (module docstring), given
        the joint ``torques`` applied since the previous update; zeros on its first update. It runs at the
        low level's rate, so it works in the detector's buffers: the only arrays a tick creates are the
        copies Pinocchio's Python bindings return (the dynamics terms are read from ``data``) and the four
        feet's forces solved together."""
        model, data, robot = self.robot.model, self.data, self.robot
        q, v = measurement.q, measurement.v
        pin.crba(model, data, q)  # fills the upper triangle of data.M
        np.copyto(self._mass, data.M, where=self._upper)
        np.copyto(self._mass, data.M.T, where=self._lower)
        momentum = np.matmul(self._mass, v, out=self._momentum)
        pin.computeCoriolisMatrix(model, data, q, v)
        np.copyto(self._coriolis, data.C)
        pin.computeGeneralizedGravity(model, data, q)  # data.g
        self._generalized_torque[model.nv - robot.nu :] = torques
        if self._observer_time is None:
            self._momentum_start[:] = momentum
            self._momentum_integral[:] = 0.0
            self._residual[:] = 0.0
        else:
            # d p / dt = S' tau + C' v - g + (the ground's generalized force, which the residual estimates)
            rate = np.matmul(self._coriolis.T, v, out=self._rate)
            np.add(self._generalized_torque, rate, out=rate)
            rate -= data.g
            rate += self._residual
            self._momentum_integral += np.multiply(t - self._observer_time, rate, out=self._step)
            residual = np.subtract(momentum, self._momentum_start, out=self._residual)
            residual -= self._momentum_integral
            residual *= self.settings.momentum_gain
        self._observer_time = t
        pin.computeJointJacobians(model, data, q)
        pin.updateFramePlacements(model, data)
        for foot, frame_id in enumerate(robot.foot_frame_ids):
            columns = self._leg_columns[foot]
            jacobian = pin.getFrameJacobian(model, data, frame_id, pin.LOCAL_WORLD_ALIGNED)
            np.copyto(self._leg_transposes[foot], jacobian[:3, columns].T)
            self._leg_residuals[foot] = self._residual[columns]
            if self.late_descent_speed is not None or self.late_reach_speed is not None:
                # the leg's own motion, not the trunk's
                self.leg_descent_speeds[foot] = -(jacobian[2, columns] @ v[columns])
            if (
                self.late_reach_speed is not None
                or self.stumble_force is not None
                or self.early_hold_height is not None
            ):
                np.copyto(self._foot_jacobians[foot], jacobian[:3])
        forces = self.estimated_forces
        try:
            forces[:] = np.linalg.solve(self._leg_transposes, self._leg_residuals[..., None])[..., 0]
        except np.linalg.LinAlgError:  # a singular (stretched) leg: no estimate for it
            for foot in range(robot.n_feet):
                try:
                    forces[foot] = np.linalg.solve(self._leg_transposes[foot], self._leg_residuals[foot])
                except np.linalg.LinAlgError:
                    forces[foot] = 0.0
        return forces

    def _reach(self, t: float, foot: int, measurement: Measurement) -> None:
        """The leg torques of a late foot reaching down (``late_reach_speed``): from where the foot was when
        it began to reach (``p_0``, world), its target sinks at the reach speed ``c`` to ``late_reach_depth``
        ``d`` below the ground plane under ``p_0`` and stays over ``p_0``:
        ``p_d = p_0 - min(c (t - t_0), max(0, z_0 - z_g + d)) e_z``, ``v_d = -c e_z`` while it sinks. The
        leg follows it as a critically damped spring of natural frequency ``w`` through its
        operational-space inertia with the trunk held (``Lambda_f = (J_f,leg M_leg^-1 J_f,leg')^-1``) plus
        its own bias forces (``h = C v + g``, the leg's rows of the momentum observer's terms at this
        state), so that it reaches at a bounded speed and presses nothing: the plan's stance torques push
        the ground with ``-J' F*`` (Eq. (34a)'s reference ``tau*``), which with no ground under the foot
        throw it down at 4-5 m/s (docs/terrain-notes.md, "Late feet slammed down")."""
        s, data = self.settings, self.data
        speed = self.late_reach_speed
        assert speed is not None and self.ground is not None
        position = data.oMf[self.robot.foot_frame_ids[foot]].translation
        if np.isnan(self._late_since[foot]):
            self._late_since[foot] = t
            self._late_origin[foot] = position
            self._late_floor[foot] = self.ground.height_at(position[0], position[1]) + self.robot.foot_radius
        origin = self._late_origin[foot]
        room = max(0.0, origin[2] - self._late_floor[foot] + s.late_reach_depth)
        sunk = speed * (t - self._late_since[foot])
        target = self.reach_targets[foot]
        target[:] = origin
        target[2] -= min(sunk, room)
        self._target_velocity[:] = 0.0
        if sunk < room:
            self._target_velocity[2] = -speed
        self._drive(foot, measurement)

    def _stumble(self, t: float, foot: int, measurement: Measurement) -> None:
        """The leg torques of a stumbling foot (``stumble_force``): from where it stumbled (``p_0``) its
        target moves at ``c`` (``stumble_speed``) up by ``stumble_lift`` ``h``, then by ``stumble_forward``
        ``l`` along the trunk's horizontal travel ``d`` at the stumble (with ``stumble_to_plan`` at least
        to the plan's touchdown, ``_planned_step``), then down until it lands (at most
        ``h + late_reach_depth`` below ``p_0``): with ``s = c (t - t_0)``,
        ``p_d = p_0 + min(s, h) e_z + clip(s - h, 0, l) d - clip(s - h - l, 0, h + depth) e_z``; held where
        it is once the observer reads its load on the way down (``touchdown_force``), until its planned
        stance (or the detector's early touchdown) hands it to the plan; followed as the late reach's target
        (``_drive``)."""
        s = self.settings
        target, velocity = self.reach_targets[foot], self._target_velocity
        if self._stumble_held[foot]:  # landed before its planned stance: held where it landed
            velocity[:] = 0.0
            self._drive(foot, measurement)
            return
        speed, lift, forward = s.stumble_speed, s.stumble_lift, s.stumble_forward
        travelled = speed * (t - self._stumble_since[foot])
        if s.stumble_to_plan is not None:  # the step, from each new plan until the foot comes down
            if travelled < lift + self._stumble_forward[foot]:
                self._stumble_forward[foot] = max(forward, self._planned_step(t, foot))
            forward = self._stumble_forward[foot]
        target[:] = self._stumble_origin[foot]
        velocity[:] = 0.0
        direction = self._stumble_direction[foot]
        rise = min(travelled, lift)
        ahead = min(max(travelled - lift, 0.0), forward)
        sink = min(max(travelled - lift - forward, 0.0), lift + s.late_reach_depth)
        target[2] += rise - sink
        target[:2] += ahead * direction
        if travelled < lift:
            velocity[2] = speed
        elif travelled < lift + forward:
            velocity[:2] = speed * direction
        elif sink < lift + s.late_reach_depth:
            velocity[2] = -speed
        if sink > 0.0 and self.estimated_forces[foot, 2] > self.touchdown_force:
            self._stumble_held[foot] = True  # on the ground: it stops there (the schedule takes it in)
            target[:] = self.data.oMf[self.robot.foot_frame_ids[foot]].translation
            velocity[:] = 0.0
        self._drive(foot, measurement)

    def _start_stumble(self, t: float, foot: int, measurement: Measurement, force: np.ndarray) -> bool:
        """Whether a swinging foot stumbles now: the observer's horizontal force on it against the trunk's
        horizontal travel (world) above ``stumble_force`` and above the vertical force (at a lift-off the
        observer's lag still reads the stance's load for a few milliseconds: mostly vertical), the foot moving
        along the travel slower than the trunk (held back); if so its origin and direction are set."""
        assert self.stumble_force is not None
        rotation = self.data.oMi[1].rotation  # the floating base's orientation (world from base)
        travel = (rotation @ measurement.v[:3])[:2]
        norm = float(np.hypot(travel[0], travel[1]))
        if norm < 1e-3:
            return False
        direction = travel / norm
        push = -float(force[:2] @ direction)
        if push <= self.stumble_force or push <= abs(float(force[2])):  # not a lift-off's lagging load
            return False
        foot_velocity = self._foot_jacobians[foot] @ measurement.v
        if float(foot_velocity[:2] @ direction) >= norm:  # a foot moving faster than its trunk: not held
            return False
        self._stumble_since[foot] = t
        self._stumble_origin[foot] = self.data.oMf[self.robot.foot_frame_ids[foot]].translation
        self._stumble_direction[foot] = direction
        self._stumble_held[foot] = False
        self._stumble_forward[foot] = self.settings.stumble_forward
        self.stumbles += 1
        return True

    def _drive(self, foot: int, measurement: Measurement) -> None:
        """``reach_torques[foot]``: the leg follows ``reach_targets[foot]`` (moving at ``_target_velocity``)
        as a critically damped spring of natural frequency ``late_reach_frequency`` through its
        operational-space inertia with the trunk held, plus its bias forces (``_reach``)."""
        s, data = self.settings, self.data
        position = data.oMf[self.robot.foot_frame_ids[foot]].translation
        target = self.reach_targets[foot]
        v = measurement.v
        jacobian = self._foot_jacobians[foot]
        np.matmul(jacobian, v, out=self._foot_velocity)
        columns = self._leg_columns[foot]
        leg = jacobian[:, columns]
        mass = self._mass[columns, columns]
        self._leg_inertia[:] = np.linalg.inv(leg @ np.linalg.solve(mass, leg.T))
        w = s.late_reach_frequency
        accel = w * w * (target - position) - 2.0 * w * self._foot_velocity
        accel += 2.0 * w * self._target_velocity  # as written before the stumble: the same floats
        bias = self._bias[columns]
        np.matmul(self._coriolis[columns], v, out=bias)
        bias += data.g[columns]
        self.reach_torques[foot] = leg.T @ (self._leg_inertia @ accel) + bias

    def leg_torque(self, foot: int, force: np.ndarray) -> np.ndarray:
        """``J_f,leg' force``: the torques on the foot's leg that push it with ``force`` (world, N) at the
        last update's configuration (the momentum observer's Jacobians)."""
        return self._leg_transposes[foot] @ force

    def update(
        self, t: float, measurement: Measurement, plan: KnotPlan, torques: np.ndarray | None = None
    ) -> np.ndarray:
        """The detected stance flags at ``t`` (owned by the detector, overwritten next tick). ``torques``:
        the joint torques applied since the previous update (needed with ``force_estimate: momentum``)."""
        if plan is not self._plan:
            self._index_plan(plan)
        if self.force_estimate == "momentum":
            if torques is None:
                raise ValueError("contact detection with force_estimate: momentum needs the applied torques")
            foot_forces = self._observe_momentum(t, measurement, torques)
        else:
            foot_forces = measurement.foot_forces
        s = self.settings
        k = plan.knot_at(t)
        planned = plan.contacts[k]
        model, data = self.robot.model, self.data
        radius, ground, soles = self.robot.foot_radius, self.ground, self.soles
        checks_speed = ground is not None and s.landing_speed is not None
        if checks_speed:
            pin.forwardKinematics(model, data, measurement.q, measurement.v)
            pin.updateFramePlacements(model, data)
        elif self.force_estimate != "momentum":  # the observer placed the frames at this q already
            pin.framesForwardKinematics(model, data, measurement.q)
        reach = s.touchdown_height if ground is None else s.step_height
        # a late foot lands by its height where the ground is known (flat) or where the force is no
        # measurement (the static estimate echoes the stance torques); on an estimated plane with the
        # observer's force it lands when the ground pushes on it (below the plane it may be in the air)
        lands_by_height = ground is None or self.force_estimate == "static"
        for foot, frame_id in enumerate(self.robot.foot_frame_ids):
            soles[foot] = data.oMf[frame_id].translation
            soles[foot, 2] -= radius
            if ground is None:
                height = soles[foot, 2] - s.ground_height
            else:
                height = soles[foot, 2] - ground.height_at(soles[foot, 0], soles[foot, 1])
            self.heights[foot] = height
            moving = False
            if checks_speed:
                velocity = pin.getFrameVelocity(model, data, frame_id, pin.LOCAL_WORLD_ALIGNED)
                self.vertical_speeds[foot] = velocity.linear[2]
                moving = abs(self.vertical_speeds[foot]) >= s.landing_speed
            force = foot_forces[foot, 2]
            loaded = force > self.touchdown_force and height < reach
            if planned[foot]:
                if not self.in_contact[foot]:
                    at_ground = lands_by_height and height < s.touchdown_height
                    self.in_contact[foot] = (at_ground or loaded) and not moving
                elif force < self.release_force and height > s.release_height:
                    self.in_contact[foot] = False
                if not self.in_contact[foot]:
                    self.late_touchdown_ticks += 1
            else:
                if self._was_planned[foot]:  # the planned swing has begun: the schedule lifts the foot
                    self.in_contact[foot] = False
                    if self.early_hold_rise is not None:
                        self._liftoff_soles[foot] = soles[foot, 2]
                lead = self._next_touchdown[k, foot] - t
                soon = self.on_time < lead <= s.early_window
                if not self.in_contact[foot] and soon and loaded and not moving:
                    self.in_contact[foot] = True
                    self.early_touchdowns += 1
                    self.early_lead_sum += lead
                    if self.early_hold_height is not None and height > self.early_hold_height:
                        if (
                            self.early_hold_rise is None
                            or soles[foot, 2] - self._liftoff_soles[foot] > self.early_hold_rise
                        ):
                            self.holding[foot] = True  # on a higher tread: held where it landed
                            self.reach_targets[foot] = data.oMf[frame_id].translation
                        else:
                            self.lowered[foot] = True  # on lower ground: in the stance set, not held
                elif self.in_contact[foot] and force < self.release_force and height > s.release_height:
                    self.in_contact[foot] = False
                if self.in_contact[foot]:
                    self.early_ticks += 1
            self._was_planned[foot] = planned[foot]
            if self.lowered[foot] and (planned[foot] or not self.in_contact[foot]):
                self.lowered[foot] = False
            if self.holding[foot]:
                if planned[foot] or not self.in_contact[foot]:
                    self.holding[foot] = False  # its stance began (or it left the ground): the plan's
                else:
                    self._target_velocity[:] = 0.0
                    self._drive(foot, measurement)
            if self.late_reach_speed is not None:
                late = planned[foot] and not self.in_contact[foot]
                fast = self.leg_descent_speeds[foot] > self.late_reach_speed
                self.reaching[foot] = late and (self.reaching[foot] or fast)
                if self.reaching[foot]:
                    self._reach(t, foot, measurement)
                else:
                    self._late_since[foot] = np.nan
            if self.stumble_force is not None:
                if self.in_contact[foot] or (planned[foot] and self._stumble_held[foot]):
                    self.stumbling[foot] = False  # landed: the plan's stance takes it from here
                elif not self.stumbling[foot] and not planned[foot] and lead > self.on_time:
                    # (``lead``: this swing's time to its planned touchdown, set above)
                    self.stumbling[foot] = self._start_stumble(t, foot, measurement, foot_forces[foot])
                if self.stumbling[foot]:
                    self.reaching[foot] = False
                    self._stumble(t, foot, measurement)
        if ground is not None:
            ground.observe(soles, self.in_contact)
        return self.in_contact

    def statistics(self) -> dict:
        return {
            "early_touchdowns": self.early_touchdowns,
            "early_touchdown_lead_s_mean": (
                self.early_lead_sum / self.early_touchdowns if self.early_touchdowns else None
            ),
            "early_touchdown_ticks": self.early_ticks,
            "late_touchdown_ticks": self.late_touchdown_ticks,
            **({"stumbles": self.stumbles} if self.stumble_force is not None else {}),
        }
