"""``cafe-mpc experiment template-gaits``: CAFE-MPC and the template MPC on every gait, with the paper's
timing and with MIT Cheetah-Software's convex-MPC timing, and the bounding push test.

The template MPC (``planner: template``, ``planners.template``) stands for the convex / kinodynamic SRB MPC
the paper compares with (Sec. VII-C). Whether it is a fair stand-in depends on whether it does what such
controllers do on the Mini Cheetah: trot, pace, bound and pronk at 0.5 m/s, and take the push. Each gait
(``GAITS``) runs once with each planner (``--planners``) from its family's preset with ``gait.name`` set:

* trot (0.25 s a pair; the paper's and MIT's timings differ only in period, MIT's 0.13 s is not run);
* pace: the paper's 0.25 s a side and MIT's 0.13 s (``pace_short_stance``);
* bound: the paper's 0.10 s stance and 0.10 s flight per pair and MIT's 0.104 s / 0.026 s
  (``bound_short_flight``);
* pronk: the paper's 0.10 s down / 0.20 s up and MIT's 0.104 s / 0.156 s (``pronk_short_flight``);
* push: the ``bound-push`` preset (+1.5 m/s over 50 ms at 2 s) with each bound timing.

Per run: stays up, steady-state forward speed (passes when ``|vx - 0.5| < 0.1``), base height, pitch, and
the measured quantities that say why a run fell:

* the mean vertical force a stance foot must carry over a cycle (``GaitCycle.support_factor`` times the
  weight: what the gait demands of one leg) against the leg's vertical force capacity at the standing pose
  with the foot under its hip and the run's torque limits (``vertical_force_capacity``);
* the largest vertical force the template's plan asked of one foot (its low level's ``planned_force_max_n``)
  and the largest the plant's feet delivered;
* the share of control ticks whose requested torque exceeded a limit (the template's ``J' F`` request is
  clamped; the VWBC's QP keeps the limits, so its count is the clamped Riccati fallback's);
* the pitch-rate change a stance phase forces on the body (its feet's moment about the centre of mass that
  friction-limited horizontal forces cannot cancel, ``pitch_swing``) and the pitch turned in the flight
  after it, against the largest pitch and pitch rate the run reached.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin
from pydantic import Field

from cafe_mpc.assembly.resolve import resolve
from cafe_mpc.core.physics import GRAVITY
from cafe_mpc.ocp.contact_schedule import GaitCycle, get_gait
from cafe_mpc.robots.robot import Robot
from cafe_mpc_lab.experiments.common import (
    SPEED_TOLERANCE,
    RunStore,
    colors,
    fall_fields,
    fell_text,
    num,
    pct,
)
from cafe_mpc_lab.experiments.controllers import low_level_of
from cafe_mpc_lab.experiments.options import ExperimentOptions, names
from cafe_mpc_lab.experiments.registry import Experiment, ExperimentPlan, PlanContext, Variant
from cafe_mpc_lab.experiments.run import RunResult
from cafe_mpc_lab.report.figures import save_figure, subplots
from cafe_mpc_lab.report.metrics import body_rates, roll_pitch_yaw

STEADY_FROM_S = 3.0
"""s; the steady-state window starts here (0.2 s stand, 0.5 s command ramp, settling; after the push)."""
LOADED_FOOT_N = 5.0
"""N; a plant foot pushing at least this much counts as loaded (for the delivered-force mean)."""
DELIVERED_WINDOW_S = 0.02
"""s; the delivered peak is the largest moving average over this window of a foot's vertical force (the
touchdown impacts' one-tick spikes left out)."""


@dataclass(frozen=True)
class GaitCase:
    """One row of the experiment: a gait of ``GAITS`` run from ``preset``, labelled by family and timing."""

    name: str
    preset: str
    gait: str
    family: str
    timing: str


CASES = (
    GaitCase("trot", "trot", "trot", "trot", "paper"),
    GaitCase("pace", "pace", "pace", "pace", "paper"),
    GaitCase("pace-mit", "pace", "pace_short_stance", "pace", "MIT"),
    GaitCase("bound", "bound", "bound", "bound", "paper"),
    GaitCase("bound-mit", "bound", "bound_short_flight", "bound", "MIT"),
    GaitCase("pronk", "pronk", "pronk", "pronk", "paper"),
    GaitCase("pronk-mit", "pronk", "pronk_short_flight", "pronk", "MIT"),
    GaitCase("push", "bound-push", "bound", "push", "paper"),
    GaitCase("push-mit", "bound-push", "bound_short_flight", "push", "MIT"),
)
PLANNERS = (("cafe", "CAFE-MPC + VWBC"), ("template", "template MPC"))


