"""The reference's share of an MPC update (``reference.update`` + ``reference.sample``), A/B against another
commit, with the samples compared field by field.

``bench_update.record`` runs the preset once (fixed latency) and keeps its MPC calls; one replay through this
tree's MPC logs what the MPC asks of its reference: ``update(t, q, v)`` and ``sample`` at the window's times
(with the rows that need joint references, ``ReferenceWindow.joint_rows``). That log is then replayed on
fresh references of each variant (this tree and a ``make_baseline.sh`` copy of another commit), **interleaved
call by call in one process**, the order alternating between rounds; each update's time is its
``update`` + ``sample``. The report gives the medians, the median and interquartile range of the per-update
ratios new/old, and the largest difference of every sampled field (joint angles and rates compared on the
rows that need them; a reference may leave the others at its nominal joints).

Usage::

    benchmarks/make_baseline.sh main      # -> /tmp/cafe_mpc_baseline/cafe_mpc_<commit>
    python benchmarks/bench_reference.py --preset running-barrel-roll --duration 5 \\
        --baseline /tmp/cafe_mpc_baseline/cafe_mpc_<commit> --rounds 5
"""

from __future__ import annotations

import argparse
import importlib
import inspect
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_update

FIELDS = ("stance", "state", "torque", "forces", "foot_positions", "foot_velocities", "weight_set")


def reference_log(preset: str, duration: float) -> list[tuple]:
    """The reference calls of one replay of the preset's recorded MPC calls (this tree)."""
    from cafe_mpc.reference.base import Reference

    calls = bench_update.record(preset, duration, [])
    variant = bench_update.Variant("this", "cafe_mpc", [])
    bench_update.build(variant, preset, duration, [])
    reference = variant.mpc.reference
    log: list[tuple] = []
    kind = type(reference)
    update, sample = kind.update, kind.sample

    def logged_update(self: Reference, t: float, q: np.ndarray, v: np.ndarray) -> None:
        if self is reference:
            log.append(("update", float(t), np.array(q), np.array(v)))
        update(self, t, q, v)

    def logged_sample(self: Reference, window) -> None:
        if self is reference:
            log.append(("sample", window.times.copy(), window.capacity, window.joint_rows))
        sample(self, window)

    kind.update, kind.sample = logged_update, logged_sample
    try:
        variant.mpc.reset()
        for call in calls:
            bench_update.replay_step(variant, call, record_times=False)
    finally:
        kind.update, kind.sample = update, sample
    return log


class Side:
    """One variant: a package's reference factory and windows."""

    def __init__(self, package: str, preset: str, duration: float) -> None:
        config = importlib.import_module(f"{package}.config").load_config(
            preset, [f"simulation.duration={duration}", "mpc.latency=fixed"]
        )
        self.robot = importlib.import_module(f"{package}.robots.robot").load_robot(config.robot)
        self.config = config
        self.package = package
        build_reference = importlib.import_module(f"{package}.assembly.references").build_reference
        try:  # the reference is built from the resolved run where the package resolves a config once
            resolve = importlib.import_module(f"{package}.assembly.resolve").resolve
            self.build_reference = lambda config, robot: build_reference(resolve(config, robot))
        except ModuleNotFoundError:
            self.build_reference = build_reference
        self.window_class = importlib.import_module(f"{package}.reference.base").ReferenceWindow
        self.takes_joint_rows = "joint_rows" in inspect.signature(self.window_class.set_times).parameters
        self.times_ms: list[float] = []
        self.reference = None
        self.windows: dict[int, object] = {}
        self.pending = 0.0

    def reset(self) -> None:
        self.reference = self.build_reference(self.config, self.robot)
        self.windows = {}
        self.pending = 0.0

    def run(self, entry: tuple):
        """Replay one logged call; the window after a ``sample``."""
        if entry[0] == "update":
            _, t, q, v = entry
            start = time.perf_counter()
            self.reference.update(t, q, v)
            self.pending = time.perf_counter() - start
            return None
        _, times, capacity, joint_rows = entry
        window = self.windows.get(capacity)
        if window is None:
            robot = self.robot
            window = self.window_class(capacity, robot.nq, robot.nv, robot.nu, robot.n_feet)
            self.windows[capacity] = window
        if self.takes_joint_rows:
            window.set_times(times, joint_rows)
        else:
            window.set_times(times)
        start = time.perf_counter()
        self.reference.sample(window)
        self.times_ms.append((self.pending + time.perf_counter() - start) * 1e3)
        self.pending = 0.0
        return window


def differences(old, new, joint_rows: int, nq: int, worst: dict[str, float]) -> None:
    """Largest absolute difference per field (joints only on the first ``joint_rows`` rows)."""
    for name in FIELDS:
        a, b = np.asarray(getattr(old, name), dtype=float), np.asarray(getattr(new, name), dtype=float)
        if name == "state":
            base = np.r_[0:7, nq : nq + 6]
            a = np.concatenate([a[:joint_rows].ravel(), a[joint_rows:, base].ravel()])
            b = np.concatenate([b[:joint_rows].ravel(), b[joint_rows:, base].ravel()])
        if a.size:
            worst[name] = max(worst[name], float(np.max(np.abs(a - b))))


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--preset", default="trot")
    parser.add_argument("--duration", type=float, default=3.0, help="simulated seconds recorded")
    parser.add_argument("--baseline", required=True, help="another commit's package directory")
    parser.add_argument("--rounds", type=int, default=3)
    arguments = parser.parse_args()
    log = reference_log(arguments.preset, arguments.duration)
    path = Path(arguments.baseline).resolve()
    sys.path.insert(0, str(path.parent))
    old = Side(path.name, arguments.preset, arguments.duration)
    new = Side("cafe_mpc", arguments.preset, arguments.duration)
    worst = dict.fromkeys(FIELDS, 0.0)
    for round_index in range(arguments.rounds):
        old.reset()
        new.reset()
        order = (old, new) if round_index % 2 == 0 else (new, old)
        for entry in log:
            windows = {id(side): side.run(entry) for side in order}
            if entry[0] == "sample":
                differences(windows[id(old)], windows[id(new)], entry[3], new.robot.nq, worst)
    old_ms, new_ms = np.asarray(old.times_ms), np.asarray(new.times_ms)
    ratios = new_ms / old_ms
    rounds = arguments.rounds
    print(f"{arguments.preset}: {len(old_ms)} updates ({len(old_ms) // rounds} x {rounds} rounds)")
    print(f"  update + sample, median ms: {path.name} {np.median(old_ms):.3f}, this {np.median(new_ms):.3f}")
    print(
        f"  ratio this / {path.name}: median {np.median(ratios):.3f} "
        f"(IQR {np.percentile(ratios, 25):.3f}-{np.percentile(ratios, 75):.3f})"
    )
    print("  largest difference per field: " + ", ".join(f"{k} {v:.1e}" for k, v in worst.items()))


if __name__ == "__main__":
    main()
