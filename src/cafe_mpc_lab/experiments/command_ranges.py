"""The command range that works, per gait: a sweep of forward speed and yaw rate (issue 22).

The schema accepts |vx| <= 3 m/s and |yaw_rate| <= 3 rad/s for any gait; what a gait actually tracks is much
less. This experiment runs each gait preset with one constant command per run (fixed latency: the result
does not depend on the machine), short runs, one after the other, and judges each run:

* ``works``: no fall, the mean forward speed of the steady-state window (from ``METRICS_WINDOW_START_S``)
  within ``SPEED_TOLERANCE`` (absolute) + ``SPEED_FRACTION`` x |vx| of the command, and the yaw rate's RMS
  error within ``YAW_TOLERANCE`` + ``YAW_FRACTION`` x |yaw rate|.

Per gait, the tested range is the span of commanded speeds (and, at the base speed, yaw rates) that worked,
contiguous from the base command. The result is ``reference.tested_ranges.TESTED_RANGES`` (the warning a
command outside it gets) and the table in ``docs/usage.md``.

    cafe-mpc experiment command-ranges --gaits trot,bound --speeds 0.5,1,1.5 --yaw-rates 0.5,1 --workers 2

runs it on Dask like every experiment (results.csv, comparison.md/json/png); ``python -m
cafe_mpc_lab.experiments.command_ranges ... --write`` runs the same sweep in this process and writes the
ranges file the warning reads.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

from pydantic import Field

from cafe_mpc.assembly.checks import load_run_config
from cafe_mpc_lab.experiments.common import SPEED_TOLERANCE, RunStore, fell_text, num
from cafe_mpc_lab.experiments.options import ExperimentOptions, names, numbers
from cafe_mpc_lab.experiments.registry import Experiment, ExperimentPlan, PlanContext, Variant
from cafe_mpc_lab.experiments.run import RunResult, run
from cafe_mpc_lab.report.figures import save_figure, subplots

GAIT_PRESETS = ("trot", "pace", "bound", "pronk", "flying-trot")
SPEED_FRACTION = 0.2
YAW_TOLERANCE = 0.1
"""rad/s: a tracked yaw rate has an RMS error within this + ``YAW_FRACTION`` x |yaw rate|."""
YAW_FRACTION = 0.3
BASE_SPEED = 0.5
"""m/s: the presets' command, the speed the yaw-rate sweep runs at."""


@dataclass
class RangeRun:
    """One run of the sweep and its verdict."""

    gait: str
    vx: float
    yaw_rate: float
    fell: bool
    fall_time_s: float | None
    vx_mean: float | None
    yaw_rate_rms_error: float | None
    works: bool
    wall_s: float


def judge(vx: float, yaw_rate: float, metrics: dict) -> RangeRun:
    """The verdict of one run's ``metrics.json`` (see the module docstring)."""
    steady = metrics.get("steady_state") or {}
    vx_mean = steady.get("vx_mean")
    yaw_error = steady.get("yaw_rate_rms_error")
    works = bool(
        not metrics["fell"]
        and vx_mean is not None
        and abs(vx_mean - vx) <= SPEED_TOLERANCE + SPEED_FRACTION * abs(vx)
        and yaw_error is not None
        and yaw_error <= YAW_TOLERANCE + YAW_FRACTION * abs(yaw_rate)
    )
    return RangeRun(
        "",
        vx,
        yaw_rate,
        bool(metrics["fell"]),
        metrics.get("fall_time_s"),
        vx_mean,
        yaw_error,
        works,
        float(metrics.get("wall_time_s") or 0.0),
    )


def command_override(vx: float, yaw_rate: float) -> str:
    """The ``--set`` item of one constant command."""
    return f"gait.commands=[{{vx: {vx}, yaw_rate: {yaw_rate}}}]"


def sweep_commands(speeds: Sequence[float], yaw_rates: Sequence[float]) -> list[tuple[float, float]]:
    """Every speed at yaw rate 0, then every non-zero yaw rate at ``BASE_SPEED``."""
    return [(float(vx), 0.0) for vx in speeds] + [(BASE_SPEED, float(w)) for w in yaw_rates if w != 0.0]


class CommandRangesOptions(ExperimentOptions):
    gaits: names(GAIT_PRESETS) = Field(
        GAIT_PRESETS,
        description=f"gait presets (default {','.join(GAIT_PRESETS)})",
        json_schema_extra={"metavar": "trot,bound"},
    )
    speeds: numbers(0.0, 3.0) = Field(
        (0.5, 1.0, 1.5, 2.0),
        description="forward speeds at yaw rate 0, m/s (default 0.5,1,1.5,2)",
        json_schema_extra={"metavar": "0.5,1,1.5,2"},
    )
    yaw_rates: numbers(0.0, 3.0, none_word=True) = Field(
        (0.5, 1.0),
        description=f"yaw rates at {BASE_SPEED} m/s, rad/s (default 0.5,1; none: skip)",
        json_schema_extra={"metavar": "0.5,1"},
    )