def vertical_force_capacity(
    robot: Robot, torque_limits: np.ndarray | None = None, height: float | None = None
) -> float:
    """The largest vertical force (N) every leg can push with at the standing pose: base at ``height``
    (default the standing height), level, each foot under its hip (``foothold_offsets``); per leg the
    smallest ``tau_max_j / |J_j' e_z|`` over its joints (``torque_limits``, default the robot's plan limits;
    leg weight ignored)."""
    from cafe_mpc.dynamics.leg_inverse_kinematics import LegInverseKinematics

    height = robot.standing_height if height is None else height
    limits = robot.torque_limits if torque_limits is None else np.asarray(torque_limits, dtype=float)
    base = np.array([[0.0, 0.0, height, 0.0, 0.0, 0.0, 1.0]])
    feet = np.zeros((1, robot.n_feet, 3))
    feet[0, :, :2] = robot.foothold_offsets
    feet[0, :, 2] = robot.foot_radius
    joints, _, _ = LegInverseKinematics(robot).solve_batch(base, feet)
    q = np.concatenate([base[0], joints[0]])
    model, data = robot.model, robot.model.createData()
    pin.computeJointJacobians(model, data, q)
    pin.updateFramePlacements(model, data)
    capacity = np.inf
    for frame_id in robot.foot_frame_ids:
        jacobian = pin.getFrameJacobian(model, data, frame_id, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)[:3, 6:]
        per_newton = np.abs(jacobian[2])
        moving = per_newton > 1e-9
        capacity = min(capacity, float(np.min(limits[moving] / per_newton[moving])))
    return capacity


def pitch_swing(gait: GaitCycle, robot: Robot, friction: float) -> tuple[float, float]:
    """What a gait asks of the SRB's pitch, at the standing pose with the footholds under the hips: the
    largest pitch-rate change one stance phase forces on the body (rad/s) and the pitch the body then turns
    in the flight that follows it, at half that rate (rad).

    Per stance phase, each stance foot carries ``support_factor * m g`` (the gait's GRF reference) over the
    phase; those impulses' moment about the centre of mass is cancelled by horizontal forces at most
    ``friction * h`` per unit of vertical impulse (``h`` the centre of mass's height); the rest, divided by
    the SRB's pitch inertia (``template_srb``), is the pitch-rate change the phase cannot avoid. Zero for
    gaits whose front and hind feet share every stance (trot, pace, pronk)."""
    from cafe_mpc.planners.template.problem import template_srb

    parameters, offset = template_srb(robot)
    inertia = float(np.asarray(parameters.inertia)[1, 1])
    height = robot.standing_height + float(offset[2])
    levers = robot.foothold_offsets[:, 0] - float(offset[0])
    load = gait.support_factor * robot.total_mass * GRAVITY
    worst_rate = worst_turn = 0.0
    phases = gait.cycle
    for index, (flags, duration) in enumerate(phases):
        stance = np.asarray(flags, dtype=bool)
        if not stance.any():
            continue
        impulse = load * duration
        moment = abs(float(np.sum(levers[stance]))) * impulse
        rate = max(moment - friction * height * impulse * int(stance.sum()), 0.0) / inertia
        following, flight = phases[(index + 1) % len(phases)], 0.0
        if not any(following[0]):
            flight = following[1]
        worst_rate = max(worst_rate, rate)
        worst_turn = max(worst_turn, 0.5 * rate * flight)
    return worst_rate, worst_turn


CASE_NAMES = tuple(case.name for case in CASES)
PLANNER_NAMES = tuple(planner for planner, _ in PLANNERS)


class TemplateGaitsOptions(ExperimentOptions):
    gaits: names(CASE_NAMES) = Field(
        CASE_NAMES,
        description=f"cases (default all: {','.join(CASE_NAMES)})",
        json_schema_extra={"metavar": "bound,bound-mit,..."},
    )
    planners: names(PLANNER_NAMES) = Field(
        PLANNER_NAMES,
        description="cafe and/or template (default both)",
        json_schema_extra={"metavar": "cafe,template"},
    )


