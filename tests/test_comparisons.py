"""``cafe-mpc experiment``: the paper's experiments plan their runs, run them and write the comparison files.

Tiny durations (0.2 s), every run in this process (``scheduler="synchronous"``): these check the plumbing
(folders, files, variants, command line, errors), not the results; the full-length experiments are in
README.md / BENCHMARKS.md. The Dask side (clusters, incremental results, resume) is tests/test_sweep.py.
"""

from __future__ import annotations

import json

import pytest

from cafe_mpc.config import ConfigError
from cafe_mpc_lab.cli import main
from cafe_mpc_lab.experiments.catalog import experiment_names, get_experiment
from cafe_mpc_lab.experiments.comparison import COMPARISON_FILES
from cafe_mpc_lab.experiments.registry import ExperimentPlan, PlanContext
from cafe_mpc_lab.experiments.results_table import RESULTS_FILE, ResultsTable
from cafe_mpc_lab.experiments.sweep import run_experiment
from cafe_mpc_lab.experiments.warm_start import iteration_shares

RUN_FILES = ("config.yaml", "metrics.json", "log.npz", "run.log")
NO_PLOTS = ["output.plots=false"]  # per-variant plots cost more than the 0.2 s runs; one test keeps them
INLINE = "synchronous"


def check_layout(out, variants, plots: bool) -> dict:
    for name in (*COMPARISON_FILES, RESULTS_FILE):
        assert (out / name).is_file() and (out / name).stat().st_size > 0, name
    comparison = json.loads((out / "comparison.json").read_text())
    assert list(comparison["variants"]) == variants
    for variant in variants:
        for name in RUN_FILES:
            assert (out / variant / name).is_file(), (variant, name)
        assert (out / variant / "hip_knee_torques.png").is_file() == plots
        row = comparison["variants"][variant]
        assert row["error"] is None and row["fell"] is False and row["status"] == "ok"
        assert row["run_command"].startswith("cafe-mpc run ")
    table = (out / "comparison.md").read_text()
    assert comparison["command"] in table
    assert sum(line.startswith("| ") for line in table.splitlines()) == 1 + len(variants)
    rows = ResultsTable.load(out / RESULTS_FILE).rows
    assert [row["run"] for row in rows] == variants  # one row per run, in order here (one at a time)
    return comparison


@pytest.mark.slow
def test_schedules_experiment_writes_runs_and_comparison(tmp_path):
    out = tmp_path / "schedules"
    result = run_experiment(
        "schedules", out, duration=0.2, schedules="S0,S4", srb_dts="0.05", scheduler=INLINE
    )
    comparison = check_layout(out, ["S0-dt0.05", "S4-dt0.05"], plots=True)
    assert result.out_dir == out and not result.errors
    assert comparison["command"] == (
        "cafe-mpc experiment schedules --duration 0.2 --schedules S0,S4 --srb-dts 0.05"
    )
    s0, s4 = comparison["variants"]["S0-dt0.05"], comparison["variants"]["S4-dt0.05"]
    assert (s0["srb_horizon_s"], s4["srb_horizon_s"]) == (0.0, 0.4)
    assert s4["srb_dt"] == 0.05 and s4["schedule"] == "S4"
    for key in ("vx_mean", "vx_rms_error", "pitch_rms", "pitch_rate_rms", "height_rms_error"):
        assert isinstance(s4[key], float), key
    assert s4["iteration_ms_mean"] > 0 and s4["line_search_steps_per_update"] >= 1
    assert s4["timing_mode"] == "measured" and s4["mpc_solve_time_ms_median"] > 0
    assert "| S0 | 0.00 | 0.05 | no |" in (out / "comparison.md").read_text()
    assert (
        "per-worker" in (out / "comparison.md").read_text()
        or "worker process" in (out / "comparison.md").read_text()
    )
    assert (out / "traces.png").is_file()


def plan_of(name: str, context: PlanContext) -> ExperimentPlan:
    """The runs of experiment ``name`` with its default options."""
    experiment = get_experiment(name)
    return experiment.plan(experiment.options_from({}), context)


