"""``cafe-mpc report DIR``: one self-contained ``index.html`` for a run folder or an experiment folder.

A **run** (a folder with ``metrics.json``) opens with what a person asks first (``report/summary.py``): the
verdict (did it stay up; did the task succeed), then the numbers that matter for the run's kind in words with
units (a gait's speed against its command, height and attitude; a task's criteria, each next to its rule, and
margins such as the bar clearance; the MPC's rate and latency in its timing mode; the low level's fallbacks
and violations; the estimator's error). Then its video (``run.mp4``, or the GIF written without ffmpeg) and
``frames.png`` when they were recorded, its plots (``*.png``, the most telling first, each with a caption),
and last, collapsed, every metric (the top-level ones, then one table per block: ``steady_state``,
``timing``, ``mpc``, ``wbc``, ...), the resolved ``config.yaml`` and links to the raw files (``log.npz``,
``run.log``, ...).

An **experiment** (a folder with ``comparison.json``, from ``cafe-mpc experiment``): its title, the command
that made it, the comparison table and notes (``comparison.md``), its figures (``comparison.png`` and any
other ``*.png``), ``summary.json`` when there is one (reliability), and one row per variant with its
outcome and a link to the variant's own report (``<variant>/index.html``, written too).

Self-contained: images and the video are embedded as ``data:`` URIs, the style sheet and the small script
are inline, nothing is fetched from the network, so ``index.html`` opens from the file system and can be
shared as one file (the links to raw files and to the variants' reports are relative: they work when the
whole folder is shared). The script checks on load that every image decoded and shows a banner when one
did not (``<body data-images=N data-broken=M>``).
"""

from __future__ import annotations

import base64
import html
import json
import re
from pathlib import Path
from typing import Any

import yaml

from cafe_mpc_lab.report.summary import RunSummary, summarize

RUN_FILE = "metrics.json"
EXPERIMENT_FILE = "comparison.json"
REPORT_FILE = "index.html"

_STYLE = """
body { font-family: system-ui, -apple-system, "Segoe UI", sans-serif; margin: 2em auto; max-width: 1200px;
       padding: 0 1em; color: #222; }
h1 { font-size: 1.6em; margin-bottom: 0.2em; } h2 { margin-top: 1.6em; border-bottom: 1px solid #ddd; }
table { border-collapse: collapse; margin: 0.5em 0 1em; font-size: 0.9em; }
th, td { border: 1px solid #ccc; padding: 0.25em 0.6em; text-align: left; vertical-align: top; }
th { background: #f3f3f3; } td.num { text-align: right; font-variant-numeric: tabular-nums; }
.outcome-ok { color: #176b2c; font-weight: bold; } .outcome-bad { color: #a11; font-weight: bold; }
figure { display: inline-block; margin: 0.5em; vertical-align: top; }
figure img { max-width: 560px; border: 1px solid #ddd; } figcaption { font-size: 0.85em; color: #555; }
img.wide { max-width: 100%; } video { max-width: 100%; border: 1px solid #ddd; }
code, pre { background: #f6f6f6; } pre { padding: 0.8em; overflow-x: auto; font-size: 0.85em; }
.tables { display: flex; flex-wrap: wrap; gap: 0 2em; } .tables h3 { margin: 0.4em 0 0; font-size: 1em; }
#broken { display: none; background: #fdd; border: 1px solid #a11; padding: 0.5em; }
p.facts { color: #555; margin-top: 0; }
.verdict { font-size: 1.3em; font-weight: bold; padding: 0.55em 0.9em; margin: 0.8em 0;
           border-left: 6px solid; }
.verdict.ok { background: #e9f6ec; border-color: #176b2c; color: #124f22; }
.verdict.bad { background: #fdecec; border-color: #a11; color: #7d0d0d; }
.verdict.warn { background: #fdf3e4; border-color: #b35c00; color: #6b3700; }
.verdict.unjudged { background: #f3f3f3; border-color: #777; }
table.summary { font-size: 1em; width: 100%; } table.summary th { width: 9em; white-space: nowrap; }
table.summary td.status { width: 1.2em; text-align: center; font-weight: bold; }
td.ok { color: #176b2c; } td.warn { color: #b35c00; } td.bad { color: #a11; } td.info { color: #999; }
table.summary td.rule { color: #666; font-size: 0.85em; width: 35%; }
details > summary { cursor: pointer; margin: 0.4em 0; color: #333; }
"""

