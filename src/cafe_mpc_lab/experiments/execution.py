"""One run of an experiment, as a Dask task: what the worker gets (``RunTask``), what it returns
(``RunOutcome``: status, the experiment's summary row, the run's files as bytes, so that workers need no
shared file system) and the task itself (``execute_task``)."""

from __future__ import annotations

import hashlib
import json
import os
import socket
import tempfile
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path

from cafe_mpc.assembly.controllers import runs_alone
from cafe_mpc.config import RunConfig
from cafe_mpc.control.process import MpcProcessError
from cafe_mpc_lab.experiments.catalog import get_experiment
from cafe_mpc_lab.experiments.registry import Variant
from cafe_mpc_lab.experiments.run import run
from cafe_mpc_lab.sim.loop import ControllerError
from cafe_mpc_lab.sim.plant import SimulationDiverged

RUN_ERRORS = (SimulationDiverged, ControllerError, MpcProcessError)
"""A run that ends in one of these is recorded with its error (status ``error``); falling is a result."""


STATUS_OK, STATUS_ERROR, STATUS_CRASHED = "ok", "error", "crashed"
"""ok: the run finished (fell or not); error: it ended in a simulator or controller error (a result);
crashed: the task itself failed (a bug, a worker that died): not finished, ``--resume`` runs it again."""


# ------------------------------------------------------------------------------------------ the task
@dataclass(frozen=True)
class RunTask:
    """What a worker needs for one run: plain, picklable data."""

    experiment: str
    variant: Variant
    config: dict
    drop_files: tuple[str, ...] = ()


@dataclass
class RunOutcome:
    run: str
    status: str
    error: str | None = None
    row: dict = field(default_factory=dict)
    files: dict[str, bytes] = field(default_factory=dict)
    task_wall_s: float = 0.0
    worker: str = ""
    timing_mode: str | None = None


def first_line(error: BaseException) -> str:
    return f"{type(error).__name__}: {error}".splitlines()[0]


def execute_task(task: RunTask) -> RunOutcome:
    """Run one task (in a worker): simulate into a private temporary folder, summarise, return the files.

    Never raises for a run's own failure: simulator and controller errors give status ``error``, anything
    else (a bug) status ``crashed`` with the last traceback line.
    """
    start = time.perf_counter()
    worker = f"{socket.gethostname()}:{os.getpid()}"
    outcome = RunOutcome(task.variant.name, STATUS_CRASHED, worker=worker)
    try:
        experiment = get_experiment(task.experiment)
        config = RunConfig.model_validate(task.config)
        outcome.timing_mode = timing_mode(config)
        with tempfile.TemporaryDirectory(prefix="cafe-mpc-run-") as scratch:
            folder = Path(scratch) / "run"
            try:
                result = run(config, folder)
            except RUN_ERRORS as error:
                outcome.status, outcome.error = STATUS_ERROR, first_line(error)
            else:
                outcome.row = experiment.summarize(result, task.variant)
                outcome.timing_mode = (result.metrics.get("timing") or {}).get("mode") or outcome.timing_mode
                outcome.files = {
                    path.name: path.read_bytes()
                    for path in sorted(folder.iterdir())
                    if path.is_file() and path.name not in task.drop_files
                }
                outcome.status = STATUS_OK
    except Exception as error:  # a bug in a run or a summary: reported, and --resume runs it again
        outcome.status = STATUS_CRASHED
        where = traceback.extract_tb(error.__traceback__)[-1] if error.__traceback__ else None
        outcome.error = first_line(error) + (f" ({where.filename}:{where.lineno})" if where else "")
    outcome.task_wall_s = time.perf_counter() - start
    return outcome


def timing_mode(config: RunConfig) -> str:
    """``measured``, ``fixed`` or ``realtime`` for MPC runs, ``none`` for PD standing."""
    if runs_alone(config):
        return "none"
    return "realtime" if config.simulation.realtime else config.mpc.latency


def config_hash(config: RunConfig) -> str:
    """Short hash of a resolved config (a resumed run must have been made from the same one)."""
    text = json.dumps(config.model_dump(mode="json"), sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16]
