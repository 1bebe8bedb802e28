"""``cafe-mpc experiment latency``: does the controller work whatever its timing? (No paper reports this.)

One preset (``--task``) over three sweeps, each run one variant:

* fixed latency (``--latencies``, seconds): every plan takes effect that long after its measurement, MPC
  period as the preset has it (``mpc.latency=fixed``);
* MPC period (``--periods``, seconds) with a fixed latency of ``--period-latency`` (default 10 ms);
* measured latency on a slower computer (``--compute-scales``: every measured compute time multiplied by the
  factor, ``mpc.compute_scale``), each scale ``--repeats`` times (the machine's timing differs from run to
  run). Measured runs are only honest with one worker per core (``--workers``).

A run succeeds when it stays up for the whole run and, for a gait, its steady-state forward speed is within
``SPEED_TOLERANCE`` of the command; for an acrobatic task when its ``task`` block says so. ``comparison.png``
draws success and tracking error against latency, period and compute scale.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from pydantic import Field, model_validator

from cafe_mpc.assembly.checks import load_run_config
from cafe_mpc.config import ConfigError
from cafe_mpc_lab.experiments.common import SPEED_TOLERANCE, RunStore, fall_fields, fell_text, num
from cafe_mpc_lab.experiments.options import ExperimentOptions, integer, number, numbers
from cafe_mpc_lab.experiments.registry import Experiment, ExperimentPlan, PlanContext, Variant
from cafe_mpc_lab.experiments.run import RunResult
from cafe_mpc_lab.report.figures import new_figure, save_figure

DEFAULT_LATENCIES = tuple(round(0.005 * i, 3) for i in range(13))  # 0 to 60 ms
DEFAULT_PERIODS = tuple(round(0.015 + 0.005 * i, 3) for i in range(6))  # 15 to 40 ms
DEFAULT_PERIOD_LATENCY = 0.01


Latencies = numbers(0.0, 0.5, none_word=True)
"""Fixed latencies, s ('none': no latency sweep)."""
Periods = numbers(0.005, 0.5, none_word=True)
"""MPC periods, s ('none': no period sweep)."""
ComputeScales = numbers(0.1, 100.0, none_word=True)
"""Factors on the measured compute times."""
PeriodLatency = number(0.0, 0.5)
"""Fixed latency of the period sweep, s."""
Repeats = integer(1, 1000)


class LatencyOptions(ExperimentOptions):
    task: str | None = Field(
        None,
        description="the preset (or YAML config) every run uses (required)",
        json_schema_extra={"metavar": "PRESET"},
    )
    latencies: Latencies = Field(
        DEFAULT_LATENCIES,
        description="fixed latencies in s (default 0 to 0.06 in 0.005 steps; 'none': skip)",
        json_schema_extra={"metavar": "0,0.02"},
    )
    periods: Periods = Field(
        DEFAULT_PERIODS,
        description="MPC periods in s (default 0.015 to 0.04 in 0.005 steps; 'none': skip)",
        json_schema_extra={"metavar": "0.02,0.03"},
    )
    period_latency: PeriodLatency = Field(
        DEFAULT_PERIOD_LATENCY,
        description="fixed latency of the period sweep in s (default 0.01)",
        json_schema_extra={"metavar": "L"},
    )
    compute_scales: ComputeScales = Field(
        (),
        description="compute-time factors of measured-latency runs (default none)",
        json_schema_extra={"metavar": "1,2"},
    )
    repeats: Repeats = Field(
        1, description="runs per compute scale (default 1)", json_schema_extra={"metavar": "N"}
    )

    @model_validator(mode="after")
    def _task_given(self) -> LatencyOptions:
        if not self.task:
            from cafe_mpc.config import available_presets

            raise ValueError(f"--task PRESET is required (presets: {', '.join(available_presets())})")
        return self


class Latency(Experiment):
    name = "latency"
    title = "Success against latency, MPC period and computer speed"
    paper = "not in the paper (the timing issue's sweep)"
    default_duration = None  # each preset's own
    varied_keys = ("mpc.latency", "mpc.fixed_latency", "mpc.period", "mpc.compute_scale")
    Options = LatencyOptions
    default_overrides = ("output.plots=false",)
    needs_gait = False
    errors_are_results = True
    reports_timing = True

    def plan(self, options: LatencyOptions, context: PlanContext) -> ExperimentPlan:
        task = options.task
        load_run_config(str(task), list(context.overrides))  # a bad preset or override: one clear error now
        latencies, periods, scales = options.latencies, options.periods, options.compute_scales
        period_latency, repeats = options.period_latency, options.repeats
        variants = []
        for latency in latencies:
            variants.append(
                Variant(
                    f"latency-{latency * 1e3:05.1f}ms",
                    str(task),
                    ("mpc.latency=fixed", f"mpc.fixed_latency={latency:g}"),
                    f"fixed {latency * 1e3:g} ms",
                    group="latency",
                    fields=(
                        ("sweep", "latency"),
                        ("latency_s", latency),
                        ("period_s", None),
                        ("scale", None),
                    ),
                )
            )
        for period in periods:
            variants.append(
                Variant(
                    f"period-{period * 1e3:05.1f}ms",
                    str(task),
                    ("mpc.latency=fixed", f"mpc.fixed_latency={period_latency:g}", f"mpc.period={period:g}"),
                    f"period {period * 1e3:g} ms",
                    group="period",
                    fields=(
                        ("sweep", "period"),
                        ("latency_s", period_latency),
                        ("period_s", period),
                        ("scale", None),
                    ),
                )
            )
        for scale in scales:
            for repeat in range(repeats):
                variants.append(
                    Variant(
                        f"scale-{scale:g}-run-{repeat:02d}",
                        str(task),
                        ("mpc.latency=measured", f"mpc.compute_scale={scale:g}"),
                        f"measured x{scale:g} #{repeat}",
                        group="compute_scale",
                        variant=f"scale-{scale:g}",
                        fields=(
                            ("sweep", "compute_scale"),
                            ("latency_s", None),
                            ("period_s", None),
                            ("scale", scale),
                        ),
                    )
                )
        if not variants:
            raise ConfigError("nothing to run: give --latencies, --periods or --compute-scales")
        plan_options = {"--task": str(task)}
        for dest, values, default in (
            ("latencies", latencies, DEFAULT_LATENCIES),
            ("periods", periods, DEFAULT_PERIODS),
        ):
            if tuple(values) != default:
                plan_options["--" + dest] = ",".join(f"{v:g}" for v in values) or "none"
        if period_latency != DEFAULT_PERIOD_LATENCY:
            plan_options["--period-latency"] = f"{period_latency:g}"
        if scales:
            plan_options["--compute-scales"] = ",".join(f"{s:g}" for s in scales)
            plan_options["--repeats"] = str(repeats)
        return ExperimentPlan(variants, plan_options)

    def summarize(self, result: RunResult, variant: Variant) -> dict:
        metrics = result.metrics
        steady = metrics.get("steady_state") or {}
        mpc = metrics.get("mpc") or {}
        task = metrics.get("task")
        commanded = None
        if result.config.gait is not None and result.config.gait.commands:
            commanded = result.config.gait.commands[-1].vx
        vx = steady.get("vx_mean")
        if task is not None:
            success = bool(not metrics["fell"] and task.get("success"))
            criterion = "task"
        else:
            speed_ok = commanded is None or (vx is not None and abs(vx - commanded) < SPEED_TOLERANCE)
            success = bool(not metrics["fell"] and speed_ok)
            criterion = f"up, |vx - {commanded:g}| < {SPEED_TOLERANCE:g}" if commanded is not None else "up"
        return {
            "success": success,
            "criterion": criterion,
            **fall_fields(metrics),
            "vx_steady": vx,
            "vx_command": commanded,
            "height_rms_error": steady.get("height_rms_error"),
            "pitch_rms": steady.get("pitch_rms"),
            "task_success": task.get("success") if task else None,
            "roll_turned_rad": task.get("roll_turned_rad") if task else None,
            "latency_ms_median": mpc.get("latency_ms_median"),
            "latency_ms_p99": mpc.get("latency_ms_p99"),
            "feedback_ms_median": mpc.get("feedback_ms_median"),
            "feedback_ms_p99": mpc.get("feedback_ms_p99"),
            "prepare_ms_median": mpc.get("prepare_ms_median"),
            "prepare_ms_p99": mpc.get("prepare_ms_p99"),
            "rate_hz": mpc.get("rate_hz"),
            "scheme": (metrics.get("timing") or {}).get("scheme"),
        }

    def table(self, rows: list[dict], comparison: dict) -> tuple[list[str], list[list[str]], list[str]]:
        header = [
            "run",
            "success",
            "fell",
            "vx steady [m/s]",
            "height RMS error [m]",
            "latency median / p99 [ms]",
            "feedback median / p99 [ms]",
            "rate [Hz]",
        ]
        body = [
            [
                r.get("label") or r["run"],
                "yes" if r.get("success") else "**no**",
                fell_text(r),
                num(r.get("vx_steady")),
                num(r.get("height_rms_error")),
                f"{num(r.get('latency_ms_median'), 1)} / {num(r.get('latency_ms_p99'), 1)}",
                f"{num(r.get('feedback_ms_median'), 2)} / {num(r.get('feedback_ms_p99'), 2)}",
                num(r.get("rate_hz"), 1),
            ]
            for r in rows
        ]
        ok = sum(bool(r.get("success")) for r in rows)
        criterion = rows[0].get("criterion") if rows else ""
        notes = [
            f"{ok} of {len(rows)} runs succeeded (success: {criterion}; steady state from the metrics' "
            "steady-state window). Latency: measurement to plan in effect, control ticks included.",
        ]
        return header, body, notes

    def summary_line(self, comparison: dict) -> str | None:
        rows = list((comparison.get("variants") or {}).values())
        if not rows:
            return None
        failed = [r.get("label") or r["run"] for r in rows if not r.get("success")]
        ok = len(rows) - len(failed)
        return f"latency: {ok} of {len(rows)} succeeded" + (
            f"; failed: {', '.join(failed)}" if failed else ""
        )

    def plot(self, rows: list[dict], runs: RunStore, path: Path) -> None:
        plot_latency(rows, path)


def plot_latency(rows: list[dict], path: Path) -> Path:
    """Success (filled: succeeded, cross: failed) and tracking error against each swept quantity."""
    sweeps = [
        ("latency", "latency_s", "fixed latency [ms]", 1e3),
        ("period", "period_s", "MPC period [ms]", 1e3),
        ("compute_scale", "scale", "compute scale (measured latency)", 1.0),
    ]
    present = [s for s in sweeps if any(r.get("sweep") == s[0] for r in rows)]
    figure = new_figure((4.5 * max(len(present), 1), 4.2))
    for index, (sweep, key, label, factor) in enumerate(present):
        axis = figure.add_subplot(1, len(present), index + 1)
        chosen = [r for r in rows if r.get("sweep") == sweep and r.get(key) is not None]
        for r in chosen:
            x = float(r[key]) * factor
            task = r.get("criterion") == "task"
            y = r.get("roll_turned_rad") if task else r.get("height_rms_error")
            error = (
                abs(float(r["vx_steady"]) - float(r["vx_command"]))
                if r.get("vx_steady") is not None and r.get("vx_command") is not None
                else None
            )
            marker = "o" if r.get("success") else "x"
            color = "tab:green" if r.get("success") else "tab:red"
            if y is not None:
                axis.plot(x, y, marker, color=color, ms=7)
            if error is not None and not task:
                axis.plot(
                    x,
                    error,
                    "s" if r.get("success") else "x",
                    color="tab:blue" if r.get("success") else "tab:red",
                    ms=5,
                    alpha=0.7,
                )
        if chosen and chosen[0].get("criterion") != "task":
            axis.set_ylim(bottom=0.0)
        axis.set_xlabel(label)
        axis.set_ylabel("height RMS error [m] (circles), |vx error| [m/s] (squares)" if index == 0 else "")
        axis.grid(alpha=0.3)
        axis.set_title(f"{sum(bool(r.get('success')) for r in chosen)} of {len(chosen)} succeed", fontsize=9)
        if chosen and chosen[0].get("criterion") == "task":
            axis.set_ylabel("roll turned [rad] (x: failed)")
    figure.suptitle("Success against timing (green: succeeded, red x: failed)", fontsize=10)
    return save_figure(figure, path)


def success_rate(rows: list[dict]) -> float | None:
    """Share of successful runs (None without runs)."""
    return float(np.mean([bool(r.get("success")) for r in rows])) if rows else None
