"""Experiments on Dask: a local cluster with two worker processes runs short (0.2 s) runs, results.csv grows
one row per completed run, an interrupted sweep keeps its finished runs and ``--resume`` skips them, the
cluster's processes are gone afterwards (also after an error), and a running scheduler (``dask scheduler``
+ ``dask worker``, on the loopback address) is used and left running.

Fixed latency in these runs: two workers share the two cores of a CI machine with the test process.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import psutil
import pytest

from cafe_mpc_lab.cli import main
from cafe_mpc_lab.experiments import sweep
from cafe_mpc_lab.experiments.cluster import available_cores
from cafe_mpc_lab.experiments.registry import SweepError
from cafe_mpc_lab.experiments.results_table import RESULTS_FILE, ResultsTable
from cafe_mpc_lab.experiments.sweep import run_experiment

FAST = ["output.plots=false", "mpc.latency=fixed"]
SCHEDULES = {"schedules": "S0,S1,S2", "srb_dts": "0.05"}
RUNS = ["S0-dt0.05", "S1-dt0.05", "S2-dt0.05"]


def children() -> list[psutil.Process]:
    """Our child processes, except multiprocessing's resource tracker (it lives as long as this process)."""
    found = []
    for process in psutil.Process().children(recursive=True):
        try:
            if process.is_running() and "resource_tracker" not in " ".join(process.cmdline()):
                found.append(process)
        except psutil.NoSuchProcess:
            pass
    return found


def wait_for_no_children(timeout: float = 10.0) -> list[psutil.Process]:
    """Worker processes end shortly after the cluster closes; give them a moment, then report the rest."""
    deadline = time.monotonic() + timeout
    while children() and time.monotonic() < deadline:
        time.sleep(0.1)
    return children()


@pytest.mark.slow
def test_local_cluster_sweep_writes_each_result_as_it_completes_and_resumes(tmp_path):
    before = {p.pid for p in children()}
    out = tmp_path / "sweep"
    seen_rows: list[int] = []

    def interrupt_after_first(line: str) -> None:
        if line.startswith("[1/3]"):
            seen_rows.append(len(ResultsTable.load(out / RESULTS_FILE).rows))
            raise KeyboardInterrupt  # Ctrl-C after the first run completed

    with pytest.raises(KeyboardInterrupt):
        run_experiment("schedules", out, 0.2, FAST, workers=2, echo=interrupt_after_first, **SCHEDULES)
    assert seen_rows == [1]  # the row was on disk when the run was reported
    assert {p.pid for p in wait_for_no_children()} <= before  # the two workers are gone, also on error
    first = ResultsTable.load(out / RESULTS_FILE).rows
    assert len(first) == 1 and first[0]["status"] == "ok"
    done = first[0]["run"]
    assert (out / done / "metrics.json").is_file() and not (out / "comparison.json").exists()
    stamp = (out / done / "metrics.json").stat().st_mtime_ns

    lines: list[str] = []
    result = run_experiment(
        "schedules", out, 0.2, FAST, workers=2, resume=True, echo=lines.append, **SCHEDULES
    )
    assert result.skipped == 1 and not result.errors
    assert "(1 already finished" in lines[0] and "2 worker processes" in lines[0]
    assert sum(line.startswith("[") for line in lines) == 2  # only the two runs not finished before
    assert (out / done / "metrics.json").stat().st_mtime_ns == stamp  # the finished run was not redone
    rows = ResultsTable.load(out / RESULTS_FILE).rows
    assert sorted(row["run"] for row in rows) == RUNS and rows[0] == first[0]
    for row in rows:
        assert row["timing_mode"] == "fixed" and row["seed"] is None and row["variant"] == row["run"]
        assert row["worker"] and row["config_hash"] and isinstance(row["pitch_rms"], float)
    workers = {row["worker"] for row in rows[1:]}
    assert len(workers) >= 1 and all(w.split(":")[1] != str(os.getpid()) for w in workers)
    comparison = json.loads((out / "comparison.json").read_text())
    assert list(comparison["variants"]) == RUNS and comparison["timing_modes"] == ["fixed"]
    assert "local Dask cluster, 2 worker processes" in comparison["cluster"]
    assert {p.pid for p in wait_for_no_children()} <= before

    # everything finished: resuming again runs nothing; a different config for the same runs is refused
    again = run_experiment("schedules", out, 0.2, FAST, scheduler="synchronous", resume=True, **SCHEDULES)
    assert again.skipped == 3
    with pytest.raises(SweepError, match="different config"):
        run_experiment("schedules", out, 0.3, FAST, scheduler="synchronous", resume=True, **SCHEDULES)
    with pytest.raises(SweepError, match="holds a sweep of experiment 'schedules', not 'push'"):
        run_experiment("push", out, 0.2, FAST, scheduler="synchronous", resume=True)


