"""What a person wants to know first about a run, in words with units, from its ``metrics.json``.

The verdict (did it stay up; for an acrobatic task, did the task succeed and by what margins), then the
numbers that matter for the run's kind: a gait's speed against its command, height and attitude; a task's
criteria (roll, flight, landing, bar clearance, speeds) each next to the rule it is judged by; for every
MPC run the update rate and latency in its timing mode, the low level's fallbacks and limit violations,
and the state estimator's error when one ran. One source for the top of the HTML report
(``report/html.py``) and the lines ``cafe-mpc run`` prints at the end (``cli.py``).

Each finding carries a status: ``ok``, ``warn`` (worth a look: the machine could not keep the MPC's rate,
a fallback ran, a limit was crossed, the speed is off its command) or ``bad`` (a failed criterion, a fall).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

SPEED_TOLERANCE_M_S = 0.1
SPEED_FRACTION = 0.2
"""A gait's steady-state forward speed is on its command when within ``SPEED_TOLERANCE_M_S`` +
``SPEED_FRACTION`` x |command| of it: the rule of the tested command ranges
(``cafe_mpc_lab.experiments.command_ranges``; docs/usage.md)."""
SETTLED_SHARE = 0.8
"""The speed is judged when at least this share of the steady-state window follows the command's ramp."""
RATE_SHORTFALL = 0.9
"""An MPC that ran below this fraction of the rate its period asks for could not keep up (``warn``)."""

TIMING_WORDS = {
    "fixed": "fixed latency",
    "measured": "measured latency",
    "realtime": "real time",
}

PLANNER_WORDS = {"cafe": "CAFE-MPC", "template": "template MPC"}
CONTROLLER_WORDS = {"vwbc": "VWBC", "riccati": "Riccati feedback", "pd": "PD"}


@dataclass(frozen=True)
class Finding:
    """One line of the summary: what (``topic``), the numbers in words (``text``: statements separated by
    ``"; "``, which the HTML report puts on lines of their own), ``ok``/``warn``/``bad``/``info``, and for a
    task's criteria the rule it is judged by."""

    topic: str
    text: str
    status: str = "info"
    rule: str = ""


@dataclass(frozen=True)
class RunSummary:
    """The verdict of a run and its findings (``summarize``)."""

    name: str
    kind: str
    """``gait``, ``task`` or ``stand`` (neither: PD standing, or a run without a gait)."""
    verdict: str
    """One sentence: stayed up or fell (and when); the task's outcome; the findings worth a look."""
    ok: bool | None
    """True: stayed up (and the task succeeded); False: fell or the task failed; None: not judged."""
    facts: str
    """Robot, planner, low level, gait or task, timing mode, estimator."""
    wall_time: str
    """How long the simulation took: ``simulated in 2.24 s of wall time, real-time factor 0.89``."""
    findings: tuple[Finding, ...] = field(default_factory=tuple)

    @property
    def worth_a_look(self) -> list[str]:
        """The topics of the findings marked ``warn``."""
        return [item.topic for item in self.findings if item.status == "warn"]

    def lines(self) -> list[str]:
        """The summary as text lines: ``name: verdict (wall time)``, then one indented line per finding."""
        head = f"{self.name}: {self.verdict[:1].lower()}{self.verdict[1:]}"
        head += f" ({self.wall_time})" if self.wall_time else ""
        return [head, *(f"  {item.topic}: {item.text}" for item in self.findings)]


