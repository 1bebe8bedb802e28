"""``cafe-mpc experiment schedules``: bounding under the paper's model schedules and SRB time steps
(Sec. VII-A1, Table I, Fig. 6 and Fig. 7).

Every schedule of Table I (S0..S5, S10, S15, S20: Tw = 0.25 s, Ts = 0..2 s) with each SRB integration time
step (dts = 10 ms and 50 ms), on the ``bound`` preset. Per run: fall, pitch and pitch-rate RMS (Fig. 6's
tracking measures, against the reference's zero pitch), forward speed, MS-iLQR time per iteration and
line-search steps per MPC update (Fig. 7, averaged over the MPC updates, the cold first solve left out).

``comparison.png`` has Fig. 6's shape (pitch RMS and pitch-rate RMS against Ts, one line per dts) and
Fig. 7's (ms per iteration and line-search steps per update against Ts); ``traces.png`` the pitch, pitch
rate and forward speed of every run against time.
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping
from pathlib import Path

import numpy as np
from pydantic import Field

from cafe_mpc.planners.cafe.setup import model_schedule
from cafe_mpc_lab.experiments.common import (
    WALL_CLOCK_NOTE,
    RunStore,
    ScheduleNames,
    colors,
    fall_fields,
    fell_text,
    iteration_timing,
    num,
)
from cafe_mpc_lab.experiments.options import ExperimentOptions, numbers
from cafe_mpc_lab.experiments.registry import Experiment, ExperimentPlan, PlanContext, Variant
from cafe_mpc_lab.experiments.run import RunResult
from cafe_mpc_lab.report.figures import new_figure, save_figure
from cafe_mpc_lab.report.metrics import METRICS_WINDOW_START_S, body_rates, roll_pitch_yaw

PAPER_TABLE_I = ("S0", "S1", "S2", "S3", "S4", "S5", "S10", "S15", "S20")
"""The model schedules of the paper's Table I (Tw = 0.25 s; Ts = 0, 0.1, ..., 0.5, 1, 1.5, 2 s)."""
PAPER_SRB_DTS = (0.01, 0.05)
"""The SRB integration time steps of Fig. 6 and 7."""


def schedule_variant_name(schedule: str, srb_dt: float) -> str:
    return f"{schedule}-dt{srb_dt:g}"


def schedule_fields(result: RunResult) -> dict:
    """Schedule, horizons and SRB knots of a run."""
    schedule = model_schedule(result.config.mpc)
    return {
        "schedule": result.config.mpc.schedule,
        "whole_body_horizon_s": schedule.whole_body_horizon,
        "srb_horizon_s": schedule.srb_horizon,
        "srb_dt": schedule.srb_dt,
    }


SrbTimeSteps = numbers(0.005, 0.2)
"""A list option of SRB integration time steps, s."""


class SchedulesOptions(ExperimentOptions):
    schedules: ScheduleNames = Field(
        PAPER_TABLE_I,
        description="model schedules (default: Table I, S0..S5,S10,S15,S20)",
        json_schema_extra={"metavar": "S0,S4,..."},
    )
    srb_dts: SrbTimeSteps = Field(
        PAPER_SRB_DTS,
        description="SRB integration time steps in s (default 0.01,0.05)",
        json_schema_extra={"metavar": "0.01,0.05"},
    )


