"""``cafe-mpc experiment reliability``: repeated, domain-randomised trials of any preset (the paper's
reliability test, Sec. VII-C3 and Fig. 17: 16 of 22 Fosbury-flop barrel rolls succeeded on hardware).

Each trial runs the preset (``--task``) on a plant drawn at random from ``RandomizationRanges`` with the
trial's seed: floor friction 0.4-0.9, trunk mass +-10 %, every leg link's mass +-10 %, every motor's strength
+-10 %, Gaussian sensor noise on the measured state (with ``estimator: ground_truth``; with ``estimator:
kinematic_kf`` the controller reads the robot's sensors, ``plant.sensors``, and each trial draws constant
IMU biases: gyro, accelerometer and attitude), a latency jitter (each tick the controller sees a state
up to ``measurement_delay_max`` old), and a push of random horizontal direction, start time and magnitude (up
to ``--max-push``, m/s of base velocity change over 50 ms), added to the preset's own pushes. The sampled
values go into the trial's ``plant`` and ``pushes`` config sections (``sim.randomization``): only the
simulated robot and its sensors change, never the controller's model. ``numpy.random.default_rng(seed)`` draws
them, so a seed is a trial: ``--seeds 7`` re-runs trial 7 alone, and so does
``cafe-mpc run OUT/trial-0007/config.yaml``.

``--oracle`` is a diagnostic, not a controller: each trial's controller is told its plant (masses and motor
strengths as its ``calibration``, the floor's friction at the usual margin: ``oracle_overrides``), which a
robot never is. A failure that the oracle removes comes from not knowing the model, and online estimation
of that factor can address it; one that stays is a limit of the robot or of the motion.

Timing: trials run with ``mpc.latency=fixed`` (a plan acts 20 ms after its measurement, deterministic and
independent of the machine's load, so a seed reproduces its trial on any worker); the latency jitter comes on
top of it. ``--set mpc.latency=measured`` gives the presets' measured mode (honest only with one worker per
core).

A trial succeeds when it runs its whole duration without falling and without a simulator or controller error
(and, when the run's metrics carry a task verdict ``success``, e.g. a barrel roll that must turn, when that
is true). Failure modes, counted over all trials and over the failed ones: fell, slipped (a stance foot slid
more than ``SLIP_THRESHOLD_M``), torque saturation (a motor was commanded beyond its limit on at least one
tick), solver failures (at least one MPC update failed), simulation error.

Writes ``summary.json`` (``trials``, ``successes``, ``success_rate``, ``wilson_95``, the failure modes, the
failed seeds, the ranges and the paper's numbers) beside ``results.csv`` (one row per trial: seed, sampled
parameters, outcome) and the comparison files.
"""

from __future__ import annotations

import copy
import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from matplotlib.ticker import MaxNLocator
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from cafe_mpc.assembly.checks import load_run_config
from cafe_mpc.config import ConfigError, RunConfig, SensorNoise, format_validation_error
from cafe_mpc_lab.experiments.common import RunStore, fall_fields, markdown_table, num, pct
from cafe_mpc_lab.experiments.options import ExperimentOptions, integer, integers, number
from cafe_mpc_lab.experiments.registry import Experiment, ExperimentPlan, PlanContext, Variant
from cafe_mpc_lab.experiments.run import RunResult
from cafe_mpc_lab.report.figures import new_figure, save_figure

SLIP_THRESHOLD_M = 0.05
"""A trial 'slipped' when a stance foot slid farther than this (``foot_slip_max_m``; nominal bound: 0.03)."""
PAPER_TRIALS, PAPER_SUCCESSES = 22, 16
"""Sec. VII-C3: 22 Fosbury-flop trials on the Mini Cheetah, 16 successful (Fig. 17's caption says 20 and
70 %)."""
DEFAULT_TRIALS = PAPER_TRIALS
WILSON_Z_95 = 1.959963984540054
"""The standard normal's 97.5 % quantile."""
FAILURE_MODES = (
    ("fell", "fell"),
    ("slipped", f"slipped (a stance foot slid > {SLIP_THRESHOLD_M * 100:g} cm)"),
    ("torque_saturated", "torque saturation (a motor commanded beyond its limit)"),
    ("solver_failed", "solver failures (an MPC update failed)"),
    ("simulation_error", "simulation or controller error"),
)


