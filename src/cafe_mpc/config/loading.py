"""Settings files a user can read and edit: strict models, presets, ``--set`` overrides, one-line errors.

The machinery shared by run configs (``config.run``: ``cafe-mpc run PRESET --set key=value``) and
trajectory-optimisation tasks (``trajopt.task``: ``cafe-mpc optimize TASK --set key=value``):

* ``StrictModel``: a pydantic model that rejects unknown keys and validates every assignment;
* ``parse_override`` and ``set_dotted``: ``key.path=value`` (a YAML value) set in the raw data by its dotted
  path, after checking that the path exists in the schema (sections missing from the data are created from
  the schema's defaults, so ``--set gait.commands.0.vx=0.8`` works on any config);
* ``format_validation_error``: pydantic's errors as one line naming each bad key;
* ``load_model``: a preset by name or a YAML file, with overrides, validated.

Every problem is raised as ``ConfigError`` (or the subclass the caller names) with a message that names the
key.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, TypeVar

import yaml
from pydantic import BaseModel, ConfigDict, ValidationError


class ConfigError(ValueError):
    """A config that cannot be used, with a message naming the bad key."""


class StrictModel(BaseModel):
    """A settings section: unknown keys are errors; assignments are validated."""

    model_config = ConfigDict(extra="forbid", validate_assignment=True)


Model = TypeVar("Model", bound=BaseModel)


def parse_override(item: str, error: type[ConfigError] = ConfigError) -> tuple[str, Any]:
    """``key=value`` -> (key, YAML-parsed value)."""
    key, separator, text = item.partition("=")
    key = key.strip()
    if not separator or not key:
        raise error(f"--set expects key=value, got {item!r}")
    try:
        return key, yaml.safe_load(text)
    except yaml.YAMLError as problem:
        raise error(f"--set {key}: cannot parse value {text!r}: {problem}") from problem


def set_dotted(
    raw: dict[str, Any],
    model: type[BaseModel],
    dotted: str,
    value: Any,
    noun: str = "config",
    error: type[ConfigError] = ConfigError,
) -> None:
    """Set ``raw[a][b]... = value`` after checking that the path exists in ``model``'s schema.

    Sections missing from ``raw`` (or null, like ``gait`` of the stand preset) are created from the schema's
    defaults. ``noun`` names the file kind in messages (``unknown config key 'a.b'``)."""
    parts = dotted.split(".")
    node: Any = raw
    schema: Any = model
    for depth, part in enumerate(parts):
        last = depth == len(parts) - 1
        where = ".".join(parts[:depth]) or "top level"
        if isinstance(node, list):  # list index; the element schema stays ``schema``
            if not part.isdigit() or int(part) >= len(node):
                raise error(f"{noun} key {dotted!r}: {where} is a list of {len(node)}, not index {part}")
            if last:
                node[int(part)] = value
                return
            node = node[int(part)]
        elif isinstance(node, dict) and isinstance(schema, type) and issubclass(schema, BaseModel):
            if part not in schema.model_fields:
                allowed = ", ".join(schema.model_fields)
                raise error(f"unknown {noun} key {dotted!r}: {where} allows {allowed}")
            field = schema.model_fields[part]
            if last:
                node[part] = value
                return
            schema = _inner_model(field.annotation)
            if part not in node or node[part] is None:
                default = field.get_default(call_default_factory=True)
                if default is None and isinstance(schema, type) and issubclass(schema, BaseModel):
                    default = {}  # an optional section (gait: null) that a sub-key override creates
                node[part] = _plain(default)
            node = node[part]
        else:
            raise error(f"unknown {noun} key {dotted!r}: {where} has no sub-keys")


def _plain(value: Any) -> Any:
    """A default as plain YAML data (models and lists of models dumped)."""
    if isinstance(value, BaseModel):
        return value.model_dump()
    if isinstance(value, list | tuple):
        return [_plain(item) for item in value]
    return value


def _inner_model(annotation: Any) -> Any:
    """The pydantic model inside ``Model``, ``list[Model]`` or ``Model | None`` (else the annotation)."""
    for arg in getattr(annotation, "__args__", ()) or ():
        if isinstance(arg, type) and issubclass(arg, BaseModel):
            return arg
    return annotation


def format_validation_error(error: ValidationError, top: str = "config") -> str:
    """One line per problem, joined by ``; ``: ``key.path: message (got value)``; a check of the whole
    model (``top``-level, its message names its keys) is its message alone."""
    lines = []
    for problem in error.errors():
        location = ".".join(str(part) for part in problem["loc"]) or top
        message = problem["msg"].removeprefix("Value error, ")
        got = problem.get("input")
        if problem["type"] == "extra_forbidden":
            message = "unknown key"
        if not problem["loc"] and isinstance(got, dict):
            lines.append(message)
        elif isinstance(got, dict):
            lines.append(f"{location}: {message}")
        else:
            lines.append(f"{location}: {message} (got {got!r})")
    return "; ".join(lines)


def read_yaml(path: Path, noun: str = "config", error: type[ConfigError] = ConfigError) -> dict[str, Any]:
    """A YAML file's mapping (``error`` naming the file when it cannot be read or is not a mapping)."""
    try:
        with open(path) as handle:
            raw = yaml.safe_load(handle) or {}
    except (OSError, yaml.YAMLError) as problem:
        raise error(f"cannot read {noun} {path}: {problem}") from problem
    if not isinstance(raw, dict):
        raise error(f"{noun} {path} must be a mapping of keys to values")
    return raw


def validate(model: type[Model], raw: Mapping[str, Any], what: str, error: type[ConfigError]) -> Model:
    """``model`` from ``raw``; ``error("invalid <what>: <one line per bad key>")`` when it does not fit."""
    try:
        return model.model_validate(raw)
    except ValidationError as problem:
        raise error(f"invalid {what}: {format_validation_error(problem, what.split()[0])}") from problem


def load_model(
    model: type[Model],
    preset_or_path: str,
    overrides: Sequence[str],
    presets: Mapping[str, Callable[[], dict[str, Any]]],
    noun: str = "config",
    preset_noun: str = "preset",
    error: type[ConfigError] = ConfigError,
) -> Model:
    """A preset (by name; ``presets`` gives its raw data) or a YAML file, with ``key=value`` overrides
    applied by dotted key, validated. ``noun`` names the kind of file in messages (``unknown config key``,
    ``invalid task``), ``preset_noun`` its presets (``unknown preset 'trott'; presets: ...``)."""
    path = Path(preset_or_path)
    if path.suffix not in (".yaml", ".yml") and preset_or_path in presets:
        raw = presets[preset_or_path]()
    elif path.suffix in (".yaml", ".yml") or path.is_file():
        if not path.is_file():
            raise error(f"{noun} file {path} does not exist")
        raw = read_yaml(path, f"{noun} file", error)
    else:
        raise error(
            f"unknown {preset_noun} {preset_or_path!r}; {preset_noun}s: {', '.join(presets)} "
            f"(or give a path to a .yaml {noun})"
        )
    for item in overrides:
        key, value = parse_override(item, error)
        set_dotted(raw, model, key, value, noun, error)
    return validate(model, raw, noun, error)
