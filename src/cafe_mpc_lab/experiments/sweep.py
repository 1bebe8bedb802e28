"""Running an experiment: one Dask task per run, each result written as it completes, resumable.

``run_experiment(name, ...)`` (``cafe-mpc experiment NAME``):

1. builds the experiment's runs (``registry``) and validates every config before anything starts or is
   written (a bad option or ``--set`` is one ``ConfigError``);
2. starts the cluster: by default a ``distributed.LocalCluster`` with one worker process per core and one
   thread per worker (``workers`` changes the count), or connects to a running scheduler
   (``scheduler="tcp://HOST:PORT"``, a cluster started with ``dask scheduler`` and ``dask worker
   --nthreads 1``); ``scheduler="synchronous"`` runs everything in this process, one run after the other
   (debugging, profiling);
3. submits one task per run (``execute_task``: simulate, compute the metrics and the experiment's summary in
   the worker, return the run's files as bytes, so workers need no shared file system); real-time runs
   (``simulation.realtime``: an experiment's variant may ask for one) run in this process instead, one after
   the other once the others are done: each needs the machine to itself, and a worker may not start the
   MPC process;
4. as each task completes, writes its folder (``<out>/<run>/``, renamed into place when complete) and
   appends its row to ``results.csv`` (flushed to disk), with a progress bar over the runs;
5. at the end writes ``comparison.json``, ``comparison.md``, ``comparison.png`` (and the experiment's own
   files), from ``results.csv`` and the run folders.

An interrupted sweep (Ctrl-C, a lost connection) keeps every finished run; the same command with
``resume=True`` (``--resume --out DIR``) skips the runs that have a row in ``results.csv`` made from the same
config (a different config for the same run is an error), re-runs the rest and writes the comparison over
all of them. The cluster, and with a ``LocalCluster`` its worker processes, is closed before the function
returns or raises.

The pieces: ``execution`` (the task a worker runs), ``results_table`` (``results.csv``), ``cluster`` (where
the tasks run) and ``comparison`` (the comparison files).

**Timing.** Presets run with measured latency (a plan acts after its real update time), so results depend
on how much CPU each simulation gets: with one worker per core they are honest, with more workers than cores
they are not, and the sweep stops with an error unless every run uses ``mpc.latency=fixed`` (deterministic).
Every row records its timing mode. Timings (MPC iteration times) are per-worker wall clock.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import shutil
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cafe_mpc.assembly.checks import load_run_config
from cafe_mpc.config import ConfigError, RunConfig
from cafe_mpc_lab.experiments.catalog import get_experiment
from cafe_mpc_lab.experiments.cluster import ClusterInfo, open_cluster
from cafe_mpc_lab.experiments.comparison import write_comparison
from cafe_mpc_lab.experiments.execution import (
    STATUS_CRASHED,
    STATUS_ERROR,
    STATUS_OK,
    RunOutcome,
    RunTask,
    config_hash,
    execute_task,
    first_line,
)
from cafe_mpc_lab.experiments.registry import (
    Experiment,
    ExperimentPlan,
    PlanContext,
    SweepError,
    Variant,
    check_overrides,
    experiment_command,
    run_command,
)
from cafe_mpc_lab.experiments.results_table import RESULTS_FILE, ResultsTable

logger = logging.getLogger(__name__)


MANIFEST_FILE = "sweep.json"


# ------------------------------------------------------------------------------------------ the sweep
@dataclass
class SweepResult:
    name: str
    out_dir: Path
    comparison: dict
    rows: list[dict]
    errors: dict[str, str] = field(default_factory=dict)
    skipped: int = 0
    """Runs found finished in the folder (``resume``)."""

    @property
    def failed(self) -> bool:
        return bool(self.errors)


def default_experiment_dir(name: str, root: Path = Path("runs")) -> Path:
    return root / f"{time.strftime('%Y%m%d-%H%M%S')}-experiment-{name}"


def _write_run_folder(out_dir: Path, run: str, files: Mapping[str, bytes]) -> None:
    """The run's folder, complete or not at all (written aside, then renamed)."""
    target = out_dir / run
    partial = out_dir / f".{run}.partial"
    shutil.rmtree(partial, ignore_errors=True)
    partial.mkdir(parents=True)
    for name, content in files.items():
        (partial / name).write_bytes(content)
    if target.exists():
        shutil.rmtree(target)
    partial.rename(target)


@dataclass
class _Prepared:
    experiment: Experiment
    plan: ExperimentPlan
    duration: float | None
    overrides: list[str]
    configs: dict[str, RunConfig]
    hashes: dict[str, str]
    command: str
    base_overrides: list[str]


