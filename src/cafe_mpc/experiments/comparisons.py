"""Comparison experiments (paper Sec. VII): several variants of one preset run side by side.

``cafe-mpc experiment NAME`` runs every variant through ``experiments.run.run`` (each in its own subfolder,
with its usual config.yaml, metrics.json, log.npz, run.log and plots) and writes in the top folder:

* ``comparison.json``: the variants' key metrics side by side, the command line that reproduces the
  experiment and, per variant, the equivalent ``cafe-mpc run`` command;
* ``comparison.md``: the same as a markdown table, ready to paste into README.md / BENCHMARKS.md;
* ``comparison.png``: the experiment's plot.

Experiments:

* ``schedules`` (Fig. 6, issue 5): bounding with model schedule S0 (no SRB tail) vs S4 (or any list of the
  paper's schedules): fall, forward speed, pitch and pitch-rate RMS, height error, MPC solve time.
* ``push`` (Fig. 9, issue 6): the ``bound-push`` preset with the VWBC (34) and with the Riccati controller
  (33): torque-limit and friction-cone violations, foot slip, QP fallbacks, forward speed after the push;
  the plot shows hip and knee torques around the push (the Riccati controller's unclamped request).
* ``warm-start`` (Fig. 11, issue 6): VWBC QP iterations per tick with the previous tick's solution, the
  plan's guess and no warm start, for bounding and pacing.

A variant that ends in a simulator or controller error is recorded in the comparison with its error (the
other variants still run); falling is a result, not an error.
"""

from __future__ import annotations

import itertools
import json
import shlex
import subprocess
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import matplotlib
import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure

from cafe_mpc.config import ConfigError, RunConfig, load_config, parse_override
from cafe_mpc.experiments.run import RunResult, run
from cafe_mpc.report.figures import new_figure, save_figure, subplots
from cafe_mpc.report.metrics import METRICS_WINDOW_START_S, body_rates, roll_pitch_yaw

COMPARISON_FILES = ("comparison.json", "comparison.md", "comparison.png")


@dataclass(frozen=True)
class Variant:
    """One run of an experiment: ``cafe-mpc run PRESET --set OVERRIDES`` into subfolder ``name``."""

    name: str
    preset: str
    overrides: tuple[str, ...]
    label: str
    group: str = ""  # warm-start: the gait (one plot panel per group)


@dataclass(frozen=True)
class Experiment:
    name: str
    title: str
    paper: str
    default_duration: float
    varied_keys: tuple[str, ...]  # config keys the experiment sets per variant: not for --set
    options: tuple[str, ...]  # the list options it accepts (schedules, gaits, warm_starts)


EXPERIMENTS: dict[str, Experiment] = {
    "schedules": Experiment(
        "schedules",
        "Bounding at 0.5 m/s under different model schedules",
        "paper Fig. 6, issue 5",
        10.0,
        ("mpc.schedule", "mpc.whole_body_horizon", "mpc.srb_horizon"),
        ("schedules",),
    ),
    "push": Experiment(
        "push",
        "Bounding push test: VWBC vs Riccati controller",
        "paper Fig. 9, issue 6",
        5.0,
        ("wbc",),
        (),
    ),
    "warm-start": Experiment(
        "warm-start",
        "VWBC QP iterations per tick with and without warm start",
        "paper Fig. 11, issue 6",
        4.0,
        ("wbc", "vwbc.warm_start"),
        ("gaits", "warm_starts"),
    ),
}

DEFAULT_SCHEDULES = ("S0", "S4")
DEFAULT_GAITS = ("bound", "pace")
DEFAULT_WARM_STARTS = ("previous", "plan", "none")
PUSH_CONTROLLERS = ("vwbc", "riccati")
PUSH_PLOT_BEFORE_S, PUSH_PLOT_AFTER_S = 0.5, 1.5  # torque plot window around the push start (Fig. 9)
PUSH_SETTLE_S = 0.5  # "vx after the push" is measured from this long after the push ends


def experiment_names() -> list[str]:
    return list(EXPERIMENTS)


def get_experiment(name: str) -> Experiment:
    if name not in EXPERIMENTS:
        raise ConfigError(f"unknown experiment {name!r}; experiments: {', '.join(EXPERIMENTS)}")
    return EXPERIMENTS[name]