def wilson_interval(successes: int, trials: int, z: float = WILSON_Z_95) -> tuple[float, float]:
    """The Wilson score interval of a binomial proportion (95 % by default); ``(0, 1)`` without trials.

    ``(p + z^2 / 2n -+ z sqrt(p (1 - p) / n + z^2 / 4n^2)) / (1 + z^2 / n)`` with ``p = successes / n``:
    unlike the normal approximation it stays inside [0, 1] and is sensible for few trials and rates near
    0 or 1 (E. B. Wilson, 1927).
    """
    if trials <= 0:
        return 0.0, 1.0
    if not 0 <= successes <= trials:
        raise ValueError(f"successes must be in [0, {trials}], got {successes}")
    p = successes / trials
    z2 = z * z
    centre = (p + z2 / (2 * trials)) / (1 + z2 / trials)
    half = z / (1 + z2 / trials) * math.sqrt(p * (1 - p) / trials + z2 / (4 * trials * trials))
    return max(0.0, centre - half), min(1.0, centre + half)


# ------------------------------------------------------------------------------------------ ranges
class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


Interval = tuple[float, float]


def _ordered(name: str, interval: Interval, low: float, high: float) -> None:
    if not (low <= interval[0] <= interval[1] <= high):
        raise ValueError(f"{name}: need {low:g} <= low <= high <= {high:g}, got {list(interval)}")


class PushRange(_Strict):
    """The random push: horizontal direction uniform, start uniform in ``window`` (fractions of the run's
    duration), base velocity change uniform in [0, ``max_velocity_change``] m/s over ``duration`` s."""

    max_velocity_change: float = Field(0.5, ge=0.0, le=5.0)
    duration: float = Field(0.05, gt=0.0, le=1.0)
    window: Interval = (0.25, 0.75)

    @model_validator(mode="after")
    def _window_ok(self) -> PushRange:
        _ordered("push.window", self.window, 0.0, 1.0)
        return self


class RandomizationRanges(_Strict):
    """What a reliability trial draws (uniformly, independently per link and per motor); a YAML file with
    any of these keys changes them (``--ranges FILE``)."""

    floor_friction: Interval = (0.4, 0.9)
    body_mass_scale: Interval = (0.9, 1.1)
    link_mass_scale: Interval = (0.9, 1.1)
    motor_strength_scale: Interval = (0.9, 1.1)
    sensor_noise: SensorNoise = SensorNoise(
        base_position=0.002,
        base_orientation=0.005,
        base_linear_velocity=0.05,
        base_angular_velocity=0.02,
        joint_position=0.001,
        joint_velocity=0.05,
    )
    """Standard deviations, the same in every trial (each trial draws its own noise)."""
    measurement_delay_max: float = Field(0.004, ge=0.0, le=0.05)
    """Latency jitter, s: each control tick sees a state (or the sensors' readings) between 0 and this old
    (whole ticks)."""
    imu_gyro_bias: float = Field(0.01, ge=0.0, le=1.0)
    """rad/s: with ``estimator: kinematic_kf`` each trial draws a constant gyro bias uniformly in +-this per
    axis (instead of ``sensor_noise``; the sensors' own noise and quantisation, ``plant.sensors``, stay)."""
    imu_accelerometer_bias: float = Field(0.1, ge=0.0, le=5.0)
    """m/s^2: the same for the accelerometer (0.1 m/s^2 is 10 mg, an uncalibrated MEMS turn-on bias)."""
    imu_orientation_bias: float = Field(0.01, ge=0.0, le=0.5)
    """rad: the same for the IMU's attitude output, per axis (0.57 deg: an AHRS's pitch/roll accuracy)."""
    push: PushRange = PushRange()

    @model_validator(mode="after")
    def _intervals_ok(self) -> RandomizationRanges:
        _ordered("floor_friction", self.floor_friction, 1e-3, 2.0)
        for name in ("body_mass_scale", "link_mass_scale", "motor_strength_scale"):
            _ordered(name, getattr(self, name), 0.5, 1.5)
        return self