def test_the_paper_defaults_of_the_new_experiments():
    context = PlanContext()
    schedules = plan_of("schedules", context)
    assert len(schedules.variants) == 18  # Table I (9 schedules) x dts in {0.01, 0.05}
    assert schedules.variants[0].name == "S0-dt0.01" and schedules.variants[-1].name == "S20-dt0.05"
    solve = plan_of("solve-times", context)
    assert [v.name for v in solve.variants[:5]] == [f"pace-S{i}" for i in range(5)]
    assert {v.preset for v in solve.variants} == {"pace", "flying-trot", "pronk"}
    assert all("mpc.srb_dt=0.05" in v.overrides for v in solve.variants)
    trot = plan_of("trot-schedules", context)
    assert [v.name for v in trot.variants] == ["S0", "S1", "S2", "S3", "S4"]
    assert {v.preset for v in trot.variants} == {"trot"}


@pytest.mark.slow
def test_solve_times_and_trot_schedules_run(tmp_path):
    out = tmp_path / "solve"
    result = run_experiment(
        "solve-times",
        out,
        duration=0.2,
        overrides=NO_PLOTS,
        gaits="pronk",
        schedules="S0,S2",
        scheduler=INLINE,
    )
    assert not result.errors
    rows = result.comparison["variants"]
    assert rows["pronk-S2"]["paper_iteration_ms"] == pytest.approx(5.0574)
    assert rows["pronk-S2"]["iteration_ms_mean"] > 0
    table = (out / "comparison.md").read_text()
    assert "| Pronk | " in table and "/ 5.23 |" in table  # ours / paper for S0
    out = tmp_path / "trot"
    result = run_experiment("trot-schedules", out, duration=0.2, schedules="S0,S1", scheduler=INLINE)
    assert not result.errors
    row = result.comparison["variants"]["S1"]
    assert row["vx_desired"] == pytest.approx(0.5) and row["height_desired"] > 0.2
    assert row["height_mean"] == pytest.approx(row["height_desired"], abs=0.05)
    assert (out / "comparison.png").stat().st_size > 10_000  # Fig. 8 traces drawn from the run logs


@pytest.mark.slow
def test_push_experiment_from_the_command_line(tmp_path, capsys):
    out = tmp_path / "push"
    argv = ["experiment", "push", "--duration", "0.2", "--out", str(out), "--set", "pushes.0.start=0.1"]
    assert main([*argv, "--set", NO_PLOTS[0], "--scheduler", INLINE]) == 0
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


