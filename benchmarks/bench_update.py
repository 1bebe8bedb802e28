"""MPC updates replayed without the simulator: per-update preparation time, its parts, and A/B ratios.

A closed-loop run in fixed latency is deterministic, and so is the sequence of calls it makes to its MPC
(the cold ``update``, then ``prepare(t, q, v)`` from the predicted state and ``feedback(t, q, v)`` with the
measurement, alternating). ``record`` runs the preset once and keeps that sequence; ``replay`` feeds it to a
freshly built MPC, which then does exactly the work of the closed loop, with no simulator in the process.

Several variants can be replayed **interleaved, update by update, in one process**: each variant is a
package (``cafe_mpc`` or a renamed copy of another commit, see ``--baseline``) plus ``--set`` overrides.
The report gives, per variant, the median and p99 of the preparation (wall and thread CPU time, and the
parts' wall times), and the median of the per-update ratios to the first variant with their interquartile
range: on a shared machine a load change hits both sides of a ratio alike, which is what makes the ratio
trustworthy when the absolute times are not. The CPU time leaves out the time the process waited for a
core (on a machine loaded several times over, most of the wall time); it is the closer estimate of the
wall time on a quiet machine.

Usage::

    python benchmarks/bench_update.py --preset trot --duration 4                  # this tree
    python benchmarks/bench_update.py --preset bound --variant "shift:mpc.final_policy=shift"
    python benchmarks/make_baseline.sh 0d59906   # -> /tmp/cafe_mpc_baseline/cafe_mpc_0d59906
    python benchmarks/bench_update.py --preset trot --baseline /tmp/cafe_mpc_baseline/cafe_mpc_0d59906
    python benchmarks/bench_update.py --preset trot --profile   # pyinstrument, each variant's preparations
    python benchmarks/bench_update.py --preset trot --allocations   # + tracemalloc peak per update

Variant syntax: ``NAME:override,override`` (this tree) or ``NAME@PACKAGE_DIR:override,...`` (a package
directory on disk, imported under its directory name).
"""

from __future__ import annotations

import argparse
import gc
import importlib
import json
import platform
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

PARTS = ("problem", "linearize", "backward", "line_search")


class CollectionLog:
    """Garbage collections (generation, wall time) that happen while ``inside`` is set (``gc.callbacks``)."""

    def __init__(self) -> None:
        self.inside = False
        self.pauses: list[tuple[int, float]] = []
        self._start = 0.0

    def __call__(self, phase: str, info: dict) -> None:
        if phase == "start":
            self._start = time.perf_counter()
        elif self.inside:
            self.pauses.append((int(info["generation"]), (time.perf_counter() - self._start) * 1e3))

    def summary(self) -> dict:
        durations = [ms for _, ms in self.pauses]
        return {
            "collections": len(self.pauses),
            "by_generation": {g: sum(1 for gen, _ in self.pauses if gen == g) for g in (0, 1, 2)},
            "total_ms": float(sum(durations)),
            "max_ms": float(max(durations)) if durations else 0.0,
        }


@dataclass
class Call:
    """One recorded call to the MPC."""

    method: str  # "update", "prepare" or "feedback"
    t: float
    q: np.ndarray
    v: np.ndarray


@dataclass
class Variant:
    name: str
    package: str
    overrides: list[str]
    mpc: object = None
    prepare_ms: list[float] = field(default_factory=list)
    prepare_cpu_ms: list[float] = field(default_factory=list)
    parts_ms: dict[str, list[float]] = field(default_factory=lambda: {p: [] for p in PARTS})
    feedback_ms: list[float] = field(default_factory=list)


def _import(package: str, module: str):
    return importlib.import_module(f"{package}.{module}")


def record(preset: str, duration: float, overrides: list[str]) -> list[Call]:
    """The MPC calls of a fixed-latency closed-loop run of ``preset`` (this tree's code)."""
    from cafe_mpc.config import load_config
    from cafe_mpc.planners.cafe.planner import RecedingHorizonMpc
    from cafe_mpc_lab.experiments.run import simulate_run

    calls: list[Call] = []
    originals = {name: getattr(RecedingHorizonMpc, name) for name in ("update", "prepare", "feedback")}

    def recorder(name):
        def method(self, t, q, v):
            calls.append(Call(name, float(t), np.array(q, dtype=float), np.array(v, dtype=float)))
            return originals[name](self, t, q, v)

        return method

    for name in originals:
        setattr(RecedingHorizonMpc, name, recorder(name))
    try:
        config = load_config(
            preset,
            [f"simulation.duration={duration}", "output.plots=false", "mpc.latency=fixed", *overrides],
        )
        simulate_run(config)
    finally:
        for name, method in originals.items():
            setattr(RecedingHorizonMpc, name, method)
    return calls


def _builders(package: str):
    """The module with ``build_planner`` (``build_mpc`` before the planner registry):
    ``assembly.controllers``, or ``experiments.controllers`` in a copy of a commit from before the assembly
    layer."""
    try:
        return _import(package, "assembly.controllers")
    except ModuleNotFoundError:
        return _import(package, "experiments.controllers")