class TemplateGaits(Experiment):
    name = "template-gaits"
    title = "Gaits and push test with the paper's and MIT's timings: CAFE-MPC vs the template MPC"
    paper = "Sec. VII-C (the template baseline of Fig. 12)"
    default_duration = 10.0
    varied_keys = ("planner", "gait.name")
    Options = TemplateGaitsOptions

    def plan(self, options: TemplateGaitsOptions, context: PlanContext) -> ExperimentPlan:
        chosen_cases, planners = options.gaits, options.planners
        labels = dict(PLANNERS)
        variants = []
        for case in CASES:
            if case.name not in chosen_cases:
                continue
            for planner in planners:
                variants.append(
                    Variant(
                        f"{case.name}-{planner}",
                        case.preset,
                        (f"planner={planner}", f"gait.name={case.gait}"),
                        f"{labels[planner]}, {case.family} ({case.timing})",
                        group=case.name,
                        fields=(
                            ("case", case.name),
                            ("family", case.family),
                            ("timing", case.timing),
                            ("gait", case.gait),
                            ("planner", planner),
                        ),
                    )
                )
        return ExperimentPlan(variants, {"--gaits": ",".join(chosen_cases), "--planners": ",".join(planners)})

    def summarize(self, result: RunResult, variant: Variant) -> dict:
        return gait_summary(result)

    def table(self, rows: list[dict], comparison: dict) -> tuple[list[str], list[list[str]], list[str]]:
        header = [
            "gait",
            "timing",
            "planner",
            "fell",
            "vx steady [m/s]",
            "passes",
            "height mean [m]",
            "pitch max [rad]",
            "pitch rate max [rad/s]",
            "forced pitch rate [rad/s] / turn in flight [rad]",
            "demand / capacity per foot [N]",
            "plan peak / delivered peak [N]",
            "ticks over torque limit",
        ]
        order = {case.name: index for index, case in enumerate(CASES)}
        ordered = sorted(rows, key=lambda r: (order.get(str(r.get("case")), 99), str(r.get("planner"))))
        body = [
            [
                str(r.get("family")),
                f"{r.get('timing')} ({r.get('gait')})",
                str(r.get("planner")),
                fell_text(r),
                num(r.get("vx_steady")),
                "yes" if r.get("passes") else "no",
                num(r.get("height_mean_m")),
                num(r.get("pitch_abs_max_rad"), 2),
                num(r.get("pitch_rate_abs_max"), 1),
                f"{num(r.get('pitch_rate_swing'), 1)} / {num(r.get('pitch_in_flight_rad'), 2)}",
                f"{num(r.get('demand_per_foot_n'), 0)} / {num(r.get('capacity_per_foot_n'), 0)}",
                f"{num(r.get('planned_force_max_n'), 0)} / {num(r.get('delivered_force_max_n'), 0)}",
                pct(r.get("torque_over_limit_ticks")),
            ]
            for r in ordered
        ]
        mode = next((r.get("timing_mode") for r in rows if r.get("timing_mode")), None)
        notes = [
            f"vx steady: mean forward speed (heading frame) from t = {STEADY_FROM_S:g} s (half the run if "
            f"shorter); passes: stayed up and |vx - commanded| < {SPEED_TOLERANCE:g} m/s. The push cases "
            "push the bound +1.5 m/s over 50 ms at t = 2 s (paper Sec. VII-B).",
            "Demand: the mean vertical force a stance foot carries over a gait cycle (support factor x "
            "weight: the weight's impulse over the cycle shared by the stance feet); capacity: the vertical "
            "force one leg can push at the standing pose with its foot under the hip within the run's "
            "torque limits. A stance's force is not flat: its peak is well above the mean (a half sine: "
            "pi/2 x).",
            "Forced pitch rate: the pitch-rate change one stance phase cannot avoid when its feet carry the "
            "gait's GRF reference and friction-limited horizontal forces cancel what they can of its moment "
            "(pitch_swing); turn in flight: the pitch the body turns at half that rate in the flight after "
            "it.",
            "Plan peak: the largest vertical GRF the template's plan asked of one stance foot (n/a for "
            "CAFE-MPC, which plans torques); delivered peak: the largest vertical force a foot of the plant "
            f"pushed with, averaged over {1000 * DELIVERED_WINDOW_S:g} ms (without the touchdown impacts). "
            "Ticks over torque limit: control ticks whose requested torque exceeded a limit (then "
            "clamped; the template's J'F request, CAFE-MPC's VWBC or its Riccati fallback).",
            *diagnosis(rows),
            f"Timing mode: {mode or 'n/a'} (each run's metrics.json `timing` block).",
        ]
        return header, body, notes

    def plot(self, rows: list[dict], runs: RunStore, path: Path) -> None:
        if rows:
            plot_gaits(rows, runs, path)

    def outputs(self, rows: list[dict], comparison: dict, out_dir: Path) -> dict:
        return {"passes": _passes(rows)}

    def summary_line(self, comparison: dict) -> str | None:
        passes = comparison.get("passes") or {}
        return "; ".join(f"{planner}: {text}" for planner, text in passes.items()) or None


