"""Run configurations: YAML files a user can read and edit, validated at the boundary.

A run config names a robot, the low-level controller (``wbc``: PD standing, or CAFE-MPC with the Riccati
feedback (33) or the VWBC QP (34) at the control rate), the gait and its velocity commands, the MPC's model
schedule and rates, the whole-body cost weights, pushes and simulation settings. Presets live in
``cafe_mpc/configs/<name>.yaml``; ``cafe-mpc run PRESET_OR_FILE --set key=value`` overrides any key by its
dotted path (``simulation.duration=3``, ``pushes.0.start=1.5``, ``gait.commands.0.vx=0.8``). Unknown keys and
out-of-range values are rejected with a one-line message that names the key and the allowed range.
"""

from __future__ import annotations

import functools
import itertools
import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, Literal

from pydantic import ConfigDict, Field, ValidationInfo, field_validator, model_validator

from cafe_mpc.config.estimation import KinematicKFSettings
from cafe_mpc.config.loading import StrictModel, load_model, read_yaml
from cafe_mpc.config.weights import BaseError, SRBWeights, WholeBodyWeights

PRESET_DIR = Path(__file__).parent.parent / "configs"


class FallConfig(StrictModel):
    """When a run counts as fallen (and, with ``stop_on_fall``, ends)."""

    min_base_height: float = Field(0.10, ge=0.0, le=1.0, description="m; below this the robot has fallen")
    max_tilt_rad: float = Field(1.2, gt=0.0, le=3.1416, description="base tilt that counts as a fall")


class SimulationConfig(StrictModel):
    """How long and how finely the closed loop is simulated."""

    duration: float = Field(5.0, gt=0.0, le=3600.0, description="simulated seconds")
    control_rate_hz: float = Field(500.0, gt=0.0, le=10000.0, description="low-level controller rate")
    plant_timestep: float = Field(0.001, gt=0.0, le=0.01, description="MuJoCo step, s")
    initial_height_offset: float = Field(0.0, ge=-0.05, le=1.0, description="start this far above standing")
    stop_on_fall: bool = Field(True, description="end the run when the robot falls (fall.*)")
    realtime: bool = Field(
        False,
        description="run against the wall clock: plant + low level at control_rate_hz in this process, "
        "the MPC in its own process (cafe-mpc run --realtime)",
    )
    realtime_priority: int = Field(
        50,
        ge=0,
        le=99,
        description="with realtime: the 500 Hz loop's thread in SCHED_FIFO at this priority where the OS "
        "allows it (root or CAP_SYS_NICE; elsewhere the normal class, said in the run's record); 0: off",
    )
    lock_memory: bool = Field(
        True,
        description="with realtime: lock the loop's and the MPC process's memory (mlockall) so that no tick "
        "waits for a page the OS reclaimed (root or CAP_IPC_LOCK; elsewhere said in the run's record)",
    )
    fall: FallConfig = Field(default_factory=FallConfig, description="what counts as a fall")

    @model_validator(mode="after")
    def _rate_matches_step(self) -> SimulationConfig:
        ratio = 1.0 / (self.control_rate_hz * self.plant_timestep)
        if ratio < 1.0 - 1e-9 or abs(ratio - round(ratio)) > 1e-6:
            raise ValueError(
                f"control period 1/{self.control_rate_hz} s must be a whole multiple of plant_timestep "
                f"{self.plant_timestep} s"
            )
        return self


class PushConfig(StrictModel):
    """A push on the base: either a world force (N) or the base velocity change it should cause (m/s)."""

    start: float = Field(ge=0.0, description="s")
    duration: float = Field(gt=0.0, le=10.0, description="s")
    force: tuple[float, float, float] | None = Field(None, description="N, world frame (or velocity_change)")
    velocity_change: tuple[float, float, float] | None = Field(
        None, description="m/s of base velocity the push should cause, world frame (or force)"
    )

    @model_validator(mode="after")
    def _one_of(self) -> PushConfig:
        if (self.force is None) == (self.velocity_change is None):
            raise ValueError("a push needs exactly one of 'force' (N) or 'velocity_change' (m/s)")
        return self

    def force_on(self, mass: float) -> tuple[float, float, float]:
        if self.force is not None:
            return self.force
        dv = self.velocity_change or (0.0, 0.0, 0.0)
        return (mass * dv[0] / self.duration, mass * dv[1] / self.duration, mass * dv[2] / self.duration)


class PDSettings(StrictModel):
    """The standing controller (``wbc: pd``; ``low_level.pd.PDController``): joint PD about the standing
    pose. The gains are the reference robot's; the assembly carries them to the run's robot
    (``robots.scaling``: the torque scale, times the time scale for the damping)."""

    kp: float = Field(60.0, ge=0.0, le=1000.0, description="Nm/rad")
    kd: float = Field(1.5, ge=0.0, le=100.0, description="Nm s/rad")
    gravity_feedforward: bool = Field(True, description="add the torques that hold the standing pose")


WarmStart = Literal["previous", "plan", "equality", "none"]
"""How the VWBC QP starts: the previous tick's solution, the plan's guess, the equality-constrained
solution (ProxQP), or cold."""


ON_TIME_FLAT = 0.025
"""s: ``vwbc.contact_detection.on_time`` when it is null and the run is on flat ground (``terrain: flat``)."""

ON_TIME_OFF_FLAT = 0.015
"""s: ``vwbc.contact_detection.on_time`` when it is null and the run has terrain (``terrain`` not
``flat``). On flat ground 25 ms keeps the bound's front feet, which land 15-20 ms early, under the plan's
stance timing; off it a foot landing early is what the detector is for: with 25 ms the blind bound fell on a
10 degree slope at 3.74 s, with 15 ms it climbed it (docs/terrain-notes.md)."""


class ContactDetectionSettings(StrictModel):
    """Thresholds of the contact detector (``low_level.contact_detection``; ``vwbc.contact_detection``):
    forces as fractions of a foot's share of the robot's weight (``m g / n_feet``), heights in metres above
    the (flat) ground, the early window and the on-time margin in seconds around a planned touchdown. The
    heights and times are the reference robot's: a run scales them to its robot once (its resolved
    ``contact_detection``), for the detector and the reference's touchdown events alike."""

    touchdown_force: float = Field(0.35, gt=0.0, le=5.0, description="touchdown above this x m g / n_feet")
    release_force: float = Field(0.1, ge=0.0, le=5.0, description="release below this x m g / n_feet")
    touchdown_height: float = Field(
        0.02, gt=0.0, le=0.5, description="m; foot sole within this of the ground"
    )
    release_height: float = Field(0.03, gt=0.0, le=0.5, description="m; foot sole above this: released")
    early_window: float = Field(0.08, ge=0.0, le=1.0, description="s before a planned touchdown that count")
    on_time: float | None = Field(
        None,
        ge=0.0,
        le=1.0,
        description="s; a touchdown this close to its planned time is on time (null: config.ON_TIME_FLAT, "
        "0.025, on flat ground, config.ON_TIME_OFF_FLAT, 0.015, with terrain other than flat)",
    )
    ground_height: float = Field(0.0, description="m; the flat ground's height")
    step_height: float = Field(
        0.1,
        gt=0.0,
        le=0.5,
        description="m; with a ground plane (terrain: blind), a loaded foot up to this above it touches down",
    )
    landing_speed: float | None = Field(
        None,
        gt=0.0,
        le=10.0,
        description="m/s; with a ground plane (terrain: blind), a touchdown (early or late) counts only "
        "while the foot's vertical speed is below this: a foot still moving is in the air (its load may be "
        "the echo of the torques pushing it, its height is measured above an estimated plane); null: not "
        "checked",
    )
    late_descent_speed: float | None = Field(
        None,
        gt=0.0,
        le=10.0,
        description="m/s; with a ground plane and the momentum observer, a late foot (planned in stance, not "
        "landed) whose leg moves it down faster than this (its joints' share of the foot's velocity) loses "
        "its planned ground force from the leg's torque reference in the VWBC, all of it at twice this "
        "speed, so that its stance torques do not slam it into a lower tread; null: off",
    )
    late_reach_speed: float | None = Field(
        None,
        gt=0.0,
        le=10.0,
        description="m/s; with a ground plane and the momentum observer, a late foot (planned in stance, not "
        "landed) whose leg moves it down faster than this (its joints' share of the foot's velocity) is "
        "position-controlled from then on as a swing that reaches down at this speed to late_reach_depth "
        "below the ground plane, and carries no planned ground force until it lands (instead of its leg's "
        "stance torques, which throw it down unchecked); null: off",
    )
    late_reach_depth: float = Field(
        0.1,
        gt=0.0,
        le=0.5,
        description="m; how far below the ground plane a late foot reaches (late_reach_speed)",
    )
    late_reach_frequency: float = Field(
        50.0,
        gt=0.0,
        le=1000.0,
        description="rad/s; natural frequency of a reaching late foot's position control (critically "
        "damped, through its leg's operational-space inertia; late_reach_speed)",
    )
    stumble_force: float | None = Field(
        None,
        gt=0.0,
        le=5.0,
        description="x m g / n_feet; with a ground plane and the momentum observer, a swinging foot (planned "
        "swing, not in contact, more than the on-time margin before its touchdown) pushed back by more than "
        "this horizontal force against the trunk's travel, and by more than its vertical force, while it "
        "moves along the travel slower than the trunk (a riser's face in the way) stumbles: from then on it "
        "is position-controlled, rising stumble_lift at stumble_speed, moving stumble_forward along the "
        "travel, then reaching down, held where it lands, until its planned stance (a stumble reflex); "
        "null: off",
    )
    stumble_lift: float = Field(
        0.07, gt=0.0, le=0.5, description="m; how far a stumbling foot rises above where it stumbled"
    )
    stumble_forward: float = Field(
        0.05, ge=0.0, le=0.5, description="m; how far a stumbling foot moves forward once it has risen"
    )
    stumble_to_plan: float | None = Field(
        None,
        ge=0.0,
        le=1.0,
        description="a stumbling foot moves forward at least to this share of the way from the plan's base "
        "to the plan's foothold at its planned touchdown, or to the foothold if that is nearer (a hind "
        "foot; 0: under the trunk's centre, 1: on the foothold; along the travel; stumble_forward if the "
        "plan has no configurations), not only stumble_forward: held where it lands until its planned "
        "stance, a foot stepped 5 cm past a riser was left 7-28 cm behind the base when its stance came "
        "(stumble_force); null: stumble_forward only",
    )
    stumble_speed: float = Field(
        2.0, gt=0.0, le=10.0, description="m/s; the speed of a stumbling foot's target (stumble_force)"
    )
    early_force: float | None = Field(
        None,
        ge=0.0,
        le=10.0,
        description="x m g / n_feet; with a ground plane (terrain: blind), an early foot (taken into the "
        "stance set before its planned touchdown) may push the ground with at most this normal force in the "
        "VWBC (34e), so that its swing knot's policy does not drive it into the ground with the trunk in "
        "flight (an incline met early); null: no cap",
    )
    early_hold_height: float | None = Field(
        None,
        ge=0.0,
        le=0.5,
        description="m; with a ground plane and the momentum observer, a foot taken in early (landed in its "
        "planned swing, within early_window) with its sole more than this above the ground plane (a higher "
        "tread than the plane knows) is held where it landed until its planned stance (position-controlled "
        "as a landed stumbling foot, late_reach_frequency), instead of driven along its swing curve into the "
        "tread; null: off",
    )
    early_hold_rise: float | None = Field(
        None,
        ge=-0.5,
        le=0.5,
        description="m; with early_hold_height, a foot is held only if its sole also landed more than this "
        "above its sole at its planned lift-off (a higher tread than the one it left); a foot landing early "
        "on lower ground under a plane tilted past it stays in the stance set unheld; null: no such check",
    )
    """Going down the 6 cm steps the blind bound's front feet landed on the floor 80-90 ms early, 4 cm above
    the detector's plane (tilted down from the hind feet on the tread) but 4 cm below where they lifted off:
    held where they landed they carried 5-15 N while the hinds lifted off on schedule, and the trunk fell on
    its nose (docs/terrain-notes.md, "Early feet on lower ground")."""
    early_low_force: float | None = Field(
        None,
        ge=0.0,
        le=10.0,
        description="x m g / n_feet; with early_hold_rise, a foot it keeps from being held (taken in early "
        "above the plane, not above its lift-off) pushes at most this normal force in the VWBC (34e) until "
        "its planned stance; null: no cap",
    )
    """Unheld, such a foot on the floor past the blind bound's last 6 cm riser was driven down its swing curve
    at 150 N per foot and threw the trunk up (docs/terrain-notes.md, "Early feet on lower ground")."""
    ground_max_slope: float | None = Field(
        None,
        gt=0.0,
        le=2.0,
        description="rise per run; with a ground plane (terrain: blind), the steepest plane the detector's "
        "and the reference's ground plane estimates believe (their least-squares slope through the feet's "
        "latest contact points is scaled down to it); null: core.ground.MAX_SLOPE (0.7, 35 deg)",
    )
    """Going down 6 cm steps the blind bound's pairs stood 10-12 cm apart in x on two treads and both planes
    tilted 0.6 (31 deg): 17 cm ahead they lay 10 cm under the tread, the front feet's swing aimed there and
    met the tread 100 ms early, more than ``step_height`` above the detector's plane (docs/terrain-notes.md,
    "Early feet on the next tread")."""
    ground_min_span: float | None = Field(
        None,
        gt=0.0,
        le=1.0,
        description="m; with a ground plane (terrain: blind), both ground planes (the detector's, the "
        "reference's) fit their slope only along directions their points spread at least this along (root "
        "mean square about their centroid) and hold the last fitted slope along the others; null: every "
        "fit's slope",
    )
    """Climbing 6 cm steps the blind bound's hind feet landed 6-7 cm ahead of the front feet's last points,
    1.6 cm lower (the soles sinking, the estimate drifting): both planes tilted to -0.25 to -0.3, 7-8 cm under
    the next tread where the front feet landed early, so the detector (``step_height`` above its plane) did
    not take them in and their swing drove them into the tread at 150 N (docs/terrain-notes.md)."""
    force_estimate: Literal["static", "momentum"] | None = Field(
        None,
        description="the ground force the detector reads: static (the measurement's, from the joint torques "
        "through the leg Jacobians, legs massless: a leg swinging or pushed through the air reads its own "
        "torques as a load) or momentum (a generalized-momentum observer on the torques the low level "
        "applied: only what the ground adds to the robot's momentum; momentum_gain); null: static on flat "
        "ground, momentum off it (terrain: blind or height_map)",
    )
    """Off flat ground the observer took 36 of the blind grid's 45 runs over (static 32:
    docs/terrain-notes.md, "The momentum observer"); on flat ground both give the same runs to the bit, and
    static costs less."""
    momentum_gain: float = Field(
        150.0, gt=0.0, le=2000.0, description="1/s; bandwidth of the momentum observer (force_estimate)"
    )

    def ground_plane_limits(self) -> dict[str, float]:
        """The keyword arguments of ``core.ground.GroundPlane`` these settings fix: ``max_slope`` when
        ``ground_max_slope`` is set, ``min_span`` when ``ground_min_span`` is (none when they are null: the
        plane's defaults)."""
        limits = {} if self.ground_max_slope is None else {"max_slope": self.ground_max_slope}
        if self.ground_min_span is not None:
            limits["min_span"] = self.ground_min_span
        return limits

    def force_estimate_for(self, flat: bool) -> str:
        """The ground force the detector reads: ``force_estimate``, or when it is null ``static`` on flat
        ground and ``momentum`` off it."""
        if self.force_estimate is not None:
            return self.force_estimate
        return "static" if flat else "momentum"

    def on_time_for(self, flat: bool) -> float:
        """The on-time margin (s): ``on_time``, or when it is null ``ON_TIME_FLAT`` on flat ground and
        ``ON_TIME_OFF_FLAT`` off it. The default is an explicit null rather than "not set", so that a config
        written out (``config.yaml``, an experiment's task) and read back runs the same."""
        if self.on_time is not None:
            return self.on_time
        return ON_TIME_FLAT if flat else ON_TIME_OFF_FLAT


