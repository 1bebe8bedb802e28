"""``cafe-mpc experiment push``: the bounding push test with the VWBC (34) and with the Riccati controller
(33) (Sec. VII-B, Fig. 9 and Fig. 10).

The ``bound-push`` preset (+1.5 m/s over 50 ms at t = 2 s) with each low-level controller: torque-limit and
friction-cone violations, foot slip, QP fallbacks, forward speed after the push. ``comparison.png`` shows the
hip and knee torques of the front-right and hind-right legs around the push with the limits (the Riccati
controller's unclamped request), as Fig. 9.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.axes import Axes

from cafe_mpc.config import RunConfig
from cafe_mpc_lab.experiments.common import (
    PUSH_SETTLE_S,
    RunStore,
    colors,
    fall_fields,
    fell_text,
    integer,
    num,
    window_mask,
)
from cafe_mpc_lab.experiments.options import ExperimentOptions
from cafe_mpc_lab.experiments.registry import Experiment, ExperimentPlan, PlanContext, Variant
from cafe_mpc_lab.experiments.run import RunResult
from cafe_mpc_lab.report.figures import new_figure, save_figure
from cafe_mpc_lab.report.metrics import body_rates

PUSH_CONTROLLERS = ("vwbc", "riccati")
PUSH_PLOT_BEFORE_S, PUSH_PLOT_AFTER_S = 0.5, 1.5  # torque plot window around the push start (Fig. 9)


class Push(Experiment):
    name = "push"
    title = "Bounding push test: VWBC vs Riccati controller"
    paper = "paper Fig. 9"
    default_duration = 5.0
    varied_keys = ("wbc",)

    def plan(self, options: ExperimentOptions, context: PlanContext) -> ExperimentPlan:
        return ExperimentPlan(
            [
                Variant(c, "bound-push", (f"wbc={c}",), c.upper() if c == "vwbc" else "Riccati")
                for c in PUSH_CONTROLLERS
            ]
        )

    def summarize(self, result: RunResult, variant: Variant) -> dict:
        return push_summary(result)

    def table(self, rows: list[dict], comparison: dict) -> tuple[list[str], list[list[str]], list[str]]:
        header = [
            "controller",
            "fell",
            "torque limit violations [ticks]",
            "max request over limit [Nm]",
            "friction cone violations [ticks]",
            "foot slip max [m]",
            "QP fallbacks",
            "vx peak after push [m/s]",
            "vx mean after push [m/s]",
        ]
        body = [
            [
                r.get("label") or r["run"],
                fell_text(r),
                integer(r.get("torque_limit_violations")),
                num(r.get("requested_torque_over_limit_max_nm"), 2),
                integer(r.get("friction_cone_violations")),
                num(r.get("foot_slip_max_m"), 4),
                integer(r.get("fallbacks")),
                num(r.get("vx_push_peak")),
                num(r.get("vx_after_push_mean")),
            ]
            for r in rows
        ]
        first = rows[0] if rows else {}
        window = first.get("vx_after_push_window_s")
        notes = [
            "Torque limit violations: ticks where the requested torque exceeds a limit (Riccati: its "
            "unclamped (33) torque, which is clamped before it is sent; VWBC: the QP's torque). Friction "
            "cone violations: ticks where the planned/commanded stance forces leave the friction pyramid. "
            "Foot slip: largest horizontal slide of a stance foot in the plant. QP fallbacks: VWBC only.",
            f"vx peak: largest heading-frame vx from the push start to {PUSH_SETTLE_S} s after its end; vx "
            f"mean after push: from {PUSH_SETTLE_S} s after the push to the end of the run"
            + (f" ({window[0]:.2f}-{window[1]:.2f} s for the first controller)." if window else ".")
            + " n/a: the run ended before.",
        ]
        duration = comparison.get("duration_s")
        if (
            first.get("push_start_s") is not None
            and duration is not None
            and duration <= first["push_start_s"]
        ):
            notes.append(f"The run ends before the push at {first['push_start_s']:g} s.")
        return header, body, notes

    def plot(self, rows: list[dict], runs: RunStore, path: Path) -> None:
        loaded = runs.load_all([r["run"] for r in rows if r.get("status") == "ok"])
        if loaded:
            plot_push(loaded, {r["run"]: r.get("label") or r["run"] for r in rows}, path)


def _first_push(config: RunConfig) -> tuple[float, float] | None:
    if not config.pushes:
        return None
    push = config.pushes[0]
    return push.start, push.start + push.duration


def push_summary(result: RunResult) -> dict:
    """The push table's fields; speeds are heading-frame vx from the log."""
    metrics, wbc, log = result.metrics, result.metrics.get("wbc") or {}, result.log
    limits = result.robot.torque_limits
    requested = log.extra.get("torque_requested")
    excess = None
    if requested is not None and np.any(np.isfinite(requested)):
        finite = np.where(np.isfinite(requested), np.abs(requested), 0.0)
        excess = float(max(np.max(finite - limits), 0.0))
    push = _first_push(result.config)
    peak = after = None
    window = None
    if push is not None and log.ticks:
        vx = body_rates(log.q, log.v)[0][:, 0]
        start, end = push
        during = (log.time >= start - 1e-9) & (log.time <= end + PUSH_SETTLE_S)
        if during.any():
            peak = float(np.max(vx[during]))
        window = [end + PUSH_SETTLE_S, float(log.time[-1])]
        later = log.time >= window[0] - 1e-9
        after = float(np.mean(vx[later])) if later.any() else None
        if after is None:
            window = None
    return {
        **fall_fields(metrics),
        "push_start_s": push[0] if push else None,
        "push_end_s": push[1] if push else None,
        "torque_limit_violations": wbc.get("torque_limit_violations"),
        "requested_torque_over_limit_max_nm": excess,
        "friction_cone_violations": wbc.get("friction_cone_violations"),
        "foot_slip_max_m": wbc.get("foot_slip_max_m"),
        "fallbacks": wbc.get("fallbacks"),
        "vx_push_peak": peak,
        "vx_after_push_mean": after,
        "vx_after_push_window_s": window,
        "vx_mean": metrics.get("vx_mean"),
        "qp_solve_time_ms_median": wbc.get("qp_solve_time_ms_median"),
    }