_SCRIPT = """
window.addEventListener("load", function () {
  var images = Array.prototype.slice.call(document.images);
  var broken = images.filter(function (image) { return !(image.complete && image.naturalWidth > 0); });
  document.body.setAttribute("data-images", String(images.length));
  document.body.setAttribute("data-broken", String(broken.length));
  if (broken.length) {
    var banner = document.getElementById("broken");
    banner.textContent = broken.length + " of " + images.length + " images did not load.";
    banner.style.display = "block";
  }
});
"""


class ReportError(ValueError):
    """The folder is neither a run nor an experiment, or a file in it cannot be read."""


def write_report(folder: Path) -> Path:
    """Write ``index.html`` into ``folder`` (a run or an experiment; for an experiment also into every
    variant's folder) and return its path. Raises ``ReportError``."""
    folder = Path(folder)
    if not folder.is_dir():
        raise ReportError(f"{folder} is not a folder")
    if (folder / EXPERIMENT_FILE).is_file():
        page = _experiment_page(folder)
    elif (folder / RUN_FILE).is_file():
        page = _run_page(folder)
    else:
        raise ReportError(
            f"{folder} is neither a run folder ({RUN_FILE}) nor an experiment folder ({EXPERIMENT_FILE})"
        )
    path = folder / REPORT_FILE
    path.write_text(page, encoding="utf-8")
    return path


# --------------------------------------------------------------------------------------------- pages
def _page(title: str, body: list[str]) -> str:
    return "\n".join(
        [
            "<!DOCTYPE html>",
            '<html lang="en"><head><meta charset="utf-8">',
            '<meta name="viewport" content="width=device-width, initial-scale=1">',
            f"<title>{_e(title)}</title>",
            f"<style>{_STYLE}</style>",
            f"<script>{_SCRIPT}</script>",
            "</head><body>",
            '<div id="broken"></div>',
            *body,
            '<p style="color:#777;font-size:0.8em">Written by <code>cafe-mpc report</code>; images and video '
            "are embedded in this file.</p>",
            "</body></html>",
        ]
    )


def _run_page(folder: Path, experiment_link: str | None = None) -> str:
    metrics = _read_json(folder / RUN_FILE)
    name = _config_name(folder) or folder.name
    summary = summarize(metrics, _config_dict(folder), name)
    body = []
    if experiment_link:
        body.append(f'<p><a href="{_e(experiment_link)}">&larr; experiment</a></p>')
    body.append(f"<h1>{_e(name)}</h1>")
    facts = " · ".join(part for part in (summary.facts, summary.wall_time) if part)
    body.append(f'<p class="facts">{_e(facts)}</p>')
    body.append(_verdict(summary))
    body.append(_findings_table(summary))
    body.append("<p>Re-run it from this folder: <code>cafe-mpc run config.yaml</code></p>")
    video = _video(folder)
    frames = folder / FRAMES_FILE
    if video or frames.is_file():
        body.append("<h2>Video</h2>" if video else "<h2>Frames</h2>")
        if video:
            body.append(video)
        if frames.is_file():
            body.append(_figure(frames, wide=True))
    figures = _figures(
        folder, order=PLOT_ORDER_TASK if summary.kind == "task" else PLOT_ORDER, skip={FRAMES_FILE}
    )
    if figures:
        body += ["<h2>Plots</h2>", figures]
    count = len(_flatten(metrics))
    body += [
        "<h2>All metrics</h2>",
        f"<details><summary>every value of <code>metrics.json</code> ({count}), with its unit</summary>",
        _metrics_tables(metrics),
        "</details>",
    ]
    config = folder / "config.yaml"
    if config.is_file():
        body += [
            "<h2>Config</h2>",
            f"<details><summary>config.yaml</summary><pre>{_e(config.read_text())}</pre></details>",
        ]
    body += ["<h2>Files</h2>", _file_links(folder)]
    return _page(f"cafe-mpc run {name}", body)


