"""The faults of a run and what the safe ladder did about them (``metrics.json``'s ``faults`` block;
docs/faults.md): ``plot_run_faults`` for one run (its ``faults.png``), ``plot_ladders`` for the runs of the
faults experiment side by side (``experiments.faults``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.patches import Patch

from cafe_mpc.control.plan_follower import SafetyStep
from cafe_mpc_lab.report.figures import new_figure, save_figure
from cafe_mpc_lab.report.metrics import body_rates
from cafe_mpc_lab.sim.loop import SimulationLog

STEP_COLORS = {
    SafetyStep.PLAN: "#4caf50",
    SafetyStep.LAST_PLAN: "#cddc39",
    SafetyStep.STOP: "#03a9f4",
    SafetyStep.BALANCE: "#ff9800",
    SafetyStep.DAMPED: "#e53935",
}
"""The safe ladder's steps' colours, from green (following plans) to red (the damped stance)."""


def _steps_of(log: SimulationLog) -> np.ndarray:
    """The safe ladder's step per tick (``extra_safety_step``; all plan when the run has none)."""
    steps = log.extra.get("safety_step")
    return np.asarray(steps, dtype=int) if steps is not None else np.zeros(log.ticks, dtype=int)


def _fault_windows(faults: dict) -> list[tuple[float, float, str]]:
    windows = []
    for fault in faults.get("injected") or []:
        start = float(fault.get("start") or 0.0)
        duration = fault.get("duration")
        end = start + float(duration) if duration is not None else start
        windows.append((start, end, fault["kind"]))
    return windows


def _draw_steps(axis, times: np.ndarray, steps: np.ndarray, row: float, height: float = 0.8) -> None:
    order = list(SafetyStep)
    if len(times) == 0:
        return
    changes = np.flatnonzero(np.diff(steps)) + 1
    starts = np.concatenate([[0], changes])
    ends = np.concatenate([changes, [len(times) - 1]])
    dt = float(times[1] - times[0]) if len(times) > 1 else 0.002
    for first, last in zip(starts, ends, strict=True):
        step = order[int(steps[first])]
        width = float(times[last] - times[first]) + dt
        axis.barh(row, width, left=float(times[first]), height=height, color=STEP_COLORS[step], lw=0)


def plot_ladders(runs: list[tuple[str, SimulationLog, dict]], path: Path) -> Path:
    """One row per run (``(label, log, faults block)``): its safe-ladder steps over time, its fault's window
    (black outline), a fall (x)."""
    figure = new_figure((11, 1.0 + 0.35 * len(runs)))
    axis = figure.add_subplot(1, 1, 1)
    labels = []
    for index, (label, log, faults) in enumerate(runs):
        _draw_steps(axis, log.time, _steps_of(log), index)
        for start, end, _ in _fault_windows(faults):
            axis.barh(index, max(end - start, 0.02), left=start, height=0.95, fill=False, ec="k", lw=1.0)
        if log.fell:
            axis.plot(log.time[-1], index, "x", color="k", ms=8, mew=2)
        labels.append(label)
    axis.set_yticks(range(len(labels)), labels, fontsize=7)
    axis.invert_yaxis()
    axis.set_xlabel("time [s] (black box: the fault; x: fall)")
    handles = [Patch(color=STEP_COLORS[step], label=str(step)) for step in SafetyStep]
    axis.legend(handles=handles, loc="upper right", fontsize=7, ncol=4)
    axis.set_title(
        "Safe ladder per run: following the plan, the last plan, balance stance, damped stance", fontsize=9
    )
    return save_figure(figure, path)


def plot_run_faults(log: SimulationLog, faults: dict, path: Path, title: str = "") -> Path:
    """One run's faults: base height and forward speed with the injected faults shaded and the MPC process's
    events marked, and the safe ladder's step over time."""
    figure = new_figure((10, 6))
    grid = figure.add_gridspec(3, 1, height_ratios=(2, 2, 1))
    height = figure.add_subplot(grid[0])
    speed = figure.add_subplot(grid[1], sharex=height)
    ladder = figure.add_subplot(grid[2], sharex=height)
    times = log.time
    height.plot(times, log.q[:, 2], lw=0.9, color="C0")
    height.set_ylabel("base height [m]")
    if log.ticks:
        speed.plot(times, body_rates(log.q, log.v)[0][:, 0], lw=0.9, color="C1")
    speed.set_ylabel("forward speed [m/s]")
    for axis in (height, speed):
        for start, end, _ in _fault_windows(faults):
            if end > start:
                axis.axvspan(start, end, color="grey", alpha=0.25, lw=0)
            else:
                axis.axvline(start, color="grey", lw=2)
        for event in (faults.get("mpc") or {}).get("events") or []:
            axis.axvline(event["t"], color="r" if event["event"] != "mpc_restarted" else "g", lw=0.8, ls="--")
        axis.grid(alpha=0.3)
    _draw_steps(ladder, times, _steps_of(log), 0)
    ladder.set_yticks([])
    ladder.set_xlabel("time [s] (grey: injected fault; dashed: MPC process events, green: back)")
    handles = [Patch(color=STEP_COLORS[step], label=str(step)) for step in SafetyStep]
    ladder.legend(handles=handles, loc="upper right", fontsize=7, ncol=4)
    figure.suptitle(
        f"{title}: faults and the safe ladder" if title else "faults and the safe ladder", fontsize=10
    )
    return save_figure(figure, path)