class Schedules(Experiment):
    name = "schedules"
    title = "Bounding under the model schedules of Table I and two SRB time steps"
    paper = "paper Table I, Fig. 6 and Fig. 7"
    default_duration = 10.0
    varied_keys = ("mpc.schedule", "mpc.whole_body_horizon", "mpc.srb_horizon", "mpc.srb_dt")
    Options = SchedulesOptions
    reports_timing = True

    def plan(self, options: SchedulesOptions, context: PlanContext) -> ExperimentPlan:
        from cafe_mpc.planners.cafe.problem import PAPER_SCHEDULES

        schedules, dts = options.schedules, options.srb_dts
        variants = [
            Variant(
                schedule_variant_name(s, dt),
                "bound",
                (f"mpc.schedule={s}", f"mpc.srb_dt={dt:g}"),
                f"{s} (Ts = {PAPER_SCHEDULES[s]:g} s), dts = {1e3 * dt:g} ms",
                group=f"{dt:g}",
                fields=(("schedule", s), ("srb_dt", dt), ("srb_horizon_s", PAPER_SCHEDULES[s])),
            )
            for dt in dts
            for s in schedules
        ]
        return ExperimentPlan(
            variants,
            {"--schedules": ",".join(schedules), "--srb-dts": ",".join(f"{dt:g}" for dt in dts)},
        )

    def summarize(self, result: RunResult, variant: Variant) -> dict:
        metrics, mpc = result.metrics, result.metrics.get("mpc") or {}
        steady = metrics.get("steady_state") or metrics  # the paper's numbers skip the start from rest
        return {
            **fall_fields(metrics),
            **schedule_fields(result),
            "metrics_window_start_s": steady.get("metrics_window_start_s"),
            "vx_mean": steady.get("vx_mean"),
            "vx_rms_error": steady.get("vx_rms_error"),
            "pitch_rms": steady.get("pitch_rms"),
            "pitch_rate_rms": steady.get("pitch_rate_rms"),
            "height_rms_error": steady.get("height_rms_error"),
            **iteration_timing(result),
            "mpc_solve_time_ms_median": mpc.get("solve_time_ms_median"),
            "mpc_solve_time_ms_p99": mpc.get("solve_time_ms_p99"),
            "mpc_failures": mpc.get("failures"),
        }

    def table(self, rows: list[dict], comparison: dict) -> tuple[list[str], list[list[str]], list[str]]:
        header = [
            "schedule",
            "Ts [s]",
            "dts [s]",
            "fell",
            "vx mean [m/s]",
            "pitch RMS [rad]",
            "pitch rate RMS [rad/s]",
            "height RMS error [m]",
            "ms / iteration (mean)",
            "LS steps / update",
            "MPC solve median / p99 [ms]",
        ]
        body = [
            [
                str(r.get("schedule") or r["run"]),
                num(r.get("srb_horizon_s"), 2),
                num(r.get("srb_dt"), 2),
                fell_text(r),
                num(r.get("vx_mean")),
                num(r.get("pitch_rms")),
                num(r.get("pitch_rate_rms")),
                num(r.get("height_rms_error")),
                num(r.get("iteration_ms_mean"), 2),
                num(r.get("line_search_steps_per_update"), 2),
                f"{num(r.get('mpc_solve_time_ms_median'), 1)} / {num(r.get('mpc_solve_time_ms_p99'), 1)}",
            ]
            for r in rows
        ]
        window = next((r["metrics_window_start_s"] for r in rows if r.get("metrics_window_start_s")), None)
        notes = [
            "Tw = 0.25 s for every schedule. Tracking metrics "
            + (
                f"from t = {window:g} s (the start from rest is skipped)"
                if window
                else f"over the whole run (shorter than the {METRICS_WINDOW_START_S} s start-up window)"
            )
            + " to the end of the run or the fall; pitch and pitch rate against the reference's zero pitch "
            "(the paper's Fig. 6 measures); vx in the heading frame.",
            "ms / iteration: mean wall time of one MS-iLQR iteration over the MPC updates; LS steps / "
            "update: line-search trials per MPC update (the paper's Fig. 7); the cold first solve is left "
            "out. " + WALL_CLOCK_NOTE,
        ]
        return header, body, notes

    def plot(self, rows: list[dict], runs: RunStore, path: Path) -> None:
        plot_schedule_summary(rows, path)
        loaded = runs.load_all([r["run"] for r in rows if r.get("status") == "ok"])
        if loaded:
            labels = {r["run"]: r.get("label") or r["run"] for r in rows}
            plot_traces(loaded, labels, {r["run"]: r for r in rows}, path.with_name("traces.png"))