class VWBCSettings(StrictModel):
    """The VWBC QP (34) and its solver (``low_level.vwbc.VWBCController``): the run config's ``vwbc``
    section. What the run derives for it (the friction of its pyramid: ``friction`` or the plan's, the
    Baumgarte rate and the cone tolerance scaled to the robot, the detector's thresholds scaled to the
    robot) is resolved once (``planners.resolved.ResolvedRun``), not a setting here.

    ``solver``: ``daqp`` (DAQP, a dual active-set solver, on (34) condensed onto ``tau``) or ``proxqp``
    (ProxQP on (34) as is). ``warm_start``: ``plan`` (guess from the plan, the paper's choice: for ProxQP the
    primal ``[qdd_fd, tau*, F*]`` with zero multipliers, for DAQP the constraints active at ``tau*``),
    ``previous`` (previous tick's solution, ProxQP primal-dual, DAQP working set, when the stance pattern is
    unchanged, else the plan guess), ``equality`` (ProxQP's default initial guess: the equality-constrained
    QP's solution; for DAQP the same as ``none``) or ``none`` (cold start: ProxQP from zero, DAQP from the
    empty working set). ``stance_source``: the stance set ``C`` of (34c)-(34f): ``detected`` (the contact
    detector's, ``contact_detection``), ``plan`` (the plan knot's, the paper's) or ``intersect`` (planned and
    measured in contact). ``time_budget_ms``: if set, a tick whose assembly + solve took longer falls back to
    the Riccati torque; off by default because a wall-clock rule makes simulated runs depend on machine
    load (slow ticks are counted either way)."""

    solver: Literal["daqp", "proxqp"] = Field(
        "daqp", description="daqp: dual active set on the QP condensed onto tau; proxqp: the QP as written"
    )
    warm_start: WarmStart = Field(
        "previous",
        description="previous tick's solution, the plan's guess, the equality-constrained solution (proxqp), "
        "or none (cold)",
    )
    friction: float | None = Field(
        None,
        gt=0.0,
        le=2.0,
        description="friction coefficient of the QP's pyramid (34f); null: 1.25 x the plan's (mpc.friction), "
        "headroom over the plan's relaxed pyramid",
    )
    stance_source: Literal["plan", "intersect", "detected"] = Field(
        "detected",
        description="detected: the contact detector's stance (low_level.contact_detection: force, foot "
        "height and the schedule's prior); plan: the plan knot's stance (the paper's); intersect: planned "
        "and in contact",
    )
    contact_detection: ContactDetectionSettings = Field(
        default_factory=ContactDetectionSettings, description="thresholds of stance_source: detected"
    )
    state_reference: Literal["knot", "interpolated"] = Field(
        "knot",
        description="the planned state x* of the state error in (34a): knot: x*_k of the knot whose "
        "interval holds t, held over the interval (the paper's); interpolated: the plan's state at t, "
        "between x*_k and x*_k+1 (Plan.state_at). In fast motions the held x*_k falls behind within an "
        "interval and the feedback takes back the planned push (docs/tasks.md, backflip)",
    )
    eps_abs: float = Field(1e-6, gt=0.0, le=1.0, description="absolute tolerance of the QP solver")
    eps_rel: float = Field(0.0, ge=0.0, le=1.0, description="relative tolerance of the QP solver (proxqp)")
    max_iter: int = Field(200, ge=1, le=100000, description="iterations of one QP solve")
    regularization: float = Field(
        0.0, ge=0.0, le=1.0, description="proxqp: weight of 0.5 |(qdd, F)|^2 added to the QP (0: none)"
    )
    time_budget_ms: float | None = Field(
        None, gt=0.0, le=1000.0, description="ms; a slower tick falls back to the Riccati torque (null: off)"
    )


DEFAULT_FRICTION = 0.6
"""The nominal floor's friction coefficient (the paper's, the Mini Cheetah table's): the default of the
library's components built without a run config (plan pyramid, VWBC cone, template, trajectory
optimisation)."""

CONTROLLER_FRICTION = 0.4
"""The friction coefficient a run's controller assumes (``mpc.friction``): the low end of the floors it must
work on, not the nominal 0.6. Planned at 0.6, the approach pace of the running roll puts a tenth of its stance
ticks at the cone's edge on a 0.6 floor and every gait slides on a lower one (docs/robustness.md)."""

BLIND_SWING_HEIGHT = 0.1
"""m: ``gait.blind_swing_height``, the least swing apex of a blind run (``terrain: blind``). The presets' 6 cm
apex above lift-off catches a 6 cm riser the foot does not know of; with 10 cm and ``BLIND_SWING_LIFT`` the
blind trot, pace and flying trot climb and descend three 6 cm steps (docs/terrain-notes.md)."""

BLIND_SWING_LIFT = 0.2
"""``gait.blind_swing_lift``: a blind swing's foot rises for the first fifth of the swing before it moves
forward, so that a foot that landed against a riser lifts off it instead of dragging into it."""

VWBC_FRICTION_HEADROOM = 1.25
"""The VWBC's pyramid (34f) over the plan's (26) when ``vwbc.friction`` is not set: ``1.25 mpc.friction`` (0.5
for the plan's 0.4). The plan's pyramid is a relaxed barrier, so its forces may pass its edge by a little; the
VWBC's is hard. At one coefficient for both, the low level clipped the forces the plans hold pitch with where
the plans lean on them: the bound's hind feet sat at the VWBC's edge in half their stance ticks and the trunk
rode 1.5-2.5 cm high, pitched nose-down (docs/robustness.md)."""


STANDING_CONTROLLERS = ("pd", "balance")
"""``wbc`` values that stand in place by themselves, without a planner (no gait, no reference)."""


PAPER_BUDGET_FRACTION = 0.9
"""The share of the MPC period a solve may take in measured mode (the paper's budget: 18 ms of 20 ms)."""


BAUMGARTE_ALPHA = 10.0
"""1/s, the first-order Baumgarte rate of the contact constraints (paper Eq. (20), (34c)) on the reference
robot: the whole-body knots' and the VWBC's (a run scales it to its robot: its ``ContactModel``)."""

CONE_TOLERANCE = 1e-3
"""N on the reference robot: a contact force further than this outside the friction pyramid counts as a
violation (the VWBC's count and the post-hoc score; scaled with the robot's mass in a run)."""

WHOLE_BODY_DT = 0.01
"""dt_w, s: the whole-body knots' time step (paper Table I): ``mpc.whole_body_dt``'s default, and the one of
whole-body knots built outside a run config."""

SRB_DT = 0.05
"""dt_s, s: the SRB knots' time step (paper Table I): ``mpc.srb_dt``'s default, and the one of SRB knots built
outside a run config."""


