"""Reproducibility of runs made in an experiment: a run's record holds its config written out
(``config.yaml``; an experiment's task carries it as JSON to its worker), and ``runs.md`` gives its
``cafe-mpc run`` command.
Both must run what the original config runs, also in a process (the synchronous scheduler, a Dask worker)
that made other runs before."""

from __future__ import annotations

import dataclasses
import io
import os
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from pydantic import BaseModel

from cafe_mpc.assembly import load_run_config
from cafe_mpc.assembly.resolve import resolve
from cafe_mpc.config import RunConfig
from cafe_mpc.robots.robot import load_robot

ROOT = Path(__file__).resolve().parents[1]
PRESETS = sorted(path.stem for path in (ROOT / "src" / "cafe_mpc" / "configs").glob("*.yaml"))
TERRAIN_MODES = {
    "flat": ["terrain=flat"],
    "blind": ["terrain=blind"],
    "height_map": ["terrain=height_map", "plant.height_map.enabled=true"],
}


def differences(first: object, second: object, path: str = "run") -> list[str]:
    """Where two resolved runs differ: pydantic models and plain values by ``==``, arrays element by
    element, dataclasses, tuples, lists and dicts item by item (robots and other objects are built from
    the config's names and are not compared)."""
    if isinstance(first, BaseModel | int | float | str | bool | type(None)):
        return [] if first == second else [path]
    if isinstance(first, np.ndarray):
        return [] if np.array_equal(first, second) else [path]
    if dataclasses.is_dataclass(first) and not isinstance(first, type):
        return [
            found
            for item in dataclasses.fields(first)
            for found in differences(
                getattr(first, item.name), getattr(second, item.name), f"{path}.{item.name}"
            )
        ]
    if isinstance(first, list | tuple):
        if len(first) != len(second):
            return [path]
        return [
            found
            for i, (a, b) in enumerate(zip(first, second, strict=True))
            for found in differences(a, b, f"{path}[{i}]")
        ]
    if isinstance(first, dict):
        if first.keys() != second.keys():
            return [path]
        return [found for key in first for found in differences(first[key], second[key], f"{path}[{key}]")]
    return []


@pytest.mark.parametrize("mode", TERRAIN_MODES)
def test_a_config_written_out_and_read_back_resolves_to_the_same_run(mode: str) -> None:
    """No setting may depend on whether it was written in the config (``model_fields_set``): an experiment's
    worker and ``cafe-mpc run config.yaml`` get every field written. The on-time margin of the contact
    detector did (25 ms instead of 15 ms off flat ground) until its default became an explicit null."""
    for preset in PRESETS:
        config = load_run_config(preset, TERRAIN_MODES[mode])
        robot = load_robot(config.robot)
        read_back = RunConfig.model_validate(config.model_dump(mode="json"))
        assert differences(resolve(config, robot), resolve(read_back, robot)) == [], preset


@pytest.mark.slow
def test_a_run_after_another_in_one_worker_is_reproduced_by_its_command(tmp_path: Path) -> None:
    """Two runs of the terrain experiment in this process, as a synchronous sweep or a Dask worker makes
    them (``execute_task``), then the second one's ``cafe-mpc run`` command in a fresh process: the logs are
    equal to the last bit (fixed latency is deterministic). The blind bound lands its front feet early in the
    first second, so a run whose detector had a different on-time margin parts from the command's."""
    from cafe_mpc_lab.experiments.execution import STATUS_OK, RunTask, execute_task
    from cafe_mpc_lab.experiments.registry import run_command
    from cafe_mpc_lab.experiments.sweep import prepare

    duration = 1.5
    prepared = prepare(
        "terrain",
        duration,
        ["output.plots=false"],
        {"gaits": "trot,bound", "terrains": "step2", "modes": "blind"},
    )
    first, second = prepared.plan.variants
    assert (first.preset, second.preset) == ("trot", "bound")
    outcomes = [
        execute_task(
            RunTask(
                prepared.experiment.name,
                variant,
                prepared.configs[variant.name].model_dump(mode="json"),
                prepared.plan.drop_files,
            )
        )
        for variant in (first, second)
    ]
    assert [outcome.status for outcome in outcomes] == [STATUS_OK, STATUS_OK], [o.error for o in outcomes]

    words = shlex.split(run_command(second, prepared.duration, prepared.base_overrides))
    assert words[:2] == ["cafe-mpc", "run"]
    out = tmp_path / "alone"
    environment = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    result = subprocess.run(
        [sys.executable, "-m", "cafe_mpc_lab.cli", *words[1:], "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=600,
        cwd=ROOT,
        env=environment,
    )
    assert result.returncode == 0, result.stderr[-2000:]

    in_worker = np.load(io.BytesIO(outcomes[1].files["log.npz"]))
    alone = np.load(out / "log.npz")
    for name in ("time", "q", "v", "torque_applied", "foot_forces", "contacts"):
        assert np.array_equal(in_worker[name], alone[name]), name
