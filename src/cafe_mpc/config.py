"""Run configurations: YAML files a user can read and edit, validated at the boundary.

A run config names a robot, the low-level controller and simulation settings. Presets live in
``cafe_mpc/configs/<name>.yaml``; ``cafe-mpc run PRESET_OR_FILE --set key=value`` overrides any key by its
dotted path (``simulation.duration=3``, ``pushes.0.start=1.5``). Unknown keys and out-of-range values are
rejected with a one-line message that names the key and the allowed range.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

PRESET_DIR = Path(__file__).parent / "configs"


class ConfigError(ValueError):
    """A config that cannot be used, with a message naming the bad key."""


class StrictModel(BaseModel):
    model_config = ConfigDict(extra="forbid", validate_assignment=True)


class FallConfig(StrictModel):
    min_base_height: float = Field(0.10, ge=0.0, le=1.0, description="m; below this the robot has fallen")
    max_tilt_rad: float = Field(1.2, gt=0.0, le=3.1416, description="base tilt that counts as a fall")


class SimulationConfig(StrictModel):
    duration: float = Field(5.0, gt=0.0, le=3600.0, description="simulated seconds")
    control_rate_hz: float = Field(500.0, gt=0.0, le=10000.0, description="low-level controller rate")
    plant_timestep: float = Field(0.001, gt=0.0, le=0.01, description="MuJoCo step, s")
    initial_height_offset: float = Field(0.0, ge=-0.05, le=1.0, description="start this far above standing")
    stop_on_fall: bool = True
    fall: FallConfig = FallConfig()

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
    force: tuple[float, float, float] | None = None
    velocity_change: tuple[float, float, float] | None = None

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


class PDConfig(StrictModel):
    kp: float = Field(60.0, ge=0.0, le=1000.0, description="Nm/rad")
    kd: float = Field(1.5, ge=0.0, le=100.0, description="Nm s/rad")
    gravity_feedforward: bool = True


class OutputConfig(StrictModel):
    plots: bool = True
    render: bool = False
    render_fps: int = Field(30, ge=1, le=120)


class RunConfig(StrictModel):
    """Everything a run needs; written back as ``config.yaml`` beside its results."""

    name: str = "stand"
    robot: str = "mini_cheetah"
    wbc: Literal["pd"] = Field("pd", description="low-level controller")
    pd: PDConfig = PDConfig()
    simulation: SimulationConfig = SimulationConfig()
    pushes: list[PushConfig] = Field(default_factory=list)
    output: OutputConfig = OutputConfig()

    @field_validator("robot")
    @classmethod
    def _robot_known(cls, value: str) -> str:
        from cafe_mpc.robots.robot import RobotLoadError, robot_file

        try:
            robot_file(value)
        except RobotLoadError as error:
            raise ValueError(str(error)) from error
        return value


def available_presets() -> list[str]:
    return sorted(path.stem for path in PRESET_DIR.glob("*.yaml"))


def _read_yaml(path: Path) -> dict[str, Any]:
    try:
        with open(path) as handle:
            raw = yaml.safe_load(handle) or {}
    except (OSError, yaml.YAMLError) as error:
        raise ConfigError(f"cannot read config {path}: {error}") from error
    if not isinstance(raw, dict):
        raise ConfigError(f"config {path} must be a mapping of keys to values")
    return raw


def _set_dotted(raw: dict[str, Any], model: type[BaseModel], dotted: str, value: Any) -> None:
    """Set ``raw[a][b]... = value`` after checking that the path exists in the config schema."""
    parts = dotted.split(".")
    node: Any = raw
    schema: Any = model
    for depth, part in enumerate(parts):
        last = depth == len(parts) - 1
        if isinstance(schema, type) and issubclass(schema, BaseModel):
            if part not in schema.model_fields:
                allowed = ", ".join(schema.model_fields)
                where = ".".join(parts[:depth]) or "top level"
                raise ConfigError(f"unknown config key {dotted!r}: {where} allows {allowed}")
            field = schema.model_fields[part]
            annotation = field.annotation
            if last:
                node[part] = value
                return
            if part not in node or node[part] is None:
                default = field.get_default(call_default_factory=True)
                node[part] = default.model_dump() if isinstance(default, BaseModel) else default
            node = node[part]
            schema = _inner_model(annotation)
        elif isinstance(node, list):
            if not part.isdigit() or int(part) >= len(node):
                raise ConfigError(f"config key {dotted!r}: index {part} is not in a list of {len(node)}")
            if last:
                node[int(part)] = value
                return
            node = node[int(part)]
        else:
            raise ConfigError(f"unknown config key {dotted!r}: {'.'.join(parts[:depth])} has no sub-keys")


def _inner_model(annotation: Any) -> Any:
    """The pydantic model inside ``Model``, ``list[Model]`` or ``Model | None`` (else the annotation)."""
    for arg in getattr(annotation, "__args__", ()) or ():
        if isinstance(arg, type) and issubclass(arg, BaseModel):
            return arg
    return annotation


def parse_override(item: str) -> tuple[str, Any]:
    """``key=value`` -> (key, YAML-parsed value)."""
    if "=" not in item:
        raise ConfigError(f"--set expects key=value, got {item!r}")
    key, text = item.split("=", 1)
    key = key.strip()
    if not key:
        raise ConfigError(f"--set expects key=value, got {item!r}")
    try:
        value = yaml.safe_load(text)
    except yaml.YAMLError as error:
        raise ConfigError(f"--set {key}: cannot parse value {text!r}: {error}") from error
    return key, value


def format_validation_error(error: ValidationError) -> str:
    """One line per problem: ``key.path: message (got value)``."""
    lines = []
    for problem in error.errors():
        location = ".".join(str(part) for part in problem["loc"]) or "config"
        message = problem["msg"]
        got = problem.get("input")
        if problem["type"] == "extra_forbidden":
            message = "unknown key"
        lines.append(
            f"{location}: {message} (got {got!r})" if not isinstance(got, dict) else f"{location}: {message}"
        )
    return "; ".join(lines)


def load_config(preset_or_path: str, overrides: list[str] | None = None) -> RunConfig:
    """Load a preset name or a YAML file, apply ``key=value`` overrides, validate."""
    path = Path(preset_or_path)
    if path.suffix in (".yaml", ".yml") or path.is_file():
        if not path.is_file():
            raise ConfigError(f"config file {path} does not exist")
        raw = _read_yaml(path)
    else:
        candidate = PRESET_DIR / f"{preset_or_path}.yaml"
        if not candidate.is_file():
            raise ConfigError(
                f"unknown preset {preset_or_path!r}; presets: {', '.join(available_presets())} "
                "(or give a path to a .yaml config)"
            )
        raw = _read_yaml(candidate)
    for item in overrides or []:
        key, value = parse_override(item)
        _set_dotted(raw, RunConfig, key, value)
    try:
        return RunConfig.model_validate(raw)
    except ValidationError as error:
        raise ConfigError(f"invalid config: {format_validation_error(error)}") from error
