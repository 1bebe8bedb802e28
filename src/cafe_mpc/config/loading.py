"""Settings files a user can read and edit: strict models, presets, ``--set`` overrides, one-line errors.

The machinery shared by run configs (``config.run``: ``cafe-mpc run PRESET --set key=value``) and
trajectory-optimisation tasks (``trajopt.task``: ``cafe-mpc optimize TASK --set key=value``):

* ``StrictModel``: a pydantic model that rejects unknown keys and validates every assignment;
* ``parse_override`` and ``set_dotted``: ``key.path=value`` (a YAML value) set in the raw data by its dotted
  path, after checking that the path exists in the schema (sections missing from the data are created from
  the schema's defaults, so ``--set gait.commands.0.vx=0.8`` works on any config);
* ``format_validation_error``: pydantic's errors as one line naming each bad key;
* ``load_model``: a preset by name or a YAML file, with overrides, validated; with ``inherit``, a file may
  say ``base: PRESET_OR_FILE`` and give only what it changes (``deep_merge``).

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
        reason = getattr(problem, "problem", None) or str(problem).splitlines()[0]
        raise error(
            f"--set {key}: cannot parse value {text!r} as YAML: {' '.join(str(reason).split())}"
        ) from problem


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


BASE_KEY = "base"
"""The key by which a settings file names the preset or file it starts from (``load_model(inherit=True)``)."""


def deep_merge(base: Mapping[str, Any], changes: Mapping[str, Any]) -> dict[str, Any]:
    """``base`` with ``changes`` applied: mappings merge key by key, anything else (values, lists, null)
    replaces the base's entry whole (a list of commands is one value: a file that gives ``commands`` gives all
    of them)."""
    merged = dict(base)
    for key, value in changes.items():
        if isinstance(value, Mapping) and isinstance(merged.get(key), Mapping):
            merged[key] = deep_merge(merged[key], value)
        else:
            merged[key] = value
    return merged


def _raw_of(
    preset_or_path: str,
    presets: Mapping[str, Callable[[], dict[str, Any]]],
    noun: str,
    preset_noun: str,
    error: type[ConfigError],
    relative_to: Path | None = None,
) -> tuple[dict[str, Any], Path | None]:
    """A preset's raw data (by name) or a YAML file's (a relative path from ``relative_to`` first), and the
    file's path (``None`` for a preset)."""
    path = Path(preset_or_path)
    if relative_to is not None and not path.is_absolute() and (relative_to / path).is_file():
        path = relative_to / path
    if path.suffix not in (".yaml", ".yml") and preset_or_path in presets:
        return presets[preset_or_path](), None
    if path.suffix in (".yaml", ".yml") or path.is_file():
        if not path.is_file():
            raise error(f"{noun} file {path} does not exist")
        return read_yaml(path, f"{noun} file", error), path
    raise error(
        f"unknown {preset_noun} {preset_or_path!r}; {preset_noun}s: {', '.join(presets)} "
        f"(or give a path to a .yaml {noun})"
    )


def resolve_base(
    raw: dict[str, Any],
    path: Path | None,
    presets: Mapping[str, Callable[[], dict[str, Any]]],
    noun: str = "config",
    preset_noun: str = "preset",
    error: type[ConfigError] = ConfigError,
    seen: tuple[str, ...] = (),
) -> dict[str, Any]:
    """``raw`` merged onto the data its ``base`` key names (recursively; a cycle is an error)."""
    if BASE_KEY not in raw:
        return raw
    base_name = raw[BASE_KEY]
    if not isinstance(base_name, str) or not base_name:
        raise error(
            f"{noun} key {BASE_KEY!r}: expected a {preset_noun} name or a .yaml path, got {base_name!r}"
        )
    if base_name in seen:
        raise error(f"{noun} key {BASE_KEY!r}: {' -> '.join((*seen, base_name))} is a cycle")
    base_raw, base_path = _raw_of(
        base_name, presets, noun, preset_noun, error, None if path is None else path.parent
    )
    base_raw = resolve_base(base_raw, base_path, presets, noun, preset_noun, error, (*seen, base_name))
    changes = {key: value for key, value in raw.items() if key != BASE_KEY}
    return deep_merge(base_raw, changes)


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
    inherit: bool = False,
    name_from_file: bool = False,
) -> Model:
    """A preset (by name; ``presets`` gives its raw data) or a YAML file, with ``key=value`` overrides
    applied by dotted key, validated. ``noun`` names the kind of file in messages (``unknown config key``,
    ``invalid task``), ``preset_noun`` its presets (``unknown preset 'trott'; presets: ...``).

    ``inherit``: a file (or preset) may name the preset or file it starts from with ``base:`` and give only
    what it changes (``deep_merge``; a relative base path is taken from the file's folder first).
    ``name_from_file``: a file that gives no ``name`` of its own is named after the file (its stem), so that
    a hand-written file is never labelled as a default (``stand``) or as its base."""
    raw, path = _raw_of(preset_or_path, presets, noun, preset_noun, error)
    named = "name" in raw
    if inherit:
        raw = resolve_base(raw, path, presets, noun, preset_noun, error)
    elif BASE_KEY in raw and BASE_KEY not in model.model_fields:
        raise error(f"{noun} key {BASE_KEY!r} is not supported here")
    if path is not None and name_from_file and not named:
        raw["name"] = path.stem
    for item in overrides:
        key, value = parse_override(item, error)
        set_dotted(raw, model, key, value, noun, error)
    return validate(model, raw, noun, error)