def load_ranges(path: str | None, max_push: float | None) -> RandomizationRanges:
    """The defaults, or a YAML file's values over them; ``--max-push`` last."""
    raw: dict = {}
    if path is not None:
        try:
            with open(path) as handle:
                raw = yaml.safe_load(handle) or {}
        except (OSError, yaml.YAMLError) as error:
            raise ConfigError(f"--ranges: cannot read {path}: {error}") from error
        if not isinstance(raw, dict):
            raise ConfigError(f"--ranges: {path} must be a mapping of keys to values")
    if max_push is not None:
        raw.setdefault("push", {})["max_velocity_change"] = max_push
    try:
        return RandomizationRanges.model_validate(raw)
    except ValidationError as error:
        raise ConfigError(f"--ranges: {format_validation_error(error)}") from error


def sample_trial(
    ranges: RandomizationRanges,
    seed: int,
    n_joints: int,
    duration: float,
    estimator: str = "ground_truth",
    sensors: dict | None = None,
) -> tuple[dict, dict]:
    """The ``plant`` section and the push of trial ``seed`` (plain data, rounded to 6 digits).

    ``estimator``: the run's (``ground_truth``: Gaussian noise on the measured state, ``sensor_noise``;
    otherwise the robot's sensors, ``plant.sensors`` from ``sensors`` (the base config's, as plain data) with
    IMU biases drawn from the ranges' ``imu_*`` bounds)."""
    rng = np.random.default_rng(seed)

    def uniform(interval: Interval, size: int | None = None) -> Any:
        value = rng.uniform(interval[0], interval[1], size)
        return np.round(value, 6).tolist() if size is not None else round(float(value), 6)

    plant = {
        "floor_friction": uniform(ranges.floor_friction),
        "body_mass_scale": uniform(ranges.body_mass_scale),
        "link_mass_scales": uniform(ranges.link_mass_scale, n_joints),
        "motor_strength_scales": uniform(ranges.motor_strength_scale, n_joints),
        "measurement_delay_max": ranges.measurement_delay_max,
        "seed": int(seed),
    }
    if estimator == "ground_truth":
        plant["sensor_noise"] = ranges.sensor_noise.model_dump()
    window = ranges.push.window
    start = uniform((window[0] * duration, window[1] * duration))
    angle = float(rng.uniform(0.0, 2.0 * np.pi))
    magnitude = float(rng.uniform(0.0, ranges.push.max_velocity_change))
    push = {
        "start": start,
        "duration": ranges.push.duration,
        "velocity_change": [round(magnitude * np.cos(angle), 6), round(magnitude * np.sin(angle), 6), 0.0],
    }
    if (
        estimator != "ground_truth"
    ):  # drawn after the push: a seed's plant and push stay those of ground truth
        sensors = copy.deepcopy(sensors) if sensors is not None else {}
        imu = sensors.setdefault("imu", {})
        for key, bound in (
            ("gyro_bias", ranges.imu_gyro_bias),
            ("accelerometer_bias", ranges.imu_accelerometer_bias),
            ("orientation_bias", ranges.imu_orientation_bias),
        ):
            imu[key] = uniform((-bound, bound), 3)
        plant["sensors"] = sensors
    return plant, push


ORACLE_KEYS = ("calibration", "mpc.friction", "vwbc.friction")
"""What ``--oracle`` sets per trial (``oracle_overrides``)."""


def oracle_overrides(plant: dict, base: RunConfig, nominal_friction: float) -> tuple[str, ...]:
    """The ``--oracle`` overrides of a trial: the controller told the plant's randomised values, which a
    robot never is. A diagnostic: it says whether a failure under a model error comes from not knowing the
    model (then online estimation can fix it) or from the robot's physical limits (then it cannot).

    The plant's mass, trunk, link and motor factors become the controller's ``calibration`` (its model and
    its torque commands, ``robots.calibration``); the friction the controller assumes keeps its ratio to the
    floor's: ``mpc.friction`` (and ``vwbc.friction`` when the base config sets it) times the trial's floor
    friction over the robot table's (``nominal_friction``; 0.4 / 0.6 on the Mini Cheetah)."""
    calibration = {
        key: plant.get(key, 1.0)
        for key in ("mass_scale", "body_mass_scale", "link_mass_scales", "motor_strength_scales")
    }
    floor = plant.get("floor_friction") or nominal_friction
    ratio = floor / nominal_friction
    overrides = [f"calibration={_flow(calibration)}", f"mpc.friction={round(base.mpc.friction * ratio, 6)}"]
    if base.vwbc.friction is not None:
        overrides.append(f"vwbc.friction={round(base.vwbc.friction * ratio, 6)}")
    return tuple(overrides)


