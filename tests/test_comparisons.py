"""``cafe-mpc experiment``: the comparison experiments run their variants and write the comparison files.

Tiny durations (0.2 s): these check the plumbing (folders, files, variants, command line, errors), not the
results; the full-length experiments are in README.md / BENCHMARKS.md.
"""

from __future__ import annotations

import json

import pytest

from cafe_mpc.cli import main
from cafe_mpc.config import ConfigError
from cafe_mpc.experiments.comparisons import (
    COMPARISON_FILES,
    experiment_names,
    iteration_shares,
    plan_variants,
    run_experiment,
)

RUN_FILES = ("config.yaml", "metrics.json", "log.npz", "run.log")
NO_PLOTS = ["output.plots=false"]  # per-variant plots cost more than the 0.2 s runs; one test keeps them


def check_layout(out, variants, plots: bool) -> dict:
    for name in COMPARISON_FILES:
        assert (out / name).is_file() and (out / name).stat().st_size > 0, name
    comparison = json.loads((out / "comparison.json").read_text())
    assert list(comparison["variants"]) == variants
    for variant in variants:
        for name in RUN_FILES:
            assert (out / variant / name).is_file(), (variant, name)
        assert (out / variant / "hip_knee_torques.png").is_file() == plots
        row = comparison["variants"][variant]
        assert row["error"] is None and row["fell"] is False
        assert row["run_command"].startswith("cafe-mpc run ")
    table = (out / "comparison.md").read_text()
    assert comparison["command"] in table
    assert sum(line.startswith("| ") for line in table.splitlines()) == 1 + len(variants)
    return comparison


def test_schedules_experiment_writes_runs_and_comparison(tmp_path):
    out = tmp_path / "schedules"
    result = run_experiment("schedules", out, duration=0.2)
    comparison = check_layout(out, ["S0", "S4"], plots=True)
    assert result.out_dir == out and not result.errors
    assert comparison["command"] == "cafe-mpc experiment schedules --duration 0.2 --schedules S0,S4"
    s0, s4 = comparison["variants"]["S0"], comparison["variants"]["S4"]
    assert (s0["srb_horizon_s"], s4["srb_horizon_s"]) == (0.0, 0.4)
    for key in ("vx_mean", "vx_rms_error", "pitch_rms", "pitch_rate_rms", "height_rms_error"):
        assert isinstance(s4[key], float), key
    assert s4["mpc_solve_time_ms_median"] > 0
    assert "| S0 | 0.00 | no |" in (out / "comparison.md").read_text()


def test_push_experiment_from_the_command_line(tmp_path, capsys):
    out = tmp_path / "push"
    argv = ["experiment", "push", "--duration", "0.2", "--out", str(out), "--set", "pushes.0.start=0.1"]
    assert main([*argv, "--set", NO_PLOTS[0]]) == 0
    assert "results in" in capsys.readouterr().out
    comparison = check_layout(out, ["vwbc", "riccati"], plots=False)
    assert comparison["command"] == (
        "cafe-mpc experiment push --duration 0.2 --set pushes.0.start=0.1 --set output.plots=false"
    )
    vwbc, riccati = comparison["variants"]["vwbc"], comparison["variants"]["riccati"]
    assert vwbc["fallbacks"] is not None and riccati["fallbacks"] is None
    assert (vwbc["push_start_s"], vwbc["push_end_s"]) == pytest.approx((0.1, 0.15))
    assert vwbc["vx_push_peak"] > 0 and vwbc["vx_after_push_mean"] is None  # the run ends before 0.65 s
    for row in (vwbc, riccati):
        for key in ("torque_limit_violations", "friction_cone_violations", "foot_slip_max_m"):
            assert row[key] is not None, key
    assert vwbc["torque_limit_violations"] == 0