def gait_summary(result: RunResult) -> dict:
    """The table's fields of one run (see the module docstring)."""
    robot, log, metrics, config = result.robot, result.log, result.metrics, result.config
    assert config.gait is not None
    gait = get_gait(config.gait.name)
    commanded = config.gait.commands[0].vx
    start = min(STEADY_FROM_S, 0.5 * config.simulation.duration)
    window = log.time >= start - 1e-9
    vx = None
    if log.ticks and np.any(window):
        vx = float(np.mean(body_rates(log.q[window], log.v[window])[0][:, 0]))
    pitch = roll_pitch_yaw(log.q[:, 3:7])[:, 1] if log.ticks else np.zeros(0)
    pitch_rate = body_rates(log.q, log.v)[2] if log.ticks else np.zeros(0)
    weight = robot.total_mass * GRAVITY
    normal = log.foot_forces[:, :, 2] if log.ticks else np.zeros((0, robot.n_feet))
    loaded = normal[normal > LOADED_FOOT_N]
    period = 1.0 / config.simulation.control_rate_hz
    width = max(1, round(DELIVERED_WINDOW_S / period))
    smoothed = np.zeros(0)
    if len(normal) >= width:
        box = np.ones(width) / width
        smoothed = np.stack([np.convolve(normal[:, j], box, mode="valid") for j in range(normal.shape[1])])
    limits = resolve(config, robot).torque_limits
    requested = log.extra.get("torque_requested")
    over = None
    if requested is not None and len(requested):
        finite = np.where(np.isfinite(requested), np.abs(requested), 0.0)
        over = float(np.mean(np.any(finite > limits + 1e-6, axis=1)))
    planned = None
    if result.controller is not None:  # the template's low level reports it, the others have none
        planned = low_level_of(result.controller).statistics().get("planned_force_max_n")
    swing = pitch_swing(gait, robot, config.mpc.friction)
    stayed_up = not metrics["fell"] and log.ticks > 0
    return {
        **fall_fields(metrics),
        "fall_reason": metrics.get("fall_reason") or "",
        "vx_commanded": commanded,
        "vx_steady": vx,
        "passes": bool(stayed_up and vx is not None and abs(vx - commanded) < SPEED_TOLERANCE),
        "stayed_up": stayed_up,
        "height_mean_m": metrics.get("base_height_mean"),
        "pitch_abs_max_rad": float(np.max(np.abs(pitch))) if len(pitch) else None,
        "pitch_rate_abs_max": float(np.max(np.abs(pitch_rate))) if len(pitch_rate) else None,
        "support_factor": gait.support_factor,
        "demand_per_foot_n": gait.support_factor * weight,
        "capacity_per_foot_n": vertical_force_capacity(robot, limits),
        "pitch_rate_swing": swing[0],
        "pitch_in_flight_rad": swing[1],
        "planned_force_max_n": planned,
        "delivered_force_max_n": float(np.max(smoothed)) if smoothed.size else None,
        "delivered_force_mean_n": float(np.mean(loaded)) if loaded.size else None,
        "torque_over_limit_ticks": over,
        "mpc_update_ms_median": (metrics.get("mpc") or {}).get("update_ms_median"),
        "latency_ms_median": (metrics.get("mpc") or {}).get("latency_ms_median"),
        "timing_mode": (metrics.get("timing") or {}).get("mode"),
    }


def diagnosis(rows: list[dict]) -> list[str]:
    """One sentence per run that fell: when, and what was measured about the legs and the pitch."""
    lines = []
    for row in rows:
        if not row.get("fell"):
            continue
        demand, capacity = row.get("demand_per_foot_n"), row.get("capacity_per_foot_n")
        parts = [
            f"{row.get('planner')}, {row.get('family')} ({row.get('timing')}) fell at "
            f"{num(row.get('fall_time_s'), 2)} s ({row.get('fall_reason') or 'n/a'})"
        ]
        if demand is not None and capacity is not None:
            parts.append(
                f"each stance foot has to carry {demand:.0f} N on average "
                f"({100 * demand / capacity:.0f} % of the {capacity:.0f} N a leg pushes at the standing pose)"
            )
        if row.get("planned_force_max_n") is not None:
            parts.append(
                f"the plan asked up to {row['planned_force_max_n']:.0f} N of one foot, the feet delivered at "
                f"most {num(row.get('delivered_force_max_n'), 0)} N"
            )
        if row.get("pitch_rate_swing"):
            parts.append(
                f"each stance forces a pitch-rate change of {row['pitch_rate_swing']:.1f} rad/s and the body "
                f"turns {num(row.get('pitch_in_flight_rad'), 2)} rad in each flight"
            )
        parts.append(
            f"{pct(row.get('torque_over_limit_ticks'))} of the ticks asked for more than the torque limits; "
            f"pitch reached {num(row.get('pitch_abs_max_rad'), 2)} rad, "
            f"its rate {num(row.get('pitch_rate_abs_max'), 1)} rad/s"
        )
        lines.append("; ".join(parts) + ".")
    return lines


