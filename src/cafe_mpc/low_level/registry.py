"""The low-level controllers a run config's ``wbc`` key names, and the low level of a run.

``LOW_LEVELS``: ``wbc`` -> ``LowLevelEntry`` (how a run config builds it, the plan type it follows): ``pd``
(joint PD standing) and ``balance`` (the safe ladder's balance controller, ``low_level.balance``) follow no
plan and run alone, without a planner; ``riccati`` (Eq. (33)) and ``vwbc`` (Eq. (34)) follow CAFE-MPC's
``Plan``. ``build_balance(run)`` and ``build_damped(run)`` are what every MPC loop's safe ladder holds the
robot with.
``build_low_level(run, planner)``: the planner's own low level when its slice has one (the template's), else
the ``wbc`` entry, which must follow the planner's plan type. Every low level built here sends its torques
for the run's calibrated motors (``low_level.motor_strength``: ``tau / run.motor_strength``; itself when the
strengths are 1).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from cafe_mpc.config import ConfigError
from cafe_mpc.core.controller import LowLevelController
from cafe_mpc.estimation.support_ratio import SupportRatioEstimator
from cafe_mpc.low_level.balance import BalanceController
from cafe_mpc.low_level.motor_strength import (
    MotorStrengthCompensation,
    OnlineSupportCompensation,
    with_motor_strength,
)
from cafe_mpc.low_level.pd import PDController
from cafe_mpc.low_level.riccati import RiccatiController
from cafe_mpc.low_level.vwbc import VWBCController
from cafe_mpc.planners.base import PlannerSlice, Registry
from cafe_mpc.planners.cafe.plan import Plan
from cafe_mpc.planners.resolved import ResolvedRun


@dataclass(frozen=True)
class LowLevelEntry:
    """``build(run)``: the controller of a resolved run (``planners.resolved.ResolvedRun``); ``plan_type``:
    the plans it follows (None: it needs none and is a closed-loop controller by itself, with no planner)."""

    build: Callable[[ResolvedRun], LowLevelController]
    plan_type: type | None

    @property
    def needs_plan(self) -> bool:
        return self.plan_type is not None


def build_pd(run: ResolvedRun) -> LowLevelController:
    """Joint PD standing: the ``pd`` section, its gains carried to the robot."""
    return with_motor_strength(
        PDController(run.controller_robot, run.config.pd, run.scale), run.motor_strength
    )


def build_balance(run: ResolvedRun) -> LowLevelController:
    """The balance controller (``recovery.balance``): its gains scaled to the robot as the PD gains are, the
    run's torque limits and the friction the MPC assumes."""
    config, scale = run.config, run.scale
    settings = config.recovery.balance
    gains = {"kp": scale.stiffness(settings.kp), "kd": scale.damping(settings.kd)}
    scaled = settings.model_copy(update=gains)
    balance = BalanceController(run.controller_robot, scaled, run.torque_limits.copy(), run.contact.friction)
    return with_motor_strength(balance, run.motor_strength)


def build_damped(run: ResolvedRun) -> LowLevelController:
    """The safe ladder's last rung, the damped PD stance (``low_level.pd`` with its default gains)."""
    return with_motor_strength(PDController(run.controller_robot), run.motor_strength)


def build_riccati(run: ResolvedRun) -> LowLevelController:
    """The Riccati feedback (33), clamped to the run's torque limits."""
    riccati = RiccatiController(run.controller_robot)
    riccati.limits = run.torque_limits.copy()
    return with_motor_strength(riccati, run.motor_strength)


def build_vwbc(run: ResolvedRun) -> LowLevelController:
    """The VWBC QP (34): the ``vwbc`` section, the run's torque limits, its VWBC contact model (the pyramid's
    friction, the Baumgarte rate and the cone tolerance of the robot) and contact-detection thresholds; off
    flat ground (``run.ground_plane``) its contact detector measures heights above the stance feet's plane."""
    vwbc = VWBCController(
        run.controller_robot,
        run.config.vwbc,
        run.torque_limits.copy(),
        run.vwbc_contact,
        run.contact_detection,
        ground_plane=run.ground_plane,
    )
    return with_motor_strength(vwbc, run.motor_strength)


LOW_LEVELS: Registry[LowLevelEntry] = Registry(
    "wbc",
    "low-level controller",
    {
        "pd": LowLevelEntry(build_pd, None),
        "balance": LowLevelEntry(build_balance, None),
        "riccati": LowLevelEntry(build_riccati, Plan),
        "vwbc": LowLevelEntry(build_vwbc, Plan),
    },
)
"""``wbc`` -> its entry; ``LOW_LEVELS.get(name)`` raises ``ConfigError`` naming the key for an unknown one."""


def build_low_level(run: ResolvedRun, planner: PlannerSlice) -> LowLevelController:
    """The low level of a run under ``planner`` (module docstring), with the support ratio estimated online
    when ``calibration.online`` is on (``with_online_support``); ``ConfigError`` (one line naming ``wbc``)
    when the ``wbc`` entry follows another plan type than the planner makes."""
    if planner.low_level is not None:
        return with_online_support(run, with_motor_strength(planner.low_level(run), run.motor_strength))
    name = run.config.wbc
    entry = LOW_LEVELS.get(name)
    if entry.needs_plan and entry.plan_type is not planner.plan_type:
        raise ConfigError(
            f"wbc: {name!r} follows {entry.plan_type.__name__} plans; planner {run.config.planner!r} makes "
            f"{planner.plan_type.__name__} plans"
        )
    return with_online_support(run, entry.build(run))


def with_online_support(run: ResolvedRun, low_level: LowLevelController) -> LowLevelController:
    """``low_level`` (as ``build_low_level`` made it) with the support ratio estimated and applied online
    (``low_level.motor_strength.OnlineSupportCompensation`` around the inner low level, in place of the
    calibrated strengths' division) when ``calibration.online.enabled``, else ``low_level`` itself. The
    commands stay within the motors' own limits (``robot.plant.motor_torque_limits``). The safe ladder's
    balance and damped stances keep the calibrated strengths alone."""
    settings = run.config.calibration.online
    if not settings.enabled:
        return low_level
    inner = low_level.inner if isinstance(low_level, MotorStrengthCompensation) else low_level
    estimator = SupportRatioEstimator(run.controller_robot, settings, run.control_period)
    limits = np.asarray(run.robot.plant.motor_torque_limits, dtype=float)
    return OnlineSupportCompensation(inner, run.motor_strength, estimator, limits)