def check_oracle_overrides(overrides: Sequence[str]) -> None:
    """``--oracle`` sets ``ORACLE_KEYS`` per trial: ``--set`` must leave them alone."""
    for item in overrides:
        key = item.split("=", 1)[0].strip()
        if any(key == k or key.startswith(k + ".") or k.startswith(key + ".") for k in ORACLE_KEYS):
            raise ConfigError(f"--set {key}: --oracle sets it per trial (the plant's values)")


def _flow(value: Any) -> str:
    """A value as one line of YAML (JSON is YAML)."""
    return json.dumps(value, separators=(", ", ": "))


# ------------------------------------------------------------------------------------------ experiment
TrialCount = integer(1, 1_000_000)
Seed = integer(0, 2**31)
Seeds = integers(0)
PushSize = number(0.0, 5.0)
"""m/s of base velocity change."""


class ReliabilityOptions(ExperimentOptions):
    task: str | None = Field(
        None,
        description="the preset (or YAML config) every trial runs (required)",
        json_schema_extra={"metavar": "PRESET"},
    )
    trials: TrialCount | None = Field(
        None,
        description=f"number of trials (default {DEFAULT_TRIALS}, the paper's)",
        json_schema_extra={"metavar": "N"},
    )
    seed: Seed | None = Field(
        None,
        description="seed of the first trial (default 0); trial i has seed + i",
        json_schema_extra={"metavar": "S"},
    )
    seeds: Seeds | None = Field(
        None,
        description="exactly these trial seeds (re-run single trials), instead of --trials/--seed",
        json_schema_extra={"metavar": "7,12"},
    )
    ranges: str | None = Field(
        None,
        description="YAML file of randomisation ranges (keys of RandomizationRanges; README)",
        json_schema_extra={"metavar": "FILE"},
    )
    max_push: PushSize | None = Field(
        None,
        description="largest random push, m/s of base velocity change (default 0.5)",
        json_schema_extra={"metavar": "M"},
    )
    keep_logs: bool = Field(
        False, description="keep every trial's log.npz (default: config, metrics and run.log only)"
    )
    oracle: bool = Field(
        False,
        description="diagnostic: tell the controller each trial's plant (masses, motor strengths as its "
        "calibration; friction at the usual margin), which a robot never knows",
    )

    @model_validator(mode="after")
    def _task_and_seeds(self) -> ReliabilityOptions:
        if not self.task:
            from cafe_mpc.config import available_presets

            raise ValueError(f"--task PRESET is required (presets: {', '.join(available_presets())})")
        if self.seeds is not None and (self.trials is not None or self.seed is not None):
            raise ValueError("--seeds replaces --trials and --seed; give one or the other")
        return self

    @property
    def trial_seeds(self) -> list[int]:
        """The seeds of the trials: ``seeds``, or ``trials`` consecutive ones from ``seed``."""
        if self.seeds is not None:
            return list(self.seeds)
        first = self.seed if self.seed is not None else 0
        return list(range(first, first + (self.trials if self.trials is not None else DEFAULT_TRIALS)))


