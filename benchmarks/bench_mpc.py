"""Closed-loop MPC timing per gait: ``cafe-mpc bench mpc`` over all five gait presets by default.

Run it alone on the machine (no other simulation), e.g.

    .venv/bin/python benchmarks/bench_mpc.py --duration 10 --gaits trot pace bound pronk flying-trot
    .venv/bin/cafe-mpc bench mpc --gaits trot,bound --duration 4 --json
"""

from __future__ import annotations

import argparse
import json

from cafe_mpc_lab.bench.mpc_bench import format_report, run_mpc_benchmark


def main() -> None:
    formatter = argparse.RawDescriptionHelpFormatter
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=formatter)
    parser.add_argument("--duration", type=float, default=10.0, help="simulated seconds per gait")
    parser.add_argument("--gaits", nargs="+", default=["trot", "pace", "bound", "pronk", "flying-trot"])
    parser.add_argument("--set", dest="overrides", action="append", default=[], help="config override")
    parser.add_argument("--json", action="store_true", help="print JSON instead of a table")
    args = parser.parse_args()
    result = run_mpc_benchmark(tuple(args.gaits), args.duration, tuple(args.overrides))
    print(json.dumps(result, indent=2) if args.json else format_report(result))


if __name__ == "__main__":
    main()
