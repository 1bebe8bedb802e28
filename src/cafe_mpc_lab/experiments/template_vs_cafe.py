"""``cafe-mpc experiment template-vs-cafe``: the in-place barrel roll planned by CAFE-MPC and by the template
MPC (paper Sec. VII-C, Fig. 12).

Both runs follow the same composed barrel-roll reference (``barrel-roll`` preset; ``--task`` may name another
acrobatic preset, e.g. ``running-barrel-roll``) on the same MuJoCo plant; only the planner differs:

* ``cafe``: CAFE-MPC (whole-body dynamics near term, SRB tail) over the VWBC QP (34);
* ``template``: the HKD-MPC-like baseline (``planners.template``): SRB dynamics over the whole horizon,
  footholds from the reference, stance torques ``J' F`` from the planned GRFs, Bezier swings by joint PD. It
  ignores the legs' momentum, which the roll's leg swing throws around.

Each run's ``task`` block (``report.task_metrics``: roll turned, landing, uprightness, bar contact when the
task has a bar) is the result; ``comparison.png`` puts their roll, height and lateral position over the
reference (as Fig. 12), and each run folder holds its video (``output.render``; needs off-screen OpenGL,
otherwise the run says why in ``metrics.json`` and the comparison goes on without it). The paper reports
that the template MPC fails the landing; whatever happens here is reported as it happened.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from pydantic import Field

from cafe_mpc.config import ConfigError, available_presets, load_config
from cafe_mpc_lab.experiments.common import RunStore, colors, fall_fields, fell_text, integer, num
from cafe_mpc_lab.experiments.options import ExperimentOptions
from cafe_mpc_lab.experiments.registry import Experiment, ExperimentPlan, PlanContext, Variant
from cafe_mpc_lab.experiments.run import RunResult
from cafe_mpc_lab.report.figures import save_figure, subplots
from cafe_mpc_lab.report.metrics import roll_pitch_yaw

PLANNERS = (("cafe", "CAFE-MPC + VWBC"), ("template", "template MPC (SRB) + J'F / swing PD"))
DEFAULT_TASK = "barrel-roll"
TASK_FIELDS = (
    "success",
    "roll_turned_rad",
    "roll_turned_at_touchdown_rad",
    "max_base_height_m",
    "landed",
    "upright_after",
    "stayed_up",
    "stayed_up_s",
    "tilt_at_touchdown_rad",
    "tilt_max_first_second_after_landing_rad",
    "lowest_trunk_m",
    "roll_motor_torque_limit_violations",
    "bar_contact",
    "speed_before_roll_mps",
    "speed_after_roll_mps",
)


class TemplateVsCafeOptions(ExperimentOptions):
    task: str | None = Field(
        None,
        description=f"the acrobatic preset both planners run (default {DEFAULT_TASK})",
        json_schema_extra={"metavar": "PRESET"},
    )


class TemplateVsCafe(Experiment):
    name = "template-vs-cafe"
    title = "Barrel roll: CAFE-MPC vs the template MPC"
    paper = "paper Fig. 12"
    varied_keys = ("planner",)
    needs_gait = False
    Options = TemplateVsCafeOptions
    default_overrides = ("output.render=true",)

    def plan(self, options: TemplateVsCafeOptions, context: PlanContext) -> ExperimentPlan:
        task = options.task or DEFAULT_TASK
        if task not in available_presets() and not Path(task).is_file():
            raise ConfigError(f"--task: unknown preset {task!r}; presets: {', '.join(available_presets())}")
        if load_config(task).reference is None:
            raise ConfigError(f"--task {task}: not an acrobatic task (it has no reference section)")
        chosen = {"--task": task} if options.task else {}
        return ExperimentPlan([Variant(p, task, (f"planner={p}",), label) for p, label in PLANNERS], chosen)

    def summarize(self, result: RunResult, variant: Variant) -> dict:
        task = result.metrics.get("task") or {}
        mpc = result.metrics.get("mpc") or {}
        return {
            **fall_fields(result.metrics),
            **{key: task.get(key) for key in TASK_FIELDS},
            "update_ms_median": mpc.get("update_ms_median"),
            "latency_ms_median": mpc.get("latency_ms_median"),
            "timing_mode": (result.metrics.get("timing") or {}).get("mode"),
            "video": _video_of(result),
        }

    def table(self, rows: list[dict], comparison: dict) -> tuple[list[str], list[list[str]], list[str]]:
        header = [
            "planner",
            "success",
            "roll turned [rad]",
            "roll at touchdown [rad]",
            "apex [m]",
            "landed",
            "upright after",
            "fell",
            "motor torque-limit violations (roll)",
            "MPC update median [ms]",
        ]

        def yes_no(value) -> str:
            return "n/a" if value is None else ("yes" if value else "no")

        body = [
            [
                r.get("label") or r["run"],
                yes_no(r.get("success")),
                num(r.get("roll_turned_rad"), 2),
                num(r.get("roll_turned_at_touchdown_rad"), 2),
                num(r.get("max_base_height_m"), 3),
                yes_no(r.get("landed")),
                yes_no(r.get("upright_after")),
                fell_text(r),
                integer(r.get("roll_motor_torque_limit_violations")),
                num(r.get("update_ms_median"), 1),
            ]
            for r in rows
        ]
        mode = next((r.get("timing_mode") for r in rows if r.get("timing_mode")), None)
        notes = [
            "Success: the roll turned >= 2 pi - 0.3 rad (integral of the body roll rate), all four feet down "
            "within 0.3 s of the touchdown, tilt < 0.3 rad for 1 s after it, no fall for 2 s, no motor "
            "torque-limit violation during the roll (and no bar contact, and the pace resumed, for the "
            "running roll). Roll at touchdown: turned when the first foot touched down after the flight.",
            f"Timing mode: {mode or 'n/a'} (see each run's metrics.json `timing` block).",
        ]
        return header, body, notes

    def plot(self, rows: list[dict], runs: RunStore, path: Path) -> None:
        loaded = runs.load_all([r["run"] for r in rows if r.get("status") == "ok"])
        if loaded:
            plot_comparison(loaded, {r["run"]: r.get("label") or r["run"] for r in rows}, path)

    def summary_line(self, comparison: dict) -> str | None:
        rows = list((comparison.get("variants") or {}).values())
        parts = [
            f"{r['run']}: success {r.get('success')}, roll {num(r.get('roll_turned_rad'), 2)} rad"
            for r in rows
        ]
        return "; ".join(parts) or None


def _video_of(result: RunResult) -> str | None:
    """The run's video file name, or why it has none."""
    folder = getattr(result, "out_dir", None)
    if folder is not None:
        for name in ("run.mp4", "run.gif"):
            if (Path(folder) / name).is_file():
                return name
    error = result.metrics.get("render_error")
    return f"none ({error})" if error else None