def summarize(metrics: dict, config: dict | None = None, name: str | None = None) -> RunSummary:
    """The summary of a run from its ``metrics.json`` (and its resolved config, as a dict, for the gait's
    commands; without it the speed is given without a command)."""
    config = config or {}
    name = name or str(config.get("name") or metrics.get("gait") or "run")
    task = metrics.get("task") or None
    kind = "task" if task else ("gait" if metrics.get("gait") else "stand")
    verdict, ok = _verdict(metrics, task)
    findings: list[Finding] = []
    if task:
        findings += _task_findings(task)
    if kind == "gait":
        gait = _gait_findings(metrics, config)  # speed, then height, then attitude
        findings += [item for item in gait if item.topic == "Speed"] + _height_findings(metrics, kind)
        findings += [item for item in gait if item.topic != "Speed"]
    else:
        findings += _height_findings(metrics, kind)
    findings += _mpc_findings(metrics)
    findings += _low_level_findings(metrics)
    findings += _realtime_findings(metrics)
    findings += _estimator_findings(metrics)
    look = [item.topic for item in findings if item.status == "warn"]
    if look and ok is not False:
        verdict += f"; worth a look: {', '.join(_lower_first(topic) for topic in look)}"
    return RunSummary(name, kind, verdict, ok, _facts(metrics), _simulated(metrics), tuple(findings))


# --------------------------------------------------------------------------------------------- verdict
def _verdict(metrics: dict, task: dict | None) -> tuple[str, bool | None]:
    duration = metrics.get("sim_time_s")
    if metrics.get("fell"):
        when = metrics.get("fall_time_s")
        text = "fell" + (f" at {when:.2f} s" if _is_number(when) else "")
        if metrics.get("fall_reason"):
            text += f" ({metrics['fall_reason']})"
        if task and task.get("failed_criteria"):
            text += f"; the task failed: {_criteria_words(task['failed_criteria'])}"
        return _sentence(text), False
    up = "stayed up" + (f" for the whole {duration:.2f} s" if _is_number(duration) else "")
    if task:
        if task.get("success") is True:
            return _sentence(f"{up} and the {_task_name(task)} succeeded"), True
        if task.get("success") is False:
            failed = _criteria_words(task.get("failed_criteria") or [])
            return _sentence(f"{up}, but the {_task_name(task)} failed: {failed}"), False
        reason = task.get("success_reason") or "the run was too short to judge it"
        return _sentence(f"{up}; the {_task_name(task)} was not judged ({reason})"), None
    return _sentence(up), True


def _simulated(metrics: dict) -> str:
    wall, factor = metrics.get("wall_time_s"), metrics.get("real_time_factor")
    if not _is_number(wall):
        return ""
    text = f"simulated in {wall:.2f} s of wall time"
    return text + (f", real-time factor {factor:.2f}" if _is_number(factor) else "")


def _facts(metrics: dict) -> str:
    timing = (metrics.get("timing") or {}).get("mode")
    planner = metrics.get("planner") if timing in TIMING_WORDS else None  # not for PD standing
    parts = [
        metrics.get("robot"),
        PLANNER_WORDS.get(planner, planner),
        CONTROLLER_WORDS.get(metrics.get("controller"), metrics.get("controller")),
        f"gait {metrics['gait']}" if metrics.get("gait") else None,
        f"task {metrics['task']['name']}" if (metrics.get("task") or {}).get("name") else None,
        TIMING_WORDS.get(timing, timing),
        (metrics.get("estimator") or {}).get("kind"),
    ]
    return " · ".join(str(part) for part in parts if part)


# ----------------------------------------------------------------------------------------------- tasks
def _task_name(task: dict) -> str:
    return str(task.get("name") or "task").replace("-", " ")


CRITERION_WORDS = {
    "roll_turned": "roll turned",
    "landed": "landing",
    "upright_after": "upright after landing",
    "stayed_up": "stayed up after landing",
    "motor_torque_limits": "motor torque limits",
    "bar_contact": "bar contact",
    "pace_resumed": "pace resumed",
}


def _criteria_words(names: list[str]) -> str:
    return ", ".join(CRITERION_WORDS.get(name, name) for name in names) or "no criterion named"


def _criterion_status(task: dict, name: str) -> str:
    if name in (task.get("failed_criteria") or []):
        return "bad"
    if name in (task.get("unjudged") or {}):
        return "info"
    return "ok"