class VelocityCommand(StrictModel):
    """A velocity command from ``start`` on: speeds in the heading (yaw) frame, yaw rate and body height
    (``reference.locomotion`` tracks it; a gait's ``commands``). Which commands a robot can follow is the
    library's check (``reference.locomotion.validate_command``)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    start: float = Field(0.0, ge=0.0, description="s; the command holds until the next one starts")
    vx: float = Field(0.0, description="m/s forward in the heading frame")
    vy: float = Field(0.0, description="m/s to the left in the heading frame")
    yaw_rate: float = Field(0.0, description="rad/s")
    height: float | None = Field(None, description="m body height; null: the robot's standing height")


def _default_commands() -> list[VelocityCommand]:
    return [VelocityCommand(vx=0.5)]


class GaitConfig(StrictModel):
    """The periodic gait and the heuristic reference's parameters (paper Sec. VI-A)."""

    name: str = Field("trot", description="a gait of cafe_mpc.ocp.contact_schedule.GAITS")
    swing_height: float = Field(0.06, ge=0.0, le=0.2, description="m, swing apex above lift-off")
    swing_lift: float = Field(
        0.0,
        ge=0.0,
        le=0.4,
        description="fraction of each swing the foot rises before it moves forward (0: the paper's swing, "
        "rising and moving together; > 0: a foot that lands against a riser lifts off it before it swings)",
    )
    blind_swing_height: float = Field(
        BLIND_SWING_HEIGHT,
        ge=0.0,
        le=0.2,
        description="m; with terrain: blind, the least swing apex above lift-off (a blind foot must clear a "
        "riser it does not know of; swing_height where that is higher)",
    )
    blind_swing_lift: float = Field(
        BLIND_SWING_LIFT,
        ge=0.0,
        le=0.4,
        description="with terrain: blind, the least swing_lift (a blind foot that landed against a riser "
        "rises off it before it swings)",
    )
    blind_touchdown_clearance: float | None = Field(
        None,
        ge=0.0,
        le=0.2,
        description="m; with terrain: blind, the least swing apex above a touchdown higher than its lift-off "
        "(null: blind_swing_height, the apex that high above the higher end). Lower than blind_swing_height, "
        "a swing up a slope rises less above its touchdown, where the plane may lie above the ground, while "
        "a swing to level ground still clears blind_swing_height above its lift-off",
    )
    blind_ground: Literal["predicted", "estimate"] = Field(
        "predicted",
        description="with terrain: blind, the states the reference's ground plane takes its stance feet's "
        "points from: predicted (each MPC update's state: with the real-time iteration the plan's "
        "prediction, whose landing feet stand where the plan put them) | estimate (each control tick's "
        "state estimate; the MPC in its own process sees only its updates' states and keeps predicted)",
    )
    """The plane's frame-shift rule (``GroundPlane.observe``) reads a standing foot's change of height as
    the estimator's frame moving. In the predicted states a landing foot stands where the plan put it (the
    floor z = 0 with ``mpc.touchdown_surface: floor``) and rises to where it stands over the next updates:
    on a slope the blind bound's reference read that as the frame rising 5-10 cm at every touchdown and
    moved the other pair's points with it, so that its plane flipped between 20 deg and flat (slightly
    downhill) every half cycle, with ground truth as with the estimator (docs/terrain-notes.md)."""
    blind_ground_below: float | None = Field(
        None,
        ge=0.0,
        le=0.2,
        description="m, with blind_ground: estimate, a foot planned in stance that is still moving counts as "
        "a point of the plane once its sole is this far below it (a foot sliding or landing down a slope "
        "the plane has not seen; a late foot hanging above the plane stays out); null: only still feet",
    )
    """Going down the 15 deg slope the blind bound's stance feet slid and bounced at 0.3-3 m/s, above
    ``GROUND_FOOT_SPEED``: its plane took no point for 0.8 s from the crest and stayed flat at the top's
    level, 6-15 cm above the incline (docs/terrain-notes.md)."""
    blind_ground_follow: float | None = Field(
        None,
        ge=0.0,
        le=0.2,
        description="m, with blind_ground: estimate, a foot that became a point of the plane in its planned "
        "stance stays one, however fast it moves up or down, while it stays within this horizontal distance "
        "of where it became one, to the stance's end: its change of height is read as the estimator's frame "
        "moving and moves the other points with it; null: off",
    )
    """Going down 6 cm steps the blind bound's front pair landed on the lower tread, became points (below
    the plane), and while the estimator's frame moved up 6-8 cm to stand them at z = 0 they moved in the
    estimate (0.2-0.5 m/s): no longer still nor below the plane, their points stayed at the landing's height
    and the hind pair's were not moved. When the hind pair then stood on the upper tread, still, the frame
    moved down 7 cm and the plane moved the front points with it: 7 cm under the tread, the plane tilted to
    its slope limit and the base's reference sank 12 cm (docs/terrain-notes.md). Feet sliding on (down the
    15 deg slope) are not followed: their drop is the ground's, not the frame's."""
    raibert_gain: float = Field(0.03, ge=0.0, le=1.0, description="s, Raibert velocity feedback gain")
    start_stance: float = Field(
        0.0, ge=0.0, le=3600.0, description="s of all-feet stand before the gait's first cycle starts"
    )
    command_ramp: float = Field(
        0.0,
        ge=0.0,
        le=60.0,
        description="s over which the reference moves linearly to each new command (0: steps); the robot is "
        "at rest until the gait starts (start_stance), then ramps to the first command",
    )
    commands: list[VelocityCommand] = Field(default_factory=_default_commands, min_length=1)
    path_gain: float = Field(
        0.0,
        ge=0.0,
        le=10.0,
        description="rad of heading per m off the commanded path (0: the commands are dead-reckoned from "
        "each "
        "measurement, as a joystick's; > 0: the reference holds the path the commands trace from the start)",
    )
    path_heading_limit: float = Field(
        0.2, ge=0.0, le=1.0, description="rad; the largest heading correction toward the path"
    )
    path_anchor: float = Field(
        0.0,
        ge=0.0,
        le=1.0,
        description="with path_gain > 0: the fraction of the cross-track error taken out of the reference's "
        "anchor at each update, so the base reference and the footholds under its hips are placed that much "
        "closer to the path than the measured base (0: from the measurement; 1: on the path)",
    )
    touchdown_events: float | None = Field(
        None,
        ge=0.0,
        le=0.5,
        description="s; advance the gait's clock when a swing foot lands more than this before its planned "
        "touchdown (seen at each MPC update within the contact detector's early window and height), so that "
        "the plans stand on it; null: the schedule keeps its clock",
    )

    @field_validator("name")
    @classmethod
    def _gait_key(cls, value: str) -> str:
        """Gaits are named in snake case (``flying-trot`` -> ``flying_trot``); which exist is the library's
        (``assembly.checks``)."""
        return value.replace("-", "_").lower()

    @field_validator("commands")
    @classmethod
    def _commands_in_order(cls, commands: list[VelocityCommand]) -> list[VelocityCommand]:
        starts = [command.start for command in commands]
        if starts[0] != 0.0:
            raise ValueError(f"the first command must start at 0 s, got {starts[0]}")
        if any(later <= earlier for earlier, later in itertools.pairwise(starts)):
            raise ValueError(f"command start times must increase strictly, got {starts}")
        return commands

    @model_validator(mode="after")
    def _anchor_needs_path(self) -> GaitConfig:
        if self.path_anchor > 0.0 and self.path_gain == 0.0:
            raise ValueError(f"path_anchor {self.path_anchor} needs a path: give path_gain > 0")
        return self


class MpcSettings(StrictModel):
    """Receding-horizon settings of an MPC (``planners.base``; docs/settings.md: "MPC loop" and "Solver").

    ``latency``: ``measured`` (default): a plan takes effect once its real wall-clock update time has passed
    in simulated time (times ``compute_scale``: a computer that much slower), and the next update starts
    from the newest measurement when the worker is free; ``fixed``: the same with a constant
    ``fixed_latency`` (deterministic, for tests and for the paper's C++ budget). ``time_budget``: wall-clock
    cap of one solve (the paper's 0.9 x period), applied in measured mode only so that fixed-latency runs do
    not depend on the machine's load. ``max_iterations``: MS-iLQR iterations per update: 1, the real-time
    iteration scheme (the paper uses 4 with ~5 ms C++ iterations; in Python, with measured latency, 4
    iterations made 20-32 ms updates and the pace and bound presets fell, while 1 iteration keeps the latency
    near 12 ms and all five gaits stay up: BENCHMARKS.md). ``touchdown_max_penalty``: cap of the
    augmented-Lagrangian penalty of the touchdown constraint (25) (``SolverOptions.al_max_penalty``; the
    authors' 1e4 when null). The penalty starts at 20 and grows x5 per update while a planned foot misses the
    floor by more than 5 mm (the AL parameters carry over between updates); the barrel-roll preset caps it
    at 20. ``final_policy``: ``shift`` keeps the sweep the step was taken from, moved to the new plan to
    first order (one linearisation and one backward sweep per update); ``relinearize`` linearises and sweeps
    again at the new plan (a third more work per preparation; with the real-time iteration both track the
    gaits alike at fixed 20-60 ms latency, and the running barrel roll succeeds at 10-40 ms with either, at
    50 ms only with ``relinearize``: BENCHMARKS.md). ``warm_up``: seconds of future updates whose solver data
    (one per knot object: Pinocchio ``Data``, kinematics, buffers) are created right after the cold first
    solve, before the clock starts, instead of inside the first update that meets each knot object (which
    took 25-60 ms extra at the start of a gait and when the barrel roll entered the horizon). ``scheme``:
    ``rti`` (real-time iteration: ``prepare`` before the measurement, ``feedback`` after it) or
    ``one_phase`` (the whole update after the measurement). ``rti_line_search``: the preparation takes its
    MS-iLQR iteration(s) on the predicted state, line search included, and the feedback only embeds the
    measured state; or the preparation stops after the backward sweep and the feedback takes the full
    Newton step (the classical real-time iteration, no globalisation). ``rti_feedback``: how the feedback
    carries the measured initial state through the plan: the tangential predictor through the prepared
    ``A``, ``B`` (``linear``) or the dynamics rolled out under the prepared policy (``nonlinear``).
    ``threads``: threads that linearise the knots of an update (``SolverOptions.threads``).
    """

    period: float = Field(0.02, gt=0.0, le=0.5, description="s between MPC update starts (at most)")
    latency: Literal["fixed", "measured"] = Field(
        "measured",
        description="a plan takes effect after the measured wall time of its update (what a robot sees) "
        "or after fixed_latency (deterministic test mode)",
    )
    fixed_latency: float = Field(0.02, ge=0.0, le=0.5, description="s, with latency: fixed")
    time_budget: float | None = Field(
        None,
        gt=0.0,
        le=0.5,
        description="wall-clock cap of an update: problem and solve, with room left for the final policy, s "
        "(null: 0.9 x period; measured only)",
    )
    max_iterations: int = Field(
        1, ge=1, le=50, description="MS-iLQR iterations per update (1: real-time iteration; the paper: 4)"
    )
    touchdown_max_penalty: float | None = Field(
        None,
        gt=0.0,
        le=1e6,
        description="cap of the touchdown constraint's AL penalty (null: 1e4, the authors'; starts at 20)",
    )
    warm_up: float = Field(
        1.0,
        ge=0.0,
        le=20.0,
        description="s of future updates whose solver data are created after the cold solve, before the "
        "clock starts (0: none; each first use inside an update cost 25-60 ms)",
    )
    final_policy: Literal["relinearize", "shift"] = Field(
        "shift",
        description="policy an update returns: shift (the sweep the step was taken from, moved to the new "
        "plan: one linearisation and one sweep per update) or relinearize (linearise and sweep again at the "
        "new plan: more work, more tolerant of a long fixed latency)",
    )
    scheme: Literal["rti", "one_phase"] = Field(
        "rti",
        description="rti: real-time iteration (the update prepared from the predicted state before the "
        "measurement, only the feedback phase after it) | one_phase: the whole update after the measurement",
    )
    rti_line_search: bool = Field(
        True,
        description="rti: the preparation takes its line search on the predicted state (false: it stops "
        "after the backward sweep and the feedback takes the full step)",
    )
    threads: int = Field(
        1,
        ge=1,
        le=64,
        description="threads linearising the knots of an update (1: none; Pinocchio's Python bindings hold "
        "the GIL, so only the compiled kernels run in parallel: BENCHMARKS.md)",
    )
    rti_feedback: Literal["linear", "nonlinear"] = Field(
        "linear",
        description="rti: the measured state carried through the prepared policy by the linearised dynamics "
        "or by the dynamics themselves",
    )
    delay_compensation: bool = Field(
        True,
        description="rti with fixed latency: each update's problem starts at the last whole-body knot time "
        "at or before its plan takes effect (measurement + fixed_latency) and its feedback embeds the "
        "measured state carried there by the planning model under the plans in effect meanwhile "
        "(planners.cafe.prediction)",
    )
    compute_scale: float = Field(
        1.0,
        gt=0.0,
        le=100.0,
        description="measured latency: every measured compute time is multiplied by this (a computer that "
        "many times slower; its time budget is on that computer's clock); not with simulation.realtime",
    )

    @property
    def budget(self) -> float | None:
        """The wall-clock cap of an update's solve: ``time_budget`` or 0.9 x period in measured mode, in
        this computer's seconds.

        The cap is simulated time, like the latency: with ``compute_scale`` s (a computer s times slower)
        an update of w wall seconds here takes s w, so it gets ``cap / s`` of this computer's wall time, the
        share the slower computer's solver would see on its own clock."""
        if self.latency != "measured":
            return None
        cap = self.time_budget if self.time_budget is not None else PAPER_BUDGET_FRACTION * self.period
        return cap / self.compute_scale


