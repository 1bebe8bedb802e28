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
   the worker, return the run's files as bytes, so workers need no shared file system);
4. as each task completes, writes its folder (``<out>/<run>/``, renamed into place when complete) and
   appends its row to ``results.csv`` (flushed to disk), with a progress bar over the runs;
5. at the end writes ``comparison.json``, ``comparison.md``, ``comparison.png`` (and the experiment's own
   files), from ``results.csv`` and the run folders.

An interrupted sweep (Ctrl-C, a lost connection) keeps every finished run; the same command with
``resume=True`` (``--resume --out DIR``) skips the runs that have a row in ``results.csv`` made from the same
config (a different config for the same run is an error), re-runs the rest and writes the comparison over
all of them. The cluster, and with a ``LocalCluster`` its worker processes, is closed before the function
returns or raises.

**Timing.** Presets run with measured latency (a plan acts after its real update time), so results depend
on how much CPU each simulation gets: with one worker per core they are honest, with more workers than cores
they are not, and the sweep stops with an error unless every run uses ``mpc.latency=fixed`` (deterministic).
Every row records its timing mode. Timings (MPC iteration times) are per-worker wall clock.
"""

from __future__ import annotations

import contextlib
import csv
import hashlib
import json
import logging
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
import traceback
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from distributed import WorkerPlugin

from cafe_mpc.config import ConfigError, RunConfig, load_config
from cafe_mpc.control.realtime import MpcProcessError
from cafe_mpc.experiments.common import RunStore, markdown_table
from cafe_mpc.experiments.registry import (
    Experiment,
    Plan,
    PlanContext,
    SweepError,
    Variant,
    check_options,
    check_overrides,
    experiment_command,
    get_experiment,
    run_command,
)
from cafe_mpc.experiments.run import run
from cafe_mpc.sim.loop import ControllerError
from cafe_mpc.sim.plant import SimulationDiverged

logger = logging.getLogger(__name__)

RUN_ERRORS = (SimulationDiverged, ControllerError, MpcProcessError)
"""A run that ends in one of these is recorded with its error (status ``error``); falling is a result."""

RESULTS_FILE = "results.csv"
MANIFEST_FILE = "sweep.json"
COMPARISON_FILES = ("comparison.json", "comparison.md", "comparison.png")
SYNCHRONOUS = "synchronous"

FIXED_COLUMNS = (
    "run",
    "variant",
    "seed",
    "label",
    "group",
    "preset",
    "status",
    "error",
    "timing_mode",
    "duration_s",
    "task_wall_s",
    "worker",
    "finished",
    "config_hash",
    "run_command",
)
"""The first columns of ``results.csv``; the experiment's fields and metrics follow."""
_TEXT_COLUMNS = frozenset(FIXED_COLUMNS) - {"seed", "duration_s", "task_wall_s"}

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


def _first_line(error: BaseException) -> str:
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
                outcome.status, outcome.error = STATUS_ERROR, _first_line(error)
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
        outcome.error = _first_line(error) + (f" ({where.filename}:{where.lineno})" if where else "")
    outcome.task_wall_s = time.perf_counter() - start
    return outcome


def timing_mode(config: RunConfig) -> str:
    """``measured``, ``fixed`` or ``realtime`` for MPC runs, ``none`` for PD standing."""
    if config.wbc == "pd":
        return "none"
    return "realtime" if config.simulation.realtime else config.mpc.latency


def config_hash(config: RunConfig) -> str:
    """Short hash of a resolved config (a resumed run must have been made from the same one)."""
    text = json.dumps(config.model_dump(mode="json"), sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


# ------------------------------------------------------------------------------------------ results.csv
def _encode(column: str, value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, str):
        return value
    return json.dumps(value)


def _decode(column: str, text: str) -> Any:
    if column in _TEXT_COLUMNS:
        return text if text != "" else None
    if text == "":
        return None
    try:
        return json.loads(text)
    except ValueError:
        return text


class ResultsTable:
    """``results.csv``: one row per run, appended and flushed as each run completes.

    Columns: ``FIXED_COLUMNS``, then every other key in the order first seen. A row with a new key rewrites
    the file with the wider header (atomically: a temporary file renamed over it). Values: numbers and
    booleans as JSON (``true``, ``0.25``), lists and dicts as JSON, strings as they are, None as empty.
    """

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self.columns: list[str] = list(FIXED_COLUMNS)
        self.rows: list[dict] = []

    @classmethod
    def load(cls, path: Path) -> ResultsTable:
        table = cls(path)
        if table.path.is_file():
            with open(table.path, newline="") as handle:
                reader = csv.DictReader(handle)
                for column in reader.fieldnames or []:
                    if column not in table.columns:
                        table.columns.append(column)
                for raw in reader:
                    table.rows.append({key: _decode(key, text or "") for key, text in raw.items() if key})
        return table

    def _line(self, row: Mapping[str, Any]) -> list[str]:
        return [_encode(column, row.get(column)) for column in self.columns]

    def rewrite(self) -> None:
        """Write every row (atomically)."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        temporary = self.path.with_name(f".{self.path.name}.tmp")
        with open(temporary, "w", newline="") as handle:
            writer = csv.writer(handle)
            writer.writerow(self.columns)
            for row in self.rows:
                writer.writerow(self._line(row))
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(temporary, self.path)

    def add(self, row: Mapping[str, Any]) -> None:
        """Append one row: a plain append (flushed and synced) unless it brings a new column."""
        row = dict(row)
        self.rows.append(row)
        new = [key for key in row if key not in self.columns]
        if new or not self.path.is_file():
            self.columns += new
            self.rewrite()
            return
        with open(self.path, "a", newline="") as handle:
            csv.writer(handle).writerow(self._line(row))
            handle.flush()
            os.fsync(handle.fileno())


# ------------------------------------------------------------------------------------------ cluster
def available_cores() -> int:
    """Cores this process may run on (its CPU affinity, which containers and ``taskset`` restrict)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


class _IgnoreInterrupts(WorkerPlugin):
    """Worker plugin of the local cluster: Ctrl-C reaches the whole process group, but it is the command's
    to handle (it cancels the runs and closes the cluster); the workers ignore SIGINT instead of each
    printing a traceback."""

    name = "cafe-mpc-ignore-sigint"

    def setup(self, worker: Any) -> None:
        import signal
        import threading

        if threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGINT, signal.SIG_IGN)