def _task_findings(task: dict) -> list[Finding]:
    rules = task.get("criteria") or {}
    out: list[Finding] = []
    axis = task.get("rotation_axis", "roll")  # the axis the task turns about: roll, pitch or yaw
    turned = task.get("roll_turned_rad") if axis == "roll" else task.get("rotation_turned_rad")
    target = task.get("roll_target_rad")
    if _is_number(turned):
        text = f"{turned:.2f} rad"
        if _is_number(target):
            text += (
                f" of the {target:.2f} rad asked ({math.degrees(turned):.0f}° of {math.degrees(target):.0f}°)"
            )
        if _is_number(task.get("roll_turned_at_touchdown_rad")):
            text += f"; {task['roll_turned_at_touchdown_rad']:.2f} rad at touchdown"
        out.append(
            Finding(
                axis.capitalize(), text, _criterion_status(task, "roll_turned"), rules.get("roll_turned", "")
            )
        )
    flight = []
    if _is_number(task.get("max_base_height_m")):
        flight.append(f"apex {task['max_base_height_m']:.2f} m")
    if _is_number(task.get("touchdown_s")):
        touchdown = f"touchdown at {task['touchdown_s']:.2f} s"
        if _is_number(task.get("planned_touchdown_s")):
            early = task["touchdown_s"] - task["planned_touchdown_s"]
            touchdown += f" ({abs(early) * 1e3:.0f} ms {'late' if early > 0 else 'early'} on the plan)"
        flight.append(touchdown)
    elif task.get("touchdown_s") is None and "touchdown_s" in task:
        flight.append("no touchdown found")
    if flight:
        out.append(Finding("Flight", ", ".join(flight), "info", rules.get("touchdown", "")))
    if "landed" in task:
        lowest = [
            f"{part} {task[key] * 1e3:.0f} mm"
            for part, key in (
                ("trunk", "lowest_trunk_m"),
                ("thigh", "lowest_thigh_m"),
                ("knee", "lowest_knee_m"),
            )
            if _is_number(task.get(key))
        ]
        text = "on all four feet" if task.get("landed") else "did not land on its feet"
        if _is_number(task.get("all_feet_down_s")):
            text += f" at {task['all_feet_down_s']:.2f} s"
        if lowest:
            text += "; lowest above the floor: " + ", ".join(lowest)
        out.append(Finding("Landing", text, _criterion_status(task, "landed"), rules.get("landed", "")))
    tilt = task.get("tilt_max_first_second_after_landing_rad")
    if _is_number(tilt):
        text = f"tilt at most {_angle(tilt)} in the second after landing"
        if _is_number(task.get("tilt_final_rad")):
            text += f", {_angle(task['tilt_final_rad'])} at the end"
        out.append(
            Finding("Upright", text, _criterion_status(task, "upright_after"), rules.get("upright_after", ""))
        )
    if _is_number(task.get("stayed_up_s")):
        out.append(
            Finding(
                "Stayed up",
                f"{task['stayed_up_s']:.2f} s after the touchdown",
                _criterion_status(task, "stayed_up"),
                rules.get("stayed_up", ""),
            )
        )
    if task.get("bar_contact") is not None:
        out.append(_bar_finding(task, rules))
    speeds = _task_speeds(task)
    if speeds:
        status = _criterion_status(task, "pace_resumed") if task.get("pace_resumed") is not None else "info"
        out.append(Finding("Speed", speeds, status, rules.get("pace_resumed", "") or rules.get("speeds", "")))
    motor = task.get("roll_motor_torque_limit_violations")
    if motor is not None:
        text = f"{_count(motor, 'tick')} over the motor limits during the roll"
        requested = task.get("roll_requested_torque_limit_violations")
        if requested is not None:
            text += f", {_count(requested, 'request')} over the enforced limits before clamping"
        cone = task.get("roll_friction_cone_violations")
        if cone is not None:
            text += f", {_count(cone, 'tick')} outside the friction cone"
        status = _criterion_status(task, "motor_torque_limits")
        out.append(Finding("Limits", text, status, rules.get("violations", "")))
    unjudged = task.get("unjudged") or {}
    for criterion, reason in unjudged.items():
        out.append(Finding("Not judged", f"{CRITERION_WORDS.get(criterion, criterion)}: {reason}", "info"))
    return out