def parse_list(text: str | Sequence[str] | None) -> tuple[str, ...] | None:
    """``"S0,S4"`` or ``["S0", "S4"]`` -> ``("S0", "S4")`` (None stays None)."""
    if text is None:
        return None
    items = text.split(",") if isinstance(text, str) else list(text)
    return tuple(item.strip() for item in items if item.strip())


def _check_list(option: str, values: tuple[str, ...], known: Sequence[str] | None = None) -> None:
    if not values:
        raise ConfigError(f"--{option.replace('_', '-')}: give at least one value")
    if len(set(values)) != len(values):
        raise ConfigError(f"--{option.replace('_', '-')}: repeated value in {','.join(values)}")
    if known is not None:
        for value in values:
            if value not in known:
                raise ConfigError(
                    f"--{option.replace('_', '-')}: unknown value {value!r}; known: {', '.join(known)}"
                )


def plan_variants(
    name: str,
    schedules: Sequence[str] | None = None,
    gaits: Sequence[str] | None = None,
    warm_starts: Sequence[str] | None = None,
) -> list[Variant]:
    """The runs of experiment ``name`` (lists default to the paper's comparison)."""
    from cafe_mpc.mpc.problem import PAPER_SCHEDULES

    experiment = get_experiment(name)
    given = {"schedules": schedules, "gaits": gaits, "warm_starts": warm_starts}
    for option, value in given.items():
        if value is not None and option not in experiment.options:
            raise ConfigError(
                f"--{option.replace('_', '-')} does not apply to experiment {name!r}"
                + (
                    f" (it takes {', '.join('--' + o.replace('_', '-') for o in experiment.options)})"
                    if experiment.options
                    else ""
                )
            )
    if name == "schedules":
        chosen = tuple(schedules) if schedules is not None else DEFAULT_SCHEDULES
        _check_list("schedules", chosen, list(PAPER_SCHEDULES))
        return [
            Variant(s, "bound", (f"mpc.schedule={s}",), f"{s} (Ts = {PAPER_SCHEDULES[s]:g} s)")
            for s in chosen
        ]
    if name == "push":
        return [
            Variant(c, "bound-push", (f"wbc={c}",), c.upper() if c == "vwbc" else "Riccati")
            for c in PUSH_CONTROLLERS
        ]
    chosen_gaits = tuple(gaits) if gaits is not None else DEFAULT_GAITS
    modes = tuple(warm_starts) if warm_starts is not None else DEFAULT_WARM_STARTS
    from cafe_mpc.config import available_presets

    _check_list("gaits", chosen_gaits, [p for p in available_presets() if p != "stand"])
    _check_list("warm_starts", modes, ["previous", "plan", "equality", "none"])
    return [
        Variant(f"{gait}-{mode}", gait, ("wbc=vwbc", f"vwbc.warm_start={mode}"), mode, group=gait)
        for gait in chosen_gaits
        for mode in modes
    ]


def _check_overrides(experiment: Experiment, overrides: Sequence[str]) -> None:
    """``--set`` may change anything the experiment does not vary itself (nor the duration)."""
    reserved = (*experiment.varied_keys, "simulation.duration")
    for item in overrides:
        key, _ = parse_override(item)
        for varied in reserved:
            if key == varied or key.startswith(varied + ".") or varied.startswith(key + "."):
                hint = (
                    "use --duration"
                    if varied == "simulation.duration"
                    else "the experiment sets it per variant"
                )
                raise ConfigError(f"--set {key}: not allowed in experiment {experiment.name!r} ({hint})")


def experiment_command(
    name: str,
    duration: float,
    overrides: Sequence[str],
    schedules: Sequence[str] | None = None,
    gaits: Sequence[str] | None = None,
    warm_starts: Sequence[str] | None = None,
) -> str:
    """The ``cafe-mpc experiment`` command line that reproduces an experiment (into a new folder)."""
    words = ["cafe-mpc", "experiment", name, "--duration", f"{duration:g}"]
    for option, values in (("--schedules", schedules), ("--gaits", gaits), ("--warm-starts", warm_starts)):
        if values is not None:
            words += [option, ",".join(values)]
    for item in overrides:
        words += ["--set", item]
    return shlex.join(words)


