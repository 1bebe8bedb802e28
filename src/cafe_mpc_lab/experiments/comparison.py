"""The comparison files of an experiment: ``comparison.json`` (every row, the command, the cluster, the git
state), ``comparison.md`` (the experiment's table) and ``comparison.png`` (its plot)."""

from __future__ import annotations

import json
import subprocess
import time
from pathlib import Path

from cafe_mpc_lab.experiments.cluster import ClusterInfo
from cafe_mpc_lab.experiments.common import RunStore, markdown_table
from cafe_mpc_lab.experiments.execution import STATUS_OK
from cafe_mpc_lab.experiments.registry import Experiment
from cafe_mpc_lab.experiments.results_table import RESULTS_FILE

COMPARISON_FILES = ("comparison.json", "comparison.md", "comparison.png")


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


def write_comparison(prepared, rows: list[dict], out_dir: Path, cluster: ClusterInfo) -> dict:
    experiment = prepared.experiment
    modes = sorted({str(row.get("timing_mode")) for row in rows if row.get("timing_mode")})
    comparison: dict = {
        "experiment": experiment.name,
        "title": experiment.title,
        "paper": experiment.paper,
        "command": prepared.command,
        "duration_s": prepared.duration,
        "overrides": prepared.overrides,
        "options": prepared.plan.options,
        "out_dir": str(out_dir),
        "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "git": _git_state(),
        "cluster": cluster.describe(),
        "timing_modes": modes,
        "results_csv": RESULTS_FILE,
        "variants": {row["run"]: {"folder": row["run"], **row} for row in rows},
        "errors": {row["run"]: row["error"] for row in rows if row.get("status") != STATUS_OK},
    }
    comparison.update(experiment.outputs(rows, comparison, out_dir))
    with open(out_dir / "comparison.json", "w") as handle:
        json.dump(comparison, handle, indent=2)
    (out_dir / "comparison.md").write_text(comparison_markdown(experiment, rows, comparison))
    plot_path = out_dir / "comparison.png"
    plot_path.unlink(missing_ok=True)
    experiment.plot(rows, RunStore(out_dir), plot_path)
    if not plot_path.exists():  # nothing to draw: an explicit empty figure, not a missing file
        from cafe_mpc_lab.report.figures import save_figure, subplots

        figure, axis = subplots(figsize=(6, 2))
        axis.text(0.5, 0.5, "no run produced a log to plot", ha="center", va="center")
        axis.set_axis_off()
        save_figure(figure, plot_path)
    return comparison


def comparison_markdown(experiment: Experiment, rows: list[dict], comparison: dict) -> str:
    """``comparison.md``: a title line with the command, the table, and what the columns mean."""
    duration = comparison["duration_s"]
    simulated = f"{duration:g} s simulated" if duration is not None else "each preset's duration"
    lines = [
        f"**{comparison['title']}** ({comparison['paper']}; {simulated}; timing: "
        f"{', '.join(comparison['timing_modes']) or 'n/a'})",
        "",
        f"Command: `{comparison['command']}`",
        "",
        *experiment.markdown_intro(rows, comparison),
    ]
    header, table_rows, notes = experiment.table(rows, comparison)
    lines += markdown_table(header, table_rows)
    lines += ["", *notes, ""]
    return "\n".join(lines)
