"""``cafe-mpc robot --init`` on the model file of every shipped robot, then a trot with the file it wrote.

For each robot of ``known_robots()``: its model file (the Mini Cheetah's generated URDF, Go1's
example-robot-data URDF, the others' MJCF), ``starting_robot_file`` as ``robot --init`` writes it (nothing
edited, the FILL IN placeholders left as they are), then ``cafe-mpc run trot`` with that file, fixed 20 ms
latency (deterministic), estimator on. Prints one line per robot and a JSON summary to ``--out``.

    python benchmarks/robot_init_trot.py --duration 4 --out /tmp/robot_init_trot.json
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

from cafe_mpc.robots.robot import known_robots, shipped_model_file
from cafe_mpc.robots.starting_file import starting_robot_file


def trot(robot_yaml: Path, duration: float, out: Path) -> dict:
    """A fixed-latency trot of ``duration`` s with the robot file; its metrics.json's verdict."""
    command = [
        sys.executable,
        "-m",
        "cafe_mpc_lab.cli",
        "run",
        "trot",
        "--set",
        f"robot={robot_yaml}",
        "--set",
        "mpc.latency=fixed",
        "--set",
        "mpc.fixed_latency=0.02",
        "--set",
        "output.plots=false",
        "--duration",
        str(duration),
        "--out",
        str(out),
        "-q",
    ]
    result = subprocess.run(command, capture_output=True, text=True)
    metrics_file = out / "metrics.json"
    if not metrics_file.exists():
        return {"error": (result.stderr.strip().splitlines() or ["no output"])[-1]}
    metrics = json.loads(metrics_file.read_text())
    return {
        "fell": bool(metrics.get("fell")),
        "fall_time_s": metrics.get("fall_time_s"),
        "vx_mean": metrics.get("vx_mean"),
        "estimator_orientation_rms_rad": (metrics.get("estimator") or {}).get("orientation_rms_error_rad"),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=4.0, help="s of trot per robot (default 4)")
    parser.add_argument("--robots", help="comma-separated robot names (default: every shipped robot)")
    parser.add_argument("--out", help="write the summary (JSON) here")
    arguments = parser.parse_args()
    names = arguments.robots.split(",") if arguments.robots else known_robots()
    summary: dict[str, dict] = {}
    with tempfile.TemporaryDirectory() as folder:
        folder_path = Path(folder)
        for name in names:
            text = starting_robot_file(shipped_model_file(name, folder_path), f"{name}_init")
            robot_yaml = folder_path / f"{name}_init.yaml"
            robot_yaml.write_text(text)
            summary[name] = row = trot(robot_yaml, arguments.duration, folder_path / f"run_{name}")
            fell = row.get("fell") and f"fell at {row['fall_time_s']:.2f} s"
            verdict = row.get("error") or fell or "up"
            speed = row.get("vx_mean")
            print(f"{name:18s} {verdict:16s} vx {speed if speed is None else round(speed, 3)}", flush=True)
    if arguments.out:
        Path(arguments.out).write_text(json.dumps(summary, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
