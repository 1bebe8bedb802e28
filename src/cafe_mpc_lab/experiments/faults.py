"""``cafe-mpc experiment faults --task PRESET``: does the robot stay up and walk on when things fail?

No paper reports this; it is what a robot's operator expects (docs/faults.md). One preset (``--task``, a
gait), each fault kind (``--kinds``) at each start time (``--times``), one run per fault, injected by the
plant (``plant.faults``, ``sim.faults``):

* the sensors, with fixed latency (deterministic; these run in parallel): the IMU drops out for 50 and 500
  ms (``imu_dropout``), one knee encoder freezes for 100 and 500 ms (``encoder_freeze``), one NaN sample per
  second of the gyro and of every joint angle (``nan_sample``), one out-of-range accelerometer sample per
  second (``out_of_range``); the MPC's plans withheld for 0.2, 0.5 and 2 s, then a cold solve
  (``mpc_pause``: a stall or restart of the planner in simulated time);
* the MPC process, in real time (``simulation.realtime``; one after the other, each with the machine to
  itself): killed (``mpc_kill``), stopped for 0.2, 0.5 and 2 s (``mpc_stall``).

A run succeeds when the robot did not fall and the gait resumed: every safe-ladder episode off the plans
(``faults.ladder.episodes``) ended with a fresh plan taking the robot back, and after that (and after the
fault) every foot stepped again (``gait_resumed_s``: how long until each had lifted off). ``comparison.png``
shows each run's safe-ladder steps over time with its fault; each run's folder has its own ``faults.png``
(``report.fault_plots``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from pydantic import Field, model_validator

from cafe_mpc.assembly.checks import load_run_config, robot_of
from cafe_mpc.config import MPC_FAULTS, available_presets
from cafe_mpc.control.plan_follower import SafetyStep
from cafe_mpc_lab.experiments.common import RunStore, fall_fields, fell_text, num
from cafe_mpc_lab.experiments.options import ExperimentOptions, names, numbers
from cafe_mpc_lab.experiments.registry import Experiment, ExperimentPlan, PlanContext, Variant
from cafe_mpc_lab.experiments.run import RunResult
from cafe_mpc_lab.report.fault_plots import plot_ladders
from cafe_mpc_lab.sim.loop import SimulationLog

FAULT_KINDS = (
    "imu_dropout",
    "encoder_freeze",
    "nan_sample",
    "out_of_range",
    "mpc_pause",
    "mpc_kill",
    "mpc_stall",
)
"""The kinds ``--kinds`` chooses from, in the table's order."""
DURATIONS: dict[str, tuple[float, ...]] = {
    "imu_dropout": (0.05, 0.5),
    "encoder_freeze": (0.1, 0.5),
    "mpc_pause": (0.2, 0.5, 2.0),
    "mpc_stall": (0.2, 0.5, 2.0),
}
"""s; each kind that lasts is run with each of these."""
BAD_SAMPLES: dict[str, tuple[tuple[str, str | None], ...]] = {
    "nan_sample": (("gyro", None), ("joint_position", None)),
    "out_of_range": (("accelerometer", None),),
}
"""The sensors (and joint, None: every one) a bad sample hits, per kind."""
BAD_SAMPLE_PERIOD = 1.0
"""s between two bad samples (one per second)."""
FROZEN_JOINT = "FR_knee"
"""The encoder ``encoder_freeze`` freezes (a joint of every quadruped the presets run; else joint 2)."""
DEFAULT_TIMES = (2.0,)
"""s; when each fault starts (the gait is under way)."""

Kinds = names(FAULT_KINDS)
Times = numbers(0.0, 3600.0)


class FaultsOptions(ExperimentOptions):
    task: str | None = Field(
        None,
        description="the gait preset (or YAML config) every run uses (required)",
        json_schema_extra={"metavar": "PRESET"},
    )
    kinds: Kinds = Field(
        FAULT_KINDS,
        description="fault kinds to inject (default all: " + ", ".join(FAULT_KINDS) + ")",
        json_schema_extra={"metavar": "imu_dropout,mpc_kill"},
    )
    times: Times = Field(
        DEFAULT_TIMES,
        description="s, when each fault starts (default 2)",
        json_schema_extra={"metavar": "2,3.5"},
    )

    @model_validator(mode="after")
    def _task_given(self) -> FaultsOptions:
        if not self.task:
            raise ValueError(f"--task PRESET is required (presets: {', '.join(available_presets())})")
        return self