class Reliability(Experiment):
    name = "reliability"
    title = "Reliability: domain-randomised trials"
    paper = "paper Sec. VII-C3, Fig. 17 (16 of 22 on hardware)"
    default_duration = None  # each preset's own
    varied_keys = ("plant",)
    Options = ReliabilityOptions
    default_overrides = ("output.plots=false", "mpc.latency=fixed")
    needs_gait = False
    errors_are_results = True
    ranges: RandomizationRanges | None = None

    def plan(self, options: ReliabilityOptions, context: PlanContext) -> ExperimentPlan:
        from cafe_mpc.robots.robot import load_robot

        task = options.task
        seeds = options.trial_seeds
        max_push = options.max_push
        ranges = load_ranges(options.ranges, max_push)
        extra = [f"simulation.duration={context.duration}"] if context.duration is not None else []
        base = load_run_config(str(task), [*context.overrides, *extra])
        duration = base.simulation.duration
        robot = load_robot(base.robot)
        n_joints = robot.nu
        existing = [push.model_dump(mode="json", exclude_none=True) for push in base.pushes]
        task_name = Path(str(task)).stem if str(task).endswith((".yaml", ".yml")) else str(task)
        variants = []
        sensors = base.plant.sensors.model_dump(mode="json")
        if options.oracle:
            check_oracle_overrides(context.overrides)
        nominal_friction = robot.plant.floor_friction
        for seed in seeds:
            plant, push = sample_trial(ranges, seed, n_joints, duration, base.estimator, sensors)
            oracle = oracle_overrides(plant, base, nominal_friction) if options.oracle else ()
            dv = push["velocity_change"]
            magnitude = math.hypot(dv[0], dv[1])
            links, motors = plant["link_mass_scales"], plant["motor_strength_scales"]
            variants.append(
                Variant(
                    f"trial-{seed:04d}",  # the same name whichever sweep the seed is in
                    str(task),
                    (f"plant={_flow(plant)}", f"pushes={_flow([*existing, push])}", *oracle),
                    f"seed {seed}",
                    variant=task_name,
                    seed=seed,
                    fields=(
                        ("floor_friction", plant["floor_friction"]),
                        ("body_mass_scale", plant["body_mass_scale"]),
                        ("link_mass_scale_min", min(links)),
                        ("link_mass_scale_max", max(links)),
                        ("motor_strength_min", min(motors)),
                        ("motor_strength_max", max(motors)),
                        ("push_start_s", push["start"]),
                        ("push_direction_deg", round(math.degrees(math.atan2(dv[1], dv[0])) % 360.0, 2)),
                        ("push_velocity_change", round(magnitude, 6)),
                    ),
                )
            )
        plan_options = {"--task": str(task)}
        if options.seeds is not None:
            plan_options["--seeds"] = ",".join(str(s) for s in seeds)
        else:
            plan_options["--trials"] = str(len(seeds))
            plan_options["--seed"] = str(seeds[0])
        if options.ranges is not None:
            plan_options["--ranges"] = str(options.ranges)
        if max_push is not None:
            plan_options["--max-push"] = f"{max_push:g}"
        if options.keep_logs:
            plan_options["--keep-logs"] = ""
        if options.oracle:
            plan_options["--oracle"] = ""
        self.ranges = ranges
        return ExperimentPlan(variants, plan_options, drop_files=() if options.keep_logs else ("log.npz",))

    def summarize(self, result: RunResult, variant: Variant) -> dict:
        metrics, log = result.metrics, result.log
        mpc, wbc = metrics.get("mpc") or {}, metrics.get("wbc") or {}
        motor_limits = np.asarray(result.robot.plant.motor_torque_limits)
        saturated = int(np.sum(np.any(np.abs(log.torque_command) > motor_limits + 1e-9, axis=1)))
        slip = wbc.get("foot_slip_max_m")
        verdict = metrics.get("success")
        if verdict is None:  # a task's own block (the barrel roll's ``task``), when the run has one
            verdict = (metrics.get("task") or {}).get("success")
        failures = int(mpc.get("failures") or 0)
        return {
            "success": bool(not metrics["fell"] and verdict is not False),
            **fall_fields(metrics),
            "fall_reason": metrics.get("fall_reason") or None,
            "task_success": verdict,
            "slipped": bool(slip is not None and slip > SLIP_THRESHOLD_M),
            "foot_slip_max_m": slip,
            "torque_saturated": saturated > 0,
            "torque_saturation_ticks": saturated,
            "solver_failed": failures > 0,
            "solver_failures": failures,
            "time_budget_stops": mpc.get("time_budget_stops"),
            "friction_cone_violations": wbc.get("friction_cone_violations"),
            "vx_mean": metrics.get("vx_mean"),
            "base_height_min": metrics.get("base_height_min"),
            "sensor_delay_ticks_mean": (
                metrics.get("sensor") or (metrics.get("estimator") or {}).get("sensors") or {}
            ).get("delay_ticks_mean"),
            "estimator": (metrics.get("estimator") or {}).get("kind"),
            "velocity_rms_error_m_s": (metrics.get("estimator") or {}).get("velocity_rms_error_m_s"),
        }

    # -------------------------------------------------------------------------------------- reports
    def outputs(self, rows: list[dict], comparison: dict, out_dir: Path) -> dict:
        summary = reliability_summary(rows)
        summary["command"] = comparison["command"]
        summary["task"] = comparison["options"].get("--task")
        summary["ranges"] = self.ranges.model_dump(mode="json") if self.ranges is not None else None
        summary["timing_modes"] = comparison["timing_modes"]
        with open(out_dir / "summary.json", "w") as handle:
            json.dump(summary, handle, indent=2)
        return {"reliability": summary}

    def markdown_intro(self, rows: list[dict], comparison: dict) -> list[str]:
        summary = comparison.get("reliability") or reliability_summary(rows)
        paper = summary["paper"]
        low, high = summary["wilson_95"]
        lines = [
            f"Success: **{summary['successes']} of {summary['trials']}** trials = "
            f"{pct(summary['success_rate'])} (Wilson 95 % interval {pct(low)} - {pct(high)}). "
            f"Paper (hardware, Fosbury flop): {paper['successes']} of {paper['trials']} = "
            f"{pct(paper['success_rate'])} ({pct(paper['wilson_95'][0])} - {pct(paper['wilson_95'][1])}).",
            "",
        ]
        if summary["crashed"]:
            lines += [f"{summary['crashed']} trials crashed (not counted; --resume runs them again).", ""]
        return lines

    def table(self, rows: list[dict], comparison: dict) -> tuple[list[str], list[list[str]], list[str]]:
        summary = comparison.get("reliability") or reliability_summary(rows)
        header = ["failure mode", "trials", "of the failed trials"]
        body = [
            [
                label,
                str(summary["failure_modes"][key]["trials"]),
                str(summary["failure_modes"][key]["failed"]),
            ]
            for key, label in FAILURE_MODES
        ]
        failed = [r for r in rows if r.get("status") != "crashed" and not _succeeded(r)]
        notes = [
            "A trial succeeds when it runs its whole duration without falling or a simulator/controller "
            "error (and with the task's own verdict, when its metrics have one). The modes are not "
            "exclusive: a trial can slip, saturate and fall. Every trial's seed, sampled parameters and "
            "outcome are in results.csv; re-run one alone with --seeds SEED or "
            "cafe-mpc run OUT/trial-NNNN/config.yaml.",
        ]
        if failed:
            shown = failed[:50]
            table = markdown_table(
                [
                    "seed",
                    "outcome",
                    "floor friction",
                    "push [m/s] at [s]",
                    "slip max [m]",
                    "saturated ticks",
                    "solver failures",
                ],
                [
                    [
                        str(r.get("seed")),
                        _outcome(r),
                        num(r.get("floor_friction"), 2),
                        f"{num(r.get('push_velocity_change'), 2)} at {num(r.get('push_start_s'), 2)}",
                        num(r.get("foot_slip_max_m"), 3),
                        str(
                            r.get("torque_saturation_ticks")
                            if r.get("torque_saturation_ticks") is not None
                            else "n/a"
                        ),
                        str(r.get("solver_failures") if r.get("solver_failures") is not None else "n/a"),
                    ]
                    for r in shown
                ],
            )
            notes += [
                "",
                "Failed trials" + (f" (first 50 of {len(failed)})" if len(failed) > 50 else "") + ":",
                "",
            ]
            notes += table
        return header, body, notes

    def summary_line(self, comparison: dict) -> str | None:
        summary = comparison.get("reliability")
        if not summary:
            return None
        low, high = summary["wilson_95"]
        return (
            f"reliability: {summary['successes']} of {summary['trials']} trials succeeded "
            f"({pct(summary['success_rate'])}, Wilson 95 % {pct(low)} - {pct(high)}); paper: 16 of 22"
        )

    def plot(self, rows: list[dict], runs: RunStore, path: Path) -> None:
        plot_reliability(rows, reliability_summary(rows), path)