def _run_command(variant: Variant, duration: float, overrides: Sequence[str]) -> str:
    words = ["cafe-mpc", "run", variant.preset, "--duration", f"{duration:g}"]
    for item in (*overrides, *variant.overrides):
        words += ["--set", item]
    return shlex.join(words)


def _git_state() -> dict | None:
    """Commit and dirty flag of the source tree (None outside a git checkout)."""
    root = Path(__file__).resolve().parent
    try:
        commit = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True, timeout=5, check=True
        ).stdout.strip()
        status = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=root,
            capture_output=True,
            text=True,
            timeout=5,
            check=True,
        ).stdout
    except (OSError, subprocess.SubprocessError):
        return None
    return {"commit": commit, "dirty": bool(status.strip())}


# ------------------------------------------------------------------------------------------ summaries
def _fall_fields(metrics: dict) -> dict:
    return {
        "fell": metrics["fell"],
        "fall_time_s": metrics["fall_time_s"],
        "sim_time_s": metrics["sim_time_s"],
    }


def schedule_summary(result: RunResult) -> dict:
    metrics, mpc = result.metrics, result.metrics.get("mpc") or {}
    schedule = result.config.mpc.model_schedule()
    return {
        **_fall_fields(metrics),
        "whole_body_horizon_s": schedule.whole_body_horizon,
        "srb_horizon_s": schedule.srb_horizon,
        "metrics_window_start_s": metrics.get("metrics_window_start_s"),
        "vx_mean": metrics.get("vx_mean"),
        "vx_rms_error": metrics.get("vx_rms_error"),
        "pitch_rms": metrics.get("pitch_rms"),
        "pitch_rate_rms": metrics.get("pitch_rate_rms"),
        "height_rms_error": metrics.get("height_rms_error"),
        "mpc_solve_time_ms_median": mpc.get("solve_time_ms_median"),
        "mpc_solve_time_ms_p99": mpc.get("solve_time_ms_p99"),
        "mpc_iterations_mean": mpc.get("iterations_mean"),
        "mpc_failures": mpc.get("failures"),
    }


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
        **_fall_fields(metrics),
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


def iteration_shares(histogram: dict | None) -> dict:
    """QP solves, share solved in at most 1 and at most 3 iterations, mean iterations, from a histogram."""
    counts = {int(k): int(n) for k, n in (histogram or {}).items()}
    total = sum(counts.values())
    if total == 0:
        return {
            "qp_solves": 0,
            "one_iteration_share": None,
            "at_most_3_iterations_share": None,
            "iterations_mean": None,
        }
    return {
        "qp_solves": total,
        "one_iteration_share": sum(n for k, n in counts.items() if k <= 1) / total,
        "at_most_3_iterations_share": sum(n for k, n in counts.items() if k <= 3) / total,
        "iterations_mean": sum(k * n for k, n in counts.items()) / total,
    }


def warm_start_summary(result: RunResult) -> dict:
    from cafe_mpc.experiments.controllers import low_level_of

    metrics, wbc = result.metrics, result.metrics.get("wbc") or {}
    ticks = low_level_of(result.controller).statistics() if result.controller is not None else {}

    def finite(value: float | None) -> float | None:
        return float(value) if value is not None and np.isfinite(value) else None

    return {
        **_fall_fields(metrics),
        "gait": metrics.get("gait"),
        "warm_start": result.config.vwbc.warm_start,
        "solver": result.config.vwbc.solver,
        **iteration_shares(wbc.get("qp_iterations_histogram")),
        "qp_iterations_histogram": wbc.get("qp_iterations_histogram"),
        "qp_solve_time_ms_median": wbc.get("qp_solve_time_ms_median"),
        "qp_solve_time_ms_p99": wbc.get("qp_solve_time_ms_p99"),
        "tick_time_ms_median": finite(ticks.get("tick_time_ms_median")),
        "tick_time_ms_p99": finite(ticks.get("tick_time_ms_p99")),
        "fallbacks": wbc.get("fallbacks"),
    }


SUMMARIES: dict[str, Callable[[RunResult], dict]] = {
    "schedules": schedule_summary,
    "push": push_summary,
    "warm-start": warm_start_summary,
}