class MpcConfig(MpcSettings):
    """The run's MPC: its model schedule (Tw, Ts, dt_w, dt_s), the friction it assumes and its
    receding-horizon settings (``MpcSettings``).

    ``schedule`` names one of the paper's schedules (S0..S20: Tw = 0.25 s, Ts = 0..2 s); for another split
    set ``schedule: null`` and give ``whole_body_horizon`` and ``srb_horizon``. The time steps apply to both.
    """

    schedule: str | None = Field("S4", description="paper schedule S0..S5, S10, S15, S20; null: explicit")
    whole_body_horizon: float | None = Field(None, gt=0.0, le=2.0, description="Tw, s (schedule: null)")
    srb_horizon: float | None = Field(None, ge=0.0, le=5.0, description="Ts, s (schedule: null)")
    whole_body_dt: float = Field(WHOLE_BODY_DT, gt=0.0, le=0.1, description="dt_w, s")
    srb_dt: float = Field(SRB_DT, gt=0.0, le=0.5, description="dt_s, s")
    integration: Literal["explicit", "semi_implicit", "explicit_world"] = Field(
        "explicit",
        description="time stepping of the whole-body knots: explicit (the paper's Eq. (23), body-frame base "
        "velocity), semi_implicit (Crocoddyl's Euler) or explicit_world (Eq. (23) with the base's linear "
        "velocity stepped in the world frame: keeps a spinning body's momentum in flight)",
    )
    touchdown_surface: Literal["floor", "reference", "lower"] | None = Field(
        None,
        description="where the touchdown constraint (25) puts a landing foot: the floor z = 0 (the paper's), "
        "the reference's foothold height at the touchdown (a stored trajectory onto a box, the height "
        "map's footholds; the blind ground plane's footholds made the blind bound fall on a 10 deg slope) "
        "or the lower of the two (a foothold below the floor, going down a blind slope, is reached; one "
        "above it is met early, as on the floor); null: reference with terrain: height_map, else floor",
    )
    friction: float = Field(
        CONTROLLER_FRICTION,
        gt=0.0,
        le=2.0,
        description="friction coefficient the controller assumes (plan's pyramid, VWBC's cone); the plant's "
        "own is plant.floor_friction, so a mismatch between the two is explicit",
    )
    torque_barrier_eps: float = Field(
        0.01,
        ge=0.0,
        le=100.0,
        description="weight of the plan's relaxed torque-limit barrier (delta 1 Nm); the authors' 0.01 lets "
        "plans "
        "ask for more than the low level can give",
    )
    plan_torque_fraction: float = Field(
        1.0,
        gt=0.0,
        le=1.0,
        description="the plan's torque limits as a fraction of the low level's (headroom for feedback)",
    )

    @model_validator(mode="after")
    def _schedule_consistent(self) -> MpcConfig:
        explicit = self.whole_body_horizon is not None or self.srb_horizon is not None
        if self.schedule is not None and explicit:
            raise ValueError(
                f"give either schedule ({self.schedule!r}) or whole_body_horizon and srb_horizon, not both "
                "(set mpc.schedule=null for an explicit split)"
            )
        if self.schedule is None and (self.whole_body_horizon is None or self.srb_horizon is None):
            raise ValueError("with schedule null, give both whole_body_horizon and srb_horizon")
        return self


def _weights_over_defaults(model: type[StrictModel], data: Any) -> Any:
    """``data`` of a section of weight sets with every weight set given as a mapping completed from that
    set's default: a file that gives ``running: {base_position: ...}`` changes that weight alone, as the
    ``--set running.base_position=...`` override does, instead of taking every other weight from the weight
    class's own defaults (which are another set's)."""
    if not isinstance(data, dict):
        return data
    merged = dict(data)
    for name, value in data.items():
        field = model.model_fields.get(name)
        if isinstance(value, dict) and field is not None and field.default_factory is not None:
            default = field.get_default(call_default_factory=True)
            merged[name] = {**default.model_dump(), **value}
    return merged


class CostsConfig(StrictModel):
    """Cost weights of the whole-body plan (``running``, ``terminal``: the authors' "regular" set,
    ``WholeBodyWeights``) and of the SRB tail (``srb_running``, ``srb_terminal``: the authors' SRB tracking
    set with ten times its height weight, ``SRBWeights.regular_running``, which says why, and why the tail
    does not take the whole-body base weights as Eq. (28) does). Sources in docs/settings.md. A set given in
    part keeps its default's other weights."""

    running: WholeBodyWeights = Field(default_factory=WholeBodyWeights.regular_running)
    terminal: WholeBodyWeights = Field(default_factory=WholeBodyWeights.regular_terminal)
    srb_running: SRBWeights = Field(default_factory=SRBWeights.regular_running)
    srb_terminal: SRBWeights = Field(default_factory=SRBWeights.regular_terminal)

    @model_validator(mode="before")
    @classmethod
    def _complete_sets(cls, data: Any) -> Any:
        return _weights_over_defaults(cls, data)


class TrajectoryCostsConfig(StrictModel):
    """Weight set ``barrel_roll`` of the knots inside a stored trajectory (default: the authors' barrel-roll
    set, ``WholeBodyWeights.barrel_roll_running/terminal``; docs/settings.md). The SRB tail uses the same base
    weights (Eq. (28)). A set given in part keeps the barrel-roll set's other weights."""

    running: WholeBodyWeights = Field(default_factory=WholeBodyWeights.barrel_roll_running)
    terminal: WholeBodyWeights = Field(default_factory=WholeBodyWeights.barrel_roll_terminal)

    @model_validator(mode="before")
    @classmethod
    def _complete_sets(cls, data: Any) -> Any:
        return _weights_over_defaults(cls, data)


class ReferenceSegmentConfig(StrictModel):
    """One piece of a composed reference (``reference.composition.ComposedReference``)."""

    kind: Literal["stand", "trajectory", "gait"] = Field(
        description="stand: the locomotion reference with gait stand; trajectory: a stored whole-body "
        "trajectory sampled by time (reference.trajectory.TrajectoryReference); gait: the locomotion "
        "reference of a gait section (segment time: its commands start at the segment's start)"
    )
    duration: float | None = Field(
        None,
        gt=0.0,
        le=3600.0,
        description="s; null: a trajectory's own length, or a last stand until the end of the run",
    )
    trajectory: str | None = Field(
        None, description="kind trajectory: a packaged trajectory (barrel-roll) or the path of a .npz file"
    )
    from_phase: int = Field(
        0, ge=0, description="kind trajectory: the first phase played (0: all; 1: skip the first phase)"
    )
    touchdown_events: float | None = Field(
        None,
        ge=0.0,
        le=0.5,
        description="kind trajectory: s; advance the trajectory's clock when a foot lands more than this "
        "before its planned touchdown (seen at each MPC update within the contact detector's early window "
        "and height), so that the plans stand on it; null: the trajectory keeps its clock",
    )
    height: float | None = Field(None, description="kind stand: body height, m (null: standing height)")
    gait: GaitConfig | None = Field(None, description="kind gait: the gait section (name, commands, ...)")
    offset: tuple[float, float, float] | None = Field(
        None, description="x (m), y (m), yaw (rad) placement; null: start where the previous segment ends"
    )

    @model_validator(mode="after")
    def _kind_fields(self) -> ReferenceSegmentConfig:
        if self.kind == "trajectory" and self.trajectory is None:
            raise ValueError("a trajectory segment needs 'trajectory' (e.g. barrel-roll or a .npz path)")
        if self.kind == "stand" and self.trajectory is not None:
            raise ValueError("'trajectory' belongs to segments of kind trajectory, not stand")
        if self.kind != "stand" and self.height is not None:
            raise ValueError(f"'height' belongs to segments of kind stand, not {self.kind}")
        if self.kind == "gait" and self.gait is None:
            raise ValueError("a gait segment needs 'gait' (e.g. {name: flying_pace, commands: [{vx: 0.8}]})")
        if self.kind != "gait" and self.gait is not None:
            raise ValueError(f"'gait' belongs to segments of kind gait, not {self.kind}")
        if self.kind != "trajectory" and self.from_phase:
            raise ValueError(f"'from_phase' belongs to segments of kind trajectory, not {self.kind}")
        if self.kind != "trajectory" and self.touchdown_events is not None:
            raise ValueError(
                f"'touchdown_events' belongs to segments of kind trajectory, not {self.kind} (a gait's: "
                "gait.touchdown_events)"
            )
        if self.offset is not None and not all(math.isfinite(value) for value in self.offset):
            raise ValueError(f"offset must be finite, got {self.offset}")
        return self


class ReferenceConfig(StrictModel):
    """A reference composed of segments joined in time (paper Sec. VII-C): e.g. stand, the barrel-roll
    trajectory, stand. Replaces ``gait`` for CAFE-MPC runs. Knots inside a trajectory use the weight set
    ``barrel_roll`` (``costs`` below and the whole-body ``base_error``; the constraints are the regular ones);
    stand segments use the run's ``costs`` (the regular set)."""

    segments: list[ReferenceSegmentConfig] = Field(min_length=1)
    costs: TrajectoryCostsConfig = Field(default_factory=TrajectoryCostsConfig)
    base_error: BaseError = Field(
        "world",
        description="whole-body base residual of the barrel_roll set: world-frame position, log3(R_ref' R) "
        "and world-frame linear velocity (world), or the tangent-space difference (tangent)",
    )

    join: Literal["fixed", "measured"] = Field(
        "fixed",
        description="where a segment without an offset starts: fixed, where the previous one ends as planned "
        "at the start; measured, re-joined at every MPC update to the end the active segment predicts from "
        "the measurement (a locomotion segment re-anchors on it), until the segment starts",
    )

    @model_validator(mode="after")
    def _segments_valid(self) -> ReferenceConfig:
        for index, segment in enumerate(self.segments[:-1]):
            if segment.kind in ("stand", "gait") and segment.duration is None:
                raise ValueError(
                    f"segments.{index}: a {segment.kind} segment needs a duration unless it is the last one"
                )
        return self