def _experiment_page(folder: Path) -> str:
    comparison = _read_json(folder / EXPERIMENT_FILE)
    title = str(comparison.get("title") or comparison.get("experiment") or folder.name)
    body = [f"<h1>{_e(title)}</h1>"]
    facts = [
        ("experiment", comparison.get("experiment")),
        ("paper", comparison.get("paper")),
        ("created", comparison.get("created")),
        ("cluster", comparison.get("cluster")),
        ("timing", ", ".join(comparison.get("timing_modes") or []) or None),
        ("git", _git_text(comparison.get("git"))),
    ]
    body.append(_key_value_table([(key, value) for key, value in facts if value is not None]))
    markdown = folder / "comparison.md"
    if comparison.get("command") and not markdown.is_file():  # comparison.md starts with the command
        body.append(f"<p>Command: <code>{_e(comparison['command'])}</code></p>")
    if markdown.is_file():
        body += ["<h2>Comparison</h2>", _markdown(markdown.read_text())]
    figures = _figures(folder, wide=True)
    if figures:
        body += ["<h2>Figures</h2>", figures]
    summary = folder / "summary.json"
    if summary.is_file():
        body += ["<h2>Summary</h2>", _metrics_tables(_read_json(summary))]
    variants = comparison.get("variants") or {}
    body += ["<h2>Variants</h2>", _variants_table(folder, variants)]
    errors = comparison.get("errors") or {}
    if errors:
        body += ["<h2>Errors</h2>", _key_value_table(sorted(errors.items()))]
    body += ["<h2>Files</h2>", _file_links(folder)]
    return _page(f"cafe-mpc experiment {comparison.get('experiment', folder.name)}", body)


def _variants_table(folder: Path, variants: dict) -> str:
    """One row per variant: name, label, status, outcome, its report (written here) and its command."""
    rows = [
        "<table><tr><th>variant</th><th>label</th><th>status</th><th>outcome</th><th>report</th>"
        "<th>command</th></tr>"
    ]
    for run, row in variants.items():
        variant_folder = folder / str(row.get("folder") or run)
        link = ""
        if (variant_folder / RUN_FILE).is_file():
            (variant_folder / REPORT_FILE).write_text(
                _run_page(variant_folder, experiment_link=f"../{REPORT_FILE}"), encoding="utf-8"
            )
            target = f"{_e(variant_folder.name)}/{REPORT_FILE}"
            link = f'<a href="{target}">{target}</a>'
        elif variant_folder.is_dir():
            link = f'<a href="{_e(variant_folder.name)}/">{_e(variant_folder.name)}/</a>'
        outcome = "fell" if row.get("fell") else ("ok" if row.get("status") == "ok" else "")
        if row.get("fell") and row.get("fall_time_s") is not None:
            outcome += f" at {row['fall_time_s']:.2f} s"
        if row.get("success") is not None:
            outcome = ("success" if row["success"] else "failure") + (f" ({outcome})" if outcome else "")
        rows.append(
            "<tr>"
            f"<td>{_e(run)}</td><td>{_e(row.get('label') or '')}</td><td>{_e(row.get('status') or '')}</td>"
            f"<td>{_e(outcome)}</td><td>{link}</td><td><code>{_e(row.get('run_command') or '')}</code></td>"
            "</tr>"
        )
    rows.append("</table>")
    return "\n".join(rows)