def build(variant: Variant, preset: str, duration: float, common: list[str]) -> None:
    config_module = _import(variant.package, "config")
    controllers = _builders(variant.package)
    robots = _import(variant.package, "robots.robot")
    config = config_module.load_config(
        preset,
        [
            f"simulation.duration={duration}",
            "output.plots=false",
            "mpc.latency=fixed",
            *common,
            *variant.overrides,
        ],
    )
    robot = robots.load_robot(config.robot)
    build_planner = getattr(controllers, "build_planner", None) or controllers.build_mpc
    try:  # the builders take the resolved run where the package resolves a config once
        resolve = _import(variant.package, "assembly.resolve").resolve
    except ModuleNotFoundError:
        variant.mpc = build_planner(config, robot)
    else:
        variant.mpc = build_planner(resolve(config, robot))


def replay_step(variant: Variant, call: Call, record_times: bool) -> None:
    mpc = variant.mpc
    statistics = mpc.statistics
    if call.method == "update":
        mpc.update(call.t, call.q, call.v)
    elif call.method == "prepare":
        start, cpu_start = time.perf_counter(), time.thread_time()
        ok = mpc.prepare(call.t, call.q, call.v)
        elapsed, cpu = time.perf_counter() - start, time.thread_time() - cpu_start
        if record_times and ok:
            variant.prepare_ms.append(elapsed * 1e3)
            variant.prepare_cpu_ms.append(cpu * 1e3)
            parts = variant.parts_ms
            parts["problem"].append(statistics.problem_times[-1] * 1e3)
            parts["linearize"].append(statistics.linearize_times[-1] * 1e3)
            parts["backward"].append(statistics.backward_times[-1] * 1e3)
            parts["line_search"].append(statistics.line_search_times[-1] * 1e3)
    else:
        start = time.perf_counter()
        mpc.feedback(call.t, call.q, call.v)
        if record_times:
            variant.feedback_ms.append((time.perf_counter() - start) * 1e3)


def summary(values: list[float]) -> dict:
    if not values:
        return {"median": None, "p99": None}
    array = np.asarray(values)
    return {"median": float(np.median(array)), "p99": float(np.percentile(array, 99))}


def run(arguments: argparse.Namespace) -> dict:
    common = list(arguments.set or [])
    started = time.strftime("%Y-%m-%d %H:%M")
    calls = record(arguments.preset, arguments.duration, common)
    variants = [Variant("this", "cafe_mpc", [])]
    if arguments.baseline:
        path = Path(arguments.baseline).resolve()
        sys.path.insert(0, str(path.parent))
        variants.insert(0, Variant(path.name, path.name, []))
    for spec in arguments.variant or []:
        head, _, overrides = spec.partition(":")
        name, _, package_dir = head.partition("@")
        package = "cafe_mpc"
        if package_dir:
            path = Path(package_dir).resolve()
            sys.path.insert(0, str(path.parent))
            package = path.name
        variants.append(Variant(name, package, [o for o in overrides.split(",") if o]))
    for variant in variants:
        build(variant, arguments.preset, arguments.duration, common)
    collections = CollectionLog()
    gc.callbacks.append(collections)
    profilers = {}
    if arguments.profile:
        from pyinstrument import Profiler

        profilers = {variant.name: Profiler(interval=0.0005) for variant in variants}
    for round_index in range(arguments.rounds):
        for variant in variants:
            variant.mpc.reset()
        for call in calls:
            for variant in variants if round_index % 2 == 0 else reversed(variants):
                if arguments.gc == "collect-between" and call.method == "prepare":
                    gc.collect(0)
                profiler = profilers.get(variant.name) if call.method == "prepare" else None
                if profiler is not None:
                    profiler.start()
                collections.inside = call.method != "update"
                replay_step(variant, call, record_times=call.method != "update")
                collections.inside = False
                if profiler is not None:
                    profiler.stop()
            if arguments.gc == "freeze" and call.method == "update":
                gc.collect()
                gc.freeze()
    gc.callbacks.remove(collections)
    allocations: dict[str, float] = {}
    if arguments.allocations:
        allocations = allocation_peaks(variants, calls)
    reference = variants[0]
    result = {
        "date": started,
        "machine": {
            "processor": platform.processor() or platform.machine(),
            "python": platform.python_version(),
        },
        "preset": arguments.preset,
        "duration_s": arguments.duration,
        "rounds": arguments.rounds,
        "gc": arguments.gc,
        "overrides": common,
        "updates": sum(call.method == "prepare" for call in calls),
        "collections_inside_updates": collections.summary(),
        "variants": [],
    }
    for variant in variants:
        entry = {
            "name": variant.name,
            "package": variant.package,
            "overrides": variant.overrides,
            "prepare_ms": summary(variant.prepare_ms),
            "prepare_cpu_ms": summary(variant.prepare_cpu_ms),
            "feedback_ms": summary(variant.feedback_ms),
            "parts_ms_median": {p: summary(v)["median"] for p, v in variant.parts_ms.items()},
        }
        if variant.name in allocations:
            entry["update_allocation_peak_kb_median"] = allocations[variant.name]
        if variant is not reference and len(variant.prepare_ms) == len(reference.prepare_ms):
            for key, mine, theirs in (
                ("ratio_to_first", variant.prepare_ms, reference.prepare_ms),
                ("cpu_ratio_to_first", variant.prepare_cpu_ms, reference.prepare_cpu_ms),
            ):
                ratios = np.asarray(mine) / np.asarray(theirs)
                entry[key] = {
                    "median": float(np.median(ratios)),
                    "q25": float(np.percentile(ratios, 25)),
                    "q75": float(np.percentile(ratios, 75)),
                }
        result["variants"].append(entry)
    if profilers:
        result["profiles"] = {
            name: profiler.output_text(unicode=False, color=False, show_all=False)
            for name, profiler in profilers.items()
        }
    return result