class TerrainConfig(StrictModel):
    """A piece of terrain in the plant's scene (``sim.terrain``: static MuJoCo geoms along the world x axis
    from ``start``, ``width`` m across centred on ``center_y``). The controller does not see it: it plans on
    flat ground or, with ``terrain: blind``, on the plane of its stance feet (docs/terrain.md).

    ``slope``: an incline rising at ``angle_deg`` over ``length`` m (horizontal), a flat top of ``top_length``
    m, then (``descend``) the same incline down. ``steps``: ``count`` steps of ``rise`` m up, each ``run`` m
    deep, the top, then (``descend``) the same steps down. ``stairs``: a building's staircase, ``count``
    steps of ``rise`` and ``tread``, a landing of ``landing_length`` m after every ``flight_steps`` steps (0:
    one flight), the top, then (``descend``) the same down. ``rough``: a random field ``length`` m long of
    heights within ``+-amplitude`` of ``amplitude`` (from 0 to twice it) on a ``cell_size`` grid, drawn from
    ``seed``. ``gaps``: ``count`` trenches ``gap_width`` m wide along x, ``spacing`` m apart, their bottom
    ``depth`` m below the floor. Each kind takes only its own keys (``TERRAIN_KEYS``); those it does not
    give take their defaults."""

    model_config = ConfigDict(validate_default=True)  # a kind's keys it was not given get their defaults

    kind: Literal["slope", "steps", "stairs", "rough", "gaps"] = Field(
        description="slope | steps | stairs | rough | gaps"
    )
    start: float = Field(1.0, ge=-50.0, le=500.0, description="m, world x where the terrain begins")
    width: float = Field(2.0, gt=0.0, le=50.0, description="m across (world y), centred on center_y")
    center_y: float = Field(0.0, ge=-50.0, le=50.0, description="m, world y of the centre line")
    top_length: float | None = Field(
        None, ge=0.0, le=100.0, description="slope, steps, stairs: m of flat top (default 1)"
    )
    descend: bool | None = Field(
        None, description="slope, steps, stairs: go down again after the top (default true)"
    )
    angle_deg: float | None = Field(None, gt=0.0, le=30.0, description="slope: incline, degrees")
    length: float | None = Field(
        None, gt=0.0, le=100.0, description="slope: horizontal length of the incline; rough: the field's, m"
    )
    count: int | None = Field(None, ge=1, le=50, description="steps, stairs: steps up; gaps: trenches")
    rise: float | None = Field(
        None, gt=0.0, le=0.3, description="steps, stairs: m per step (a box up to 0.3 m)"
    )
    run: float | None = Field(None, ge=0.05, le=5.0, description="steps: m of tread per step")
    tread: float | None = Field(None, ge=0.05, le=5.0, description="stairs: m of tread per step")
    flight_steps: int | None = Field(
        None, ge=0, le=50, description="stairs: steps per flight, a landing after each (0: one flight)"
    )
    landing_length: float | None = Field(None, ge=0.0, le=20.0, description="stairs: m of each landing")
    amplitude: float | None = Field(
        None, gt=0.0, le=0.2, description="rough: m, heights within +-amplitude of amplitude"
    )
    cell_size: float | None = Field(None, ge=0.02, le=2.0, description="rough: m between the field's heights")
    seed: int | None = Field(
        None, ge=0, description="rough: random stream of the field (same seed, same field)"
    )
    gap_width: float | None = Field(None, gt=0.0, le=2.0, description="gaps: m of each trench along x")
    spacing: float | None = Field(None, gt=0.0, le=20.0, description="gaps: m of ground between trenches")
    depth: float | None = Field(
        None, gt=0.0, le=10.0, description="gaps: m from the floor to a trench's bottom"
    )

    @field_validator(
        "top_length",
        "descend",
        "angle_deg",
        "length",
        "count",
        "rise",
        "run",
        "tread",
        "flight_steps",
        "landing_length",
        "amplitude",
        "cell_size",
        "seed",
        "gap_width",
        "spacing",
        "depth",
        mode="after",
    )
    @classmethod
    def _kind_key(cls, value: Any, info: ValidationInfo) -> Any:
        """A kind's own key: its default when not given; another kind's key: an error naming its kinds."""
        kind, key = info.data.get("kind"), info.field_name
        if kind is None:  # the kind itself is wrong: its own error says so
            return value
        if key in TERRAIN_KEYS[kind]:
            return TERRAIN_KEYS[kind][key] if value is None else value
        if value is not None:
            owners = [name for name, keys in TERRAIN_KEYS.items() if key in keys]
            raise ValueError(f"'{key}' belongs to terrain of kind {' or '.join(owners)}, not {kind}")
        return None

    @model_validator(mode="after")
    def _fits(self) -> TerrainConfig:
        if self.kind == "rough" and self.length is not None and self.cell_size is not None:
            if min(self.length, self.width) < 2 * self.cell_size:
                raise ValueError(
                    f"rough terrain: length {self.length} m and width {self.width} m must hold two cells of "
                    f"cell_size {self.cell_size} m"
                )
            cells = (self.length / self.cell_size + 1) * (self.width / self.cell_size + 1)
            if cells > 250_000:
                raise ValueError(f"rough terrain: {cells:.0f} heights is too many (at most 250000)")
        return self


_SLOPED = {"top_length": 1.0, "descend": True}
TERRAIN_KEYS: dict[str, dict[str, Any]] = {
    "slope": {"angle_deg": 5.0, "length": 1.0, **_SLOPED},
    "steps": {"count": 3, "rise": 0.03, "run": 0.3, **_SLOPED},
    "stairs": {"count": 5, "rise": 0.1, "tread": 0.3, "flight_steps": 0, "landing_length": 1.0, **_SLOPED},
    "rough": {"length": 2.0, "amplitude": 0.02, "cell_size": 0.1, "seed": 0},
    "gaps": {"count": 3, "gap_width": 0.1, "spacing": 0.6, "depth": 1.0},
}
"""Each terrain kind's own keys and their defaults (the keys every kind has: ``start``, ``width``,
``center_y``)."""


class SceneConfig(StrictModel):
    """What the plant stands on besides its robot: terrain pieces (``sim.terrain``) and a bar to jump over
    (``sim.bar``). The floor's friction is ``plant.floor_friction``."""

    terrain: list[TerrainConfig] = Field(
        default_factory=list, description="slopes, steps, stairs, rough fields and gaps (empty: flat floor)"
    )

    bar_height: float | None = Field(
        None,
        ge=0.0,
        le=2.0,
        description="m, height of a thin horizontal bar's axis above the floor (sim.bar; the running barrel "
        "roll's 0.4 m cable); 0 or null: no bar",
    )
    bar_position: tuple[float, float] = Field((0.0, 0.0), description="m, world (x, y) of the bar's centre")
    bar_yaw: float = Field(
        0.0, ge=-math.pi, le=math.pi, description="rad, direction of the bar's axis from the world x axis"
    )
    bar_length: float = Field(2.0, gt=0.0, le=20.0, description="m, length of the bar")
    bar_radius: float = Field(0.005, gt=0.0, le=0.1, description="m, radius of the bar (a capsule)")

    @field_validator("bar_position")
    @classmethod
    def _bar_position_finite(cls, value: tuple[float, float]) -> tuple[float, float]:
        if not all(math.isfinite(item) and abs(item) <= 500.0 for item in value):
            raise ValueError(f"bar_position must be finite, within 500 m, got {value}")
        return value


class OutputConfig(StrictModel):
    """What a run writes besides metrics.json, log.npz and run.log."""

    plots: bool = Field(True, description="write the PNG plots")
    render: bool = Field(False, description="write run.mp4 (needs off-screen OpenGL: libosmesa6 or EGL)")
    render_fps: int = Field(30, ge=1, le=120, description="frames per second of run.mp4")


class SensorNoise(StrictModel):
    """Standard deviations of zero-mean Gaussian noise on the measured state (``sim.randomization``)."""

    base_position: float = Field(0.0, ge=0.0, le=0.1, description="m")
    base_orientation: float = Field(0.0, ge=0.0, le=0.5, description="rad, per axis of a rotation vector")
    base_linear_velocity: float = Field(0.0, ge=0.0, le=2.0, description="m/s, base frame")
    base_angular_velocity: float = Field(0.0, ge=0.0, le=5.0, description="rad/s, base frame")
    joint_position: float = Field(0.0, ge=0.0, le=0.2, description="rad")
    joint_velocity: float = Field(0.0, ge=0.0, le=10.0, description="rad/s")

    @property
    def is_zero(self) -> bool:
        return not any(getattr(self, name) for name in type(self).model_fields)


Vector3 = tuple[float, float, float]


def _bounded(name: str, value: Vector3, bound: float) -> Vector3:
    if not all(math.isfinite(item) and abs(item) <= bound for item in value):
        raise ValueError(f"{name} must be 3 finite numbers within +-{bound:g}, got {list(value)}")
    return value


class ImuSpec(StrictModel):
    """The IMU on the trunk (``sim.sensors``): noise (standard deviation per sample, Gaussian) and
    constant bias of the gyro and the accelerometer, and of the orientation its attitude filter outputs (a
    body-frame rotation vector), sampled at ``rate_hz`` and held in between.

    Defaults: the Mini Cheetah's VectorNav IMU as MIT's own simulator models it (``Cheetah-Software``,
    ``config/simulator-defaults.yaml``: ``vectornav_imu_gyro_noise 0.005``, ``..._accelerometer_noise 0.005``,
    ``..._quat_noise 0.003``, drawn there uniformly in +-value; here Gaussian with that value as standard
    deviation, sqrt(3) x MIT's). No bias by default (MIT's simulator has none); ``rate_hz`` 500, the control
    rate (the robot reads its VectorNav at 200 Hz: ``robot/src/rt/rt_vectornav.cpp``, 800 Hz / 4);
    ``average``: the VectorNav filters its 800 Hz samples over a window (its ``ImuFilteringConfiguration``
    register, which ``rt_vectornav.cpp`` reads)."""

    rate_hz: float = Field(500.0, gt=0.0, le=10000.0, description="Hz, IMU samples (held between samples)")
    gyro_noise: float = Field(0.005, ge=0.0, le=1.0, description="rad/s, standard deviation per sample")
    gyro_bias: Vector3 = Field((0.0, 0.0, 0.0), description="rad/s, constant (base frame)")
    accelerometer_noise: float = Field(0.005, ge=0.0, le=10.0, description="m/s^2, standard deviation")
    accelerometer_bias: Vector3 = Field((0.0, 0.0, 0.0), description="m/s^2, constant (base frame)")
    orientation_noise: float = Field(0.003, ge=0.0, le=0.5, description="rad per axis, standard deviation")
    orientation_bias: Vector3 = Field((0.0, 0.0, 0.0), description="rad, constant body-frame rotation vector")
    average: bool = Field(
        True,
        description="gyro and accelerometer report their mean over the sample period (an anti-aliasing IMU, "
        "as the VectorNav's averaging window); false: the instantaneous value at the sample",
    )

    @field_validator("gyro_bias")
    @classmethod
    def _gyro_bias(cls, value: Vector3) -> Vector3:
        return _bounded("gyro_bias", value, 1.0)

    @field_validator("accelerometer_bias")
    @classmethod
    def _accelerometer_bias(cls, value: Vector3) -> Vector3:
        return _bounded("accelerometer_bias", value, 5.0)

    @field_validator("orientation_bias")
    @classmethod
    def _orientation_bias(cls, value: Vector3) -> Vector3:
        return _bounded("orientation_bias", value, 0.5)


class EncoderSpec(StrictModel):
    """The joint sensors (``sim.sensors``): Gaussian noise, then quantisation to a resolution.

    Default resolutions: the Mini Cheetah's motor controllers report joint angle, rate and torque over CAN as
    16-, 12- and 12-bit integers over +-12.5 rad, +-65 rad/s and +-18 Nm (``P_MIN``/``V_MIN``/``T_MIN`` and
    ``pack_reply`` of Ben Katz's motor-controller firmware and the SPIne board, which MIT's Mini Cheetah
    uses): 25/65535 rad, 130/4095 rad/s, 36/4095 Nm. No noise beyond that by default (not published)."""

    position_noise: float = Field(0.0, ge=0.0, le=0.1, description="rad, standard deviation")
    velocity_noise: float = Field(0.0, ge=0.0, le=5.0, description="rad/s, standard deviation")
    torque_noise: float = Field(0.0, ge=0.0, le=5.0, description="Nm, standard deviation")
    position_resolution: float = Field(25.0 / 65535.0, ge=0.0, le=0.1, description="rad (0: none)")
    velocity_resolution: float = Field(130.0 / 4095.0, ge=0.0, le=1.0, description="rad/s (0: none)")
    torque_resolution: float = Field(36.0 / 4095.0, ge=0.0, le=1.0, description="Nm (0: none)")