@pytest.mark.slow
def test_the_command_leaves_no_worker_processes_behind_after_an_error(tmp_path, capsys, monkeypatch):
    before = {p.pid for p in children()}

    def broken(row: dict) -> str:  # the client fails while reporting the first result
        raise KeyboardInterrupt

    monkeypatch.setattr(sweep, "_outcome_text", broken)
    out = tmp_path / "push"
    argv = ["experiment", "push", "--duration", "0.2", "--out", str(out), "--workers", "2"]
    assert main([*argv, *[item for s in FAST for item in ("--set", s)]]) == 130
    assert "cafe-mpc: interrupted" in capsys.readouterr().err
    assert {p.pid for p in wait_for_no_children()} <= before
    assert len(ResultsTable.load(out / RESULTS_FILE).rows) == 1


def test_more_workers_than_cores_need_fixed_latency(tmp_path):
    too_many = available_cores() + 1
    with pytest.raises(SweepError, match=r"workers on \d+ cores here: with measured latency"):
        run_experiment("push", tmp_path / "a", 0.2, ["output.plots=false"], workers=too_many)
    assert not (tmp_path / "a").exists()


def test_a_worker_with_several_threads_is_refused(tmp_path):
    from distributed import LocalCluster

    with (
        LocalCluster(n_workers=1, threads_per_worker=2, processes=False, dashboard_address=None) as cluster,
        pytest.raises(SweepError, match="start workers with dask worker --nthreads 1"),
    ):
        run_experiment("push", tmp_path / "b", 0.2, FAST, scheduler=cluster.scheduler_address)


@pytest.mark.slow
def test_a_running_dask_cluster_is_used_and_left_running(tmp_path):
    """``dask scheduler`` and ``dask worker`` as the README starts them (here on 127.0.0.1 only)."""
    dask = Path(sys.executable).with_name("dask")
    scheduler_file = tmp_path / "scheduler.json"
    common = {"stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL}
    scheduler = subprocess.Popen(
        [
            dask,
            "scheduler",
            "--host",
            "127.0.0.1",
            "--port",
            "0",
            "--no-dashboard",
            "--scheduler-file",
            scheduler_file,
        ],
        **common,
    )
    worker = None
    try:
        deadline = time.monotonic() + 60
        while not scheduler_file.is_file() and time.monotonic() < deadline:
            time.sleep(0.2)
        address = json.loads(scheduler_file.read_text())["address"]
        worker = subprocess.Popen(
            [dask, "worker", address, "--nthreads", "1", "--nworkers", "1", "--no-dashboard"], **common
        )
        out = tmp_path / "remote"
        result = run_experiment("push", out, 0.2, FAST, scheduler=address)
        assert not result.errors
        assert f"Dask scheduler {address}, 1 workers" in result.comparison["cluster"]
        assert len(ResultsTable.load(out / RESULTS_FILE).rows) == 2
        assert scheduler.poll() is None and worker.poll() is None  # not ours to stop
    finally:
        for process in (worker, scheduler):
            if process is not None:
                process.terminate()
        for process in (worker, scheduler):
            if process is not None:
                try:
                    process.wait(timeout=20)
                except subprocess.TimeoutExpired:
                    process.kill()
                    process.wait()
