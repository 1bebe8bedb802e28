"""Planners as vertical slices behind one plan protocol: the registries, a toy planner that plugs in through
them alone, the plan channel and the plan follower on any plan type."""

from __future__ import annotations

import functools
import typing
from dataclasses import dataclass

import numpy as np
import pytest

from cafe_mpc.assembly import build_controller, build_low_level, load_run_config, resolve
from cafe_mpc.config import ConfigError, MpcSettings, RunConfig
from cafe_mpc.control.inline import InlineMpcLoop
from cafe_mpc.control.ipc.channels import PlanChannel, PlanLayout
from cafe_mpc.control.plan_follower import NewestPlanFollower
from cafe_mpc.core.controller import LowLevelController
from cafe_mpc.core.measurement import Measurement
from cafe_mpc.core.plan import PlanFormat, interval_at
from cafe_mpc.low_level import registry as low_levels
from cafe_mpc.low_level.registry import LOW_LEVELS
from cafe_mpc.low_level.riccati import RiccatiController
from cafe_mpc.low_level.synthetic import synthetic_plan
from cafe_mpc.planners.base import MpcStatistics, PlannerSlice
from cafe_mpc.planners.cafe.plan import Plan, plan_format
from cafe_mpc.planners.registry import PLANNERS
from cafe_mpc.planners.resolved import ResolvedRun
from cafe_mpc.planners.template.low_level import TemplateLowLevelController
from cafe_mpc.planners.template.plan import TemplatePlan, template_plan_format
from cafe_mpc.reference.base import Reference
from cafe_mpc_lab.sim.loop import SimulationOptions, simulate
from cafe_mpc_lab.sim.mujoco_plant import MujocoPlant


# ------------------------------------------------------------------------------------------ registries
def test_every_planner_and_low_level_the_schema_allows_is_registered():
    """The config's ``planner`` and ``wbc`` keys name exactly what the registries build."""
    fields = RunConfig.model_fields
    assert set(typing.get_args(fields["planner"].annotation)) == set(PLANNERS.names)
    assert set(typing.get_args(fields["wbc"].annotation)) == set(LOW_LEVELS.names)


def test_an_unknown_name_is_one_config_error_line_naming_the_key(robot):
    with pytest.raises(ConfigError, match=r"^planner: unknown planner 'hkd'; known: cafe, template$"):
        PLANNERS.get("hkd")
    with pytest.raises(
        ConfigError, match=r"^wbc: unknown low-level controller 'qp'; known: pd, balance, riccati, vwbc$"
    ):
        LOW_LEVELS.get("qp")
    # a config that bypassed the schema (model_copy does not validate) meets the same error when built
    config = load_run_config("trot").model_copy(update={"planner": "hkd"})
    with pytest.raises(ConfigError, match=r"^planner: unknown planner 'hkd'"):
        build_controller(resolve(config, robot))


def test_registering_a_name_twice_is_refused():
    with pytest.raises(ValueError, match="registered already"):
        PLANNERS.register("cafe", PLANNERS.get("cafe"))


def test_the_low_levels_follow_their_planners_plan_type(robot):
    """``wbc`` picks the low level of a planner that has none of its own; the template brings its own
    whatever ``wbc`` says."""
    riccati = resolve(load_run_config("trot", ["wbc=riccati"]), robot)
    assert isinstance(build_low_level(riccati), RiccatiController)
    template = load_run_config("trot", ["planner=template", "wbc=riccati"])
    assert isinstance(build_low_level(resolve(template, robot)), TemplateLowLevelController)
    pd = LOW_LEVELS.get("pd")
    assert not pd.needs_plan and LOW_LEVELS.get("vwbc").plan_type is Plan


# ------------------------------------------------------------------------------------- a toy planner
@dataclass
class HoldPlan:
    """A toy plan: hold the joint angles ``targets[k]`` over each knot interval, all feet in stance."""

    times: np.ndarray  # (n,)
    dt: np.ndarray  # (n,)
    contacts: np.ndarray  # (n, n_feet)
    forces: np.ndarray  # (n, n_feet, 3)
    targets: np.ndarray  # (n, nu)

    @property
    def start_time(self) -> float:
        return float(self.times[0])

    @property
    def end_time(self) -> float:
        return float(self.times[-1] + self.dt[-1])

    def knot_at(self, t: float) -> int:
        return interval_at(self.times, t)

    def knot_configurations(self, nq: int) -> None:
        return None