def _shade_push(axis: Axes, push: tuple[float, float] | None, label: bool = False) -> None:
    if push is not None:
        axis.axvspan(push[0], push[1], color="orange", alpha=0.3, lw=0, label="push" if label else None)


def plot_push(results: dict[str, RunResult], labels: dict[str, str], path: Path) -> Path:
    """Hip and knee torques of the front-right and hind-right legs around the push, both controllers, with
    the torque limits (paper Fig. 9); the Riccati controller's unclamped request is drawn. Bottom: vx."""
    any_result = next(iter(results.values()))
    robot = any_result.robot
    push = _first_push(any_result.config)
    legs = [robot.leg_names.index(n) for n in ("FR", "HR") if n in robot.leg_names] or [1, 3]
    window = None
    if push is not None:
        window = (max(push[0] - PUSH_PLOT_BEFORE_S, 0.0), push[0] + PUSH_PLOT_AFTER_S)
    reached = window is not None and any(
        r.log.ticks and r.log.time[-1] >= window[0] for r in results.values()
    )
    figure = new_figure((11, 9))
    grid = figure.add_gridspec(len(legs) + 1, 2)
    palette = dict(zip(results, colors(len(results)), strict=True))
    torque_axes = []
    for row, leg in enumerate(legs):
        for column, kind in enumerate((1, 2)):  # hip, knee
            axis = figure.add_subplot(grid[row, column], sharex=torque_axes[0] if torque_axes else None)
            torque_axes.append(axis)
            j = 3 * leg + kind
            for name, result in results.items():
                log = result.log
                if log.ticks == 0:
                    continue
                requested = log.extra.get("torque_requested")
                values = log.torque_command[:, j]
                what = "sent"
                if result.config.wbc == "riccati" and requested is not None:
                    values, what = requested[:, j], "requested (unclamped)"
                mask = window_mask(log.time, window if reached else None)
                axis.plot(
                    log.time[mask],
                    values[mask],
                    color=palette[name],
                    lw=0.9,
                    label=f"{labels.get(name, name)}: {what}",
                )
                if log.fell and mask[-1]:
                    axis.plot(log.time[-1], values[-1], "x", color=palette[name], ms=8, mew=2)
            limit = robot.torque_limits[j]
            axis.axhline(limit, color="r", ls="--", lw=0.9, label="torque limit")
            axis.axhline(-limit, color="r", ls="--", lw=0.9)
            _shade_push(axis, push if reached else None, label=True)
            axis.set_title(f"{robot.leg_names[leg]} {('abad', 'hip', 'knee')[kind]}", fontsize=9)
            axis.set_ylabel("torque [Nm]")
            axis.grid(alpha=0.3)
    torque_axes[0].legend(loc="best", fontsize=7)
    axis = figure.add_subplot(grid[len(legs), :], sharex=torque_axes[0])
    for name, result in results.items():
        log = result.log
        if log.ticks == 0:
            continue
        mask = window_mask(log.time, window if reached else None)
        vx = body_rates(log.q[mask], log.v[mask])[0][:, 0]
        axis.plot(log.time[mask], vx, color=palette[name], lw=0.9, label=labels.get(name, name))
    _shade_push(axis, push if reached else None, label=True)
    axis.set_ylabel("forward speed vx [m/s]")
    axis.set_xlabel("time [s] (x: fall)")
    axis.grid(alpha=0.3)
    axis.legend(loc="best", fontsize=7)
    if reached:
        last = max(float(r.log.time[-1]) for r in results.values() if r.log.ticks)
        axis.set_xlim(window[0], min(window[1], last))
    title = "Push while bounding: hip and knee torques with limits (paper Fig. 9)"
    if window is not None and not reached:
        title += f" - the run ended before the push at {push[0]:g} s"
    figure.suptitle(title, fontsize=10)
    return save_figure(figure, path)