def _fault_text(fault: dict) -> str:
    """A fault as a ``plant.faults`` item in YAML flow style."""
    return "{" + ", ".join(f"{key}: {value}" for key, value in fault.items()) + "}"


def fault_variants(task: str, kinds: tuple[str, ...], times: tuple[float, ...], joints) -> list[Variant]:
    """One variant per fault kind, start time and duration (or bad-sample sensor) (module docstring)."""
    frozen = FROZEN_JOINT if FROZEN_JOINT in joints else 2
    variants = []
    for kind in kinds:
        for start in times:
            faults: list[tuple[str, dict, float | None]] = []
            if kind in DURATIONS:
                for duration in DURATIONS[kind]:
                    fault = {"kind": kind, "start": start, "duration": duration}
                    if kind == "encoder_freeze":
                        fault["joint"] = frozen
                    faults.append((f"{duration * 1e3:g}ms", fault, duration))
            elif kind in BAD_SAMPLES:
                for sensor, joint in BAD_SAMPLES[kind]:
                    fault = {"kind": kind, "start": start, "sensor": sensor, "period": BAD_SAMPLE_PERIOD}
                    if joint is not None:
                        fault["joint"] = joint
                    faults.append((sensor, fault, None))
            else:
                faults.append(("", {"kind": kind, "start": start}, 0.0))
            for tag, fault, duration in faults:
                realtime = kind in MPC_FAULTS
                overrides = [f"plant.faults=[{_fault_text(fault)}]"]
                if realtime:
                    overrides.append("simulation.realtime=true")
                name = "-".join(part for part in (kind, f"{start:g}s", tag) if part)
                variants.append(
                    Variant(
                        name,
                        task,
                        tuple(overrides),
                        f"{kind} at {start:g} s" + (f", {tag}" if tag else ""),
                        group=kind,
                        fields=(
                            ("kind", kind),
                            ("fault_start_s", start),
                            ("fault_duration_s", duration),
                            ("sensor", fault.get("sensor")),
                            ("realtime", realtime),
                        ),
                    )
                )
    return variants


class Faults(Experiment):
    name = "faults"
    title = "Faults on the robot's side: sensors and the MPC process"
    paper = "not in the paper (the safe ladder and recovery, docs/faults.md)"
    default_duration = 7.0
    varied_keys = ("plant.faults",)
    Options = FaultsOptions
    default_overrides = ("mpc.latency=fixed", "output.plots=true")
    errors_are_results = True

    def plan(self, options: FaultsOptions, context: PlanContext) -> ExperimentPlan:
        task = str(options.task)
        config = load_run_config(task, list(context.overrides))  # a bad preset or override: one error now
        joints = robot_of(config).joint_names
        plan_options = {"--task": task}
        if tuple(options.kinds) != FAULT_KINDS:
            plan_options["--kinds"] = ",".join(options.kinds)
        if tuple(options.times) != DEFAULT_TIMES:
            plan_options["--times"] = ",".join(f"{t:g}" for t in options.times)
        return ExperimentPlan(fault_variants(task, options.kinds, options.times, joints), plan_options)

    def summarize(self, result: RunResult, variant: Variant) -> dict:
        return fault_summary(result, dict(variant.fields))

    def table(self, rows: list[dict], comparison: dict) -> tuple[list[str], list[list[str]], list[str]]:
        header = [
            "fault",
            "fell",
            "lowest step",
            "off the plans [s]",
            "back after [s]",
            "MPC restarts (s each)",
            "rejected samples",
            "gait resumed after [s]",
            "success",
        ]
        body = []
        for row in rows:
            if row.get("status") != "ok":
                body.append(
                    [row.get("label") or row["run"], "", "", "", "", "", "", "", f"error: {row['error']}"]
                )
                continue
            restarts = row.get("restart_s") or []
            body.append(
                [
                    row.get("label") or row["run"],
                    fell_text(row),
                    row.get("lowest_step") or "plan",
                    num(row.get("off_plans_s"), 2),
                    num(row.get("back_after_s"), 2),
                    ", ".join(f"{value:.1f}" for value in restarts) if restarts else "0",
                    str(row.get("rejected_samples") or 0),
                    num(row.get("gait_resumed_s"), 2),
                    "yes" if row.get("success") else "no",
                ]
            )
        notes = [
            "Lowest step: the lowest rung of the safe ladder the run reached (plan, last_plan: the last "
            "plan still followed, balance: the balance stance, damped: the damped stance). Off the plans: "
            "seconds on balance or damped; back after: from leaving the plans to the fresh plan that took "
            "the robot back (the longest episode). MPC restarts: each restart's time from the exit to the "
            "new process's first plan. Rejected samples: what the sensing front end held at the last good "
            "value.",
            "Success: the robot did not fall and the gait resumed (every foot lifted off again after the "
            "fault and the take-back; gait resumed after: how long that took). Sensor faults run with fixed "
            "latency, MPC-process faults in real time (--realtime), one after the other.",
        ]
        return header, body, notes

    def plot(self, rows: list[dict], runs: RunStore, path: Path) -> None:
        ok = [row for row in rows if row.get("status") == "ok"]
        loaded = runs.load_all([row["run"] for row in ok])
        if loaded:
            labels = {row["run"]: row.get("label") or row["run"] for row in ok}
            runs = [
                (labels[name], result.log, result.metrics.get("faults") or {})
                for name, result in loaded.items()
            ]
            plot_ladders(runs, path)

    def summary_line(self, comparison: dict) -> str | None:
        rows = list(comparison.get("variants", {}).values())
        if not rows:
            return None
        succeeded = sum(1 for row in rows if row.get("success"))
        return f"faults: {succeeded} of {len(rows)} runs stayed up and walked on"