def prepare(
    name: str, duration: float | None, overrides: Sequence[str], options: Mapping[str, Any]
) -> _Prepared:
    """Plan and validate every run of an experiment (nothing is started or written)."""
    experiment = get_experiment(name)
    chosen = experiment.options_from(options)
    overrides = list(overrides)
    check_overrides(experiment, overrides)
    if duration is None:
        duration = experiment.default_duration
    base = [*experiment.default_overrides, *overrides]
    plan = experiment.plan(chosen, PlanContext(duration, tuple(base)))
    if not plan.variants:
        raise ConfigError(f"experiment {name!r}: no runs to make")
    extra = [f"simulation.duration={duration}"] if duration is not None else []
    configs: dict[str, RunConfig] = {}
    for variant in plan.variants:
        if variant.name in configs:
            raise ConfigError(f"experiment {name!r}: two runs named {variant.name!r}")
        configs[variant.name] = load_run_config(variant.preset, [*base, *extra, *variant.overrides])
        if experiment.needs_gait and configs[variant.name].gait is None:
            raise ConfigError(f"experiment {name!r}: preset {variant.preset!r} has no gait to run")
    hashes = {run: config_hash(config) for run, config in configs.items()}
    command = experiment_command(name, duration, overrides, plan.options)
    return _Prepared(experiment, plan, duration, overrides, configs, hashes, command, base)


def _finished_runs(out_dir: Path, prepared: _Prepared, table: ResultsTable) -> dict[str, dict]:
    """Rows of runs already done in ``out_dir`` (status ok with their folder, or error); drops the rows of
    runs that must run again from ``results.csv``."""
    finished: dict[str, dict] = {}
    for row in table.rows:
        run_name = str(row.get("run"))
        if run_name not in prepared.hashes:
            continue  # a run of a wider earlier sweep (more trials): its row stays, it is not reported
        if row.get("status") == STATUS_OK and not (out_dir / run_name).is_dir():
            continue
        if row.get("status") not in (STATUS_OK, STATUS_ERROR):
            continue
        if row.get("config_hash") != prepared.hashes[run_name]:
            raise SweepError(
                f"run {run_name!r} in {out_dir} was made from a different config than this command gives "
                "(other options, --set or --duration); resume with the original command or use a new --out"
            )
        finished[run_name] = row
    kept = [
        row for row in table.rows if row.get("run") not in prepared.hashes or finished.get(row["run"]) is row
    ]
    if len(kept) != len(table.rows):
        table.rows = kept
        table.rewrite()
    return finished


def run_experiment(
    name: str,
    out_dir: Path | str | None = None,
    duration: float | None = None,
    overrides: Sequence[str] = (),
    *,
    scheduler: str | None = None,
    workers: int | None = None,
    resume: bool = False,
    show_progress: bool = False,
    echo: Callable[[str], None] | None = None,
    **options: Any,
) -> SweepResult:
    """Run every run of experiment ``name`` on Dask into ``out_dir`` and write the comparison (module
    docstring). ``options`` are the experiment's own (``schedules="S0,S4"``, ``trials=10``, ...).

    Raises ``ConfigError`` for bad options or overrides (before anything starts), ``FileExistsError`` for
    a used folder without ``resume``, ``SweepError`` for a cluster that cannot run the sweep, and
    ``KeyboardInterrupt`` when interrupted (the finished runs stay).
    """
    prepared = prepare(name, duration, overrides, options)
    experiment, plan = prepared.experiment, prepared.plan
    if resume and out_dir is None:
        raise ConfigError("--resume needs --out: the folder of the sweep to continue")
    out_dir = Path(out_dir) if out_dir is not None else default_experiment_dir(name)
    manifest_path = out_dir / MANIFEST_FILE
    finished: dict[str, dict] = {}
    table = ResultsTable(out_dir / RESULTS_FILE)
    if out_dir.exists() and any(out_dir.iterdir()):
        if not resume:
            raise FileExistsError(
                f"output folder {out_dir} exists and is not empty; choose another --out (or --resume)"
            )
        if not manifest_path.is_file():
            raise SweepError(f"{out_dir} holds no sweep ({MANIFEST_FILE} missing); nothing to resume")
        stored = json.loads(manifest_path.read_text())
        if stored.get("experiment") != name:
            raise SweepError(
                f"{out_dir} holds a sweep of experiment {stored.get('experiment')!r}, not {name!r}"
            )
        table = ResultsTable.load(out_dir / RESULTS_FILE)
        finished = _finished_runs(out_dir, prepared, table)
    pending = [v for v in plan.variants if v.name not in finished]
    say = echo or (lambda _line: None)

    cluster_context = (
        open_cluster(scheduler, workers, prepared.configs)
        if pending
        else contextlib.nullcontext((None, ClusterInfo("nothing to run", 0)))
    )
    with cluster_context as (client, cluster):
        out_dir.mkdir(parents=True, exist_ok=True)
        for leftover in out_dir.glob(".*.partial"):
            shutil.rmtree(leftover, ignore_errors=True)
        manifest = {
            "experiment": name,
            "command": prepared.command,
            "options": plan.options,
            "duration_s": prepared.duration,
            "overrides": prepared.overrides,
            "runs": prepared.hashes,
            "cluster": cluster.describe(),
            "updated": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        }
        manifest_path.write_text(json.dumps(manifest, indent=2))
        say(
            f"{name}: {len(plan.variants)} runs"
            + (f" ({len(finished)} already finished in {out_dir})" if finished else "")
            + f"; {cluster.describe()}"
        )
        latest = dict(finished)
        _run_pending(client, prepared, pending, table, out_dir, latest, show_progress, say)

    rows = [latest[variant.name] for variant in plan.variants]
    comparison = write_comparison(prepared, rows, out_dir, cluster)
    failed = (STATUS_CRASHED,) if experiment.errors_are_results else (STATUS_CRASHED, STATUS_ERROR)
    errors = {row["run"]: row["error"] for row in rows if row["status"] in failed}
    return SweepResult(name, out_dir, comparison, rows, errors, len(finished))