def _passes(rows: list[dict]) -> dict[str, str]:
    """Per planner: which cases passed (stayed up at the commanded speed) and which fell."""
    out = {}
    for planner, _ in PLANNERS:
        chosen = [r for r in rows if r.get("planner") == planner]
        if not chosen:
            continue
        passed = [str(r.get("case")) for r in chosen if r.get("passes")]
        fell = [str(r.get("case")) for r in chosen if not r.get("stayed_up")]
        text = f"passes {len(passed)} of {len(chosen)}"
        if fell:
            text += f" (fell: {', '.join(fell)})"
        out[planner] = text
    return out


def plot_gaits(rows: list[dict], runs: RunStore, path: Path) -> Path:
    """Top: time each run stayed up (bar), its steady-state speed written on it, per case and planner.
    Bottom: base pitch of the template's runs of the bound and the pronk over their first two seconds."""
    cases = [case for case in CASES if any(r.get("case") == case.name for r in rows)]
    planners = [p for p, _ in PLANNERS if any(r.get("planner") == p for r in rows)]
    figure, axes = subplots(2, 1, figsize=(11, 8))
    axis = axes[0]
    width = 0.8 / max(len(planners), 1)
    palette = dict(zip(planners, colors(len(planners)), strict=True))
    for p_index, planner in enumerate(planners):
        for c_index, case in enumerate(cases):
            row = next((r for r in rows if r.get("case") == case.name and r.get("planner") == planner), None)
            if row is None:
                continue
            up = row.get("fall_time_s") if row.get("fell") else row.get("sim_time_s")
            x = c_index + (p_index - (len(planners) - 1) / 2) * width
            axis.bar(
                x,
                up or 0.0,
                width,
                color=palette[planner],
                alpha=0.9 if row.get("passes") else 0.35,
                hatch=None if row.get("stayed_up") else "//",
                label=planner if c_index == 0 else None,
            )
            text = "fell" if row.get("fell") else f"{num(row.get('vx_steady'), 2)}"
            axis.text(x, (up or 0.0) + 0.1, text, ha="center", fontsize=7)
    axis.set_xticks(range(len(cases)))
    axis.set_xticklabels([f"{c.family}\n{c.timing}" for c in cases], fontsize=8)
    axis.set_ylabel("time up [s] (label: vx steady)")
    axis.grid(alpha=0.3, axis="y")
    longest = max((float(r.get("sim_time_s") or 0.0) for r in rows), default=1.0)
    axis.set_ylim(0.0, 1.25 * max(longest, 0.1))
    axis.legend(fontsize=8, loc="upper right", ncol=len(planners))
    axis = axes[1]
    wanted = [r for r in rows if r.get("planner") == "template" and r.get("family") in ("bound", "pronk")]
    loaded = runs.load_all([r["run"] for r in wanted if r.get("status") == "ok"])
    for color, (name, result) in zip(colors(len(loaded)), loaded.items(), strict=True):
        log = result.log
        mask = log.time <= 2.0
        pitch = roll_pitch_yaw(log.q[mask, 3:7])[:, 1]
        row = next(r for r in wanted if r["run"] == name)
        label = f"{row.get('family')} ({row.get('timing')})"
        axis.plot(log.time[mask], pitch, color=color, lw=1.0, label=label)
        if log.fell and mask[-1]:
            axis.plot(log.time[mask][-1], pitch[-1], "x", color=color, ms=8, mew=2)
    axis.set_xlabel("time [s] (x: fall)")
    axis.set_ylabel("template: base pitch [rad]")
    axis.grid(alpha=0.3)
    if loaded:
        axis.legend(fontsize=8, loc="best")
    figure.suptitle(
        "Gaits with the paper's and MIT's timings (hatched: fell; pale: stayed up off the commanded speed)",
        fontsize=10,
    )
    return save_figure(figure, path)
