"""``cafe-mpc experiment warm-start``: VWBC QP iterations per tick with the previous tick's solution, the
plan's guess and no warm start, for bounding and pacing (Sec. VII-B, Fig. 11).

``comparison.png``: histograms of QP iterations per tick, one panel per gait, one bar per warm-start mode.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from pydantic import Field

from cafe_mpc_lab.experiments.common import (
    GaitPresetNames,
    RunStore,
    colors,
    fall_fields,
    fell_text,
    integer,
    num,
    pct,
)
from cafe_mpc_lab.experiments.options import ExperimentOptions, names
from cafe_mpc_lab.experiments.registry import Experiment, ExperimentPlan, PlanContext, Variant
from cafe_mpc_lab.experiments.run import RunResult
from cafe_mpc_lab.report.figures import save_figure, subplots

DEFAULT_GAITS = ("bound", "pace")
DEFAULT_WARM_STARTS = ("previous", "plan", "none")
WARM_START_MODES = ("previous", "plan", "equality", "none")
MAX_HISTOGRAM_BIN = 10  # iterations >= this share one bar


WarmStartModes = names(WARM_START_MODES)
"""A list option of VWBC warm-start modes."""


class WarmStartOptions(ExperimentOptions):
    gaits: GaitPresetNames = Field(
        DEFAULT_GAITS,
        description="gait presets (default bound,pace)",
        json_schema_extra={"metavar": "bound,pace"},
    )
    warm_starts: WarmStartModes = Field(
        DEFAULT_WARM_STARTS,
        description="VWBC warm-start modes (default previous,plan,none; also equality)",
        json_schema_extra={"metavar": "previous,plan,none"},
    )


class WarmStart(Experiment):
    name = "warm-start"
    title = "VWBC QP iterations per tick with and without warm start"
    paper = "paper Fig. 11"
    default_duration = 4.0
    varied_keys = ("wbc", "vwbc.warm_start")
    Options = WarmStartOptions

    def plan(self, options: WarmStartOptions, context: PlanContext) -> ExperimentPlan:
        gaits, modes = options.gaits, options.warm_starts
        variants = [
            Variant(f"{gait}-{mode}", gait, ("wbc=vwbc", f"vwbc.warm_start={mode}"), mode, group=gait)
            for gait in gaits
            for mode in modes
        ]
        return ExperimentPlan(variants, {"--gaits": ",".join(gaits), "--warm-starts": ",".join(modes)})

    def summarize(self, result: RunResult, variant: Variant) -> dict:
        return warm_start_summary(result)

    def table(self, rows: list[dict], comparison: dict) -> tuple[list[str], list[list[str]], list[str]]:
        header = [
            "gait",
            "warm start",
            "fell",
            "QP solves",
            "1 iteration",
            "<= 3 iterations",
            "iterations mean",
            "QP solve median / p99 [ms]",
            "VWBC tick median / p99 [ms]",
            "fallbacks",
        ]
        body = [
            [
                r.get("gait") or r.get("group") or "n/a",
                r.get("warm_start") or r.get("label") or r["run"],
                fell_text(r),
                integer(r.get("qp_solves")),
                pct(r.get("one_iteration_share")),
                pct(r.get("at_most_3_iterations_share")),
                num(r.get("iterations_mean"), 2),
                f"{num(r.get('qp_solve_time_ms_median'))} / {num(r.get('qp_solve_time_ms_p99'))}",
                f"{num(r.get('tick_time_ms_median'))} / {num(r.get('tick_time_ms_p99'))}",
                integer(r.get("fallbacks")),
            ]
            for r in rows
        ]
        notes = [
            "Iterations as the QP solver reports them (DAQP: active-set iterations; '1 iteration' counts "
            "solves with at most one). Warm start: previous = the last tick's solution/working set, plan = "
            "the MPC plan's guess (paper Sec. V-A), none = cold. Shares are of all QP solves of the run. "
            "QP solve: the solver call; VWBC tick: assembly + solve + fallback, against the 2 ms budget "
            "(wall clock of the worker that ran the simulation).",
        ]
        return header, body, notes

    def plot(self, rows: list[dict], runs: RunStore, path: Path) -> None:
        plot_warm_start(rows, path)


def iteration_shares(histogram: dict | None) -> dict:
    """QP solves, share solved in at most 1 and at most 3 iterations, mean iterations, from a histogram."""
    counts = {int(k): int(n) for k, n in (histogram or {}).items()}
    total = sum(counts.values())
    if total == 0:
        return {
            "qp_solves": 0,
            "one_iteration_share": None,
            "at_most_3_iterations_share": None,
            "iterations_mean": None,
        }
    return {
        "qp_solves": total,
        "one_iteration_share": sum(n for k, n in counts.items() if k <= 1) / total,
        "at_most_3_iterations_share": sum(n for k, n in counts.items() if k <= 3) / total,
        "iterations_mean": sum(k * n for k, n in counts.items()) / total,
    }


def warm_start_summary(result: RunResult) -> dict:
    from cafe_mpc_lab.experiments.controllers import low_level_of

    metrics, wbc = result.metrics, result.metrics.get("wbc") or {}
    ticks = low_level_of(result.controller).statistics() if result.controller is not None else {}

    def finite(value: float | None) -> float | None:
        return float(value) if value is not None and np.isfinite(value) else None

    return {
        **fall_fields(metrics),
        "gait": metrics.get("gait"),
        "warm_start": result.config.vwbc.warm_start,
        "solver": result.config.vwbc.solver,
        **iteration_shares(wbc.get("qp_iterations_histogram")),
        "qp_iterations_histogram": wbc.get("qp_iterations_histogram"),
        "qp_solve_time_ms_median": wbc.get("qp_solve_time_ms_median"),
        "qp_solve_time_ms_p99": wbc.get("qp_solve_time_ms_p99"),
        "tick_time_ms_median": finite(ticks.get("tick_time_ms_median")),
        "tick_time_ms_p99": finite(ticks.get("tick_time_ms_p99")),
        "fallbacks": wbc.get("fallbacks"),
    }


def plot_warm_start(rows: Sequence[dict], path: Path) -> Path:
    """Histograms of QP iterations per tick: one panel per gait, one bar per warm-start mode (Fig. 11)."""
    groups = list(dict.fromkeys(str(r.get("group") or r.get("gait")) for r in rows))
    figure, axes = subplots(1, len(groups), figsize=(5.5 * len(groups), 4), squeeze=False)
    for axis, group in zip(axes[0], groups, strict=True):
        members = [r for r in rows if str(r.get("group") or r.get("gait")) == group]
        histograms = {
            r["run"]: {int(k): int(n) for k, n in (r.get("qp_iterations_histogram") or {}).items()}
            for r in members
        }
        keys = [k for counts in histograms.values() for k in counts]
        top = min(max([*keys, 3]), MAX_HISTOGRAM_BIN)
        bins = np.arange(0 if 0 in keys else 1, top + 1)
        width = 0.8 / max(len(members), 1)
        for index, (row, color) in enumerate(zip(members, colors(len(members)), strict=True)):
            counts = histograms[row["run"]]
            total = sum(counts.values())
            shares = np.zeros(len(bins))
            for k, n in counts.items():
                shares[min(k, top) - bins[0]] += n
            if total:
                shares *= 100.0 / total
            label = row.get("label") or row["run"]
            label = (
                f"{label} ({pct(row.get('one_iteration_share'))} in <= 1)"
                if total
                else f"{label} (no QP solves)"
            )
            axis.bar(bins + (index - (len(members) - 1) / 2) * width, shares, width, color=color, label=label)
        axis.set_xticks(bins, [str(b) if b < top or top < MAX_HISTOGRAM_BIN else f">={b}" for b in bins])
        axis.set_xlabel("QP iterations in the tick")
        axis.set_ylabel("share of ticks [%]")
        axis.set_title(group, fontsize=10)
        axis.grid(alpha=0.3, axis="y")
        axis.legend(fontsize=8, title="warm start", title_fontsize=8)
    figure.suptitle("VWBC QP iterations per tick with and without warm start (paper Fig. 11)", fontsize=10)
    return save_figure(figure, path)
