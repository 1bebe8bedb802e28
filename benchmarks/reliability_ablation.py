"""Which randomised factor makes a preset fail: the reliability trials with one factor at a time.

Each *cell* runs ``cafe-mpc experiment reliability`` (fixed 20 ms latency, the estimator as the preset
sets it) with every randomised factor at its nominal value except one, at one magnitude. The nominal plant
is the robot table's (floor friction, masses, motors), no IMU bias, no jitter, no push; the robot's sensors
keep their default noise and quantisation whenever the estimator runs (they are part of the nominal robot).

Beside the success rate and its Wilson interval, every failed trial gets an *anatomy* from its metrics and
run.log: when the first anomaly happened (bar contact, a touchdown off the plan by more than
``TOUCHDOWN_TOLERANCE``, the first failed MPC update, the fall) and in which part of the motion (approach,
take-off, flight, landing, run-out, from the task block's planned times), and what the failed MPC updates
reported (solver statuses, exceptions).

Usage::

    python benchmarks/reliability_ablation.py --task running-barrel-roll --trials 10 --workers 2 \
        --out runs/ablation
    python benchmarks/reliability_ablation.py --task running-barrel-roll --cells friction_low,push --trials 20

Writes ``OUT/CELL/`` (the reliability sweep of each cell), ``OUT/ablation.json`` (every cell's rate,
interval, failure modes and anatomy) and ``OUT/ablation.md`` (the table).
"""

from __future__ import annotations

import argparse
import collections
import json
import re
from pathlib import Path

import yaml

from cafe_mpc_lab.experiments.reliability import wilson_interval
from cafe_mpc_lab.experiments.sweep import run_experiment

NOMINAL_RANGES = {
    "floor_friction": [0.6, 0.6],
    "body_mass_scale": [1.0, 1.0],
    "link_mass_scale": [1.0, 1.0],
    "motor_strength_scale": [1.0, 1.0],
    "sensor_noise": {},
    "measurement_delay_max": 0.0,
    "imu_gyro_bias": 0.0,
    "imu_accelerometer_bias": 0.0,
    "imu_orientation_bias": 0.0,
    "push": {"max_velocity_change": 0.0},
}
"""Every factor at its nominal value (the robot table's friction, 0.6 for the Mini Cheetah)."""

DEFAULT_BIASES = {"imu_gyro_bias": 0.01, "imu_accelerometer_bias": 0.1, "imu_orientation_bias": 0.01}
NOISE_TIMES_3 = [
    "plant.sensors.imu.gyro_noise=0.015",
    "plant.sensors.imu.accelerometer_noise=0.015",
    "plant.sensors.imu.orientation_noise=0.009",
    "plant.sensors.encoders.velocity_noise=0.15",
]

CELLS: dict[str, tuple[str, dict, list[str]]] = {
    # name: (label, ranges over the nominal ones, extra --set overrides)
    "nominal": ("nothing randomised (sensor noise of the robot's sensors only)", {}, []),
    "ground_truth": ("nothing randomised, estimator: ground_truth", {}, ["estimator=ground_truth"]),
    "friction": ("floor friction 0.4-0.9", {"floor_friction": [0.4, 0.9]}, []),
    "friction_0.4": ("floor friction 0.4", {"floor_friction": [0.4, 0.4]}, []),
    "friction_0.3": ("floor friction 0.3", {"floor_friction": [0.3, 0.3]}, []),
    "body_mass": ("trunk mass +-10 %", {"body_mass_scale": [0.9, 1.1]}, []),
    "body_mass_20": ("trunk mass +-20 %", {"body_mass_scale": [0.8, 1.2]}, []),
    "link_mass": ("link masses +-10 %", {"link_mass_scale": [0.9, 1.1]}, []),
    "link_mass_20": ("link masses +-20 %", {"link_mass_scale": [0.8, 1.2]}, []),
    "motor": ("motor strength +-10 %", {"motor_strength_scale": [0.9, 1.1]}, []),
    "motor_20": ("motor strength +-20 %", {"motor_strength_scale": [0.8, 1.2]}, []),
    "noise_x3": ("sensor noise x3 (IMU, joint rates)", {}, NOISE_TIMES_3),
    "imu_bias": ("IMU biases (gyro 0.01 rad/s, acc 0.1 m/s^2, attitude 0.01 rad)", DEFAULT_BIASES, []),
    "imu_bias_x2": ("IMU biases x2", {k: 2 * v for k, v in DEFAULT_BIASES.items()}, []),
    "gyro_bias_x2": ("gyro bias 0.02 rad/s alone", {"imu_gyro_bias": 0.02}, []),
    "accelerometer_bias_x2": ("accelerometer bias 0.2 m/s^2 alone", {"imu_accelerometer_bias": 0.2}, []),
    "orientation_bias_x2": ("attitude bias 0.02 rad alone", {"imu_orientation_bias": 0.02}, []),
    "jitter": ("measurement jitter up to 4 ms", {"measurement_delay_max": 0.004}, []),
    "jitter_8": ("measurement jitter up to 8 ms", {"measurement_delay_max": 0.008}, []),
    "push": ("push up to 0.5 m/s", {"push": {"max_velocity_change": 0.5}}, []),
    "push_1": ("push up to 1.0 m/s", {"push": {"max_velocity_change": 1.0}}, []),
    "all": ("all factors at the default ranges", None, []),
}
"""The cells (``None`` ranges: the experiment's default ranges)."""

