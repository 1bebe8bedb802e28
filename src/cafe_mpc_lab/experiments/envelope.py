"""``cafe-mpc experiment envelope``: a preset's success rate against the size of one model error at a time.

The reliability test (``experiments.reliability``) draws every factor at once from fixed ranges; this sweep
moves one factor over a range of values with every other factor at its nominal value, so that a user sees
where a controller stops working before putting it on a robot: floor friction, the whole robot's mass (and
inertia) scale, the motors' strength, the size of a random push, the IMU biases (times the reliability test's
default bounds). Each point is ``--trials`` trials that differ by their seed (the sensors' noise, the push's
direction and start time, the biases' signs); the preset's estimator and sensors are kept. A point's value is
set exactly (``friction 0.35``: every trial on a 0.35 floor); the push's magnitude and the biases are drawn
uniformly up to it, as in the reliability test.

``--oracle`` tells each trial's controller its plant (``reliability.oracle_overrides``: a diagnostic of
whether knowing the model would help, not something a robot can do).

Timing: ``mpc.latency=fixed`` like the reliability test (a seed reproduces its trial on any worker). Each
point's rate comes with its Wilson 95 % interval; ``comparison.png`` draws one curve per factor.
"""

from __future__ import annotations

import math
from collections import defaultdict
from pathlib import Path

import numpy as np
from pydantic import Field, model_validator

from cafe_mpc_lab.experiments.common import RunStore, pct
from cafe_mpc_lab.experiments.options import ExperimentOptions, integer, integers, numbers
from cafe_mpc_lab.experiments.registry import Experiment, ExperimentPlan, PlanContext, Variant
from cafe_mpc_lab.experiments.reliability import (
    RandomizationRanges,
    Reliability,
    _flow,
    _succeeded,
    check_oracle_overrides,
    oracle_overrides,
    sample_trial,
    wilson_interval,
)
from cafe_mpc_lab.experiments.run import RunResult
from cafe_mpc_lab.report.figures import new_figure, save_figure

FACTORS: dict[str, tuple[str, tuple[float, ...]]] = {
    "friction": ("floor friction", (0.2, 0.3, 0.35, 0.4, 0.5, 0.6, 0.8, 1.0)),
    "mass": ("mass scale (whole robot)", (0.7, 0.8, 0.9, 1.0, 1.1, 1.15, 1.2, 1.3)),
    "motor": ("motor strength", (0.7, 0.8, 0.85, 0.9, 1.0, 1.1)),
    "push": ("push, m/s (up to)", (0.0, 0.25, 0.5, 0.75, 1.0, 1.25, 1.5)),
    "imu_bias": ("IMU bias (x the default bounds)", (0.0, 1.0, 2.0, 3.0)),
}
"""Factor -> (axis label, default values)."""

NOMINAL = RandomizationRanges(
    floor_friction=(0.6, 0.6),
    body_mass_scale=(1.0, 1.0),
    link_mass_scale=(1.0, 1.0),
    motor_strength_scale=(1.0, 1.0),
    measurement_delay_max=0.0,
    imu_gyro_bias=0.0,
    imu_accelerometer_bias=0.0,
    imu_orientation_bias=0.0,
    push={"max_velocity_change": 0.0},
)
"""Every factor nominal (the floor: the robot table's friction, replaced per robot in ``plan``)."""
DEFAULT_BIASES = RandomizationRanges()


class EnvelopeOptions(ExperimentOptions):
    task: str | None = Field(
        None,
        description="the preset (or YAML config) every trial runs (required)",
        json_schema_extra={"metavar": "PRESET"},
    )
    factors: str | None = Field(
        None,
        description=f"comma-separated factors (default all: {', '.join(FACTORS)})",
        json_schema_extra={"metavar": "friction,motor"},
    )
    values: numbers(0.0, 10.0) | None = Field(
        None,
        description="comma-separated values for a single --factors (default: the factor's own list)",
        json_schema_extra={"metavar": "0.3,0.4"},
    )
    trials: integer(1, 10_000) = Field(10, description="trials per point (default 10)")
    seed: integer(0, 2**31) = Field(0, description="seed of a point's first trial (default 0)")
    seeds: integers(0) | None = Field(None, description="exactly these seeds at every point")
    oracle: bool = Field(
        False,
        description="diagnostic: tell the controller each trial's plant (masses, motor strengths as its "
        "calibration; friction at the usual margin), which a robot never knows",
    )

    @model_validator(mode="after")
    def _check(self) -> EnvelopeOptions:
        if not self.task:
            raise ValueError("--task PRESET is required")
        unknown = [name for name in self.factor_names if name not in FACTORS]
        if unknown:
            raise ValueError(f"--factors: unknown {unknown}; known: {', '.join(FACTORS)}")
        if self.values is not None and len(self.factor_names) != 1:
            raise ValueError("--values needs exactly one --factors")
        return self

    @property
    def factor_names(self) -> list[str]:
        if not self.factors:
            return list(FACTORS)
        return [name.strip() for name in self.factors.split(",") if name.strip()]

    def points(self, factor: str) -> tuple[float, ...]:
        return tuple(self.values) if self.values is not None else FACTORS[factor][1]

    @property
    def trial_seeds(self) -> list[int]:
        return list(self.seeds) if self.seeds is not None else list(range(self.seed, self.seed + self.trials))