# ------------------------------------------------------------------------------------------ markdown
def _num(value: float | None, digits: int = 3) -> str:
    return "n/a" if value is None else f"{value:.{digits}f}"


def _pct(value: float | None) -> str:
    return "n/a" if value is None else f"{100.0 * value:.1f} %"


def _int(value: int | None) -> str:
    return "n/a" if value is None else str(value)


def _fell(row: dict) -> str:
    if row.get("error"):
        return f"error: {row['error']}"
    if row["fell"]:
        return f"yes, at {row['fall_time_s']:.2f} s" if row["fall_time_s"] is not None else "yes"
    return "no"


def _table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return lines


def comparison_markdown(comparison: dict) -> str:
    """``comparison.md``: a title line with the command, the table, and what the columns mean."""
    name, variants = comparison["experiment"], comparison["variants"]
    lines = [
        f"**{comparison['title']}** ({comparison['paper']}; {comparison['duration_s']:g} s simulated)",
        "",
        f"Command: `{comparison['command']}`",
        "",
    ]
    if name == "schedules":
        header = [
            "schedule",
            "Ts [s]",
            "fell",
            "vx mean [m/s]",
            "vx RMS error [m/s]",
            "pitch RMS [rad]",
            "pitch rate RMS [rad/s]",
            "height RMS error [m]",
            "MPC solve median / p99 [ms]",
        ]
        rows = [
            [
                v,
                _num(r.get("srb_horizon_s"), 2),
                _fell(r),
                _num(r.get("vx_mean")),
                _num(r.get("vx_rms_error")),
                _num(r.get("pitch_rms")),
                _num(r.get("pitch_rate_rms")),
                _num(r.get("height_rms_error")),
                f"{_num(r.get('mpc_solve_time_ms_median'), 1)} / {_num(r.get('mpc_solve_time_ms_p99'), 1)}",
            ]
            for v, r in variants.items()
        ]
        window = next((r["metrics_window_start_s"] for r in variants.values() if r.get("sim_time_s")), None)
        notes = [
            "Tw = 0.25 s for every schedule. Tracking metrics "
            + (
                f"from t = {window:g} s (the start from rest is skipped)"
                if window
                else f"over the whole run (shorter than the {METRICS_WINDOW_START_S} s start-up window)"
            )
            + " to the end of the run or the fall; pitch and pitch rate against the reference's zero pitch; "
            "vx in the heading frame against the commanded speed.",
        ]
    elif name == "push":
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
        rows = [
            [
                r.get("label", v),
                _fell(r),
                _int(r.get("torque_limit_violations")),
                _num(r.get("requested_torque_over_limit_max_nm"), 2),
                _int(r.get("friction_cone_violations")),
                _num(r.get("foot_slip_max_m"), 4),
                _int(r.get("fallbacks")),
                _num(r.get("vx_push_peak")),
                _num(r.get("vx_after_push_mean")),
            ]
            for v, r in variants.items()
        ]
        first = next(iter(variants.values()), {})
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
        if first.get("push_start_s") is not None and comparison["duration_s"] <= first["push_start_s"]:
            notes.append(f"The run ends before the push at {first['push_start_s']:g} s.")
    else:
        header = [
            "gait",
            "warm start",
            "fell",
            "QP solves",
            "1 iteration",
            "<= 3 iterations",
            "iterations mean",
            "QP solve median / p99 [ms]",
            "VWBC tick median / p99 [ms]",
            "fallbacks",
        ]
        rows = [
            [
                r.get("gait") or "n/a",
                r.get("warm_start") or v,
                _fell(r),
                _int(r.get("qp_solves")),
                _pct(r.get("one_iteration_share")),
                _pct(r.get("at_most_3_iterations_share")),
                _num(r.get("iterations_mean"), 2),
                f"{_num(r.get('qp_solve_time_ms_median'))} / {_num(r.get('qp_solve_time_ms_p99'))}",
                f"{_num(r.get('tick_time_ms_median'))} / {_num(r.get('tick_time_ms_p99'))}",
                _int(r.get("fallbacks")),
            ]
            for v, r in variants.items()
        ]
        notes = [
            "Iterations as the QP solver reports them (DAQP: active-set iterations; '1 iteration' counts "
            "solves with at most one). Warm start: previous = the last tick's solution/working set, plan = "
            "the MPC plan's guess (paper Sec. V-A), none = cold. Shares are of all QP solves of the run. "
            "QP solve: the solver call; VWBC tick: assembly + solve + fallback, against the 2 ms budget "
            "(wall clock on this machine).",
        ]
    lines += _table(header, rows)
    lines += ["", *notes, ""]
    return "\n".join(lines)