# ------------------------------------------------------------------------------------------ summary
def fault_summary(result: RunResult, fields: dict) -> dict:
    """The table's fields of one run (module docstring)."""
    metrics, log = result.metrics, result.log
    faults = metrics.get("faults") or {}
    ladder = faults.get("ladder") or {}
    episodes = ladder.get("episodes") or []
    order = list(SafetyStep)
    lowest = max((SafetyStep(episode["lowest"]) for episode in episodes), key=order.index, default=None)
    backs = [episode.get("back_at") for episode in episodes]
    recoveries = [episode.get("recovery_s") for episode in episodes if episode.get("recovery_s") is not None]
    time_s = ladder.get("time_s") or {}
    start = fields.get("fault_start_s") or 0.0
    duration = fields.get("fault_duration_s")
    fault_end = start + (duration or 0.0)
    taken_back = all(back is not None for back in backs)
    resume_from = max([fault_end, *(back for back in backs if back is not None)])
    resumed_after = stepping_again(log, resume_from) if taken_back and not log.fell else None
    mpc = faults.get("mpc") or {}
    sensors = faults.get("sensors") or {}
    rejected = sum((sensors.get("rejected") or {}).values())
    return {
        **fall_fields(metrics),
        "status_run": metrics.get("status", "completed"),
        "lowest_step": str(lowest) if lowest is not None else "plan",
        "episodes": len(episodes),
        "off_plans_s": time_s.get("balance", 0.0) + time_s.get("damped", 0.0) if time_s else 0.0,
        "back_after_s": max(recoveries) if recoveries else None,
        "taken_back": taken_back,
        "restarts": len(mpc.get("restarts") or []),
        "restart_s": [
            restart["restart_s"] for restart in mpc.get("restarts") or [] if restart.get("restart_s")
        ],
        "resyncs": mpc.get("resyncs"),
        "mpc_failure": mpc.get("failure"),
        "rejected_samples": rejected,
        "estimator_resets": len(sensors.get("estimator_resets") or []),
        "gait_resumed_s": resumed_after,
        "success": bool(not log.fell and resumed_after is not None and "status" not in metrics),
        "vx_mean": metrics.get("vx_mean"),
    }


def stepping_again(log: SimulationLog, since: float) -> float | None:
    """Seconds after ``since`` until every foot has lifted off at least once (the plant's contacts), None
    when some foot never did before the run ended."""
    after = log.time >= since - 1e-9
    if not after.any():
        return None
    contacts = log.contacts[after]
    times = log.time[after]
    lifted = ~contacts
    if not lifted.any(axis=0).all():
        return None
    first = np.argmax(lifted, axis=0)  # the first tick each foot is off the ground
    return float(times[int(first.max())] - since)