def _worker_resources() -> dict:
    """Run on each remote worker: its host and the cores it may use."""
    return {"host": socket.gethostname(), "cores": available_cores()}


@dataclass
class ClusterInfo:
    kind: str  # "local", "scheduler" or "synchronous"
    workers: int
    address: str | None = None

    def describe(self) -> str:
        if self.workers == 0:
            return "every run already finished"
        if self.kind == SYNCHRONOUS:
            return "in this process, one run after the other"
        if self.kind == "local":
            return f"local Dask cluster, {self.workers} worker processes x 1 thread"
        return f"Dask scheduler {self.address}, {self.workers} workers"


def _measured_runs(configs: Mapping[str, RunConfig]) -> list[str]:
    return [name for name, config in configs.items() if timing_mode(config) == "measured"]


def _oversubscribed(workers: int, cores: int, measured: list[str], where: str) -> None:
    if workers > cores and measured:
        raise SweepError(
            f"{workers} workers on {cores} cores{where}: with measured latency (the presets' default) a "
            "run's result depends on the CPU it gets, so each worker needs its own core; use fewer workers "
            "(--workers) or --set mpc.latency=fixed (deterministic)"
        )


@contextlib.contextmanager
def open_cluster(
    scheduler: str | None, workers: int | None, configs: Mapping[str, RunConfig]
) -> Iterator[tuple[Any, ClusterInfo]]:
    """A Dask ``Client`` (None for ``scheduler="synchronous"``) and what it runs on; closes the client and
    the local cluster (its worker processes) on exit, also on errors and Ctrl-C."""
    measured = _measured_runs(configs)
    if scheduler == SYNCHRONOUS:
        if workers is not None:
            raise ConfigError("--workers does not apply to --scheduler synchronous")
        yield None, ClusterInfo(SYNCHRONOUS, 1)
        return
    from distributed import Client, LocalCluster

    if scheduler is None:
        cores = available_cores()
        count = cores if workers is None else workers
        if count < 1:
            raise ConfigError(f"--workers must be at least 1, got {count}")
        _oversubscribed(count, cores, measured, " here")
        with (
            LocalCluster(
                n_workers=count,
                threads_per_worker=1,
                processes=True,
                host="127.0.0.1",
                dashboard_address=None,
                scheduler_kwargs={"dashboard_address": "127.0.0.1:0"},  # no dashboard; health page: any port
                silence_logs=logging.ERROR,
            ) as cluster,
            Client(cluster, set_as_default=False) as client,
        ):
            client.register_plugin(_IgnoreInterrupts())
            yield client, ClusterInfo("local", count, cluster.scheduler_address)
        return
    if workers is not None:
        raise ConfigError("--workers applies to the local cluster only (a scheduler's workers are its own)")
    if not scheduler.startswith(("tcp://", "tls://", "ucx://", "inproc://")):
        raise ConfigError(f"--scheduler: expected tcp://HOST:PORT or synchronous, got {scheduler!r}")
    try:
        client = Client(scheduler, timeout="15s", set_as_default=False)
    except (OSError, TimeoutError) as error:
        raise SweepError(f"cannot reach the Dask scheduler at {scheduler}: {error}") from error
    with client:
        try:
            client.wait_for_workers(1, timeout=60)
        except TimeoutError as error:
            raise SweepError(
                f"the Dask scheduler at {scheduler} has no workers (start: dask worker)"
            ) from error
        info = client.scheduler_info(n_workers=-1)["workers"]
        for address, worker in info.items():
            if worker.get("nthreads", 1) != 1:
                raise SweepError(
                    f"worker {address} has {worker['nthreads']} threads; start workers with "
                    "dask worker --nthreads 1 (one simulation per process)"
                )
        resources = client.run(_worker_resources)
        per_host: dict[str, list[int]] = {}
        for address in info:
            item = resources.get(address)
            if item is not None:
                per_host.setdefault(item["host"], []).append(item["cores"])
        for host, cores in per_host.items():
            _oversubscribed(len(cores), max(cores), measured, f" of host {host}")
        yield client, ClusterInfo("scheduler", len(info), scheduler)


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


