"""A run config resolved once against the robot it drives: what every builder of the run reads.

``assembly.resolve(config, robot)`` makes the ``ResolvedRun`` before anything is built: the robot's scale
(``robots.scaling``: the config's tuned values are the reference robot's), the model schedule with its
horizons scaled, the torque limits the plan and the low level respect, the contact models of the plan and
the VWBC (friction, Baumgarte rate, cone tolerance), the contact detector's thresholds, the ground the
controller assumes (``terrain``), the gaits with their timings and lengths scaled, what the run commands
over time, and the control period. The planner slices, the low-level registry, the reference, the estimator
and the lab's plant and metrics read these values; none derives them from the config again.

Each component's own settings are the schema's class for it (``config.MpcSettings``, ``PDSettings``,
``VWBCSettings``, ``TemplateSettings``, ``KinematicKFSettings``), reached through ``config``; what a run
derives for several components lives here.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cafe_mpc.config import (
    BAUMGARTE_ALPHA,
    CONE_TOLERANCE,
    DEFAULT_FRICTION,
    ContactDetectionSettings,
    GaitConfig,
    RunConfig,
    TerrainMapSettings,
)
from cafe_mpc.ocp.contact_schedule import GaitCycle
from cafe_mpc.planners.cafe.problem import ModelSchedule
from cafe_mpc.reference.locomotion import CommandProfile
from cafe_mpc.robots.robot import Robot
from cafe_mpc.robots.scaling import RobotScale


@dataclass(frozen=True)
class ContactModel:
    """The contacts a controller assumes: the friction coefficient of its pyramids (the plan's (26), the
    VWBC's (34f), the template's GRF constraints, the post-hoc score), the first-order Baumgarte rate of the
    contact constraints (1/s: the whole-body knots' (20), the VWBC's (34c)) and the force (N) a contact force
    may lie outside the pyramid before it counts as a violation. The defaults are the reference robot's."""

    friction: float = DEFAULT_FRICTION
    baumgarte_alpha: float = BAUMGARTE_ALPHA
    cone_tolerance: float = CONE_TOLERANCE

    def __post_init__(self) -> None:
        if not self.friction > 0:
            raise ValueError(f"friction coefficient must be positive, got {self.friction}")
        if not (self.baumgarte_alpha >= 0 and self.cone_tolerance >= 0):
            raise ValueError(f"Baumgarte rate and cone tolerance must be non-negative, got {self}")


@dataclass(frozen=True)
class ResolvedGait:
    """A gait section carried to the robot: the gait cycle with its phase durations scaled, and the
    locomotion reference's swing height, Raibert gain and foothold box (Sec. VI-A), path gain (rad/m) and
    touchdown-event threshold (s, None: off); ``section`` keeps what is used as written (commands, start
    stance, command ramp, path heading limit)."""

    section: GaitConfig
    cycle: GaitCycle
    swing_height: float
    raibert_gain: float
    swing_lift: float
    foothold_box: tuple[float, float]
    path_gain: float
    touchdown_events: float | None
    blind_ground_below: float | None = None
    """m (length-scaled), ``gait.blind_ground_below``; None: off."""
    blind_ground_follow: float | None = None
    """m (length-scaled), ``gait.blind_ground_follow``; None: off."""
    touchdown_clearance: float | None = None
    """m (length-scaled), a swing's least apex above its touchdown (``gait.blind_touchdown_clearance``
    with ``terrain: blind``); None: ``swing_height`` above the higher end."""


@dataclass(frozen=True)
class ResolvedRun:
    """A run config resolved against its robot (module docstring).

    ``config``, ``robot``: the run config and the robot it drives, as its robot file describes it (what the
    lab's plant is built from). ``controller_robot``: the robot as the controller models it, ``robot`` with
    the config's ``calibration`` (``robots.calibration``: payload and link masses in its Pinocchio model,
    torque limits times the motors' strengths; ``robot`` itself by default): every planner, low level,
    reference and estimator is built from it. ``motor_strength``: the calibrated torque each motor delivers
    per commanded torque (read-only, ones by default); the low level sends ``tau / motor_strength``
    (``low_level.motor_strength``). ``scale``: the robot's scale (the robot file's; the identity with
    ``scaling: none``), for the component settings tuned on the reference robot. ``schedule``: the
    ``mpc`` section's model schedule (Tw, Ts, dt_w, dt_s), its horizons scaled. ``torque_limits``: what the
    plan and the low level respect (``torque_limits``: the robot table's or the motors', times
    ``motor_strength``; read-only; the CAFE plan takes ``mpc.plan_torque_fraction`` of them,
    ``planners.cafe.setup.plan_constraints``).
    ``contact``: the contact model of the plan (``mpc.friction``), the whole-body knots and the post-hoc
    cone score; ``vwbc_contact``: the VWBC's (``vwbc.friction`` if set, else the plan's times
    ``config.VWBC_FRICTION_HEADROOM``).
    ``contact_detection``: the contact detector's thresholds (``vwbc.contact_detection``, heights and times
    scaled to the robot), read by the VWBC's detector and the reference's touchdown events.
    ``ground_plane``: the controller's ground is the plane through the feet's latest contact points
    (``terrain`` blind or height_map, docs/terrain.md), read by the reference (base and footholds on it), the
    contact detector (heights above it), the VWBC (its cone about the plane's normal) and the estimator
    (stance feet not dropped for standing above z = 0); False (``terrain: flat``): flat ground at
    ``contact_detection.ground_height``. ``terrain_map``: how the reference plans on the height maps
    (``terrain: height_map``; the config's ``terrain_map``, lengths scaled to the robot), else None.
    ``touchdown_on_reference``: the touchdown constraint (25) puts a landing foot at the reference's
    foothold height, not on the floor (``mpc.touchdown_surface``; null: with the height map, whose
    footholds are where the treads are). ``touchdown_below_floor``: with it, at the lower of that height
    and the floor (``mpc.touchdown_surface: lower``).
    ``gait``: the
    ``gait`` section resolved (None without one); ``segment_gaits``: each ``reference`` segment's gait
    resolved (None for the others). ``command_profile``: what the run commands over time (tracking metrics
    and plots). ``control_period``: seconds between two low-level ticks."""

    config: RunConfig
    robot: Robot
    controller_robot: Robot
    motor_strength: np.ndarray
    scale: RobotScale
    schedule: ModelSchedule
    torque_limits: np.ndarray
    contact: ContactModel
    vwbc_contact: ContactModel
    contact_detection: ContactDetectionSettings
    ground_plane: bool
    terrain_map: TerrainMapSettings | None
    touchdown_on_reference: bool
    touchdown_below_floor: bool
    gait: ResolvedGait | None
    segment_gaits: tuple[ResolvedGait | None, ...]
    command_profile: CommandProfile
    control_period: float