@pytest.mark.slow
def test_warm_start_experiment(tmp_path):
    plan = plan_of("warm-start", PlanContext())
    assert [v.name for v in plan.variants] == [
        f"{gait}-{mode}" for gait in ("bound", "pace") for mode in ("previous", "plan", "none")
    ]
    out = tmp_path / "warm"
    run_experiment(
        "warm-start",
        out,
        duration=0.2,
        overrides=NO_PLOTS,
        gaits="pace",
        warm_starts="previous,none",
        scheduler=INLINE,
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


def test_experiment_help_and_list_show_the_registry(capsys):
    names = [
        "schedules",
        "solve-times",
        "trot-schedules",
        "push",
        "warm-start",
        "reliability",
        "envelope",
        "template-vs-cafe",
        "template-gaits",
        "latency",
        "robots",
        "command-ranges",
        "terrain",
        "faults",
    ]
    assert experiment_names() == names
    with pytest.raises(SystemExit):
        main(["experiment", "--help"])
    out = capsys.readouterr().out
    for name in names:
        assert name in out
    assert main(["experiment", "--list"]) == 0
    listing = capsys.readouterr().out
    assert all(name in listing for name in names) and "--srb-dts" in listing and "--trials" in listing


def test_each_experiment_help_shows_its_own_options(capsys):
    """``cafe-mpc experiment NAME --help``: the sweep options and that experiment's, no other's."""
    with pytest.raises(SystemExit):
        main(["experiment", "push", "--help"])
    push = capsys.readouterr().out
    assert "--scheduler" in push and "--resume" in push
    assert "--schedules" not in push and "--trials" not in push and "--task" not in push
    with pytest.raises(SystemExit):
        main(["experiment", "reliability", "--help"])
    reliability = capsys.readouterr().out
    assert "--trials" in reliability and "--keep-logs" in reliability and "--schedules" not in reliability


def test_experiment_options_are_typed():
    """Options parse into the experiment's model: lists become tuples of values, flags booleans."""
    reliability = get_experiment("reliability").options_from(
        {"task": "bound", "seeds": "7,12", "keep_logs": True}
    )
    assert reliability.seeds == (7, 12) and reliability.keep_logs and reliability.trial_seeds == [7, 12]
    latency = get_experiment("latency").options_from({"task": "bound", "latencies": "none", "repeats": "3"})
    assert latency.latencies == () and latency.repeats == 3 and latency.periods[0] == pytest.approx(0.015)
    schedules = get_experiment("schedules").options_from({"srb_dts": [0.05]})
    assert schedules.srb_dts == (0.05,) and schedules.schedules[0] == "S0"


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (
            ["gallop"],
            "unknown experiment 'gallop'; experiments: schedules, solve-times, trot-schedules, push, "
            "warm-start, reliability",
        ),
        ([], "give an experiment (cafe-mpc experiment --list shows them)"),
        (["schedules", "--schedules", "S0,S7"], "--schedules: unknown value 'S7'"),
        (["schedules", "--srb-dts", "0.05,fast"], "--srb-dts: 'fast' is not a number"),
        (["push", "--schedules", "S0"], "--schedules does not apply to experiment 'push'"),
        (["push", "--trials", "3"], "--trials does not apply to experiment 'push'"),
        (["push", "--set", "wbc=pd"], "--set wbc: not allowed in experiment 'push'"),
        (["push", "--set", "simulation.realtime=true"], "--set simulation.realtime: not allowed"),
        (["schedules", "--set", "simulation.duration=3"], "use --duration"),
        (["warm-start", "--warm-starts", "hot"], "--warm-starts: unknown value 'hot'"),
        (
            ["warm-start", "--gaits", "gallop"],
            "--gaits: unknown value 'gallop'; known: bound, bound-push, bound-steps, flying-trot",
        ),
        (["schedules", "--duration", "-1"], "simulation.duration"),
        (["schedules", "--set", "gait.commands.0.vx=10"], "gait.commands.0"),
        (["reliability"], "--task PRESET is required"),
        (["reliability", "--task", "gallop"], "unknown preset 'gallop'"),
        (["reliability", "--task", "bound", "--trials", "0"], "--trials: 0 is outside [1, 1000000]"),
        (["reliability", "--task", "bound", "--seeds", "1", "--trials", "2"], "--seeds replaces --trials"),
        (["reliability", "--task", "bound", "--max-push", "-1"], "--max-push: -1 is outside [0, 5]"),
        (["reliability", "--task", "bound", "--set", "plant.seed=3"], "--set plant.seed: not allowed"),
        (["push", "--workers", "0"], "--workers must be at least 1"),
        (["push", "--scheduler", "localhost:8786"], "--scheduler: expected tcp://HOST:PORT"),
        (["push", "--resume"], "--resume needs --out"),
    ],
)
def test_bad_experiments_are_one_line_errors(tmp_path, capsys, argv, message):
    out = tmp_path / "out"
    with_out = [] if "--resume" in argv else ["--out", str(out)]
    assert main(["experiment", *argv, *with_out]) == 2
    error = capsys.readouterr().err.strip().splitlines()
    assert len(error) == 1 and error[0].startswith("cafe-mpc: error:"), error
    assert message in error[0]
    assert not out.exists()  # validated before anything is written


def test_experiment_refuses_a_used_folder(tmp_path):
    (tmp_path / "keep.txt").write_text("x")
    with pytest.raises(FileExistsError):
        run_experiment("push", tmp_path, duration=0.2, scheduler=INLINE)
    with pytest.raises(ConfigError, match="give at least one value"):
        run_experiment("schedules", tmp_path / "new", schedules="", scheduler=INLINE)


def test_a_variant_that_errors_is_recorded_and_the_others_still_run(tmp_path, capsys, monkeypatch):
    from cafe_mpc_lab.experiments import execution
    from cafe_mpc_lab.sim.plant import SimulationDiverged

    def diverging(config, out_dir, show_progress=False):
        raise SimulationDiverged("non-finite state at t = 0.1 s")

    monkeypatch.setattr(execution, "run", diverging)
    out = tmp_path / "push"
    assert main(["experiment", "push", "--duration", "0.2", "--out", str(out), "--scheduler", INLINE]) == 1
    captured = capsys.readouterr()
    assert captured.err.strip().splitlines() == [
        "cafe-mpc: error: runs ended in an error: vwbc, riccati (see comparison.json)"
    ]
    comparison = json.loads((out / "comparison.json").read_text())
    assert comparison["variants"]["vwbc"]["error"] == "SimulationDiverged: non-finite state at t = 0.1 s"
    assert comparison["variants"]["vwbc"]["status"] == "error"
    assert "error: SimulationDiverged" in (out / "comparison.md").read_text()
    assert (out / "comparison.png").is_file()
    assert not (out / "vwbc").exists()  # an errored run has a row, no folder