def point_ranges(factor: str, value: float, nominal_friction: float) -> tuple[RandomizationRanges, float]:
    """The randomisation ranges of one point (every other factor nominal) and the whole-robot mass scale."""
    update: dict = {"floor_friction": (nominal_friction, nominal_friction)}
    mass = 1.0
    if factor == "friction":
        update["floor_friction"] = (value, value)
    elif factor == "mass":
        mass = value
    elif factor == "motor":
        update["motor_strength_scale"] = (value, value)
    elif factor == "push":
        update["push"] = {"max_velocity_change": value}
    elif factor == "imu_bias":
        update["imu_gyro_bias"] = value * DEFAULT_BIASES.imu_gyro_bias
        update["imu_accelerometer_bias"] = value * DEFAULT_BIASES.imu_accelerometer_bias
        update["imu_orientation_bias"] = value * DEFAULT_BIASES.imu_orientation_bias
    data = NOMINAL.model_dump() | update
    return RandomizationRanges.model_validate(data), mass


class Envelope(Experiment):
    name = "envelope"
    title = "Robustness envelope: success rate against each model error alone"
    paper = "not in the paper (its Fig. 17 is one randomised set)"
    default_duration = None
    varied_keys = ("plant",)
    Options = EnvelopeOptions
    default_overrides = ("output.plots=false", "mpc.latency=fixed")
    needs_gait = False
    errors_are_results = True

    def plan(self, options: EnvelopeOptions, context: PlanContext) -> ExperimentPlan:
        from cafe_mpc.assembly.checks import load_run_config
        from cafe_mpc.robots.robot import load_robot

        task = str(options.task)
        extra = [f"simulation.duration={context.duration}"] if context.duration is not None else []
        base = load_run_config(task, [*context.overrides, *extra])
        robot = load_robot(base.robot)
        duration = base.simulation.duration
        existing = [push.model_dump(mode="json", exclude_none=True) for push in base.pushes]
        sensors = base.plant.sensors.model_dump(mode="json")
        task_name = Path(task).stem if task.endswith((".yaml", ".yml")) else task
        if options.oracle:
            check_oracle_overrides(context.overrides)
        variants = []
        for factor in options.factor_names:
            for value in options.points(factor):
                ranges, mass = point_ranges(factor, value, robot.plant.floor_friction)
                for seed in options.trial_seeds:
                    plant, push = sample_trial(ranges, seed, robot.nu, duration, base.estimator, sensors)
                    plant["mass_scale"] = mass
                    oracle = (
                        oracle_overrides(plant, base, robot.plant.floor_friction) if options.oracle else ()
                    )
                    pushes = [*existing, push] if ranges.push.max_velocity_change > 0 else existing
                    variants.append(
                        Variant(
                            f"{factor}-{value:g}-{seed:04d}",
                            task,
                            (f"plant={_flow(plant)}", f"pushes={_flow(pushes)}", *oracle),
                            f"{factor} {value:g}, seed {seed}",
                            group=factor,
                            variant=task_name,
                            seed=seed,
                            fields=(("factor", factor), ("value", value)),
                        )
                    )
        plan_options = {"--task": task, "--factors": ",".join(options.factor_names)}
        if options.values is not None:
            plan_options["--values"] = ",".join(f"{value:g}" for value in options.values)
        if options.seeds is not None:
            plan_options["--seeds"] = ",".join(str(s) for s in options.seeds)
        else:
            plan_options["--trials"] = str(options.trials)
            plan_options["--seed"] = str(options.seed)
        if options.oracle:
            plan_options["--oracle"] = ""
        return ExperimentPlan(variants, plan_options, drop_files=("log.npz",))

    def summarize(self, result: RunResult, variant: Variant) -> dict:
        return Reliability().summarize(result, variant)

    def outputs(self, rows: list[dict], comparison: dict, out_dir: Path) -> dict:
        return {"envelope": envelope_summary(rows)}

    def table(self, rows: list[dict], comparison: dict) -> tuple[list[str], list[list[str]], list[str]]:
        summary = comparison.get("envelope") or envelope_summary(rows)
        header = ["factor", "value", "success", "Wilson 95 %", "failures: fell / slipped / solver"]
        body = []
        for factor, points in summary.items():
            for point in points:
                low, high = point["wilson_95"]
                modes = point["failure_modes"]
                body.append(
                    [
                        FACTORS[factor][0],
                        f"{point['value']:g}",
                        f"{point['successes']} of {point['trials']}",
                        f"{pct(low)} - {pct(high)}",
                        f"{modes['fell']} / {modes['slipped']} / {modes['solver_failed']}",
                    ]
                )
        notes = [
            "Each point: the factor at that value, every other factor nominal; trials differ by their seed. "
            "A trial succeeds as in the reliability test (no fall, no error, the task's own verdict)."
        ]
        return header, body, notes

    def summary_line(self, comparison: dict) -> str | None:
        summary = comparison.get("envelope")
        if not summary:
            return None
        parts = []
        for factor, points in summary.items():
            parts.append(
                f"{factor}: " + ", ".join(f"{p['value']:g} {p['successes']}/{p['trials']}" for p in points)
            )
        return "envelope: " + "; ".join(parts)

    def plot(self, rows: list[dict], runs: RunStore, path: Path) -> None:
        plot_envelope(envelope_summary(rows), path)