def _bar_finding(task: dict, rules: dict) -> Finding:
    height = f" ({task['bar_height_m']:.2f} m high)" if _is_number(task.get("bar_height_m")) else ""
    if task.get("bar_contact"):
        who = ", ".join(task.get("bar_touched_by") or []) or "the robot"
        when = task.get("bar_first_contact_s")
        text = f"touched{height} by {who}" + (f" at {when:.2f} s" if _is_number(when) else "")
        ticks = task.get("bar_contact_ticks")
        if ticks:
            text += f" ({_count(ticks, 'tick')})"
        return Finding("Bar", text, _criterion_status(task, "bar_contact"), rules.get("bar_contact", ""))
    clearance = task.get("bar_clearance_min_m")
    text = f"cleared{height}"
    if _is_number(clearance):
        text += f" by {clearance * 1e3:.1f} mm"
        if task.get("bar_clearance_geom"):
            text += f" ({task['bar_clearance_geom']}"
            text += (
                f", at {task['bar_clearance_time_s']:.2f} s)"
                if _is_number(task.get("bar_clearance_time_s"))
                else ")"
            )
    return Finding("Bar", text, _criterion_status(task, "bar_contact"), rules.get("bar_contact", ""))


def _task_speeds(task: dict) -> str:
    parts = []
    for label, key, command in (
        ("before the roll", "speed_before_roll_mps", "approach_speed_command_mps"),
        ("at the end", "speed_after_roll_mps", "resume_speed_command_mps"),
    ):
        value = task.get(key)
        if not _is_number(value):
            continue
        text = f"{value:.2f} m/s {label}"
        if _is_number(task.get(command)):
            text += f" (command {task[command]:.2f} m/s)"
        parts.append(text)
    if not any(
        _is_number(task.get(key)) for key in ("approach_speed_command_mps", "resume_speed_command_mps")
    ):
        return ""  # an in-place task: its speeds are not a result
    text = "forward " + ", ".join(parts)
    if task.get("pace_resumed") is not None:
        text += "; the pace resumed" if task["pace_resumed"] else "; the pace did not resume"
    return text


# ------------------------------------------------------------------------------------------------ gaits
def _commands(config: dict, duration: float | None) -> list[dict]:
    gait = config.get("gait") or {}
    commands = [command for command in gait.get("commands") or [] if isinstance(command, dict)]
    if duration is not None:
        commands = [command for command in commands if float(command.get("start") or 0.0) < duration]
    return commands


def _ramp_end(config: dict, command: dict) -> float | None:
    """When a gait's first command is fully ramped in: after the start stance and the command ramp."""
    gait = config.get("gait") or {}
    stance, ramp = gait.get("start_stance"), gait.get("command_ramp")
    if not (_is_number(stance) or _is_number(ramp)):
        return None
    start = float(command.get("start") or 0.0)
    return start + float(stance or 0.0) + float(ramp or 0.0)