# ------------------------------------------------------------------------------------------ plots
def _colors(n: int) -> list:
    cycle = matplotlib.rcParams["axes.prop_cycle"].by_key()["color"]
    return [cycle[i % len(cycle)] for i in range(n)]


def _save(figure: Figure, path: Path) -> Path:
    return save_figure(figure, path)


def _shade_push(axis: Axes, push: tuple[float, float] | None, label: bool = False) -> None:
    if push is not None:
        axis.axvspan(push[0], push[1], color="orange", alpha=0.3, lw=0, label="push" if label else None)


def plot_schedules(
    results: dict[str, RunResult], labels: dict[str, str], rows: dict[str, dict], path: Path
) -> Path:
    """Left: pitch, pitch rate (the paper's Fig. 6 quantities) and forward speed vs time, one line per
    schedule (an x marks a fall). Right: their RMS (vx: RMS error against the command) per schedule."""
    figure = new_figure((12, 7.5))
    grid = figure.add_gridspec(3, 2, width_ratios=(3, 1))
    axes = [figure.add_subplot(grid[0, 0])]
    axes += [figure.add_subplot(grid[i, 0], sharex=axes[0]) for i in (1, 2)]
    colors = dict(zip(labels, _colors(len(labels)), strict=True))
    command, end = None, 0.0
    for name, result in results.items():
        log = result.log
        if log.ticks == 0:
            continue
        heading, _, pitch_rate = body_rates(log.q, log.v)
        pitch = roll_pitch_yaw(log.q[:, 3:7])[:, 1]
        for axis, values in zip(axes, (pitch, pitch_rate, heading[:, 0]), strict=True):
            axis.plot(log.time, values, color=colors[name], lw=0.8, label=labels.get(name, name))
            if log.fell:
                axis.plot(log.time[-1], values[-1], "x", color=colors[name], ms=8, mew=2)
        end = max(end, float(log.time[-1]))
        if result.config.gait is not None:
            command = result.config.gait.commands
    if command is not None:
        starts = [c.start for c in command] + [end]
        for c, (t0, t1) in zip(command, itertools.pairwise(starts), strict=True):
            if t0 < end:
                axes[2].plot([t0, t1], [c.vx, c.vx], "k--", lw=1.0, label="command" if t0 == 0.0 else None)
    quantities = (
        ("pitch [rad]", "pitch_rms", "pitch RMS [rad]"),
        ("pitch rate [rad/s]", "pitch_rate_rms", "pitch rate RMS [rad/s]"),
        ("forward speed vx [m/s]", "vx_rms_error", "vx RMS error [m/s]"),
    )
    names = list(labels)
    for row, (axis, (label, key, rms_label)) in enumerate(zip(axes, quantities, strict=True)):
        axis.set_ylabel(label)
        if end > METRICS_WINDOW_START_S:
            axis.axvline(METRICS_WINDOW_START_S, color="grey", ls=":", lw=0.8)
        axis.grid(alpha=0.3)
        bars = figure.add_subplot(grid[row, 1])
        values = [rows[n].get(key) for n in names]
        bars.bar(
            range(len(names)),
            [np.nan if v is None else v for v in values],
            color=[colors[n] for n in names],
        )
        for x, name in enumerate(names):
            if rows[name].get("fell"):
                bars.annotate("fell", (x, 0), ha="center", va="bottom", fontsize=8, color="k")
        bars.set_xticks(range(len(names)), names)
        bars.set_ylabel(rms_label, fontsize=8)
        bars.grid(alpha=0.3, axis="y")
    axes[2].legend(loc="lower right", fontsize=8)
    axes[-1].set_xlabel("time [s] (x: fall; dotted: start of the metrics window)")
    figure.suptitle(
        "Bounding under model schedules: pitch, pitch rate, forward speed (paper Fig. 6); right: RMS over "
        "the metrics window (a run that fell: up to the fall)",
        fontsize=10,
    )
    return _save(figure, path)


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
    colors = dict(zip(results, _colors(len(results)), strict=True))
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
                mask = _window_mask(log.time, window if reached else None)
                axis.plot(
                    log.time[mask],
                    values[mask],
                    color=colors[name],
                    lw=0.9,
                    label=f"{labels.get(name, name)}: {what}",
                )
                if log.fell and mask[-1]:
                    axis.plot(log.time[-1], values[-1], "x", color=colors[name], ms=8, mew=2)
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
        mask = _window_mask(log.time, window if reached else None)
        vx = body_rates(log.q[mask], log.v[mask])[0][:, 0]
        axis.plot(log.time[mask], vx, color=colors[name], lw=0.9, label=labels.get(name, name))
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
    return _save(figure, path)