def hold_plan_shapes(n: int, n_feet: int, nu: int) -> dict[str, tuple[int, ...]]:
    return {"times": (n,), "dt": (n,), "contacts": (n, n_feet), "forces": (n, n_feet, 3), "targets": (n, nu)}


KNOTS = 5


class HoldPlanner:
    """A toy planner (``planners.base.Planner``): every update plans to hold the standing joint angles for
    ``KNOTS`` knots of one period each; no solver, no real-time iteration."""

    name = "hold"

    def __init__(self, robot, reference: Reference, settings: MpcSettings) -> None:
        self.robot, self.reference, self.settings = robot, reference, settings
        self.statistics = MpcStatistics()

    started = property(lambda self: self.statistics.solves > 0)
    supports_rti = False
    prepared_time = None

    def reset(self) -> None:
        self.statistics = MpcStatistics()

    def update(self, t: float, q: np.ndarray, v: np.ndarray) -> HoldPlan:
        self.statistics.solves += 1
        self.statistics.start_times.append(t)
        self.statistics.update_times.append(0.0)
        period, n_feet = self.settings.period, self.robot.n_feet
        return HoldPlan(
            t + period * np.arange(KNOTS),
            np.full(KNOTS, period),
            np.ones((KNOTS, n_feet), dtype=bool),
            np.zeros((KNOTS, n_feet, 3)),
            np.tile(self.robot.q_standing[7:], (KNOTS, 1)),
        )

    def prepare(self, t, q, v) -> bool:
        raise NotImplementedError

    def feedback(self, t, q, v):
        raise NotImplementedError

    def predict(self, t):
        return None

    def problem_start(self, t: float, delay: float) -> float:
        return t

    def carry(self, q, v, t, until, plan_at):
        raise NotImplementedError


class HoldLowLevel(LowLevelController[HoldPlan]):
    """Joint PD toward the plan's targets at the knot that holds ``t``; records the plans it was given."""

    def __init__(self, robot) -> None:
        self.robot = robot
        self.last_request = np.zeros(robot.nu)
        self.plans: list[HoldPlan] = []

    def reset(self) -> None:
        self.plans.clear()

    def compute(self, t: float, measurement: Measurement, plan: HoldPlan | None) -> np.ndarray:
        assert plan is not None
        self.plans.append(plan)
        k = plan.knot_at(t)
        self.last_request[:] = 60.0 * (plan.targets[k] - measurement.q[7:]) - 1.5 * measurement.v[6:]
        return self.last_request

    def statistics(self) -> dict:
        return {}


def _hold_slice() -> PlannerSlice[HoldPlan]:
    def plan_format_of(run: ResolvedRun) -> PlanFormat[HoldPlan]:
        shapes = functools.partial(hold_plan_shapes, n_feet=run.robot.n_feet, nu=run.robot.nu)
        return PlanFormat(HoldPlan, shapes, KNOTS, {"contacts": bool})

    return PlannerSlice(
        HoldPlan,
        lambda run, reference: HoldPlanner(run.robot, reference, run.config.mpc),
        plan_format_of,
        low_level=lambda run: HoldLowLevel(run.robot),
    )


@pytest.fixture
def hold_planner():
    """The toy planner registered as ``planner: hold`` for one test (one registry line)."""
    PLANNERS.register("hold", _hold_slice())
    yield
    PLANNERS.unregister("hold")


def test_a_new_planner_plugs_in_with_one_registry_line(robot, hold_planner):
    """A planner the loop has never seen, with its own plan type and low level, built by the assembly from a
    config that names it and closed by the same MPC loop: updates every period, its plans followed."""
    config = load_run_config("trot", ["mpc.latency=fixed", "mpc.period=0.02"]).model_copy(
        update={"planner": "hold"}
    )
    loop = build_controller(resolve(config, robot))
    assert isinstance(loop, InlineMpcLoop) and loop.scheme == "one_phase"  # no real-time iteration
    log = simulate(MujocoPlant(robot), loop, SimulationOptions(0.3))
    assert not log.fell
    assert abs(log.q[-1, 2] - robot.standing_height) < 0.03
    low_level = loop.low_level
    assert isinstance(low_level, HoldLowLevel) and all(isinstance(p, HoldPlan) for p in low_level.plans)
    assert loop.statistics.solves == 15 and loop.statistics.fallback_ticks == 0
    assert len({id(plan) for plan in low_level.plans}) >= 10  # new plans took effect along the run
    # its plans travel through the plan channel of the MPC process as they are
    channel = PlanChannel(PlanLayout(PLANNERS.get("hold").plan_format(resolve(config, robot))))
    try:
        plan = low_level.plans[-1]
        channel.publish(plan, 0.3, (0.0, 1.0, 15.0, 0.0))
        copy, measured_at, _ = channel.receive()
        assert measured_at == 0.3 and channel.receive() is None  # each plan once
        for name in ("times", "dt", "contacts", "forces", "targets"):
            np.testing.assert_array_equal(getattr(copy, name), getattr(plan, name))
        assert copy.contacts.dtype == bool
    finally:
        channel.close(unlink=True)


