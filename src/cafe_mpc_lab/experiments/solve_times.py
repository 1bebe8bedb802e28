"""``cafe-mpc experiment solve-times``: time per MS-iLQR iteration for pacing, flying trot and pronking over
the schedules S0..S4 with dts = 50 ms, beside the paper's Table II (Sec. VII-A1).

The paper's numbers are from its C++ implementation (4 threads, the authors' computer); ours are the mean wall
time of one iteration of our solver over a run's MPC updates (the cold first solve left out), in the Dask
worker process that ran the simulation. With one worker per core and nothing else running they are the
single-core times; other load on the machine inflates them.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from pydantic import Field

from cafe_mpc_lab.experiments.common import (
    WALL_CLOCK_NOTE,
    GaitPresetNames,
    RunStore,
    ScheduleNames,
    colors,
    fall_fields,
    fell_text,
    iteration_timing,
    num,
)
from cafe_mpc_lab.experiments.options import ExperimentOptions
from cafe_mpc_lab.experiments.registry import Experiment, ExperimentPlan, PlanContext, Variant
from cafe_mpc_lab.experiments.run import RunResult
from cafe_mpc_lab.report.figures import new_figure, save_figure

SRB_DT = 0.05
TABLE_II_SCHEDULES = ("S0", "S1", "S2", "S3", "S4")
PAPER_TABLE_II: dict[str, dict[str, float]] = {
    "pace": {"S0": 5.4143, "S1": 4.8653, "S2": 5.0176, "S3": 4.9466, "S4": 4.8907},
    "flying-trot": {"S0": 5.2323, "S1": 5.1333, "S2": 5.0770, "S3": 5.1805, "S4": 5.0575},
    "pronk": {"S0": 5.2313, "S1": 5.1079, "S2": 5.0574, "S3": 5.1948, "S4": 5.1342},
}
"""The paper's Table II: average ms per MS-iLQR iteration (dts = 50 ms), by gait preset and schedule."""
PAPER_GAIT_NAMES = {"pace": "Pace", "flying-trot": "FlyTrot", "pronk": "Pronk"}


class SolveTimesOptions(ExperimentOptions):
    gaits: GaitPresetNames = Field(
        tuple(PAPER_TABLE_II),
        description="gait presets (default: Table II's pace,flying-trot,pronk)",
        json_schema_extra={"metavar": "pace,pronk"},
    )
    schedules: ScheduleNames = Field(
        TABLE_II_SCHEDULES,
        description="model schedules (default: Table II's S0..S4)",
        json_schema_extra={"metavar": "S0,S4,..."},
    )


class SolveTimes(Experiment):
    name = "solve-times"
    title = "MS-iLQR time per iteration by gait and model schedule (dts = 50 ms)"
    paper = "paper Table II"
    default_duration = 5.0
    varied_keys = ("mpc.schedule", "mpc.whole_body_horizon", "mpc.srb_horizon", "mpc.srb_dt")
    Options = SolveTimesOptions
    reports_timing = True

    def plan(self, options: SolveTimesOptions, context: PlanContext) -> ExperimentPlan:
        from cafe_mpc.planners.cafe.problem import PAPER_SCHEDULES

        gaits, schedules = options.gaits, options.schedules
        variants = [
            Variant(
                f"{gait}-{s}",
                gait,
                (f"mpc.schedule={s}", f"mpc.srb_dt={SRB_DT:g}"),
                f"{gait}, {s}",
                group=gait,
                fields=(("gait", gait), ("schedule", s), ("srb_horizon_s", PAPER_SCHEDULES[s])),
            )
            for gait in gaits
            for s in schedules
        ]
        return ExperimentPlan(variants, {"--gaits": ",".join(gaits), "--schedules": ",".join(schedules)})

    def summarize(self, result: RunResult, variant: Variant) -> dict:
        timing = iteration_timing(result)
        paper = PAPER_TABLE_II.get(variant.group, {}).get(result.config.mpc.schedule or "")
        return {
            **fall_fields(result.metrics),
            "srb_dt": result.config.mpc.srb_dt,
            **timing,
            "paper_iteration_ms": paper,
            "ratio_to_paper": timing["iteration_ms_mean"] / paper
            if paper and timing["iteration_ms_mean"] is not None
            else None,
            "mpc_failures": (result.metrics.get("mpc") or {}).get("failures"),
        }

    def table(self, rows: list[dict], comparison: dict) -> tuple[list[str], list[list[str]], list[str]]:
        schedules = list(dict.fromkeys(str(r.get("schedule")) for r in rows))
        gaits = list(dict.fromkeys(str(r.get("gait") or r.get("group")) for r in rows))
        by_key = {(str(r.get("gait") or r.get("group")), str(r.get("schedule"))): r for r in rows}
        header = ["gait", *[f"{s}: ours / paper [ms]" for s in schedules], "fell"]
        body = []
        for gait in gaits:
            cells = [PAPER_GAIT_NAMES.get(gait, gait)]
            falls = []
            for s in schedules:
                row = by_key.get((gait, s), {})
                paper = PAPER_TABLE_II.get(gait, {}).get(s)
                cells.append(f"{num(row.get('iteration_ms_mean'), 2)} / {num(paper, 2)}")
                if row.get("error") or row.get("fell"):
                    falls.append(f"{s}: {fell_text(row)}")
            cells.append("; ".join(falls) or "no")
            body.append(cells)
        notes = [
            "Mean wall time of one MS-iLQR iteration over the MPC updates of each run (one iteration per "
            "update, the cold first solve left out), dts = 50 ms. Paper: C++, 4 threads (Table II). "
            + WALL_CLOCK_NOTE,
            "Line-search steps per update and iteration medians / p99 are in results.csv.",
        ]
        return header, body, notes

    def plot(self, rows: list[dict], runs: RunStore, path: Path) -> None:
        gaits = list(dict.fromkeys(str(r.get("gait") or r.get("group")) for r in rows))
        schedules = list(dict.fromkeys(str(r.get("schedule")) for r in rows))
        by_key = {(str(r.get("gait") or r.get("group")), str(r.get("schedule"))): r for r in rows}
        figure = new_figure((9, 4.5))
        axis = figure.add_subplot(1, 1, 1)
        width = 0.8 / max(len(gaits), 1)
        x = np.arange(len(schedules))
        for index, (gait, color) in enumerate(zip(gaits, colors(len(gaits)), strict=True)):
            offset = (index - (len(gaits) - 1) / 2) * width
            ours = [by_key.get((gait, s), {}).get("iteration_ms_mean") for s in schedules]
            axis.bar(
                x + offset,
                [np.nan if v is None else v for v in ours],
                width,
                color=color,
                label=f"{PAPER_GAIT_NAMES.get(gait, gait)}: ours",
            )
            paper = [PAPER_TABLE_II.get(gait, {}).get(s) for s in schedules]
            if any(p is not None for p in paper):
                axis.plot(
                    x + offset,
                    [np.nan if p is None else p for p in paper],
                    "_",
                    color="k",
                    ms=14,
                    mew=2,
                    label="paper (Table II)" if index == 0 else None,
                )
        axis.set_xticks(x, schedules)
        axis.set_xlabel("model schedule (Tw = 0.25 s, dts = 50 ms)")
        axis.set_ylabel("ms per MS-iLQR iteration (mean)")
        axis.grid(alpha=0.3, axis="y")
        axis.legend(fontsize=8)
        figure.suptitle(
            "Time per MS-iLQR iteration (paper Table II); ours: per-worker wall clock", fontsize=10
        )
        save_figure(figure, path)