def _gait_findings(metrics: dict, config: dict) -> list[Finding]:
    steady = metrics.get("steady_state") or {}
    window = steady.get("metrics_window_start_s")
    vx = steady.get("vx_mean")
    commands = _commands(config, metrics.get("sim_time_s"))
    distinct = {(command.get("vx"), command.get("vy"), command.get("yaw_rate")) for command in commands}
    out: list[Finding] = []
    whole = metrics.get("vx_mean")
    errors = (
        f"RMS error {_num(steady.get('vx_rms_error'))} m/s forward, {_num(steady.get('vy_rms_error'))} m/s "
        f"sideways, {_num(steady.get('yaw_rate_rms_error'))} rad/s in yaw rate"
    )
    since = f" from {window:g} s" if _is_number(window) else ""
    whole_text = (
        f"; whole run {_num(whole)} m/s, forward RMS error {_num(metrics.get('vx_rms_error'))} m/s"
        if _is_number(whole)
        else ""
    )
    if len(distinct) == 1 and _is_number(vx):
        command = commands[0]
        target = float(command.get("vx") or 0.0)
        off = vx - target
        tolerance = SPEED_TOLERANCE_M_S + SPEED_FRACTION * abs(target)
        text = f"{vx:.3f} m/s forward{since} against the {target:g} m/s command"
        text += f" ({abs(off):.3f} m/s {'fast' if off > 0 else 'slow'}); {errors}{whole_text}"
        status = "ok" if abs(off) <= tolerance else "warn"
        rule = f"on its command within {SPEED_TOLERANCE_M_S:g} m/s + {SPEED_FRACTION:.0%} of it"
        ramp_end = _ramp_end(config, command)
        duration = metrics.get("sim_time_s")
        if ramp_end is not None and _is_number(window) and _is_number(duration) and ramp_end > window:
            settled = (duration - ramp_end) / max(duration - window, 1e-9)
            if settled < SETTLED_SHARE:  # mostly the ramp: the mean says little about tracking
                text += f"; too short to judge: the command ramps in until {ramp_end:.2f} s"
                status = "info"
        out.append(Finding("Speed", text, status, rule))
    elif _is_number(vx):
        speeds = sorted({float(command.get("vx") or 0.0) for command in commands})
        span = f"{speeds[0]:g} to {speeds[-1]:g} m/s forward" if speeds else "changing"
        text = f"follows {len(commands)} commands ({span}); mean {vx:.3f} m/s forward{since}; "
        text += f"{errors}{whole_text}"
        out.append(Finding("Speed", text, "info"))
    pitch = steady.get("pitch_rms")
    if _is_number(pitch):
        text = f"pitch RMS {_angle(pitch)}{since}"
        if _is_number(metrics.get("pitch_rms")):
            text += f" ({_angle(metrics['pitch_rms'])} over the whole run)"
        extremes = [
            f"|{axis}| {_angle(metrics[key])}"
            for axis, key in (("roll", "roll_abs_max_rad"), ("pitch", "pitch_abs_max_rad"))
            if _is_number(metrics.get(key))
        ]
        if extremes:
            text += "; largest " + ", ".join(extremes)
        out.append(Finding("Attitude", text, "info"))
    return out


def _height_findings(metrics: dict, kind: str) -> list[Finding]:
    mean = metrics.get("base_height_mean")
    if not _is_number(mean):
        return []
    text = f"base {mean:.3f} m on average"
    low, high = metrics.get("base_height_min"), metrics.get("base_height_max")
    if _is_number(low) and _is_number(high):
        text += f" ({low:.3f}-{high:.3f} m)"
    steady = metrics.get("steady_state") or {}
    error = steady.get("height_rms_error")
    if kind == "gait" and _is_number(error):
        window = steady.get("metrics_window_start_s")
        since = f" from {window:g} s" if _is_number(window) else ""
        text += f"; RMS error against the reference {_length(error)}{since}"
    return [Finding("Height", text, "info")]