def envelope_summary(rows: list[dict]) -> dict[str, list[dict]]:
    """Per factor, per value (sorted): trials, successes, rate, Wilson interval, failure modes."""
    grouped: dict[str, dict[float, list[dict]]] = defaultdict(lambda: defaultdict(list))
    for row in rows:
        if row.get("status") == "crashed" or row.get("factor") is None:
            continue
        grouped[str(row["factor"])][float(row["value"])].append(row)
    summary: dict[str, list[dict]] = {}
    for factor in FACTORS:
        if factor not in grouped:
            continue
        points = []
        for value in sorted(grouped[factor]):
            trials = grouped[factor][value]
            successes = sum(_succeeded(r) for r in trials)
            failed = [r for r in trials if not _succeeded(r)]
            points.append(
                {
                    "value": value,
                    "trials": len(trials),
                    "successes": successes,
                    "success_rate": successes / len(trials),
                    "wilson_95": list(wilson_interval(successes, len(trials))),
                    "failure_modes": {
                        "fell": sum(bool(r.get("fell")) for r in failed),
                        "slipped": sum(bool(r.get("slipped")) for r in failed),
                        "solver_failed": sum(bool(r.get("solver_failed")) for r in failed),
                    },
                    "failed_seeds": [r.get("seed") for r in failed],
                }
            )
        summary[factor] = points
    return summary


def plot_envelope(summary: dict[str, list[dict]], path: Path) -> Path:
    """One panel per factor: success rate against the factor's value, with the Wilson 95 % interval."""
    factors = list(summary)
    columns = min(3, max(1, len(factors)))
    rows = math.ceil(len(factors) / columns) if factors else 1
    figure = new_figure((4.5 * columns, 3.4 * rows))
    for index, factor in enumerate(factors):
        axis = figure.add_subplot(rows, columns, index + 1)
        points = summary[factor]
        x = np.array([p["value"] for p in points])
        rate = np.array([100 * p["success_rate"] for p in points])
        low = np.array([100 * p["wilson_95"][0] for p in points])
        high = np.array([100 * p["wilson_95"][1] for p in points])
        axis.fill_between(x, low, high, alpha=0.25, color="C0")
        axis.plot(x, rate, "o-", color="C0")
        axis.set_xlabel(FACTORS[factor][0])
        axis.set_ylabel("success [%]")
        axis.set_ylim(-3, 103)
        axis.grid(alpha=0.3)
    figure.suptitle("Robustness envelope (each factor alone; Wilson 95 % band)", fontsize=10)
    return save_figure(figure, path)