# ------------------------------------------------------------------------------------------- pieces
STATUS_MARKS = {"ok": "\u2713", "warn": "!", "bad": "\u2717", "info": "\u00b7"}
"""The mark in front of a finding: fine, worth a look, failed, for information."""


def _verdict(summary: RunSummary) -> str:
    kind = {True: "warn" if summary.worth_a_look else "ok", False: "bad", None: "unjudged"}[summary.ok]
    return f'<div class="verdict {kind}">{_e(summary.verdict)}</div>'


def _findings_table(summary: RunSummary) -> str:
    """The findings, one row each: mark, topic, the numbers in words (a statement a line), and the rule a
    task's criterion is judged by."""
    rules = any(item.rule for item in summary.findings)
    rows = ['<table class="summary">']
    for item in summary.findings:
        mark = STATUS_MARKS.get(item.status, "")
        text = "<br>".join(_e(statement) for statement in item.text.split("; "))
        if item.rule:
            cells = f'<td>{text}</td><td class="rule">{_e(item.rule)}</td>'
        else:
            cells = f"<td{' colspan=2' if rules else ''}>{text}</td>"
        rows.append(
            f'<tr><td class="status {_e(item.status)}" title="{_e(item.status)}">{mark}</td>'
            f"<th>{_e(item.topic)}</th>{cells}</tr>"
        )
    rows.append("</table>")
    return "\n".join(rows)


def _metrics_tables(metrics: dict) -> str:
    scalars = [(key, value) for key, value in metrics.items() if not isinstance(value, dict)]
    blocks = [(key, value) for key, value in metrics.items() if isinstance(value, dict)]
    parts = ['<div class="tables">', "<div><h3>run</h3>", _key_value_table(scalars), "</div>"]
    for key, block in blocks:
        parts += [f"<div><h3>{_e(key)}</h3>", _key_value_table(_flatten(block)), "</div>"]
    parts.append("</div>")
    return "\n".join(parts)


def _flatten(block: dict, prefix: str = "") -> list[tuple[str, Any]]:
    items: list[tuple[str, Any]] = []
    for key, value in block.items():
        name = f"{prefix}{key}"
        if (
            isinstance(value, dict)
            and value
            and all(not isinstance(v, dict) for v in value.values())
            and (len(value) > 6)
        ):
            items.append((name, value))  # a histogram or similar: one cell
        elif isinstance(value, dict):
            items += _flatten(value, f"{name}.")
        else:
            items.append((name, value))
    return items


UNIT_SUFFIXES = (
    ("_rad_s", "rad/s"),
    ("_m_s", "m/s"),
    ("_mps", "m/s"),
    ("_ms", "ms"),
    ("_hz", "Hz"),
    ("_rad", "rad"),
    ("_nm", "Nm"),
    ("_m", "m"),
    ("_s", "s"),
)
"""Metric names end in their unit (docs/outputs.md); the report shows it in its own column."""


KNOWN_UNITS = {
    "vx_mean": "m/s",
    "vx_rms_error": "m/s",
    "vy_rms_error": "m/s",
    "vy_error_abs_max": "m/s",
    "yaw_rate_rms_error": "rad/s",
    "yaw_rate_error_abs_max": "rad/s",
    "height_rms_error": "m",
    "pitch_rms": "rad",
    "pitch_rate_rms": "rad/s",
    "base_height_mean": "m",
    "base_height_min": "m",
    "base_height_max": "m",
}
"""Units of the tracking metrics whose names predate the suffix convention."""


def unit_of(key: str) -> str:
    """The unit a metric's name ends in (``update_ms_median`` -> ms, ``vx_mean`` -> ''), after its
    statistic (``_median``, ``_p99``, ``_mean``, ``_max``, ``_min``)."""
    name = key.rsplit(".", 1)[-1].lower()
    if name in KNOWN_UNITS:
        return KNOWN_UNITS[name]
    for statistic in ("_median", "_p99", "_p95", "_mean", "_max", "_min"):
        name = name.removesuffix(statistic)
    for suffix, unit in UNIT_SUFFIXES:
        if name.endswith(suffix):
            return unit
    return ""