def _run_pending(
    client: Any,
    prepared: _Prepared,
    pending: list[Variant],
    table: ResultsTable,
    out_dir: Path,
    latest: dict[str, dict],
    show_progress: bool,
    say: Callable[[str], None],
) -> None:
    """Submit every pending run, write each result as it completes (progress bar over all runs); ``latest``
    receives every run's row."""
    from tqdm import tqdm

    total = len(prepared.plan.variants)
    bar = tqdm(
        total=total,
        initial=total - len(pending),
        unit="run",
        disable=None if show_progress else True,  # None: only on a terminal
        file=sys.stderr,
        dynamic_ncols=True,
    )
    write = say if bar.disable else bar.write
    tasks = {
        v.name: RunTask(
            prepared.experiment.name,
            v,
            prepared.configs[v.name].model_dump(mode="json"),
            prepared.plan.drop_files,
        )
        for v in pending
    }
    variants = {v.name: v for v in pending}
    done = total - len(pending)

    def record(outcome: RunOutcome) -> None:
        nonlocal done
        variant = variants[outcome.run]
        if outcome.status == STATUS_OK:
            _write_run_folder(out_dir, outcome.run, outcome.files)
        row = {
            "run": variant.name,
            "variant": variant.variant_name,
            "seed": variant.seed,
            "label": variant.label,
            "group": variant.group,
            "preset": variant.preset,
            "status": outcome.status,
            "error": outcome.error,
            "timing_mode": outcome.timing_mode,
            "duration_s": prepared.configs[variant.name].simulation.duration,
            "task_wall_s": round(outcome.task_wall_s, 3),
            "worker": outcome.worker,
            "finished": time.strftime("%Y-%m-%dT%H:%M:%S"),
            "config_hash": prepared.hashes[variant.name],
            "run_command": run_command(variant, prepared.duration, prepared.base_overrides),
            **dict(variant.fields),
            **outcome.row,
        }
        table.add(row)
        latest[variant.name] = row
        done += 1
        write(f"[{done}/{total}] {prepared.experiment.name}: {variant.name}: {_outcome_text(row)}")
        bar.update(1)

    # real-time runs (the MPC in its own process, against the wall clock) run here, one after the other once
    # the others are done: each needs the machine to itself, and a Dask worker may not start processes
    here = [name for name in tasks if client is None or prepared.configs[name].simulation.realtime]
    try:
        if client is not None:
            _run_on_cluster(client, {name: task for name, task in tasks.items() if name not in here}, record)
        for name in here:
            record(execute_task(tasks[name]))
    except KeyboardInterrupt:
        bar.close()
        say(
            f"interrupted: {done} of {total} runs finished in {out_dir}; continue with the same command and "
            f"--resume --out {out_dir}"
        )
        raise
    finally:
        bar.close()


def _run_on_cluster(client: Any, tasks: dict[str, RunTask], record: Callable[[RunOutcome], None]) -> None:
    """Submit ``tasks`` to the Dask cluster and ``record`` each outcome as it completes."""
    if tasks:
        from distributed import as_completed

        futures = {
            client.submit(execute_task, task, key=f"cafe-mpc-{name}-{os.urandom(4).hex()}", pure=False): name
            for name, task in tasks.items()
        }
        try:
            for future in as_completed(futures, loop=client.loop):
                name = futures[future]
                try:
                    outcome = future.result()
                except Exception as error:  # the worker died (KilledWorker), the task was lost
                    outcome = RunOutcome(name, STATUS_CRASHED, error=first_line(error))
                future.release()
                record(outcome)
        except BaseException:
            client.cancel(list(futures))
            raise


def _outcome_text(row: dict) -> str:
    if row["status"] != STATUS_OK:
        return f"{row['status']}: {row['error']}"
    text = "fell" if row.get("fell") else "ok"
    if row.get("fell") and row.get("fall_time_s") is not None:
        text += f" at {row['fall_time_s']:.2f} s"
    if row.get("success") is not None:
        text = ("success" if row["success"] else "failure") + f" ({text})"
    return text + f", {row['task_wall_s']:.1f} s on {row['worker']}"