def _window_mask(times: np.ndarray, window: tuple[float, float] | None) -> np.ndarray:
    if window is None:
        return np.ones(len(times), dtype=bool)
    return (times >= window[0] - 1e-9) & (times <= window[1] + 1e-9)


MAX_HISTOGRAM_BIN = 10  # iterations >= this share one bar


def plot_warm_start(rows: dict[str, dict], variants: Sequence[Variant], path: Path) -> Path:
    """Histograms of QP iterations per tick: one panel per gait, one bar per warm-start mode (Fig. 11)."""
    groups = list(dict.fromkeys(v.group for v in variants))
    figure, axes = subplots(1, len(groups), figsize=(5.5 * len(groups), 4), squeeze=False)
    for axis, group in zip(axes[0], groups, strict=True):
        members = [v for v in variants if v.group == group]
        histograms = {}
        for variant in members:
            counts = {
                int(k): int(n) for k, n in (rows[variant.name].get("qp_iterations_histogram") or {}).items()
            }
            histograms[variant.name] = counts
        keys = [k for counts in histograms.values() for k in counts]
        top = min(max([*keys, 3]), MAX_HISTOGRAM_BIN)
        bins = np.arange(0 if 0 in keys else 1, top + 1)
        width = 0.8 / max(len(members), 1)
        for index, (variant, color) in enumerate(zip(members, _colors(len(members)), strict=True)):
            counts = histograms[variant.name]
            total = sum(counts.values())
            shares = np.zeros(len(bins))
            for k, n in counts.items():
                shares[min(k, top) - bins[0]] += n
            if total:
                shares *= 100.0 / total
            one = rows[variant.name].get("one_iteration_share")
            label = f"{variant.label} ({_pct(one)} in <= 1)" if total else f"{variant.label} (no QP solves)"
            axis.bar(bins + (index - (len(members) - 1) / 2) * width, shares, width, color=color, label=label)
        axis.set_xticks(bins, [str(b) if b < top or top < MAX_HISTOGRAM_BIN else f">={b}" for b in bins])
        axis.set_xlabel("QP iterations in the tick")
        axis.set_ylabel("share of ticks [%]")
        axis.set_title(group, fontsize=10)
        axis.grid(alpha=0.3, axis="y")
        axis.legend(fontsize=8, title="warm start", title_fontsize=8)
    figure.suptitle("VWBC QP iterations per tick with and without warm start (paper Fig. 11)", fontsize=10)
    return _save(figure, path)


# ------------------------------------------------------------------------------------------ runner
@dataclass
class ComparisonResult:
    name: str
    out_dir: Path
    comparison: dict
    results: dict[str, RunResult] = field(default_factory=dict)
    errors: dict[str, str] = field(default_factory=dict)


def default_experiment_dir(name: str, root: Path = Path("runs")) -> Path:
    return root / f"{time.strftime('%Y%m%d-%H%M%S')}-experiment-{name}"