class SensorsConfig(StrictModel):
    """The robot's sensors in the plant (``sim.sensors``), read when ``estimator`` is not ``ground_truth``."""

    imu: ImuSpec = ImuSpec()
    encoders: EncoderSpec = EncoderSpec()


class HeightMapConfig(StrictModel):
    """The plant's height-map sensor (``sim.height_map``): vertical ray casts on a grid around the robot in
    its heading frame, as a depth camera's elevation map would give, with Gaussian noise and a limited range.
    Off by default; its maps go into the run's log (``terrain`` says whether the controller gets them)."""

    enabled: bool = Field(False, description="measure height maps (off: no sensor, the robot runs blind)")
    rate_hz: float = Field(
        20.0, gt=0.0, le=1000.0, description="Hz, maps per second (at most the control rate)"
    )
    length: float = Field(1.2, gt=0.0, le=10.0, description="m, the grid's extent along the heading")
    width: float = Field(0.8, gt=0.0, le=10.0, description="m, the grid's extent across the heading")
    resolution: float = Field(0.04, ge=0.005, le=1.0, description="m between cell centres")
    forward_offset: float = Field(
        0.0, ge=-5.0, le=5.0, description="m, the grid's centre ahead of the base along the heading"
    )
    noise: float = Field(0.005, ge=0.0, le=0.5, description="m, standard deviation of each measured height")
    range: float = Field(
        1.0,
        gt=0.0,
        le=20.0,
        description="m, farthest surface point from the base the sensor sees (else invalid)",
    )

    @model_validator(mode="after")
    def _cells(self) -> HeightMapConfig:
        columns, rows = round(self.length / self.resolution), round(self.width / self.resolution)
        if min(columns, rows) < 2 or columns * rows > 40_000:
            raise ValueError(
                f"height_map: {self.length} m x {self.width} m at {self.resolution} m gives "
                f"{columns} x {rows} cells; give at least 2 x 2 and at most 40000"
            )
        return self


class TerrainMapSettings(StrictModel):
    """How the reference plans on the height map (``terrain: height_map``; ``reference.terrain_map``): the
    footholds on flat spots of the map, the swing apexes above the terrain between lift-off and touchdown,
    the base's height and pitch from the terrain under the hips. Lengths are the reference robot's (a run
    scales them to its robot)."""

    edge_margin: float = Field(
        0.04,
        gt=0.0,
        le=0.5,
        description="m; a flat spot is a cell whose neighbours this far around (at least one cell) lie "
        "within flat_tolerance of each other",
    )
    flat_tolerance: float = Field(
        0.03,
        gt=0.0,
        le=0.5,
        description="m; the spread of heights a flat spot allows (above the map's noise)",
    )
    foothold_search: float = Field(
        0.15,
        ge=0.0,
        le=0.5,
        description="m; how far a foothold off a flat spot may move to the nearest one (a 10 cm gap with "
        "the edge margin on both sides needs 0.13)",
    )
    swing_clearance: float = Field(
        0.03,
        ge=0.0,
        le=0.2,
        description="m; how far a swing foot passes above terrain higher than its lift-off or touchdown "
        "ground (a riser), at every point of the swing",
    )
    base_window: float = Field(
        0.3,
        gt=0.0,
        le=2.0,
        description="m; the square over which the terrain under each hip is averaged for the base's height "
        "and pitch",
    )
    cone: Literal["plane", "map"] = Field(
        "plane",
        description="the ground normal the plan's (26) and the VWBC's (34f) friction pyramids are taken "
        "about: plane (the blind ground plane through the feet, tilted by steps between them) | map (the "
        "map's normal under the flat spots the feet stand on: world z on flat treads)",
    )
    foothold_hysteresis: float = Field(
        0.04,
        ge=0.0,
        le=0.5,
        description="m; over a hole in the map (a gap), a swing keeps the flat spot its foothold moved to "
        "while that is at most this much farther from each update's Raibert foothold than the nearest one "
        "(0: the nearest at every update, which flips across a gap as the foothold moves by a centimetre, "
        "and the plan lands the foot between)",
    )
    registration: Literal["feet", "motion"] = Field(
        "feet",
        description="how the map is held in the state estimate's frame, which moves when the estimator "
        "re-measures its stance feet at z = 0: feet (the lowest standing foot on a flat spot is on the "
        "terrain) | motion (the frame's move since the map was placed: the estimated height's change minus "
        "the integrated estimated vertical velocity; no foot needed, as in a bound's flights)",
    )


PlantScales = float | list[float]
"""One factor for every joint, or one per actuated joint (robot joint order)."""


FaultKind = Literal[
    "imu_dropout", "encoder_freeze", "nan_sample", "out_of_range", "mpc_kill", "mpc_stall", "mpc_pause"
]
"""What a fault the lab injects does (``FaultConfig``)."""

SENSOR_FAULTS = ("imu_dropout", "encoder_freeze", "nan_sample", "out_of_range")
"""Faults of the robot's sensors (they need ``estimator: kinematic_kf``: the controller reads sensors)."""
MPC_FAULTS = ("mpc_kill", "mpc_stall")
"""Faults of the MPC process (they need ``simulation.realtime``: the MPC in its own process)."""
INLINE_MPC_FAULTS = ("mpc_pause",)
"""Faults of the MPC in simulated time (they need an MPC run that is not ``simulation.realtime``)."""

FaultSensor = Literal["orientation", "gyro", "accelerometer", "joint_position", "joint_velocity"]
"""A sensor field a bad sample can hit."""


class FaultConfig(StrictModel):
    """A fault the lab injects into a run (``cafe_mpc_lab.sim.faults``; docs/faults.md).

    ``imu_dropout``: no new IMU sample from ``start`` for ``duration`` s (the driver repeats the last one,
    with its old time stamp). ``encoder_freeze``: the same for one joint's encoder (``joint``).
    ``nan_sample`` / ``out_of_range``: one sample of ``sensor`` (for a joint sensor, of ``joint``, or of every
    joint when null) is NaN / ``value`` every ``period`` s from ``start`` (for ``duration`` s, null: to the
    end). ``mpc_kill``: the MPC process is killed (SIGKILL) at ``start``. ``mpc_stall``: it is stopped
    (SIGSTOP) at ``start`` and continued (SIGCONT) ``duration`` s later. ``mpc_pause``: the MPC in
    simulated time sends no plan from ``start`` for ``duration`` s and then solves cold
    (``InlineMpcLoop.withhold_plans``: a stall or restart, deterministic with a fixed latency)."""

    kind: FaultKind = Field(
        description="imu_dropout | encoder_freeze | nan_sample | out_of_range (sensors) | mpc_kill | "
        "mpc_stall (the MPC process, simulation.realtime) | mpc_pause (the MPC in simulated time)"
    )
    start: float = Field(0.0, ge=0.0, le=3600.0, description="s, when the fault begins")
    duration: float | None = Field(
        None,
        gt=0.0,
        le=3600.0,
        description="s the fault lasts (imu_dropout, encoder_freeze, mpc_stall, mpc_pause; bad samples: "
        "null, to the end)",
    )
    joint: int | str | None = Field(
        None, description="encoder_freeze, bad joint samples: the joint (index or name; null: every joint)"
    )
    sensor: FaultSensor | None = Field(
        None,
        description="nan_sample, out_of_range: orientation | gyro | accelerometer | joint_position | "
        "joint_velocity",
    )
    period: float | None = Field(
        None, gt=0.0, le=3600.0, description="nan_sample, out_of_range: s between two bad samples"
    )
    value: float | None = Field(
        None, description="out_of_range: the value the bad sample reads (default 1e3)"
    )

    @model_validator(mode="after")
    def _kind_fields(self) -> FaultConfig:
        needs: dict[str, tuple[str, ...]] = {
            "imu_dropout": ("duration",),
            "encoder_freeze": ("duration", "joint"),
            "nan_sample": ("sensor", "period"),
            "out_of_range": ("sensor", "period"),
            "mpc_kill": (),
            "mpc_stall": ("duration",),
            "mpc_pause": ("duration",),
        }
        allowed: dict[str, tuple[str, ...]] = {
            "imu_dropout": ("duration",),
            "encoder_freeze": ("duration", "joint"),
            "nan_sample": ("sensor", "period", "duration", "joint"),
            "out_of_range": ("sensor", "period", "duration", "joint", "value"),
            "mpc_kill": (),
            "mpc_stall": ("duration",),
            "mpc_pause": ("duration",),
        }
        for key in needs[self.kind]:
            if getattr(self, key) is None:
                raise ValueError(f"a fault of kind {self.kind} needs '{key}'")
        for key in ("duration", "joint", "sensor", "period", "value"):
            if getattr(self, key) is not None and key not in allowed[self.kind]:
                raise ValueError(f"'{key}' does not apply to a fault of kind {self.kind}")
        if self.joint is not None and self.sensor in ("orientation", "gyro", "accelerometer"):
            raise ValueError(f"'joint' does not apply to a bad {self.sensor} sample")
        if isinstance(self.joint, int) and self.joint < 0:
            raise ValueError(f"joint must be an index >= 0 or a joint name, got {self.joint}")
        if self.value is not None and not math.isfinite(self.value):
            raise ValueError(f"value must be finite (nan_sample writes NaN), got {self.value}")
        return self

    @property
    def end(self) -> float:
        """When the fault ends (inf: at the end of the run; a kill is a moment)."""
        if self.kind == "mpc_kill":
            return self.start
        return self.start + self.duration if self.duration is not None else math.inf


class PlantConfig(StrictModel):
    """The simulated robot's deviations from its robot table, and what its sensors do (domain randomisation,
    paper Sec. VII-C3). Only the MuJoCo plant and the controller's measurements change; the controller's model
    never does (``sim.randomization``). The defaults change nothing."""

    kind: Literal["mujoco", "gym-quadruped"] = Field(
        "mujoco",
        description="mujoco: our MuJoCo plant of the robot file; gym-quadruped: the robot inside "
        "gym-quadruped's QuadrupedEnv with its own model file and contact settings (sim.gym_plant; "
        "pip install 'cafe-mpc[gym]')",
    )
    gym_scene: Literal["flat", "perlin", "random_boxes", "random_pyramids", "stairs", "ramp", "slippery"] = (
        Field(
            "flat", description="gym-quadruped's scene (plant.kind: gym-quadruped; the controller plans flat)"
        )
    )
    floor_friction: float | None = Field(
        None, gt=0.0, le=2.0, description="floor and foot sliding friction (null: the robot table's)"
    )
    mass_scale: float = Field(
        1.0, ge=0.5, le=1.5, description="every body's mass and inertia (whole robot); times those below"
    )
    body_mass_scale: float = Field(1.0, ge=0.5, le=1.5, description="trunk mass and inertia factor")
    link_mass_scales: PlantScales = Field(1.0, description="leg-link mass and inertia factors (0.5-1.5)")
    motor_strength_scales: PlantScales = Field(1.0, description="torque per commanded torque (0.5-1.5)")
    sensor_noise: SensorNoise = SensorNoise()
    measurement_delay_max: float = Field(
        0.0, ge=0.0, le=0.05, description="s; latency jitter: each tick sees a state up to this old"
    )
    seed: int = Field(0, ge=0, description="random stream of the sensor noise and delays")
    sensors: SensorsConfig = Field(
        default_factory=SensorsConfig,
        description="IMU and joint sensors the controller reads with estimator: kinematic_kf (sim.sensors)",
    )
    height_map: HeightMapConfig = Field(
        default_factory=HeightMapConfig,
        description="height-map sensor: ray casts around the robot at their rate, logged and handed to the "
        "controller with that tick's readings (sim.height_map; terrain: height_map plans on them)",
    )
    faults: list[FaultConfig] = Field(
        default_factory=list,
        description="faults injected into the run: sensor dropouts, frozen encoders, bad samples, the MPC "
        "process killed or stalled (sim.faults; docs/faults.md)",
    )

    @model_validator(mode="after")
    def _height_map_plant(self) -> PlantConfig:
        if self.height_map.enabled and self.kind != "mujoco":
            raise ValueError(
                f"plant.height_map: the height-map sensor needs plant.kind: mujoco, not {self.kind!r}"
            )
        return self

    @field_validator("link_mass_scales", "motor_strength_scales")
    @classmethod
    def _scales_in_range(cls, value: PlantScales) -> PlantScales:
        for item in value if isinstance(value, list) else [value]:
            if not 0.5 <= item <= 1.5:
                raise ValueError(f"factors must be in [0.5, 1.5], got {item}")
        return value

    @property
    def state_noise(self) -> bool:
        """Whether ``sensor_noise`` perturbs the state (only the ground-truth estimator can have it)."""
        return not self.sensor_noise.is_zero