def _succeeded(row: dict) -> bool:
    return row.get("status") == "ok" and bool(row.get("success"))


def _outcome(row: dict) -> str:
    if row.get("status") != "ok":
        return f"{row.get('status')}: {row.get('error')}"
    if row.get("fell"):
        reason = row.get("fall_reason") or ""
        at = row.get("fall_time_s")
        return "fell" + (f" at {at:.2f} s" if at is not None else "") + (f" ({reason})" if reason else "")
    if row.get("task_success") is False:
        return "task not achieved"
    return "success"


def reliability_summary(rows: list[dict]) -> dict:
    """Counts, success rate, Wilson interval and failure modes of the trials (crashed ones not counted)."""
    counted = [r for r in rows if r.get("status") != "crashed"]
    trials = len(counted)
    successes = sum(_succeeded(r) for r in counted)
    failed = [r for r in counted if not _succeeded(r)]

    def flag(row: dict, key: str) -> bool:
        if key == "simulation_error":
            return row.get("status") == "error"
        return bool(row.get(key))

    modes = {
        key: {"trials": sum(flag(r, key) for r in counted), "failed": sum(flag(r, key) for r in failed)}
        for key, _ in FAILURE_MODES
    }
    return {
        "trials": trials,
        "successes": successes,
        "success_rate": successes / trials if trials else None,
        "wilson_95": list(wilson_interval(successes, trials)),
        "failure_modes": modes,
        "slip_threshold_m": SLIP_THRESHOLD_M,
        "seeds": [r.get("seed") for r in counted],
        "failed_seeds": [r.get("seed") for r in failed],
        "crashed": len(rows) - trials,
        "paper": {
            "trials": PAPER_TRIALS,
            "successes": PAPER_SUCCESSES,
            "success_rate": PAPER_SUCCESSES / PAPER_TRIALS,
            "wilson_95": list(wilson_interval(PAPER_SUCCESSES, PAPER_TRIALS)),
            "note": "Mini Cheetah hardware, Fosbury flop (a barrel roll from a run); Fig. 17's caption: 20, "
            "70 %",
        },
    }