def run_experiment(
    name: str,
    out_dir: Path | None = None,
    duration: float | None = None,
    overrides: Sequence[str] = (),
    schedules: Sequence[str] | None = None,
    gaits: Sequence[str] | None = None,
    warm_starts: Sequence[str] | None = None,
    show_progress: bool = False,
    echo: Callable[[str], None] | None = None,
) -> ComparisonResult:
    """Run every variant of experiment ``name`` into ``out_dir/<variant>/`` and write the comparison.

    All configs are built and validated before the first run (a bad ``--set`` stops before anything is
    written). ``echo`` receives one progress line per variant.
    """
    experiment = get_experiment(name)
    overrides = list(overrides)
    schedules, gaits, warm_starts = parse_list(schedules), parse_list(gaits), parse_list(warm_starts)
    variants = plan_variants(name, schedules, gaits, warm_starts)
    _check_overrides(experiment, overrides)
    duration = experiment.default_duration if duration is None else float(duration)
    configs = {
        v.name: load_config(v.preset, [*overrides, f"simulation.duration={duration}", *v.overrides])
        for v in variants
    }
    for variant in variants:
        if configs[variant.name].gait is None:
            raise ConfigError(f"experiment {name!r}: preset {variant.preset!r} has no gait to run")
    if name == "schedules":
        schedules = tuple(v.name for v in variants)
    elif name == "warm-start":
        gaits = tuple(dict.fromkeys(v.group for v in variants))
        warm_starts = tuple(dict.fromkeys(v.label for v in variants))
    command = experiment_command(name, duration, overrides, schedules, gaits, warm_starts)
    out_dir = Path(out_dir) if out_dir is not None else default_experiment_dir(name)
    if out_dir.exists() and any(out_dir.iterdir()):
        raise FileExistsError(f"output folder {out_dir} exists and is not empty; choose another --out")
    out_dir.mkdir(parents=True, exist_ok=True)

    results: dict[str, RunResult] = {}
    errors: dict[str, str] = {}
    from cafe_mpc.sim.loop import ControllerError
    from cafe_mpc.sim.plant import SimulationDiverged

    for index, variant in enumerate(variants, start=1):
        if echo:
            echo(
                f"[{index}/{len(variants)}] {name}: {variant.name} "
                f"({_run_command(variant, duration, overrides)})"
            )
        try:
            results[variant.name] = run(configs[variant.name], out_dir / variant.name, show_progress)
        except (SimulationDiverged, ControllerError) as error:
            errors[variant.name] = f"{type(error).__name__}: {error}".splitlines()[0]
            if echo:
                echo(f"    {variant.name}: error: {errors[variant.name]}")
            continue
        if echo:
            metrics = results[variant.name].metrics
            echo(
                f"    {variant.name}: fell={metrics['fell']}"
                + (f" at {metrics['fall_time_s']:.2f} s" if metrics["fell"] else "")
                + f", vx_mean={_num(metrics.get('vx_mean'))} m/s, wall {metrics['wall_time_s']:.1f} s"
            )

    summary = SUMMARIES[name]
    rows: dict[str, dict] = {}
    for variant in variants:
        row: dict = {
            "label": variant.label,
            "folder": variant.name,
            "preset": variant.preset,
            "overrides": list(variant.overrides),
            "run_command": _run_command(variant, duration, overrides),
        }
        if variant.name in results:
            row.update(summary(results[variant.name]))
            row["error"] = None
        else:
            row.update({"fell": None, "fall_time_s": None, "sim_time_s": None, "error": errors[variant.name]})
        rows[variant.name] = row
    comparison = {
        "experiment": name,
        "title": experiment.title,
        "paper": experiment.paper,
        "command": command,
        "duration_s": duration,
        "overrides": overrides,
        "out_dir": str(out_dir),
        "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "git": _git_state(),
        "variants": rows,
        "errors": errors,
    }
    with open(out_dir / "comparison.json", "w") as handle:
        json.dump(comparison, handle, indent=2)
    (out_dir / "comparison.md").write_text(comparison_markdown(comparison))
    labels = {v.name: v.label for v in variants}
    plotted = {n: r for n, r in results.items() if r.log.ticks > 0}
    plot_path = out_dir / "comparison.png"
    if name == "schedules":
        plot_schedules(plotted, labels, rows, plot_path)
    elif name == "push" and plotted:
        plot_push(plotted, labels, plot_path)
    elif name == "warm-start":
        plot_warm_start(rows, variants, plot_path)
    if not plot_path.exists():  # every variant failed: an explicit empty figure, not a missing file
        figure, axis = subplots(figsize=(6, 2))
        axis.text(0.5, 0.5, "no variant produced a log", ha="center", va="center")
        axis.set_axis_off()
        _save(figure, plot_path)
    return ComparisonResult(name, out_dir, comparison, results, errors)
