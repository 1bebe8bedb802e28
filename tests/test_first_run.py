"""No kernel is compiled, or even loaded from numba's cache, after a run's clock starts
(``core.compilation``): a first run's kernels compiled mid-run held the robot on the PD fallback while the
plan ran out."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from numba import njit

from cafe_mpc.core import kernels
from cafe_mpc.core.compilation import CompileWatch, kernel_versions

ROOT = Path(__file__).resolve().parent.parent


@pytest.mark.slow
def test_no_kernel_compiled_or_loaded_after_the_clock_starts(tmp_path):
    """A trot (the demo's preset: RTI updates, the state estimator) in a fresh process, whose kernels start
    unloaded: every kernel a tick or an update calls was loaded (or compiled) before the clock started."""
    out = tmp_path / "run"
    command = [
        sys.executable,
        "-m",
        "cafe_mpc_lab.cli",
        "run",
        "trot",
        "--set",
        "mpc.latency=fixed",
        "--set",
        "output.plots=false",
        "--duration",
        "1.0",
        "--quiet",
        "--out",
        str(out),
    ]
    environment = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    finished = subprocess.run(command, env=environment, capture_output=True, text=True, timeout=900)
    assert finished.returncode == 0, finished.stderr[-2000:]
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["compiled_during_run"] == []
    assert metrics["compiles_during_run"] == 0
    assert metrics["kernels_loaded_during_run"] == []
    assert metrics["mpc"]["pd_fallback_ticks"] == 0


def test_compile_command_runs_a_preset(capsys):
    from cafe_mpc_lab.cli import main

    assert main(["compile", "--presets", "stand", "--quiet"]) == 0
    assert "kernels compiled and cached in" in capsys.readouterr().out


def test_compile_watch_counts_a_compilation_and_a_new_version():
    @njit
    def doubled(x):
        return 2 * x

    with CompileWatch() as watch:
        doubled(1.0)
    assert watch.count == 1 and watch.compiled[0].endswith("doubled(float64)")
    assert watch.seconds > 0.0
    with CompileWatch() as again:
        doubled(2.0)  # compiled already
    assert again.count == 0 and again.summary()["compiles_during_run"] == 0
    assert "cafe_mpc.core.kernels.all_finite" in kernel_versions()
    with CompileWatch() as watch:  # a package kernel with new argument types: a new version
        kernels.all_finite(np.ones(2, dtype=np.int16))
    assert watch.loaded == ["cafe_mpc.core.kernels.all_finite"]
