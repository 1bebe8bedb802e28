"""Task presets of ``cafe-mpc optimize`` and loading a task (preset or YAML file) with overrides.

The presets are the barrel rolls (``barrel_roll``, built in Python from the authors' values) and every task
file of the catalogue (``catalogue/<name>.yaml``: the backflip, the front flip, the running front flip and the
spin; one file each, the same format as any task file ``cafe-mpc optimize`` writes or reads).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from cafe_mpc.config.loading import load_model, read_yaml
from cafe_mpc.trajopt.barrel_roll import barrel_roll_task, running_barrel_roll_task
from cafe_mpc.trajopt.task import TrajOptTask, TrajOptTaskError

CATALOGUE_DIR = Path(__file__).parent / "catalogue"
"""Task files shipped with the package (one task per file, named after the task)."""


def catalogue_tasks() -> dict[str, Path]:
    """The catalogue's task files by task name (``front_flip.yaml`` -> ``front-flip``)."""
    return {path.stem.replace("_", "-"): path for path in sorted(CATALOGUE_DIR.glob("*.yaml"))}


TASKS: dict[str, Callable[[], TrajOptTask]] = {
    "barrel-roll": barrel_roll_task,
    "running-barrel-roll": running_barrel_roll_task,
    **{name: (lambda path=path: load_task(str(path))) for name, path in catalogue_tasks().items()},
}
"""Task presets by name."""


def load_task(name_or_path: str, overrides: list[str] | None = None) -> TrajOptTask:
    """A task preset (``TASKS``) or a task YAML file, with ``key=value`` overrides, validated
    (``TrajOptTaskError`` naming the key). A file may start from a preset or another file (``base: NAME``)
    and give only what it changes."""
    presets = {
        name: (lambda task=task: task().model_dump(mode="json"))
        for name, task in (
            ("barrel-roll", barrel_roll_task),
            ("running-barrel-roll", running_barrel_roll_task),
        )
    }
    presets.update(
        {
            name: (lambda path=path: read_yaml(path, noun="task", error=TrajOptTaskError))
            for name, path in catalogue_tasks().items()
        }
    )
    return load_model(
        TrajOptTask,
        name_or_path,
        overrides or (),
        presets,
        noun="task",
        preset_noun="task",
        error=TrajOptTaskError,
        inherit=True,
    )