# ------------------------------------------------------------------------------------------- controller
def _mpc_findings(metrics: dict) -> list[Finding]:
    timing = metrics.get("timing") or {}
    mpc = metrics.get("mpc") or {}
    mode = timing.get("mode")
    if not mpc or mode not in TIMING_WORDS:
        if not mode:
            return []
        detail = str(mode).removeprefix("none").strip(" ()")  # "none (PD standing)"
        return [Finding("MPC", f"none ({detail})" if detail else "none", "info")]
    period = timing.get("period_s")
    rate = mpc.get("rate_hz")
    status = "ok"
    parts = []
    if _is_number(rate):
        text = f"{rate:.1f} Hz"
        if _is_number(period) and period > 0:
            asked = 1.0 / period
            text += f" (its period asks for {asked:.0f} Hz)"
            if rate < RATE_SHORTFALL * asked:
                status = "warn"
                text += ": the computer did not keep up"
        parts.append(text)
    latency = mpc.get("latency_ms_median")
    if mode == "fixed":
        fixed = timing.get("fixed_latency_s")
        latency_text = "fixed latency" + (f" of {fixed * 1e3:.0f} ms" if _is_number(fixed) else "")
        latency_text += ": each plan acts that long after its measurement (deterministic)"
    else:
        where = "in its own process against the wall clock" if mode == "realtime" else "in simulated time"
        latency_text = f"{TIMING_WORDS[mode]} ({where}): plans acted {_ms(latency)} after their measurement"
        if _is_number(mpc.get("latency_ms_p99")):
            latency_text += f" (median, p99 {_ms(mpc['latency_ms_p99'])})"
        scale = timing.get("compute_scale")
        if _is_number(scale) and scale != 1:
            latency_text += f", compute times x{scale:g}"
    parts.append(latency_text)
    update = f"an update took {_ms(mpc.get('update_ms_median'))} (median"
    update += f", p99 {_ms(mpc['update_ms_p99'])})" if _is_number(mpc.get("update_ms_p99")) else ")"
    if _is_number(mpc.get("prepare_ms_median")) and _is_number(mpc.get("feedback_ms_median")):
        update += f": preparation {_ms(mpc['prepare_ms_median'])}"
        if _is_number(mpc.get("prepare_ms_p99")) and _is_number(mpc.get("prepare_cpu_ms_p99")):
            update += f" (p99 {_ms(mpc['prepare_ms_p99'])}, of CPU time {_ms(mpc['prepare_cpu_ms_p99'])})"
        update += f", feedback {_ms(mpc['feedback_ms_median'])}"
    parts.append(update)
    solves, failures = mpc.get("solves"), mpc.get("failures")
    if solves is not None:
        parts.append(f"{_count(solves, 'solve')}, {failures or 0} failed")
        if failures:
            status = "warn"
    stops = mpc.get("time_budget_stops")
    if stops:
        parts.append(f"{_count(stops, 'solve')} stopped by the time budget")
    if mpc.get("worker_error"):
        parts.append(f"the MPC process failed: {mpc['worker_error']}")
        status = "bad"
    return [Finding("MPC", "; ".join(parts), status)]


def _low_level_findings(metrics: dict) -> list[Finding]:
    wbc = metrics.get("wbc") or {}
    mpc = metrics.get("mpc") or {}
    if not wbc and not mpc:
        return []
    controller = CONTROLLER_WORDS.get(wbc.get("controller"), wbc.get("controller") or "low level")
    parts, status = [], "ok"
    fallbacks = wbc.get("fallbacks")
    if fallbacks is not None:
        parts.append(f"{_count(fallbacks, 'QP fallback')} (to the clamped Riccati feedback)")
        status = "warn" if fallbacks else status
    pd = mpc.get("pd_fallback_ticks")
    if pd:
        ticks = metrics.get("control_ticks")
        share = f" of {ticks}" if ticks else ""
        parts.append(f"{pd}{share} ticks held off the plans by the safe ladder (balance or damped stance)")
        status = "warn"
    for key, words in (
        ("torque_limit_violations", "over the torque limits"),
        ("friction_cone_violations", "outside the friction cone"),
    ):
        if wbc.get(key) is not None:
            parts.append(f"{_count(wbc[key], 'tick')} {words}")
            status = "warn" if wbc[key] else status
    if _is_number(wbc.get("foot_slip_max_m")):
        parts.append(f"feet slipped at most {_length(wbc['foot_slip_max_m'])}")
    if _is_number(wbc.get("qp_solve_time_ms_median")):
        parts.append(f"QP {_ms(wbc['qp_solve_time_ms_median'])} median")
    limit_ticks = metrics.get("torque_limit_ticks")
    if limit_ticks:
        peak = metrics.get("torque_abs_max_nm")
        parts.append(
            f"applied torque at its limit on {_count(limit_ticks, 'tick')}"
            + (f" (largest {peak:.1f} Nm)" if _is_number(peak) else "")
        )
    return [Finding(f"Low level ({controller})", "; ".join(parts), status)] if parts else []