class OnlineCalibrationConfig(StrictModel):
    """The controller's estimate, while it runs, of how much support its motors give per commanded torque
    relative to its model (``estimation.support_ratio``): a payload (the robot heavier than its model) and
    weaker motors look alike in what the robot senses, so one ratio ``r`` = motor strength / mass factor is
    estimated, from the impulse the stance legs' commanded torques give against the momentum the robot
    gains (IMU and leg kinematics), and the low level sends ``tau / r`` (``low_level.motor_strength``). On
    top of the ``calibration`` factors; off by default."""

    enabled: bool = Field(False, description="estimate the support ratio online and scale the commands by it")
    window: float = Field(
        0.2, gt=0.0, le=2.0, description="s of settled stance per estimate (one impulse balance)"
    )
    time_constant: float = Field(
        0.4,
        ge=0.0,
        le=10.0,
        description="s of settled stance over which the estimates are averaged (first-order filter; 0: the "
        "last window's)",
    )
    settle: float = Field(
        0.02, ge=0.0, le=0.2, description="s after a change of the stance set before its ticks count"
    )
    min_windows: int = Field(
        2, ge=1, le=100, description="windows accepted before the estimate is applied (1 until then)"
    )
    min_support: float = Field(
        0.3,
        gt=0.0,
        le=1.0,
        description="a window counts only if its commanded support is at least this share of the weight",
    )
    outlier: float = Field(
        0.05,
        gt=0.0,
        le=1.0,
        description="once applied, a window off the estimate by more than this share is left out (feet "
        "on the ground the stance flags miss: a take-off, a landing) unless outlier_windows in a row are",
    )
    outlier_windows: int = Field(
        3, ge=1, le=100, description="windows off the estimate in a row that are taken as a real change"
    )
    lower: float = Field(0.7, ge=0.3, le=1.0, description="lowest ratio applied")
    upper: float = Field(
        1.0,
        ge=1.0,
        le=3.0,
        description="highest ratio applied (1: a robot lighter or stronger than its model keeps its surplus; "
        "scaling its commands down cost two of 22 randomised running rolls their take-off height, "
        "docs/robustness.md)",
    )


class CalibrationConfig(StrictModel):
    """What the controller knows of its robot beyond the robot file: a weighed payload, measured link
    masses, calibrated motors. Applied once to the controller's model (``robots.calibration``, resolved in
    ``assembly.resolve``): the whole-body Pinocchio model of the plan and the low level, the SRB tail's mass
    and inertia (lumped from it), the reference's weight; and to its motors: the low level commands ``tau /
    strength`` so that a motor delivering ``strength x`` its command gives ``tau``, and the plan and the low
    level keep ``|tau|`` within ``strength x`` the torque limits. The factors mean what ``plant``'s do (a
    payload of ``p`` kg carried like the trunk: ``body_mass_scale = 1 + p / trunk mass``). The plant never
    reads this section; the defaults (1.0) are the robot file's model."""

    mass_scale: float = Field(
        1.0, ge=0.5, le=1.5, description="every body's mass and inertia (whole robot); times those below"
    )
    body_mass_scale: float = Field(
        1.0, ge=0.5, le=1.5, description="trunk mass and inertia factor (a payload carried by the trunk)"
    )
    link_mass_scales: PlantScales = Field(1.0, description="leg-link mass and inertia factors (0.5-1.5)")
    motor_strength_scales: PlantScales = Field(
        1.0, description="torque each motor delivers per commanded torque, as calibrated (0.5-1.5)"
    )

    online: OnlineCalibrationConfig = Field(
        default_factory=OnlineCalibrationConfig,
        description="the support ratio (motor strength / mass factor) estimated while running, applied on "
        "top of these factors (estimation.support_ratio)",
    )

    @field_validator("link_mass_scales", "motor_strength_scales")
    @classmethod
    def _scales_in_range(cls, value: PlantScales) -> PlantScales:
        for item in value if isinstance(value, list) else [value]:
            if not 0.5 <= item <= 1.5:
                raise ValueError(f"factors must be in [0.5, 1.5], got {item}")
        return value


class BalanceConfig(StrictModel):
    """The balance controller of the safe ladder (``low_level.balance``; ``wbc: balance`` standing): all
    feet down where they are, the base level at the standing height above them, the stance's static torques
    plus joint PD, the implied foot forces inside the friction pyramid. Gains are the reference robot's,
    scaled to the run's robot as the PD gains are."""

    kp: float = Field(
        60.0, ge=0.0, le=1000.0, description="Nm/rad, joint stiffness toward the balance posture"
    )
    kd: float = Field(2.0, ge=0.0, le=100.0, description="Nm s/rad, joint damping")
    min_normal_force: float = Field(
        0.05,
        ge=0.0,
        le=0.5,
        description="share of the weight every foot on the ground keeps pressing with (the statics' forces "
        "and the pyramid's lower bound)",
    )
    restance_after: float | None = Field(
        0.15,
        gt=0.0,
        le=10.0,
        description="s after engaging, the stance is picked again once, from the feet where they landed "
        "(their heights within landed_spread) and the attitude then; null: the first stance is held",
    )
    """Engaged in flight or at a bound's touchdown, the first stance puts the feet in the air down where the
    legs were and the base level on the attitude of that instant; the feet land elsewhere and the joint
    angles held then pitch the base (IMU out 500 ms at 3 s in the bound: it fell backwards in the balance
    stance, 0.2 rad nose up; with the stance picked again it stood and bounded on)."""
    landed_spread: float = Field(
        0.02, gt=0.0, le=1.0, description="m; the feet count as landed when their heights differ by less"
    )


class SensorLimits(StrictModel):
    """What the sensing front end accepts of a reading (``core.sensors.SensorGuard``): a value outside these
    limits, non-finite, or a sample older than ``max_sample_age`` is rejected, counted, and the last good one
    held; a sensor out for longer than ``outage_limit`` sends the MPC loop down its safe ladder."""

    gyro_max: float = Field(
        34.9, gt=0.0, le=1000.0, description="rad/s, the gyro's range (VectorNav VN-100: 2000 deg/s)"
    )
    accelerometer_max: float = Field(
        157.0, gt=0.0, le=10000.0, description="m/s^2, the accelerometer's range (VN-100: 16 g)"
    )
    joint_position_margin: float = Field(
        0.3, ge=0.0, le=3.0, description="rad a joint reading may lie beyond the robot's joint limits"
    )
    joint_velocity_factor: float = Field(
        2.0, gt=0.0, le=100.0, description="a joint rate may reach this many times the robot's velocity limit"
    )
    max_sample_age: float = Field(
        0.02, gt=0.0, le=1.0, description="s; a sample whose time stamp is older is late (missing)"
    )
    outage_limit: float = Field(
        0.1,
        gt=0.0,
        le=10.0,
        description="s a sensor may stay out (its last good value held) before the MPC loop holds the "
        "balance stance until it is back",
    )
    estimate_speed_max: float = Field(
        10.0, gt=0.0, le=100.0, description="m/s; a faster base estimate counts as a diverged estimator"
    )
    imu_outage_limit: float | None = Field(
        None,
        gt=0.0,
        le=10.0,
        description="s the IMU may stay out while the plans are followed on the attitude the estimator "
        "integrates without it (kinematic_kf.imu_outage: dynamics); null: outage_limit, as any sensor",
    )
    imu_outage_response: Literal["stop", "balance"] = Field(
        "stop",
        description="once the IMU has been out longer than its limit while the estimator integrates the "
        "attitude without it (kinematic_kf.imu_outage: dynamics): stop: the low level follows the plans "
        "while "
        "the MPC brings the robot to rest on its gait's steps (the commands rest), then the balance stance "
        "(recovery.stop_speed); balance: the balance stance at once",
    )
    """A bound whose IMU went out 500 ms at 2.0 s: the balance stance engaged in flight at 0.85 m/s, held
    joint angles toward a stance fixed in the world with the base 7 cm behind the front feet, did not slow
    it (0.85 m/s 0.35 s later, four feet down, the rear legs at their least force) and it rolled forward
    over the front feet (fell at 2.56 s). Stopped on the plans it slowed to 0.2 m/s in one front stance."""


class RecoveryConfig(StrictModel):
    """What the controller does when plans stop coming or sensors fail (docs/faults.md): the safe ladder
    (follow the last plan while it lasts, then the balance stance, then the damped stance), restarting or
    taking back the MPC process, and the sensing front end's limits."""

    stale_after: float = Field(
        0.1, gt=0.0, le=10.0, description="s without a new plan: the ladder's last_plan step (still followed)"
    )
    take_back_plans: int = Field(
        3,
        ge=1,
        le=100,
        description="fresh plans in a row (each measured after the robot left the plans, each within "
        "stale_after of the one before) before they take the robot back from the balance or damped stance",
    )
    restart_gait: bool = Field(
        True,
        description="after an episode off the plans the gait restarts from the stance the robot stands in: "
        "the MPC plans all feet down while the robot is held, and once it is taken back a stand of "
        "restart_stand and then the gait from its first phase, the commands ramped in from rest (false: the "
        "gait goes on from where its clock is)",
    )
    restart_stand: float | None = Field(
        None,
        ge=0.0,
        le=5.0,
        description="s on all feet after a take-back before the gait restarts (null: the gait's "
        "start_stance)",
    )
    stall_timeout: float | None = Field(
        None,
        gt=0.0,
        le=60.0,
        description="s without a plan from a live MPC process: it counts as stalled (null: 10 MPC periods, "
        "at least 0.5 s)",
    )
    standby: bool = Field(
        True,
        description="keep a second MPC process built and waiting beside the running one (real time): it "
        "takes over at once when that one dies or is restarted, a new standby is built after",
    )
    stall_restart_after: float = Field(
        3.0, gt=0.0, le=600.0, description="s a stalled MPC process is waited for before it is restarted"
    )
    max_restarts_per_minute: int = Field(
        3,
        ge=0,
        le=100,
        description="MPC process restarts allowed within 60 s; one more and the robot stays in the damped "
        "stance and the run fails (0: never restart)",
    )
    resync_after: float = Field(
        0.1,
        gt=0.0,
        le=60.0,
        description="s the MPC process went without looking at the measurements (it was stopped; its own "
        "updates do not count) after which it solves cold again from the newest (a bound stopped for 0.2 s "
        "fell on the stale plans of its warm start with 0.4)",
    )
    stop_speed: float = Field(
        0.2,
        ge=0.0,
        le=10.0,
        description="m/s; the safe ladder's stop step (a sensor the estimate stands in for is out: the MPC "
        "brings the robot to rest on its gait) hands over to the balance stance below this base speed",
    )
    stop_timeout: float = Field(
        0.5, gt=0.0, le=10.0, description="s; the stop step hands over to the balance stance after this long"
    )
    balance_timeout: float = Field(
        10.0, gt=0.0, le=3600.0, description="s the balance stance holds without a plan before the damped one"
    )
    balance: BalanceConfig = Field(default_factory=BalanceConfig, description="the balance controller")
    sensors: SensorLimits = Field(
        default_factory=SensorLimits, description="what the sensing front end accepts (core.sensors)"
    )