def plot_reliability(rows: list[dict], summary: dict, path: Path) -> Path:
    """Left: success rate with its Wilson 95 % interval beside the paper's. Middle: failure modes (all
    trials, failed trials). Right: each trial's floor friction and push, success or failure."""
    figure = new_figure((14, 4.5))
    grid = figure.add_gridspec(1, 3, width_ratios=(1, 1.6, 1.6))
    axis = figure.add_subplot(grid[0, 0])
    entries = [("ours", summary), ("paper", summary["paper"])]
    for x, (_, item) in enumerate(entries):
        rate = item["success_rate"]
        if rate is None:
            continue
        low, high = item["wilson_95"]
        axis.bar(x, 100 * rate, color="C0" if x == 0 else "grey", width=0.6)
        axis.errorbar(
            x,
            100 * rate,
            yerr=[[100 * max(rate - low, 0.0)], [100 * max(high - rate, 0.0)]],
            color="k",
            capsize=6,
        )
        axis.annotate(f"{item['successes']}/{item['trials']}", (x, 2), ha="center", fontsize=8, color="w")
    axis.set_xticks(range(len(entries)), [label for label, _ in entries])
    axis.set_ylim(0, 100)
    axis.set_ylabel("success rate [%] (Wilson 95 %)")
    axis.grid(alpha=0.3, axis="y")
    axis = figure.add_subplot(grid[0, 1])
    keys = [key for key, _ in FAILURE_MODES]
    x = np.arange(len(keys))
    axis.bar(x - 0.2, [summary["failure_modes"][k]["trials"] for k in keys], 0.4, label="all trials")
    axis.bar(x + 0.2, [summary["failure_modes"][k]["failed"] for k in keys], 0.4, label="failed trials")
    axis.set_xticks(
        x, ["fell", "slipped", "torque\nsaturation", "solver\nfailures", "sim\nerror"], fontsize=8
    )
    axis.set_ylabel("trials")
    axis.yaxis.set_major_locator(MaxNLocator(integer=True))
    axis.legend(fontsize=8)
    axis.grid(alpha=0.3, axis="y")
    axis = figure.add_subplot(grid[0, 2])
    counted = [r for r in rows if r.get("status") != "crashed" and r.get("floor_friction") is not None]
    for success, marker, color, label in (
        (True, "o", "tab:green", "success"),
        (False, "x", "tab:red", "failure"),
    ):
        chosen = [r for r in counted if _succeeded(r) == success]
        axis.scatter(
            [r["floor_friction"] for r in chosen],
            [r.get("push_velocity_change") or 0.0 for r in chosen],
            marker=marker,
            color=color,
            label=f"{label} ({len(chosen)})",
        )
    axis.set_xlabel("floor friction")
    axis.set_ylabel("random push [m/s]")
    axis.grid(alpha=0.3)
    axis.legend(fontsize=8)
    figure.suptitle(
        f"Reliability: {summary['successes']} of {summary['trials']} randomised trials succeeded "
        "(paper Fig. 17: 16 of 22 on hardware)",
        fontsize=10,
    )
    return save_figure(figure, path)