TOUCHDOWN_TOLERANCE = 0.03
"""s: a touchdown earlier or later than planned by more than this counts as an anomaly."""
FAILURE_LINE = re.compile(r"update at t = ([0-9.]+) s: (it returned (\w+)|it failed \((.*)\)|.*)")


def phase_of(t: float | None, task: dict) -> str | None:
    """The part of a task's motion time ``t`` falls in (from the task block's planned times)."""
    if t is None:
        return None
    start, takeoff, touchdown = (
        task.get(k) for k in ("planned_start_s", "planned_takeoff_s", "planned_touchdown_s")
    )
    if start is None or takeoff is None or touchdown is None:
        return "run"
    if t < start:
        return "approach"
    if t < takeoff:
        return "take-off"
    if t < touchdown - TOUCHDOWN_TOLERANCE:
        return "flight"
    if t < touchdown + 0.6:
        return "landing"
    return "run-out"


def anatomy(trial_dir: Path) -> dict:
    """What went wrong first in one trial, from its metrics.json and run.log."""
    metrics = json.loads((trial_dir / "metrics.json").read_text())
    task = metrics.get("task") or {}
    failures = []
    log = trial_dir / "run.log"
    if log.exists():
        for line in log.read_text().splitlines():
            if "keeping the previous plan" not in line:
                continue
            match = FAILURE_LINE.search(line)
            if match:
                why = match.group(3) or (f"exception: {match.group(4)}" if match.group(4) else "other")
                failures.append((float(match.group(1)), why))
    events = []
    if task.get("bar_first_contact_s") is not None:
        events.append((task["bar_first_contact_s"], "bar contact"))
    touchdown, planned = task.get("touchdown_s"), task.get("planned_touchdown_s")
    if touchdown is not None and planned is not None and abs(touchdown - planned) > TOUCHDOWN_TOLERANCE:
        events.append((touchdown, "early touchdown" if touchdown < planned else "late touchdown"))
    if failures:
        events.append((min(t for t, _ in failures), "MPC update failed"))
    if metrics.get("fell"):
        events.append((metrics.get("fall_time_s"), f"fell ({metrics.get('fall_reason')})"))
    events.sort(key=lambda item: item[0])
    first = events[0] if events else (None, None)
    return {
        "first_event": first[1],
        "first_event_s": first[0],
        "first_event_phase": phase_of(first[0], task),
        "events": events,
        "touchdown_error_s": None if touchdown is None or planned is None else touchdown - planned,
        "failure_statuses": dict(collections.Counter(why for _, why in failures)),
        "first_failure_s": min((t for t, _ in failures), default=None),
        "first_failure_phase": phase_of(min((t for t, _ in failures), default=None), task),
        "fall_phase": phase_of(metrics.get("fall_time_s"), task) if metrics.get("fell") else None,
        "bar_clearance_min_m": task.get("bar_clearance_min_m"),
        "roll_friction_cone_violations": task.get("roll_friction_cone_violations"),
        "foot_slip_max_m": (metrics.get("wbc") or {}).get("foot_slip_max_m"),
    }


