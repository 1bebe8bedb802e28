"""Task presets of ``cafe-mpc optimize`` and loading a task (preset or YAML file) with overrides."""

from __future__ import annotations

from collections.abc import Callable

from cafe_mpc.config.loading import load_model
from cafe_mpc.trajopt.barrel_roll import barrel_roll_task, running_barrel_roll_task
from cafe_mpc.trajopt.task import TrajOptTask, TrajOptTaskError

TASKS: dict[str, Callable[[], TrajOptTask]] = {
    "barrel-roll": barrel_roll_task,
    "running-barrel-roll": running_barrel_roll_task,
}
"""Task presets by name."""


def load_task(name_or_path: str, overrides: list[str] | None = None) -> TrajOptTask:
    """A task preset (``TASKS``) or a task YAML file, with ``key=value`` overrides, validated
    (``TrajOptTaskError`` naming the key)."""
    presets = {name: (lambda task=task: task().model_dump(mode="json")) for name, task in TASKS.items()}
    return load_model(
        TrajOptTask,
        name_or_path,
        overrides or (),
        presets,
        noun="task",
        preset_noun="task",
        error=TrajOptTaskError,
    )
