"""``cafe-mpc experiment trot-schedules``: trotting under the schedules S0..S4 (dts = 50 ms), forward speed
and body height against the desired values (Sec. VII-A2, Fig. 8).

The paper ran this on the Mini Cheetah hardware (S0 fell after a few steps, S1 later, S2..S4 trotted, with
no gain beyond S2); here it runs on the simulated robot with the ``trot`` preset. ``comparison.png`` has
Fig. 8's shape: vx and the base height against time, one line per schedule, the desired values dashed.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from pydantic import Field

from cafe_mpc.assembly.references import reference_commands, reference_profile
from cafe_mpc_lab.experiments.common import RunStore, ScheduleNames, colors, fall_fields, fell_text, num
from cafe_mpc_lab.experiments.options import ExperimentOptions
from cafe_mpc_lab.experiments.registry import Experiment, ExperimentPlan, PlanContext, Variant
from cafe_mpc_lab.experiments.run import RunResult
from cafe_mpc_lab.report.figures import new_figure, save_figure
from cafe_mpc_lab.report.metrics import METRICS_WINDOW_START_S, body_rates, commanded_at

SRB_DT = 0.05
FIG_8_SCHEDULES = ("S0", "S1", "S2", "S3", "S4")


class TrotSchedulesOptions(ExperimentOptions):
    schedules: ScheduleNames = Field(
        FIG_8_SCHEDULES,
        description="model schedules (default: Fig. 8's S0..S4)",
        json_schema_extra={"metavar": "S0,S4,..."},
    )


class TrotSchedules(Experiment):
    name = "trot-schedules"
    title = "Trotting under the model schedules S0..S4 (dts = 50 ms): speed and height tracking"
    paper = "paper Fig. 8 (hardware there, simulation here)"
    default_duration = 10.0
    varied_keys = ("mpc.schedule", "mpc.whole_body_horizon", "mpc.srb_horizon", "mpc.srb_dt")
    Options = TrotSchedulesOptions

    def plan(self, options: TrotSchedulesOptions, context: PlanContext) -> ExperimentPlan:
        from cafe_mpc.planners.cafe.problem import PAPER_SCHEDULES

        schedules = options.schedules
        variants = [
            Variant(
                s,
                "trot",
                (f"mpc.schedule={s}", f"mpc.srb_dt={SRB_DT:g}"),
                f"{s} (Ts = {PAPER_SCHEDULES[s]:g} s)",
                fields=(("schedule", s), ("srb_horizon_s", PAPER_SCHEDULES[s])),
            )
            for s in schedules
        ]
        return ExperimentPlan(variants, {"--schedules": ",".join(schedules)})

    def summarize(self, result: RunResult, variant: Variant) -> dict:
        metrics = result.metrics
        steady = metrics.get("steady_state") or metrics  # Fig. 8's numbers skip the start from rest
        commands = reference_commands(result.config)
        desired = commanded_at(np.array([0.0]), commands, result.robot.standing_height)[0]
        return {
            **fall_fields(metrics),
            "vx_desired": float(desired[0]),
            "height_desired": float(desired[3]),
            "vx_mean": steady.get("vx_mean"),
            "vx_rms_error": steady.get("vx_rms_error"),
            "height_mean": _mean_height(result),
            "height_rms_error": steady.get("height_rms_error"),
            "pitch_rms": steady.get("pitch_rms"),
            "mpc_failures": (metrics.get("mpc") or {}).get("failures"),
        }

    def table(self, rows: list[dict], comparison: dict) -> tuple[list[str], list[list[str]], list[str]]:
        header = [
            "schedule",
            "Ts [s]",
            "fell",
            "vx desired / mean [m/s]",
            "vx RMS error [m/s]",
            "height desired / mean [m]",
            "height RMS error [m]",
            "pitch RMS [rad]",
        ]
        body = [
            [
                str(r.get("schedule") or r["run"]),
                num(r.get("srb_horizon_s"), 2),
                fell_text(r),
                f"{num(r.get('vx_desired'), 2)} / {num(r.get('vx_mean'))}",
                num(r.get("vx_rms_error")),
                f"{num(r.get('height_desired'))} / {num(r.get('height_mean'))}",
                num(r.get("height_rms_error")),
                num(r.get("pitch_rms")),
            ]
            for r in rows
        ]
        notes = [
            f"Means and RMS errors from t = {METRICS_WINDOW_START_S:g} s (the start from rest is skipped) to "
            "the end of the run or the fall; vx in the heading frame; desired height: the standing height "
            "(the trot preset commands none). The paper's Fig. 8 is from the hardware.",
        ]
        return header, body, notes

    def plot(self, rows: list[dict], runs: RunStore, path: Path) -> None:
        loaded = runs.load_all([r["run"] for r in rows if r.get("status") == "ok"])
        if not loaded:
            return
        labels = {r["run"]: r.get("label") or r["run"] for r in rows}
        figure = new_figure((10, 6.5))
        axes = [figure.add_subplot(2, 1, 1)]
        axes.append(figure.add_subplot(2, 1, 2, sharex=axes[0]))
        palette = dict(zip(loaded, colors(len(loaded)), strict=True))
        desired_drawn = False
        for name, result in loaded.items():
            log = result.log
            vx = body_rates(log.q, log.v)[0][:, 0]
            for axis, values in zip(axes, (vx, log.q[:, 2]), strict=True):
                axis.plot(log.time, values, color=palette[name], lw=0.9, label=labels.get(name, name))
                if log.fell:
                    axis.plot(log.time[-1], values[-1], "x", color=palette[name], ms=8, mew=2)
            if not desired_drawn:
                desired = commanded_at(
                    log.time, reference_profile(result.config, result.robot), result.robot.standing_height
                )
                axes[0].plot(log.time, desired[:, 0], "k--", lw=1.2, label="desired")
                axes[1].plot(log.time, desired[:, 3], "k--", lw=1.2, label="desired")
                desired_drawn = True
        axes[0].set_ylabel("forward speed vx [m/s]")
        axes[1].set_ylabel("body height z [m]")
        axes[1].set_xlabel("time [s] (x: fall)")
        for axis in axes:
            axis.grid(alpha=0.3)
        axes[0].legend(fontsize=8, loc="lower right")
        figure.suptitle(
            "Trotting under model schedules S0..S4: forward speed and height against the desired values "
            "(paper Fig. 8)",
            fontsize=10,
        )
        save_figure(figure, path)


def _mean_height(result: RunResult) -> float | None:
    log = result.log
    mask = log.time >= METRICS_WINDOW_START_S - 1e-9
    if not mask.any():
        mask = np.ones(log.ticks, dtype=bool)
    return float(np.mean(log.q[mask, 2])) if log.ticks else None