def run_cell(
    name: str, task: str, trials: int, seed: int, workers: int, out: Path, overrides: list[str]
) -> dict:
    label, ranges, extra = CELLS[name]
    cell_dir = out / name
    options: dict = {"task": task, "trials": trials, "seed": seed}
    if ranges is not None:
        merged = {**NOMINAL_RANGES, **ranges}
        ranges_file = out / f"{name}.ranges.yaml"
        ranges_file.write_text(yaml.safe_dump(merged))
        options["ranges"] = str(ranges_file)
    plant_keys = [item for item in extra if item.startswith("plant.")]
    if plant_keys:  # the experiment owns plant.*: a config file on top of the task carries them
        tree: dict = {"base": task}
        for item in plant_keys:
            key, value = item.split("=", 1)
            node = tree
            *parents, leaf = key.split(".")
            for part in parents:
                node = node.setdefault(part, {})
            node[leaf] = yaml.safe_load(value)
        task_file = out / f"{name}.task.yaml"
        task_file.write_text(yaml.safe_dump(tree))
        options["task"] = str(task_file)
        extra = [item for item in extra if item not in plant_keys]
    run_experiment(
        "reliability",
        cell_dir,
        overrides=[*overrides, *extra],
        workers=workers,
        resume=cell_dir.exists(),
        **options,
    )
    summary = json.loads((cell_dir / "summary.json").read_text())
    trials_info = {}
    for seed_value in summary["seeds"]:
        trial_dir = cell_dir / f"trial-{seed_value:04d}"
        if (trial_dir / "metrics.json").exists():
            trials_info[seed_value] = anatomy(trial_dir)
    failed = [trials_info[s] for s in summary["failed_seeds"] if s in trials_info]
    successes, count = summary["successes"], summary["trials"]
    low, high = wilson_interval(successes, count)
    return {
        "cell": name,
        "label": label,
        "overrides": extra,
        "trials": count,
        "successes": successes,
        "wilson_95": [low, high],
        "failure_modes": summary["failure_modes"],
        "failed_seeds": summary["failed_seeds"],
        "first_event_phase": dict(collections.Counter(f["first_event_phase"] for f in failed)),
        "first_event": dict(collections.Counter(f["first_event"] for f in failed)),
        "trials_detail": trials_info,
    }


def markdown(cells: list[dict]) -> str:
    lines = [
        "| factor (alone) | success | Wilson 95 % | failures begin in | first anomaly "
        "| solver failures (trials) |",
        "|---|---|---|---|---|---|",
    ]
    for cell in cells:
        low, high = cell["wilson_95"]
        phases = ", ".join(f"{k} {v}" for k, v in sorted(cell["first_event_phase"].items(), key=str)) or "-"
        events = ", ".join(f"{k} {v}" for k, v in sorted(cell["first_event"].items(), key=str)) or "-"
        lines.append(
            f"| {cell['label']} | {cell['successes']} of {cell['trials']} "
            f"| {100 * low:.0f}-{100 * high:.0f} % "
            f"| {phases} | {events} | {cell['failure_modes']['solver_failed']['trials']} |"
        )
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--task", required=True)
    parser.add_argument("--cells", default=",".join(CELLS), help=f"comma-separated, of: {', '.join(CELLS)}")
    parser.add_argument("--trials", type=int, default=10)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    args = parser.parse_args()
    names = [name.strip() for name in args.cells.split(",") if name.strip()]
    unknown = [name for name in names if name not in CELLS]
    if unknown:
        parser.error(f"unknown cells {unknown}; known: {', '.join(CELLS)}")
    args.out.mkdir(parents=True, exist_ok=True)
    results_path = args.out / "ablation.json"
    results = json.loads(results_path.read_text()) if results_path.exists() else {}
    for name in names:
        print(f"== {name}: {CELLS[name][0]}", flush=True)
        results[name] = run_cell(
            name, args.task, args.trials, args.seed, args.workers, args.out, args.overrides
        )
        results_path.write_text(json.dumps(results, indent=1, default=str))
        ordered = [results[n] for n in CELLS if n in results]
        (args.out / "ablation.md").write_text(markdown(ordered))
        print(markdown([results[name]]), flush=True)


if __name__ == "__main__":
    main()