@pytest.mark.slow
def test_latency_experiment_sweeps_two_latencies_and_a_period(tmp_path):
    """``experiment latency``: one variant per fixed latency and per period (here two and one), each with its
    timing in the row and a success verdict; the command that reproduces it; a bad option is one error."""
    out = tmp_path / "latency"
    result = run_experiment(
        "latency",
        out,
        duration=0.3,
        task="trot",
        latencies="0.01,0.035",
        periods="0.025",
        scheduler=INLINE,
    )
    comparison = check_layout(out, ["latency-010.0ms", "latency-035.0ms", "period-025.0ms"], plots=False)
    assert not result.errors
    assert comparison["command"] == (
        "cafe-mpc experiment latency --duration 0.3 --task trot --latencies 0.01,0.035 --periods 0.025"
    )
    rows = comparison["variants"]
    assert rows["latency-035.0ms"]["latency_s"] == 0.035 and rows["latency-035.0ms"]["sweep"] == "latency"
    assert rows["latency-035.0ms"]["latency_ms_median"] == pytest.approx(36.0)  # the first tick after 35 ms
    assert rows["period-025.0ms"]["period_s"] == 0.025 and rows["period-025.0ms"]["latency_s"] == 0.01
    for row in rows.values():
        assert row["timing_mode"] == "fixed" and row["scheme"] == "rti"
        assert isinstance(row["success"], bool) and row["criterion"].startswith("up")
    with pytest.raises(ConfigError, match="--task PRESET is required"):
        run_experiment("latency", tmp_path / "none", duration=0.3, scheduler=INLINE)


def test_command_ranges_experiment_judges_each_command(tmp_path):
    """``experiment command-ranges``: one run per gait and command (speeds at yaw rate 0, yaw rates at the
    base speed), each judged; the tested-range table in the notes; the command that reproduces it."""
    out = tmp_path / "ranges"
    result = run_experiment(
        "command-ranges", out, duration=0.6, gaits="trot", speeds="0.5", yaw_rates="0.5", scheduler=INLINE
    )
    assert not result.errors
    comparison = json.loads((out / "comparison.json").read_text())
    assert comparison["command"] == (
        "cafe-mpc experiment command-ranges --duration 0.6 --gaits trot --speeds 0.5 --yaw-rates 0.5"
    )
    rows = comparison["variants"]
    assert set(rows) == {"trot-vx0.5-yaw0", "trot-vx0.5-yaw0.5"}
    for row in rows.values():
        assert row["timing_mode"] == "fixed" and isinstance(row["works"], bool) and not row["fell"]
    assert "forward speed that works" in (out / "comparison.md").read_text()
    with pytest.raises(ConfigError, match="--speeds"):
        run_experiment("command-ranges", tmp_path / "bad", speeds="4", scheduler=INLINE)


def test_command_ranges_judge_names_what_fails():
    """A run works only when it stays up, tracks the commanded speed and tracks the yaw rate; the tested
    range is the contiguous span of working commands from the base speed."""
    from cafe_mpc_lab.experiments.command_ranges import judge, tested_range

    def metrics(vx_mean: float, yaw_error: float, fell: bool = False) -> dict:
        return {"fell": fell, "steady_state": {"vx_mean": vx_mean, "yaw_rate_rms_error": yaw_error}}

    assert judge(1.0, 0.0, metrics(0.95, 0.05)).works
    assert not judge(1.0, 0.0, metrics(0.95, 0.05, fell=True)).works
    assert not judge(1.0, 0.0, metrics(0.6, 0.05)).works  # 0.4 m/s short: beyond 0.1 + 0.2 x 1.0
    assert not judge(0.5, 1.0, metrics(0.5, 0.5)).works  # yaw error beyond 0.1 + 0.3 x 1.0
    runs = []
    for vx, works in ((0.5, True), (1.0, True), (1.5, False), (2.0, True)):
        run = judge(vx, 0.0, metrics(vx if works else 0.0, 0.0))
        run.gait = "trot"
        runs.append(run)
    assert tested_range(runs, "trot")["vx"] == [0.5, 1.0]  # 2.0 worked, but not contiguously