def _git_state() -> dict | None:
    """Commit and dirty flag of the source tree (None outside a git checkout)."""
    root = Path(__file__).resolve().parent
    try:
        commit = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True, timeout=5, check=True
        ).stdout.strip()
        status = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=root,
            capture_output=True,
            text=True,
            timeout=5,
            check=True,
        ).stdout
    except (OSError, subprocess.SubprocessError):
        return None
    return {"commit": commit, "dirty": bool(status.strip())}


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
    plan: Plan
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
    chosen = check_options(experiment, options)
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
        configs[variant.name] = load_config(variant.preset, [*base, *extra, *variant.overrides])
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
    comparison = _write_comparison(prepared, rows, out_dir, cluster)
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

    try:
        if client is None:
            for task in tasks.values():
                record(execute_task(task))
            return
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
                    outcome = RunOutcome(name, STATUS_CRASHED, error=_first_line(error))
                future.release()
                record(outcome)
        except BaseException:
            client.cancel(list(futures))
            raise
    except KeyboardInterrupt:
        bar.close()
        say(
            f"interrupted: {done} of {total} runs finished in {out_dir}; continue with the same command and "
            f"--resume --out {out_dir}"
        )
        raise
    finally:
        bar.close()


def _outcome_text(row: dict) -> str:
    if row["status"] != STATUS_OK:
        return f"{row['status']}: {row['error']}"
    text = "fell" if row.get("fell") else "ok"
    if row.get("fell") and row.get("fall_time_s") is not None:
        text += f" at {row['fall_time_s']:.2f} s"
    if row.get("success") is not None:
        text = ("success" if row["success"] else "failure") + f" ({text})"
    return text + f", {row['task_wall_s']:.1f} s on {row['worker']}"


def _write_comparison(prepared: _Prepared, rows: list[dict], out_dir: Path, cluster: ClusterInfo) -> dict:
    experiment = prepared.experiment
    modes = sorted({str(row.get("timing_mode")) for row in rows if row.get("timing_mode")})
    comparison: dict = {
        "experiment": experiment.name,
        "title": experiment.title,
        "paper": experiment.paper,
        "command": prepared.command,
        "duration_s": prepared.duration,
        "overrides": prepared.overrides,
        "options": prepared.plan.options,
        "out_dir": str(out_dir),
        "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "git": _git_state(),
        "cluster": cluster.describe(),
        "timing_modes": modes,
        "results_csv": RESULTS_FILE,
        "variants": {row["run"]: {"folder": row["run"], **row} for row in rows},
        "errors": {row["run"]: row["error"] for row in rows if row.get("status") != STATUS_OK},
    }
    comparison.update(experiment.outputs(rows, comparison, out_dir))
    with open(out_dir / "comparison.json", "w") as handle:
        json.dump(comparison, handle, indent=2)
    (out_dir / "comparison.md").write_text(comparison_markdown(experiment, rows, comparison))
    plot_path = out_dir / "comparison.png"
    plot_path.unlink(missing_ok=True)
    experiment.plot(rows, RunStore(out_dir), plot_path)
    if not plot_path.exists():  # nothing to draw: an explicit empty figure, not a missing file
        from cafe_mpc.report.figures import save_figure, subplots

        figure, axis = subplots(figsize=(6, 2))
        axis.text(0.5, 0.5, "no run produced a log to plot", ha="center", va="center")
        axis.set_axis_off()
        save_figure(figure, plot_path)
    return comparison


def comparison_markdown(experiment: Experiment, rows: list[dict], comparison: dict) -> str:
    """``comparison.md``: a title line with the command, the table, and what the columns mean."""
    duration = comparison["duration_s"]
    simulated = f"{duration:g} s simulated" if duration is not None else "each preset's duration"
    lines = [
        f"**{comparison['title']}** ({comparison['paper']}; {simulated}; timing: "
        f"{', '.join(comparison['timing_modes']) or 'n/a'})",
        "",
        f"Command: `{comparison['command']}`",
        "",
        *experiment.markdown_intro(rows, comparison),
    ]
    header, table_rows, notes = experiment.table(rows, comparison)
    lines += markdown_table(header, table_rows)
    lines += ["", *notes, ""]
    return "\n".join(lines)
