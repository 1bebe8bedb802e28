"""Where an experiment's runs execute: a local Dask cluster (one single-threaded worker process per core), a
running Dask scheduler, or this process (``SYNCHRONOUS``); and the check that measured-latency runs get a core
each (``open_cluster``)."""

from __future__ import annotations

import contextlib
import logging
import os
import socket
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from typing import Any

from distributed import WorkerPlugin

from cafe_mpc.config import ConfigError, RunConfig
from cafe_mpc_lab.experiments.execution import timing_mode
from cafe_mpc_lab.experiments.registry import SweepError

SYNCHRONOUS = "synchronous"


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