class CommandRanges(Experiment):
    """The sweep of the module docstring on Dask: one run per gait and constant command."""

    name = "command-ranges"
    title = "The command range each gait tracks: forward speed and yaw rate"
    paper = "not in the paper (issue 22's tested ranges)"
    default_duration = 3.0
    default_overrides = ("mpc.latency=fixed",)
    varied_keys = ("gait.commands",)
    Options = CommandRangesOptions

    def plan(self, options: CommandRangesOptions, context: PlanContext) -> ExperimentPlan:
        variants = [
            Variant(
                f"{gait}-vx{vx:g}-yaw{yaw_rate:g}",
                gait,
                (command_override(vx, yaw_rate),),
                f"{gait}, vx {vx:g}, yaw rate {yaw_rate:g}",
                group=gait,
                fields=(("gait", gait), ("vx_command", vx), ("yaw_rate_command", yaw_rate)),
            )
            for gait in options.gaits
            for vx, yaw_rate in sweep_commands(options.speeds, options.yaw_rates)
        ]
        chosen = {
            "--gaits": ",".join(options.gaits),
            "--speeds": ",".join(f"{v:g}" for v in options.speeds),
            "--yaw-rates": ",".join(f"{v:g}" for v in options.yaw_rates) or "none",
        }
        return ExperimentPlan(variants, chosen)

    def summarize(self, result: RunResult, variant: Variant) -> dict:
        fields = dict(variant.fields)
        verdict = judge(float(fields["vx_command"]), float(fields["yaw_rate_command"]), result.metrics)
        verdict.gait = str(fields["gait"])
        summary = asdict(verdict)
        summary.pop("wall_s")
        return summary

    def _runs(self, rows: list[dict]) -> list[RangeRun]:
        return [
            RangeRun(
                str(r.get("gait")),
                float(r.get("vx_command")),
                float(r.get("yaw_rate_command")),
                bool(r.get("fell")),
                r.get("fall_time_s"),
                r.get("vx_mean"),
                r.get("yaw_rate_rms_error"),
                bool(r.get("works")),
                0.0,
            )
            for r in rows
            if r.get("works") is not None
        ]

    def table(self, rows: list[dict], comparison: dict) -> tuple[list[str], list[list[str]], list[str]]:
        header = [
            "gait",
            "vx command [m/s]",
            "yaw rate command [rad/s]",
            "fell",
            "vx mean [m/s]",
            "yaw rate RMS error [rad/s]",
            "works",
        ]
        body = [
            [
                str(r.get("gait")),
                num(r.get("vx_command"), 2),
                num(r.get("yaw_rate_command"), 2),
                fell_text(r),
                num(r.get("vx_mean")),
                num(r.get("yaw_rate_rms_error")),
                "yes" if r.get("works") else "no",
            ]
            for r in rows
        ]
        gaits = list(dict.fromkeys(str(r.get("gait")) for r in rows))
        notes = [
            f"works: no fall, steady-state vx within {SPEED_TOLERANCE} + {SPEED_FRACTION} |vx| of the "
            f"command, yaw rate RMS error within {YAW_TOLERANCE} + {YAW_FRACTION} |yaw rate|.",
            "",
            table(self._runs(rows), gaits),
        ]
        return header, body, notes

    def plot(self, rows: list[dict], runs: RunStore, path: Path) -> None:
        gaits = list(dict.fromkeys(str(r.get("gait")) for r in rows))
        figure, axes = subplots(1, 2, figsize=(10, 3.5))
        sweeps = (
            (axes[0], "vx_command", "yaw_rate_command", 0.0),
            (axes[1], "yaw_rate_command", "vx_command", BASE_SPEED),
        )
        for index, gait in enumerate(gaits):
            for axis, key, other, other_value in sweeps:
                for r in rows:
                    if r.get("gait") != gait or r.get(other) != other_value:
                        continue
                    works = bool(r.get("works"))
                    axis.scatter(
                        float(r[key]),
                        index,
                        marker="o" if works else "x",
                        color="tab:green" if works else "tab:red",
                    )
        for axis, label in zip(
            axes,
            ("forward speed command [m/s] (yaw rate 0)", f"yaw rate command [rad/s] (vx {BASE_SPEED} m/s)"),
            strict=True,
        ):
            axis.set_yticks(range(len(gaits)), gaits)
            axis.set_xlabel(label)
            axis.grid(alpha=0.3)
        axes[0].set_title("o works, x does not")
        save_figure(figure, path)


def run_one(gait: str, vx: float, yaw_rate: float, duration: float, overrides: list[str]) -> RangeRun:
    """One gait preset with one constant command (fixed latency, no plots)."""
    config = load_run_config(
        gait,
        [
            "mpc.latency=fixed",
            f"simulation.duration={duration}",
            "output.plots=false",
            command_override(vx, yaw_rate),
            *overrides,
        ],
    )
    start = time.perf_counter()
    result = run(config, None)
    verdict = judge(vx, yaw_rate, result.metrics)
    verdict.gait = gait
    verdict.wall_s = time.perf_counter() - start
    return verdict