def plot_schedule_summary(rows: list[dict], path: Path) -> Path:
    """Fig. 6 (pitch and pitch-rate RMS) and Fig. 7 (ms per iteration, line-search steps per update) against
    the SRB horizon Ts, one line per SRB time step; an x marks a schedule whose run fell."""
    figure = new_figure((11, 7.5))
    grid = figure.add_gridspec(2, 2)
    panels = (
        ("pitch_rms", "pitch RMS [rad]", "Fig. 6: pitch"),
        ("pitch_rate_rms", "pitch rate RMS [rad/s]", "Fig. 6: pitch rate"),
        ("iteration_ms_mean", "ms per MS-iLQR iteration", "Fig. 7: solve time per iteration"),
        ("line_search_steps_per_update", "line-search steps per update", "Fig. 7: line search"),
    )
    groups = sorted({r.get("srb_dt") for r in rows if r.get("srb_dt") is not None})
    palette = dict(zip(groups, colors(len(groups)), strict=True))
    for index, (key, label, title) in enumerate(panels):
        axis = figure.add_subplot(grid[index // 2, index % 2])
        for dt in groups:
            members = sorted(
                (r for r in rows if r.get("srb_dt") == dt and r.get("srb_horizon_s") is not None),
                key=lambda r: r["srb_horizon_s"],
            )
            ts = np.array([r["srb_horizon_s"] for r in members])
            values = np.array([np.nan if r.get(key) is None else r[key] for r in members], dtype=float)
            axis.plot(ts, values, "o-", color=palette[dt], label=f"dts = {1e3 * dt:g} ms")
            fell = np.array([bool(r.get("fell")) for r in members], dtype=bool)
            if fell.any():
                axis.plot(ts[fell], values[fell], "x", color="k", ms=9, mew=2)
        axis.set_xlabel("SRB horizon Ts [s] (Tw = 0.25 s)")
        axis.set_ylabel(label)
        axis.set_title(title, fontsize=9)
        axis.grid(alpha=0.3)
        if index == 0:
            axis.legend(fontsize=8, title="x: the run fell", title_fontsize=8)
    figure.suptitle(
        "Bounding under the model schedules of Table I: tracking (Fig. 6) and solve statistics (Fig. 7); "
        "times are per-worker wall clock",
        fontsize=10,
    )
    return save_figure(figure, path)


def plot_traces(
    results: Mapping[str, RunResult], labels: Mapping[str, str], rows: Mapping[str, dict], path: Path
) -> Path:
    """Left: pitch, pitch rate and forward speed against time, one line per run (x: a fall). Right: their
    RMS (vx: RMS error against the command) per run."""
    figure = new_figure((13, 7.5))
    grid = figure.add_gridspec(3, 2, width_ratios=(3, 1.3))
    axes = [figure.add_subplot(grid[0, 0])]
    axes += [figure.add_subplot(grid[i, 0], sharex=axes[0]) for i in (1, 2)]
    names = list(results)
    palette = dict(zip(names, colors(len(names)), strict=True))
    command, end = None, 0.0
    for name, result in results.items():
        log = result.log
        heading, _, pitch_rate = body_rates(log.q, log.v)
        pitch = roll_pitch_yaw(log.q[:, 3:7])[:, 1]
        for axis, values in zip(axes, (pitch, pitch_rate, heading[:, 0]), strict=True):
            axis.plot(log.time, values, color=palette[name], lw=0.8, label=labels.get(name, name))
            if log.fell:
                axis.plot(log.time[-1], values[-1], "x", color=palette[name], ms=8, mew=2)
        end = max(end, float(log.time[-1]))
        if result.config.gait is not None:
            command = result.config.gait.commands
    if command is not None:
        starts = [c.start for c in command] + [end]
        for c, (t0, t1) in zip(command, itertools.pairwise(starts), strict=True):
            if t0 < end:
                axes[2].plot([t0, t1], [c.vx, c.vx], "k--", lw=1.0, label="command" if t0 == 0.0 else None)
    quantities = (
        ("pitch [rad]", "pitch_rms", "pitch RMS [rad]"),
        ("pitch rate [rad/s]", "pitch_rate_rms", "pitch rate RMS [rad/s]"),
        ("forward speed vx [m/s]", "vx_rms_error", "vx RMS error [m/s]"),
    )
    for row_index, (axis, (label, key, rms_label)) in enumerate(zip(axes, quantities, strict=True)):
        axis.set_ylabel(label)
        if end > METRICS_WINDOW_START_S:
            axis.axvline(METRICS_WINDOW_START_S, color="grey", ls=":", lw=0.8)
        axis.grid(alpha=0.3)
        bars = figure.add_subplot(grid[row_index, 1])
        values = [rows.get(n, {}).get(key) for n in names]
        bars.bar(
            range(len(names)), [np.nan if v is None else v for v in values], color=[palette[n] for n in names]
        )
        for x, name in enumerate(names):
            if rows.get(name, {}).get("fell"):
                bars.annotate("fell", (x, 0), ha="center", va="bottom", fontsize=7, color="k")
        bars.set_xticks(range(len(names)), names, rotation=60, fontsize=7)
        bars.set_ylabel(rms_label, fontsize=8)
        bars.grid(alpha=0.3, axis="y")
    if len(names) <= 10:
        axes[2].legend(loc="lower right", fontsize=7)
    axes[-1].set_xlabel("time [s] (x: fall; dotted: start of the metrics window)")
    figure.suptitle(
        "Pitch, pitch rate and forward speed per run; right: RMS over the metrics window (a run that fell: "
        "up to the fall)",
        fontsize=10,
    )
    return save_figure(figure, path)