def test_a_low_level_of_another_plan_type_is_refused(robot, hold_planner):
    """A planner without a low level of its own pairs with ``wbc`` only if that low level follows its plan
    type: one ``ConfigError`` line naming ``wbc``."""
    hold = PLANNERS.get("hold")
    without_low_level = PlannerSlice(hold.plan_type, hold.build, hold.plan_format)
    run = resolve(load_run_config("trot", ["wbc=riccati"]), robot)
    with pytest.raises(
        ConfigError, match=r"^wbc: 'riccati' follows Plan plans; planner 'cafe' makes HoldPlan"
    ):
        low_levels.build_low_level(run, without_low_level)


# --------------------------------------------------------------------- the plan channel and follower
def _template_plan(robot, n: int = 3, t0: float = 0.0) -> TemplatePlan:
    """A template plan standing on all feet, each carrying a quarter of the weight."""
    feet = np.zeros((n + 1, robot.n_feet, 3))
    forces = np.zeros((n, robot.n_feet, 3))
    forces[:, :, 2] = robot.total_mass * 9.81 / robot.n_feet
    return TemplatePlan(
        t0 + 0.01 * np.arange(n),
        np.full(n, 0.01),
        np.zeros((n + 1, 13)),
        forces,
        np.ones((n, robot.n_feet), dtype=bool),
        feet,
        feet.copy(),
    )


@pytest.mark.parametrize("kind", ["cafe", "template"])
def test_the_plan_channel_carries_either_plan_type(robot, kind):
    """One channel layout per plan type (its ``PlanFormat``); a plan shorter than the capacity comes back
    with its own length, field by field."""
    if kind == "cafe":
        plan = synthetic_plan(robot, knots=6)
        plan_format_ = plan_format(10, robot.nq + robot.nv, robot.nu, 2 * robot.nv, robot.n_feet)
        fields = ("times", "xs", "us", "K", "Qu", "Quu", "Qux", "contacts", "forces", "dt")
    else:
        plan = _template_plan(robot)
        plan_format_ = template_plan_format(8, robot.n_feet)
        fields = ("times", "dt", "base_states", "forces", "contacts", "foot_positions", "foot_velocities")
    channel = PlanChannel(PlanLayout(plan_format_))
    try:
        assert channel.receive() is None
        channel.publish(plan, 0.5, (0.01, 1.0, 2.0, 0.0))
        copy, measured_at, wall = channel.receive()
    finally:
        channel.close(unlink=True)
    assert type(copy) is type(plan) and (measured_at, wall) == (0.5, 0.01)
    for name in fields:
        np.testing.assert_array_equal(getattr(copy, name), getattr(plan, name))


@pytest.mark.parametrize("kind", ["cafe", "template"])
def test_the_follower_runs_any_plan_type_and_falls_back_to_the_safe_ladder(robot, kind):
    """The one follower of both loops: the low level on a plan of its type while the plan lasts; the safe
    ladder's balance stance past the plan's end or without a plan (counted; control.plan_follower)."""
    if kind == "cafe":
        low_level, plan = RiccatiController(robot), synthetic_plan(robot, knots=4, dt=0.02)
    else:
        low_level, plan = TemplateLowLevelController(robot), _template_plan(robot)
    follower = NewestPlanFollower(robot, low_level)
    q = robot.q_standing.copy()
    q[7:] += 0.05  # off the standing pose: the safe stance and the low level disagree
    measurement = Measurement.of_state(q, np.zeros(robot.nv), np.ones(robot.n_feet, dtype=bool))
    follower.new_plan(0.0, 0.0)
    inside = follower.compute(0.005, measurement, plan).copy()
    expected = type(low_level)(robot).compute(0.005, measurement, plan)
    np.testing.assert_allclose(inside, expected)
    assert follower.step == "plan" and follower.fallback_ticks == 0
    past_end = follower.compute(plan.end_time + 0.01, measurement, plan)
    assert follower.step == "balance" and np.all(np.isfinite(past_end))
    assert not np.allclose(past_end, inside)
    follower.compute(plan.end_time + 0.02, measurement, None)
    assert follower.fallback_ticks == 2