def _key_value_table(items: list[tuple[str, Any]]) -> str:
    rows = ["<table>"]
    for key, value in items:
        numeric = isinstance(value, int | float) and not isinstance(value, bool)
        cell = _number(value) if numeric else _e(_plain(value))
        unit = unit_of(key) if numeric else ""
        rows.append(
            f"<tr><th>{_e(key)}</th><td{' class=num' if numeric else ''}>{cell}</td><td>{_e(unit)}</td></tr>"
        )
    rows.append("</table>")
    return "\n".join(rows)


def _plain(value: Any) -> str:
    if value is None:
        return "null"
    if isinstance(value, str):
        return value
    return json.dumps(value, separators=(", ", ": "))


def _number(value: Any) -> str:
    if value is None:
        return "null"
    if isinstance(value, bool) or not isinstance(value, int | float):
        return _e(str(value))
    return str(value) if isinstance(value, int) else f"{value:.4g}"


FRAMES_FILE = "frames.png"
PLOT_ORDER = (
    "velocity_tracking.png",
    "base_height.png",
    "orientation.png",
    "foot_heights.png",
    "hip_knee_torques.png",
    "mpc_solve_times.png",
    "estimator.png",
    "contact_forces.png",
    "joint_torques.png",
    "velocities.png",
)
"""A run's plots, the most telling first (a gait's); any other plot follows by name."""
PLOT_ORDER_TASK = ("task.png", "task_torques.png", "base_height.png", "orientation.png", *PLOT_ORDER)
PLOT_CAPTIONS = {
    "task.png": "the task: roll, height and lateral position against the reference",
    "task_torques.png": "applied torques against the motor limits (roll shaded)",
    "velocity_tracking.png": "commanded and actual forward, sideways and yaw speed",
    "base_height.png": "base height",
    "orientation.png": "roll, pitch and yaw",
    "foot_heights.png": "foot heights: planned stance shaded, measured contact in black",
    "hip_knee_torques.png": "front-right and hind-right hip and knee torques with the limits",
    "mpc_solve_times.png": "time of every MPC update after the first",
    "estimator.png": "the state estimate against the simulator's state",
    "contact_forces.png": "contact forces",
    "joint_torques.png": "joint torques with the plan and the motor limits",
    "velocities.png": "base velocities",
    FRAMES_FILE: "frames of the run",
}


def _figures(
    folder: Path, wide: bool = False, order: tuple[str, ...] = (), skip: set[str] | frozenset = frozenset()
) -> str:
    rank = {name: index for index, name in enumerate(dict.fromkeys(order))}
    pictures = sorted(
        (path for path in folder.glob("*.png") if path.name not in skip),
        key=lambda path: (rank.get(path.name, len(rank)), path.name),
    )
    return "\n".join(_figure(picture, wide) for picture in pictures)


def _figure(picture: Path, wide: bool = False) -> str:
    uri = _data_uri(picture, "image/png")
    css = ' class="wide"' if wide else ""
    caption = _e(picture.name)
    if picture.name in PLOT_CAPTIONS:
        caption = f"{_e(PLOT_CAPTIONS[picture.name])} <code>{caption}</code>"
    return (
        f'<figure><img{css} src="{uri}" alt="{_e(picture.name)}"><figcaption>{caption}</figcaption></figure>'
    )


def _video(folder: Path) -> str:
    mp4, gif = folder / "run.mp4", folder / "run.gif"
    if mp4.is_file():
        return f'<video controls loop muted src="{_data_uri(mp4, "video/mp4")}"></video>'
    if gif.is_file():
        return f'<img class="wide" src="{_data_uri(gif, "image/gif")}" alt="run.gif">'
    return ""