def plot_comparison(results: dict[str, RunResult], labels: dict[str, str], path: Path) -> Path:
    """Roll (integral of the body roll rate), base height and lateral position of each planner's run over the
    reference of the first run (paper Fig. 12); the planned flight shaded, a fall marked with x."""
    from cafe_mpc.assembly.references import build_reference
    from cafe_mpc.assembly.resolve import resolve
    from cafe_mpc_lab.report.task_metrics import reference_trace, task_from_reference

    first = next(iter(results.values()))
    robot = first.robot
    reference = build_reference(resolve(first.config, robot))
    task = task_from_reference(reference)
    end = max(float(r.log.time[-1]) for r in results.values() if r.log.ticks)
    times = np.arange(0.0, end, 0.01)
    planned = reference_trace(reference, times, robot.nq, robot.nv, robot.nu, robot.n_feet)
    figure, axes = subplots(3, 1, figsize=(8, 7.5), sharex=True)
    axes[0].plot(times, roll_pitch_yaw(planned[:, 3:7])[:, 0], "k--", lw=1.0, label="reference")
    axes[1].plot(times, planned[:, 2], "k--", lw=1.0, label="reference")
    axes[2].plot(times, planned[:, 1], "k--", lw=1.0, label="reference")
    for color, (name, result) in zip(colors(len(results)), results.items(), strict=True):
        log = result.log
        period = 1.0 / result.config.simulation.control_rate_hz
        series = (np.cumsum(log.v[:, 3]) * period, log.q[:, 2], log.q[:, 1])
        for axis, values in zip(axes, series, strict=True):
            axis.plot(log.time, values, color=color, lw=1.2, label=labels.get(name, name))
            if log.fell:
                axis.plot(log.time[-1], values[-1], "x", color=color, ms=8, mew=2)
    axes[0].axhline(2.0 * np.pi, color="grey", lw=0.6)
    axes[0].set_ylabel("roll turned [rad]")
    axes[1].set_ylabel("base height [m]")
    axes[2].set_ylabel("lateral position y [m]")
    axes[2].set_xlabel("time [s] (x: fall)")
    if task is not None:
        for axis in axes:
            axis.axvspan(task.takeoff, task.touchdown, color="grey", alpha=0.15, lw=0)
    for axis in axes:
        axis.grid(alpha=0.3)
        axis.legend(loc="best", fontsize=7)
    figure.suptitle(f"{first.config.name}: CAFE-MPC vs template MPC (planned flight shaded; paper Fig. 12)")
    return save_figure(figure, Path(path))
