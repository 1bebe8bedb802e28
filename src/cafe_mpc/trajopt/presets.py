"""Task presets of ``cafe-mpc optimize`` and loading a task (preset or YAML file) with overrides."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import yaml

from cafe_mpc.trajopt.barrel_roll import barrel_roll_task, running_barrel_roll_task
from cafe_mpc.trajopt.task import TrajOptTask, TrajOptTaskError, parse_override, set_dotted, validate_task

TASKS: dict[str, Callable[[], TrajOptTask]] = {
    "barrel-roll": barrel_roll_task,
    "running-barrel-roll": running_barrel_roll_task,
}
"""Task presets by name."""


def load_task(name_or_path: str, overrides: list[str] | None = None) -> TrajOptTask:
    """A task preset (``TASKS``) or a task YAML file, with ``key=value`` overrides, validated."""
    path = Path(name_or_path)
    if name_or_path in TASKS:
        raw = TASKS[name_or_path]().model_dump(mode="json")
        source = f"preset {name_or_path!r}"
    elif path.suffix in (".yaml", ".yml") or path.is_file():
        try:
            with open(path) as handle:
                raw = yaml.safe_load(handle)
        except (OSError, yaml.YAMLError) as error:
            raise TrajOptTaskError(f"cannot read task file {path}: {error}") from error
        if not isinstance(raw, dict):
            raise TrajOptTaskError(f"task file {path} must be a mapping of keys to values")
        raw = validate_task(raw, f"file {path}").model_dump(mode="json")  # fill defaults: every key settable
        source = f"file {path}"
    else:
        raise TrajOptTaskError(
            f"unknown task {name_or_path!r}; tasks: {', '.join(TASKS)} (or give a path to a task .yaml)"
        )
    for item in overrides or []:
        key, value = parse_override(item)
        set_dotted(raw, key, value)
    return validate_task(raw, source)