def allocation_peaks(variants: list[Variant], calls: list[Call]) -> dict[str, float]:
    """Per variant, the median over a further replay of the peak memory Python allocates during an update,
    its preparation and its feedback (``tracemalloc``, which slows the calls: a separate pass, not timed)."""
    import tracemalloc

    peaks: dict[str, list[float]] = {variant.name: [] for variant in variants}
    for variant in variants:  # one variant after the other: an update's window spans two calls
        variant.mpc.reset()
        for call in calls:
            if call.method == "prepare":
                tracemalloc.start()
            replay_step(variant, call, record_times=False)
            if call.method == "feedback" and tracemalloc.is_tracing():
                peaks[variant.name].append(tracemalloc.get_traced_memory()[1] / 1e3)
                tracemalloc.stop()
    return {name: float(np.median(values)) for name, values in peaks.items() if values}


def format_report(result: dict) -> str:
    lines = [
        f"{result['date']}, {result['preset']}, {result['updates']} updates x {result['rounds']} rounds, "
        f"gc {result['gc']}, {result['machine']['processor']}",
        "",
        "| variant | prepare ms median / p99 | prepare CPU ms median / p99 "
        "| problem / linearise / backward / line search ms (median) "
        "| feedback ms median | ratio to first, wall: median (IQR) | CPU |",
        "|---|---|---|---|---|---|---|",
    ]
    for entry in result["variants"]:
        parts = entry["parts_ms_median"]
        texts = []
        for key in ("ratio_to_first", "cpu_ratio_to_first"):
            ratio = entry.get(key)
            texts.append(f"{ratio['median']:.3f} ({ratio['q25']:.3f}-{ratio['q75']:.3f})" if ratio else "-")
        ratio_text = " | ".join(texts)
        lines.append(
            f"| {entry['name']} {' '.join(entry['overrides'])} "
            f"| {entry['prepare_ms']['median']:.2f} / {entry['prepare_ms']['p99']:.2f} "
            f"| {entry['prepare_cpu_ms']['median']:.2f} / {entry['prepare_cpu_ms']['p99']:.2f} "
            f"| {' / '.join(f'{parts[p]:.2f}' for p in PARTS)} "
            f"| {entry['feedback_ms']['median']:.3f} | {ratio_text} |"
        )
    collections = result["collections_inside_updates"]
    lines += ["", f"garbage collections inside updates (all variants): {collections}"]
    for entry in result["variants"]:
        if "update_allocation_peak_kb_median" in entry:
            lines.append(
                f"allocation peak per update (preparation + feedback), median (tracemalloc, separate "
                f"pass), {entry['name']}: {entry['update_allocation_peak_kb_median']:.0f} kB"
            )
    for name, profile in result.get("profiles", {}).items():
        lines += ["", f"pyinstrument, preparations of {name}:", "```", profile, "```"]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--preset", default="trot")
    parser.add_argument("--duration", type=float, default=4.0, help="simulated seconds recorded")
    parser.add_argument("--rounds", type=int, default=1, help="replays of the whole sequence")
    parser.add_argument("--set", action="append", help="override for the recording and every variant")
    parser.add_argument("--baseline", help="another commit's package directory (make_baseline.sh)")
    parser.add_argument("--variant", action="append", help="NAME[@PACKAGE_DIR]:override,override")
    parser.add_argument("--gc", choices=["default", "freeze", "collect-between"], default="default")
    parser.add_argument("--profile", action="store_true", help="pyinstrument, each variant's preparations")
    parser.add_argument(
        "--allocations", action="store_true", help="a further pass: tracemalloc peak of each update"
    )
    parser.add_argument("--json", action="store_true")
    arguments = parser.parse_args()
    result = run(arguments)
    print(json.dumps(result, indent=1) if arguments.json else format_report(result))


if __name__ == "__main__":
    main()
