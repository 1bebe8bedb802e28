"""Pieces the experiments share: summary fields of a run, MPC timing per iteration, table formatting,
plot colours, and finished runs read back from their folders (for the plots, also after ``--resume``)."""

from __future__ import annotations

import functools
import json
from collections.abc import Sequence
from pathlib import Path

import matplotlib
import numpy as np
import yaml

from cafe_mpc.config import RunConfig
from cafe_mpc.robots.robot import Robot, load_robot
from cafe_mpc_lab.experiments.controllers import mpc_statistics_of
from cafe_mpc_lab.experiments.options import names
from cafe_mpc_lab.experiments.run import RunResult
from cafe_mpc_lab.sim.loop import SimulationLog

PUSH_SETTLE_S = 0.5  # "vx after the push" is measured from this long after the push ends

SPEED_TOLERANCE = 0.1
"""m/s: a gait run tracks its command when its steady-state mean forward speed (``metrics.json``'s
``steady_state.vx_mean``, from 0.5 s) is this close to the commanded one (the issues' "within 0.1 m/s")."""


# ------------------------------------------------------------------------------------------ summaries
def fall_fields(metrics: dict) -> dict:
    """Whether and when the run fell, and how long it ran (simulated)."""
    return {
        "fell": metrics["fell"],
        "fall_time_s": metrics["fall_time_s"],
        "sim_time_s": metrics["sim_time_s"],
    }


def iteration_timing(result: RunResult) -> dict:
    """MS-iLQR time per iteration and line-search steps per MPC update, as the paper's Fig. 7 and Table II
    average them ("averaged over all MPC control ticks"): the first (cold) solve, which runs before the clock
    starts, is left out. Wall clock of the process that ran the simulation."""
    statistics = mpc_statistics_of(result.controller) if result.controller is not None else None
    empty = {
        "iteration_ms_mean": None,
        "iteration_ms_median": None,
        "iteration_ms_p99": None,
        "iterations_per_update": None,
        "line_search_steps_per_update": None,
        "mpc_updates": 0,
    }
    if statistics is None or statistics.solves == 0:
        return empty
    cold = statistics.iterations[0] if statistics.solves > 1 else 0
    times = np.asarray(statistics.iteration_times[cold:]) * 1e3
    skip = 1 if statistics.solves > 1 else 0
    steps = statistics.line_search_steps[skip:]
    iterations = statistics.iterations[skip:]
    return {
        "iteration_ms_mean": float(np.mean(times)) if times.size else None,
        "iteration_ms_median": float(np.median(times)) if times.size else None,
        "iteration_ms_p99": float(np.percentile(times, 99)) if times.size else None,
        "iterations_per_update": float(np.mean(iterations)) if iterations else None,
        "line_search_steps_per_update": float(np.mean(steps)) if steps else None,
        "mpc_updates": int(statistics.solves - skip),
    }


def gait_presets() -> list[str]:
    """The presets that run a gait (the ones ``--gaits`` may name)."""
    from cafe_mpc.config import available_presets, load_config

    return [name for name in available_presets() if load_config(name).gait is not None]


def paper_schedules() -> list[str]:
    """The model schedules the library knows (``planners.cafe.problem.PAPER_SCHEDULES``: Table I)."""
    from cafe_mpc.planners.cafe.problem import PAPER_SCHEDULES

    return list(PAPER_SCHEDULES)


GaitPresetNames = names(gait_presets)
"""A list option of gait presets (presets with a gait section)."""
ScheduleNames = names(paper_schedules)
"""A list option of model schedule names."""


# ------------------------------------------------------------------------------------------ markdown
def num(value: float | None, digits: int = 3) -> str:
    return "n/a" if value is None else f"{value:.{digits}f}"


def pct(value: float | None) -> str:
    return "n/a" if value is None else f"{100.0 * value:.1f} %"


def integer(value: int | None) -> str:
    return "n/a" if value is None else str(value)


def fell_text(row: dict) -> str:
    """``no``, ``yes, at 1.20 s`` or the run's error."""
    if row.get("error"):
        return f"{row.get('status', 'error')}: {row['error']}"
    if row.get("fell") is None:
        return "n/a"
    if row["fell"]:
        return f"yes, at {row['fall_time_s']:.2f} s" if row.get("fall_time_s") is not None else "yes"
    return "no"


def markdown_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return lines


WALL_CLOCK_NOTE = (
    "Timings are wall clock of the worker process that ran each simulation (one Dask worker per core, one "
    "thread each); with other jobs on the machine, or more workers than cores, they grow."
)


# ------------------------------------------------------------------------------------------ plots
def colors(n: int) -> list:
    cycle = matplotlib.rcParams["axes.prop_cycle"].by_key()["color"]
    return [cycle[i % len(cycle)] for i in range(n)]


def window_mask(times: np.ndarray, window: tuple[float, float] | None) -> np.ndarray:
    if window is None:
        return np.ones(len(times), dtype=bool)
    return (times >= window[0] - 1e-9) & (times <= window[1] + 1e-9)


# ------------------------------------------------------------------------------------------ stored runs
def load_log(path: Path, metrics: dict | None = None) -> SimulationLog:
    """A ``SimulationLog`` from a run's ``log.npz`` (fall and wall time from its ``metrics.json``)."""
    with np.load(path, allow_pickle=False) as archive:
        arrays = {name: archive[name] for name in archive.files}
    metrics = metrics or {}
    log = SimulationLog(
        time=arrays["time"],
        q=arrays["q"],
        v=arrays["v"],
        torque_command=arrays["torque_command"],
        torque_applied=arrays["torque_applied"],
        foot_forces=arrays["foot_forces"],
        contacts=arrays["contacts"],
        external_force=arrays["external_force"],
        ticks=len(arrays["time"]),
        fell=bool(metrics.get("fell", False)),
        fall_time=metrics.get("fall_time_s"),
        fall_reason=metrics.get("fall_reason") or "",
        wall_time=float(metrics.get("wall_time_s") or 0.0),
    )
    log.extra = {name[len("extra_") :]: value for name, value in arrays.items() if name.startswith("extra_")}
    return log


@functools.lru_cache(maxsize=4)
def _robot(name: str) -> Robot:
    return load_robot(name)


class RunStore:
    """The finished runs of an experiment folder, read back on demand as ``RunResult`` (no controller)."""

    def __init__(self, out_dir: Path) -> None:
        self.out_dir = Path(out_dir)

    def load(self, run: str) -> RunResult | None:
        """The run in folder ``run`` (None when it has no log: an error, or logs not kept)."""
        folder = self.out_dir / run
        if not (folder / "log.npz").is_file() or not (folder / "config.yaml").is_file():
            return None
        with open(folder / "config.yaml") as handle:
            config = RunConfig.model_validate(yaml.safe_load(handle))
        metrics = json.loads((folder / "metrics.json").read_text())
        log = load_log(folder / "log.npz", metrics)
        return RunResult(config, _robot(config.robot), log, metrics, folder)

    def load_all(self, runs: Sequence[str]) -> dict[str, RunResult]:
        """The runs that have a log, by name (runs without one are left out)."""
        loaded = {}
        for run in runs:
            result = self.load(run)
            if result is not None and result.log.ticks > 0:
                loaded[run] = result
        return loaded