def tested_range(runs: list[RangeRun], gait: str) -> dict:
    """The contiguous span of speeds (at yaw rate 0) and of yaw rates (at ``BASE_SPEED``) that worked."""
    speeds = sorted((r.vx, r.works) for r in runs if r.gait == gait and r.yaw_rate == 0.0)
    yaws = sorted((r.yaw_rate, r.works) for r in runs if r.gait == gait and r.vx == BASE_SPEED)
    low = high = None
    for vx, works in speeds:
        if vx < BASE_SPEED:
            continue
        if not works:
            break
        low = BASE_SPEED if low is None else low
        high = vx
    for vx, works in reversed([s for s in speeds if s[0] < BASE_SPEED]):
        if not works or low is None:
            break
        low = vx
    yaw_max = None
    for yaw, works in yaws:
        if yaw <= 0.0:
            continue
        if not works:
            break
        yaw_max = yaw
    return {"vx": [low, high] if low is not None else None, "yaw_rate_max": yaw_max}


def sweep(
    gaits: list[str], speeds: list[float], yaw_rates: list[float], duration: float, overrides: list[str]
) -> list[RangeRun]:
    """Every gait at every speed (yaw rate 0) and every yaw rate (at ``BASE_SPEED``), one after the other."""
    runs = []
    for gait in gaits:
        for vx, yaw_rate in sweep_commands(speeds, yaw_rates):
            verdict = run_one(gait, vx, yaw_rate, duration, overrides)
            print(
                f"{gait:12s} vx {vx:4.2f} yaw {yaw_rate:4.2f}: works={verdict.works} fell={verdict.fell} "
                f"vx_mean={verdict.vx_mean} yaw_err={verdict.yaw_rate_rms_error} ({verdict.wall_s:.0f} s)",
                flush=True,
            )
            runs.append(verdict)
    return runs


def table(runs: list[RangeRun], gaits: list[str]) -> str:
    """A markdown table: per gait, the tested speed span and the largest tested yaw rate."""
    lines = [
        "| gait | forward speed that works (m/s) | yaw rate that works at 0.5 m/s (rad/s) |",
        "|---|---|---|",
    ]
    for gait in gaits:
        found = tested_range(runs, gait)
        span = f"{found['vx'][0]:g} to {found['vx'][1]:g}" if found["vx"] else "none of the tested"
        yaw = f"up to {found['yaw_rate_max']:g}" if found["yaw_rate_max"] else "none of the tested"
        lines.append(f"| {gait} | {span} | {yaw} |")
    return "\n".join(lines)


def write_ranges(runs: list[RangeRun], gaits: list[str], command: str) -> Path:
    """``reference/data/tested_ranges.yaml``: per gait the ranges found, with the date and the command."""
    import datetime

    import yaml

    from cafe_mpc.reference.tested_ranges import TESTED_RANGES_FILE, TESTED_ROBOT

    data = {
        "measured": datetime.date.today().isoformat(),
        "robot": TESTED_ROBOT,
        "command": command,
        "criterion": f"no fall; steady-state mean vx within {SPEED_TOLERANCE} + {SPEED_FRACTION} |vx|; yaw "
        f"rate RMS error within {YAW_TOLERANCE} + {YAW_FRACTION} |yaw rate| (fixed latency)",
        "gaits": {gait.replace("-", "_"): tested_range(runs, gait) for gait in gaits},
    }
    TESTED_RANGES_FILE.write_text(yaml.safe_dump(data, sort_keys=False))
    return TESTED_RANGES_FILE


def _numbers(text: str) -> list[float]:
    return [float(item) for item in text.split(",") if item.strip()]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--gaits", default=",".join(GAIT_PRESETS), help="gait presets")
    parser.add_argument("--speeds", default="0.5,1.0,1.5,2.0", help="forward speeds, m/s (yaw rate 0)")
    parser.add_argument("--yaw-rates", default="0.5,1.0", help="yaw rates at 0.5 m/s, rad/s")
    parser.add_argument("--duration", type=float, default=3.0, help="simulated seconds per run")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override, every run")
    parser.add_argument("--out", help="write results.json and table.md here")
    parser.add_argument(
        "--write",
        action="store_true",
        help="write the ranges found to reference/data/tested_ranges.yaml (the warning's data)",
    )
    arguments = parser.parse_args(argv)
    gaits = [gait.strip() for gait in arguments.gaits.split(",") if gait.strip()]
    runs = sweep(
        gaits, _numbers(arguments.speeds), _numbers(arguments.yaw_rates), arguments.duration, arguments.set
    )
    text = table(runs, gaits)
    print(text)
    if arguments.out:
        out = Path(arguments.out)
        out.mkdir(parents=True, exist_ok=True)
        (out / "results.json").write_text(json.dumps([asdict(r) for r in runs], indent=2))
        (out / "table.md").write_text(text + "\n")
    if arguments.write:
        write_ranges(
            runs,
            gaits,
            " ".join(["python -m cafe_mpc_lab.experiments.command_ranges", *(argv or sys.argv[1:])]),
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