def test_warm_start_experiment(tmp_path):
    assert [v.name for v in plan_variants("warm-start")] == [
        f"{gait}-{mode}" for gait in ("bound", "pace") for mode in ("previous", "plan", "none")
    ]
    out = tmp_path / "warm"
    run_experiment(
        "warm-start", out, duration=0.2, overrides=NO_PLOTS, gaits="pace", warm_starts="previous,none"
    )
    comparison = check_layout(out, ["pace-previous", "pace-none"], plots=False)
    assert "--gaits pace --warm-starts previous,none" in comparison["command"]
    for mode in ("previous", "none"):
        row = comparison["variants"][f"pace-{mode}"]
        assert row["warm_start"] == mode and row["gait"] == "pace"
        assert row["qp_solves"] == sum(row["qp_iterations_histogram"].values()) > 0
        assert 0.0 <= row["one_iteration_share"] <= row["at_most_3_iterations_share"] <= 1.0
        assert row["qp_solve_time_ms_median"] > 0 and row["tick_time_ms_median"] > 0


def test_iteration_shares():
    shares = iteration_shares({"1": 6, "2": 2, "3": 1, "7": 1})
    assert shares == pytest.approx(
        {
            "qp_solves": 10,
            "one_iteration_share": 0.6,
            "at_most_3_iterations_share": 0.9,
            "iterations_mean": 2.0,
        }
    )
    assert iteration_shares(None)["one_iteration_share"] is None


def test_experiment_help_lists_the_experiments(capsys):
    for argv in (["--help"], ["experiment", "--help"]):
        with pytest.raises(SystemExit):
            main(argv)
        out = capsys.readouterr().out
        for name in experiment_names():
            assert name in out
    assert experiment_names() == ["schedules", "push", "warm-start"]


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["gallop"], "unknown experiment 'gallop'; experiments: schedules, push, warm-start"),
        (["schedules", "--schedules", "S0,S7"], "--schedules: unknown value 'S7'"),
        (["push", "--schedules", "S0"], "--schedules does not apply to experiment 'push'"),
        (["push", "--set", "wbc=pd"], "--set wbc: not allowed in experiment 'push'"),
        (["schedules", "--set", "simulation.duration=3"], "use --duration"),
        (["warm-start", "--warm-starts", "hot"], "--warm-starts: unknown value 'hot'"),
        (["warm-start", "--gaits", "gallop"], "--gaits: unknown value 'gallop'; known: bound, bound-push"),
        (["schedules", "--duration", "-1"], "simulation.duration"),
        (["schedules", "--set", "gait.commands.0.vx=10"], "gait.commands.0"),
    ],
)
def test_bad_experiments_are_one_line_errors(tmp_path, capsys, argv, message):
    out = tmp_path / "out"
    assert main(["experiment", *argv, "--out", str(out)]) == 2
    error = capsys.readouterr().err.strip().splitlines()
    assert len(error) == 1 and error[0].startswith("cafe-mpc: error:"), error
    assert message in error[0]
    assert not out.exists()  # validated before anything is written


def test_experiment_refuses_a_used_folder(tmp_path):
    (tmp_path / "keep.txt").write_text("x")
    with pytest.raises(FileExistsError):
        run_experiment("push", tmp_path, duration=0.2)
    with pytest.raises(ConfigError, match="give at least one value"):
        run_experiment("schedules", tmp_path / "new", schedules="")


def test_a_variant_that_errors_is_recorded_and_the_others_still_run(tmp_path, capsys, monkeypatch):
    from cafe_mpc.experiments import comparisons
    from cafe_mpc.sim.plant import SimulationDiverged

    def diverging(config, out_dir, show_progress=False):
        raise SimulationDiverged("non-finite state at t = 0.1 s")

    monkeypatch.setattr(comparisons, "run", diverging)
    out = tmp_path / "push"
    assert main(["experiment", "push", "--duration", "0.2", "--out", str(out)]) == 1
    captured = capsys.readouterr()
    assert captured.err.strip().splitlines() == [
        "cafe-mpc: error: variants ended in an error: vwbc, riccati (see comparison.json)"
    ]
    comparison = json.loads((out / "comparison.json").read_text())
    assert comparison["variants"]["vwbc"]["error"] == "SimulationDiverged: non-finite state at t = 0.1 s"
    assert "error: SimulationDiverged" in (out / "comparison.md").read_text()
    assert (out / "comparison.png").is_file()