class TemplateSettings(StrictModel):
    """The template-MPC baseline (``planner: template``; ``planners.template``): the SRB plan's horizon and
    knot spacing, the swing legs' joint PD gains (the reference robot's, scaled to the run's robot), and the
    switches of the plan's initial state, reference height, delay compensation and leg torque bounds
    (docs/settings.md has what each one changed). Period, latency and iterations per update are ``mpc``'s;
    the weights and GRF barriers are the template problem's own (``planners.template.problem``)."""

    horizon: float = Field(0.5, gt=0.0, le=2.0, description="s planned with the SRB model")
    dt: float = Field(0.01, ge=0.001, le=0.1, description="s between SRB knots (whole milliseconds)")
    swing_kp: float = Field(40.0, ge=0.0, le=500.0, description="Nm/rad, swing-leg joint PD")
    swing_kd: float = Field(1.0, ge=0.0, le=50.0, description="Nm s/rad, swing-leg joint PD")
    leg_torque_limits: bool = Field(True, description="bound the stance legs' J' f by the torque limits")
    predict_latency: bool = Field(
        True,
        description="plan from the SRB state predicted at the time the plan takes effect (the fixed latency, "
        "or the recent updates' median wall time), under the plan in effect until then",
    )
    centroidal_state: bool = Field(
        True,
        description="start each update from the measured centre of mass, its velocity and the centroidal "
        "angular momentum (false: the base state moved to the standing pose's centre of mass)",
    )
    vertical_reference: bool = Field(
        True, description="add the height and vertical speed the gait's GRF references imply to the reference"
    )

    @model_validator(mode="after")
    def _knots(self) -> TemplateSettings:
        if abs(self.dt * 1000.0 - round(self.dt * 1000.0)) > 1e-6:
            raise ValueError(f"template.dt must be a whole number of milliseconds, got {self.dt}")
        if self.horizon < 2 * self.dt - 1e-12:
            raise ValueError(f"template.horizon must cover at least two knots of {self.dt} s")
        return self

    @property
    def knots(self) -> int:
        """Running knots per problem."""
        return max(2, round(self.horizon / self.dt))


class RunConfig(StrictModel):
    """Everything a run needs; written back as ``config.yaml`` beside its results."""

    name: str = Field("stand", description="the run's label (run folder, summary line); a preset's own name")
    robot: str = Field(
        "mini_cheetah",
        description="a robot of robots/data (by name) or the path of a robot file (docs/robots.md)",
    )
    scaling: Literal["robot", "none"] = Field(
        "robot",
        description="robot: the tuned settings below (gait timings, swing height, Raibert gain, cost "
        "weights, PD gains, fall height, ...) are the Mini Cheetah's, scaled to the run's robot by its "
        "leg length and mass (robots.scaling; docs/robots.md); none: used as written. The Mini Cheetah's "
        "factors are 1",
    )
    wbc: Literal["pd", "balance", "riccati", "vwbc"] = Field(
        "pd",
        description="pd: stand in place (joint PD); balance: stand in place (the safe ladder's balance "
        "controller); riccati / vwbc: CAFE-MPC with that low-level controller",
    )
    pd: PDSettings = Field(
        default_factory=PDSettings, description="gains of the standing controller (wbc: pd)"
    )
    vwbc: VWBCSettings = Field(default_factory=VWBCSettings, description="the VWBC QP's solver (wbc: vwbc)")
    gait: GaitConfig | None = Field(None, description="gait and commands (MPC controllers); null for pd")
    reference: ReferenceConfig | None = Field(
        None, description="a composed reference (stand, stored trajectory, ...) instead of a gait; null: gait"
    )
    torque_limits: Literal["plan", "motor"] = Field(
        "plan",
        description="limits the MPC plan and the low-level controller respect: plan (the robot table's "
        "joints.torque_limits, 17 Nm for the Mini Cheetah) or motor (the plant's saturation, 17/17/26 Nm)",
    )
    mpc: MpcConfig = MpcConfig()
    planner: Literal["cafe", "template"] = Field(
        "cafe",
        description="cafe: CAFE-MPC (whole body + SRB tail) over wbc; template: the SRB-only baseline "
        "(paper Sec. VII-C) with its own stance/swing low level (wbc is not used)",
    )
    template: TemplateSettings = TemplateSettings()
    estimator: Literal["ground_truth", "kinematic_kf"] = Field(
        "kinematic_kf",
        description="what the controller measures: ground_truth (the plant's state, plus plant.sensor_noise) "
        "or kinematic_kf (the robot's sensors, plant.sensors, through the IMU + leg-kinematics Kalman filter "
        "of the MIT Mini Cheetah; estimation.estimator)",
    )
    kinematic_kf: KinematicKFSettings = Field(
        default_factory=KinematicKFSettings,
        description="the Kalman filter's tuning (estimator: kinematic_kf)",
    )
    costs: CostsConfig = Field(default_factory=CostsConfig)
    simulation: SimulationConfig = Field(
        default_factory=SimulationConfig, description="duration, rates and fall detection of the closed loop"
    )
    pushes: list[PushConfig] = Field(default_factory=list, description="pushes on the base during the run")
    plant: PlantConfig = Field(
        default_factory=PlantConfig, description="simulated plant and sensors (the controller never sees it)"
    )
    calibration: CalibrationConfig = Field(
        default_factory=CalibrationConfig,
        description="the controller's model of its robot beyond the robot file: payload, link masses, motor "
        "strengths (docs/robustness.md)",
    )
    scene: SceneConfig = Field(
        default_factory=SceneConfig, description="terrain in the plant's scene (the controller: terrain)"
    )
    terrain: Literal["flat", "blind", "height_map"] = Field(
        "flat",
        description="the ground the controller believes in. flat: z = 0 (the paper's); blind: the plane "
        "through the feet's latest contact points (core.ground), which the reference's base height, pitch "
        "and footholds and the contact detector follow; height_map: as blind, and the reference plans on the "
        "maps of the plant's height-map sensor (plant.height_map; terrain_map): footholds on flat spots, "
        "swings above the terrain, base height and pitch from it. docs/terrain.md",
    )
    terrain_map: TerrainMapSettings = Field(
        default_factory=TerrainMapSettings,
        description="how the reference plans on the height map (terrain: height_map; reference.terrain_map)",
    )
    output: OutputConfig = Field(default_factory=OutputConfig, description="plots and video")
    recovery: RecoveryConfig = Field(
        default_factory=RecoveryConfig,
        description="the safe ladder, MPC process restarts and sensor limits (docs/faults.md)",
    )

    @model_validator(mode="after")
    def _controller_matches_gait(self) -> RunConfig:
        standing = self.wbc in STANDING_CONTROLLERS
        if standing and self.gait is not None:
            raise ValueError(
                f"wbc: {self.wbc!r} stands in place and cannot follow gait {self.gait.name!r}; use "
                "wbc=riccati or wbc=vwbc (or gait=null to stand)"
            )
        if standing and self.reference is not None:
            raise ValueError(
                f"wbc: {self.wbc!r} stands in place and cannot follow a reference; use wbc=vwbc or riccati"
            )
        if self.gait is not None and self.reference is not None:
            raise ValueError("give either a gait section or a reference section, not both (set gait=null)")
        if not standing and self.gait is None and self.reference is None:
            raise ValueError(
                f"wbc: {self.wbc!r} runs CAFE-MPC and needs a gait section (e.g. --set gait.name=trot) "
                "or a reference section"
            )
        if self.planner == "template" and self.gait is None and self.reference is None:
            raise ValueError(
                "planner: 'template' needs a gait section (e.g. --set gait.name=trot) or a reference section"
            )
        if self.mpc.period < 1.0 / self.simulation.control_rate_hz - 1e-12:
            raise ValueError(
                f"mpc.period: {self.mpc.period} s is shorter than the control period "
                f"1/{self.simulation.control_rate_hz} s"
            )
        if self.plant.sensors.imu.rate_hz > self.simulation.control_rate_hz * (1.0 + 1e-9):
            raise ValueError(
                f"plant.sensors.imu.rate_hz: {self.plant.sensors.imu.rate_hz} Hz is above the control rate "
                f"simulation.control_rate_hz {self.simulation.control_rate_hz} Hz (the controller reads the "
                "sensors once per tick)"
            )
        height_map = self.plant.height_map
        if self.terrain == "height_map" and not height_map.enabled:
            raise ValueError(
                "terrain: 'height_map' needs the plant's height-map sensor (plant.height_map.enabled: true); "
                "a robot without it runs blind (terrain: blind)"
            )
        if self.simulation.realtime and self.mpc.compute_scale != 1.0:
            raise ValueError(
                "mpc.compute_scale emulates a slower computer in simulated time; a real-time run "
                "(simulation.realtime: true) runs on this one: leave compute_scale at 1"
            )
        if self.terrain == "height_map" and self.simulation.realtime:
            raise ValueError(
                "terrain: 'height_map' runs with the MPC in the simulation's loop only (simulation.realtime: "
                "false); the MPC process does not receive the maps"
            )
        if height_map.enabled and height_map.rate_hz > self.simulation.control_rate_hz * (1.0 + 1e-9):
            raise ValueError(
                f"plant.height_map.rate_hz: {height_map.rate_hz} Hz is above the control rate "
                f"simulation.control_rate_hz {self.simulation.control_rate_hz} Hz (maps are taken at control "
                "ticks)"
            )
        if self.kinematic_kf.stance_height == "touchdown" and self.terrain == "flat":
            raise ValueError(
                f"kinematic_kf.stance_height: {self.kinematic_kf.stance_height!r} holds stance feet off flat "
                "ground; with terrain: flat every stance foot is on z = 0 (use terrain: blind or height_map)"
            )
        if self.estimator != "ground_truth" and self.plant.state_noise:
            raise ValueError(
                f"plant.sensor_noise perturbs the true state handed to the controller, which estimator: "
                f"{self.estimator!r} does not see; set the sensors' noise in plant.sensors (or use "
                "estimator: ground_truth)"
            )
        for index, fault in enumerate(self.plant.faults):
            if fault.kind in SENSOR_FAULTS and self.estimator == "ground_truth":
                raise ValueError(
                    f"plant.faults.{index}: a fault of kind {fault.kind} hits the robot's sensors, which "
                    "estimator: ground_truth does not read (use estimator: kinematic_kf)"
                )
            if fault.kind in MPC_FAULTS and not (self.simulation.realtime and not standing):
                raise ValueError(
                    f"plant.faults.{index}: a fault of kind {fault.kind} hits the MPC process, which only a "
                    "real-time MPC run has (simulation.realtime: true, wbc: vwbc or riccati)"
                )
            if fault.kind in INLINE_MPC_FAULTS and (self.simulation.realtime or standing):
                raise ValueError(
                    f"plant.faults.{index}: a fault of kind {fault.kind} withholds the plans of the MPC in "
                    "simulated time, which only an MPC run that is not real time has (simulation.realtime: "
                    "false, wbc: vwbc or riccati; in real time: mpc_stall)"
                )
        return self


def available_presets() -> list[str]:
    return sorted(path.stem for path in PRESET_DIR.glob("*.yaml"))


def _presets() -> dict[str, Callable[[], dict[str, Any]]]:
    """The presets' raw data by name (each file read when asked for)."""
    return {name: functools.partial(read_yaml, PRESET_DIR / f"{name}.yaml") for name in available_presets()}


def load_config(preset_or_path: str, overrides: Sequence[str] | None = None) -> RunConfig:
    """Load a preset name or a YAML file, apply ``key=value`` overrides, validate.

    A file may start from a preset or another file with ``base: trot`` and give only what it changes (deep
    merge: sections merge key by key, lists such as ``gait.commands`` are replaced whole); a file without a
    ``name`` of its own is named after the file (``my_trot.yaml`` -> ``my_trot``)."""
    return load_model(
        RunConfig, preset_or_path, overrides or (), _presets(), inherit=True, name_from_file=True
    )