def _realtime_findings(metrics: dict) -> list[Finding]:
    realtime = metrics.get("realtime") or {}
    if "missed_ticks" not in realtime:
        return []
    missed = realtime["missed_ticks"]
    text = f"{_count(missed, 'tick')} of the 500 Hz loop started more than 1 ms late"
    if realtime.get("missed_ticks_not_scheduled"):
        text += f" ({realtime['missed_ticks_not_scheduled']} because the OS did not run the loop in time)"
    if _is_number(realtime.get("tick_lateness_ms_p99")):
        p99, worst = realtime["tick_lateness_ms_p99"], realtime["tick_lateness_ms_max"]
        text += f"; lateness p99 {p99:.2f} ms, max {worst:.1f} ms"
    if realtime.get("scheduling"):
        text += f"; {realtime['scheduling']}, memory {realtime.get('memory', 'not locked')}"
    return [Finding("Real-time loop", text, "warn" if missed else "ok")]


def _estimator_findings(metrics: dict) -> list[Finding]:
    estimator = metrics.get("estimator") or {}
    kind = estimator.get("kind")
    if not kind:
        return []
    if estimator.get("velocity_rms_error_m_s") is None:
        return [Finding("Estimator", f"{kind}: the controller saw the simulator's state", "info")]
    text = (
        f"{kind}: velocity error {_num(estimator['velocity_rms_error_m_s'], 4)} m/s RMS "
        f"(max {_num(estimator.get('velocity_error_max_m_s'))} m/s)"
    )
    if _is_number(estimator.get("height_rms_error_m")):
        text += f", height {_length(estimator['height_rms_error_m'])} RMS"
    if _is_number(estimator.get("orientation_rms_error_rad")):
        text += f", orientation {_num(estimator['orientation_rms_error_rad'], 4)} rad RMS"
    if _is_number(estimator.get("contact_agreement")):
        text += f"; contacts as the plant's on {estimator['contact_agreement']:.0%} of foot-ticks"
    return [Finding("Estimator", text, "info")]


# ------------------------------------------------------------------------------------------------ words
def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def _num(value: Any, digits: int = 3) -> str:
    return f"{value:.{digits}f}" if _is_number(value) else "n/a"


def _ms(value: Any) -> str:
    if not _is_number(value):
        return "n/a"
    return f"{value:.2f} ms" if value < 1 else f"{value:.1f} ms"


def _length(metres: float) -> str:
    """A small length in mm (below 10 cm), else in m."""
    return f"{metres * 1e3:.1f} mm" if abs(metres) < 0.1 else f"{metres:.3f} m"


def _angle(radians: float) -> str:
    return f"{radians:.3f} rad ({math.degrees(radians):.1f}°)"


def _count(number: int, noun: str) -> str:
    return f"{number} {noun}{'' if number == 1 else 's'}"


def _lower_first(topic: str) -> str:
    """``Low level (VWBC)`` -> ``low level (VWBC)``; an acronym (``MPC``) stays."""
    return topic if topic[:2].isupper() else topic[:1].lower() + topic[1:]


def _sentence(text: str) -> str:
    return text[:1].upper() + text[1:]