def _file_links(folder: Path) -> str:
    files = sorted(path for path in folder.iterdir() if path.is_file() and path.name != REPORT_FILE)
    items = [f'<li><a href="{_e(path.name)}">{_e(path.name)}</a> ({_size(path)})</li>' for path in files]
    return "<ul>" + "".join(items) + "</ul>"


def _size(path: Path) -> str:
    size = path.stat().st_size
    for unit in ("B", "kB", "MB"):
        if size < 1024 or unit == "MB":
            return f"{size:.0f} {unit}" if unit == "B" else f"{size:.1f} {unit}"
        size /= 1024
    return f"{size:.1f} GB"


def _data_uri(path: Path, mime: str) -> str:
    return f"data:{mime};base64," + base64.b64encode(path.read_bytes()).decode("ascii")


def _markdown(text: str) -> str:
    """The small Markdown subset ``comparison.md`` uses: paragraphs, tables, ``**bold**`` and code."""
    out: list[str] = []
    lines = text.splitlines()
    index = 0
    while index < len(lines):
        line = lines[index].rstrip()
        if line.startswith("|"):
            table = []
            while index < len(lines) and lines[index].lstrip().startswith("|"):
                table.append(lines[index].strip())
                index += 1
            out.append(_markdown_table(table))
            continue
        if line:
            paragraph = [line]
            index += 1
            while index < len(lines) and lines[index].strip() and not lines[index].lstrip().startswith("|"):
                paragraph.append(lines[index].strip())
                index += 1
            out.append(f"<p>{_inline(' '.join(paragraph))}</p>")
            continue
        index += 1
    return "\n".join(out)


def _markdown_table(lines: list[str]) -> str:
    rows = [[cell.strip() for cell in line.strip("|").split("|")] for line in lines]
    rows = [row for row in rows if not all(re.fullmatch(r":?-{3,}:?", cell) for cell in row)]
    if not rows:
        return ""
    head, *body = rows
    html_rows = ["<table>", "<tr>" + "".join(f"<th>{_inline(cell)}</th>" for cell in head) + "</tr>"]
    for row in body:
        html_rows.append("<tr>" + "".join(f"<td>{_inline(cell)}</td>" for cell in row) + "</tr>")
    html_rows.append("</table>")
    return "\n".join(html_rows)


def _inline(text: str) -> str:
    escaped = _e(text)
    escaped = re.sub(r"`([^`]+)`", r"<code>\1</code>", escaped)
    return re.sub(r"\*\*([^*]+)\*\*", r"<b>\1</b>", escaped)


def _git_text(git: Any) -> str | None:
    if not isinstance(git, dict) or not git.get("commit"):
        return None
    return f"{str(git['commit'])[:12]}{' (with uncommitted changes)' if git.get('dirty') else ''}"


def _config_dict(folder: Path) -> dict:
    """The run's resolved ``config.yaml`` as a dict (empty when missing or unreadable: the summary then does
    without the commands)."""
    config = folder / "config.yaml"
    try:
        value = yaml.safe_load(config.read_text()) if config.is_file() else None
    except (OSError, yaml.YAMLError):
        return {}
    return value if isinstance(value, dict) else {}


def _config_name(folder: Path) -> str | None:
    config = folder / "config.yaml"
    if not config.is_file():
        return None
    match = re.search(r"^name:\s*(.+)$", config.read_text(), flags=re.MULTILINE)
    return match.group(1).strip().strip("'\"") if match else None


def _read_json(path: Path) -> dict:
    try:
        value = json.loads(path.read_text())
    except (OSError, ValueError) as error:
        raise ReportError(f"cannot read {path}: {error}") from error
    if not isinstance(value, dict):
        raise ReportError(f"{path} does not hold a JSON object")
    return value


def _e(text: Any) -> str:
    return html.escape(str(text), quote=True)
