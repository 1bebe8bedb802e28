"""Config validation and the command line's promises (files written, one-line errors)."""

import json

import numpy as np
import pytest
import yaml

from cafe_mpc.assembly import load_run_config
from cafe_mpc.config import ConfigError
from cafe_mpc_lab.cli import main


def test_preset_loads_and_overrides_apply():
    config = load_run_config(
        "stand", ["simulation.duration=1.5", "pushes=[{start: 0.5, duration: 0.05, force: [10, 0, 0]}]"]
    )
    assert config.simulation.duration == 1.5
    assert config.pushes[0].force == (10.0, 0.0, 0.0)
    config = load_run_config("stand", ["pushes=[{start: 0.5, duration: 0.1, velocity_change: [1, 0, 0]}]"])
    assert config.pushes[0].force_on(8.0) == pytest.approx((80.0, 0.0, 0.0))


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        (["simulation.durtion=3"], "unknown config key 'simulation.durtion'"),
        (["nonsense=1"], "unknown config key 'nonsense'"),
        (["simulation.duration=-1"], "simulation.duration: Input should be greater than 0"),
        (["simulation.control_rate_hz=0"], "control_rate_hz"),
        (["simulation.control_rate_hz=300"], "whole multiple"),
        (["robot=atlas"], "unknown robot 'atlas'"),
        (["pushes=[{start: 1, duration: 0.1}]"], "exactly one of"),
        (["wbc=magic"], "wbc"),
        (["pd.kp"], "key=value"),
    ],
)
def test_bad_config_values_name_the_key(overrides, message):
    with pytest.raises(ConfigError, match=message.replace("(", r"\(")):
        load_run_config("stand", overrides)


def test_unknown_preset_and_missing_file():
    with pytest.raises(ConfigError, match="unknown preset 'trott'"):
        load_run_config("trott")
    with pytest.raises(ConfigError, match="does not exist"):
        load_run_config("missing.yaml")


@pytest.mark.slow
def test_cli_run_writes_what_it_promises(tmp_path, capsys):
    out = tmp_path / "stand"
    assert main(["run", "stand", "--duration", "0.5", "--out", str(out)]) == 0
    for name in (
        "config.yaml",
        "metrics.json",
        "log.npz",
        "run.log",
        "base_height.png",
        "orientation.png",
        "velocities.png",
        "joint_torques.png",
        "contact_forces.png",
    ):
        assert (out / name).is_file(), name
    metrics = json.loads((out / "metrics.json").read_text())
    for key in ("fell", "sim_time_s", "wall_time_s", "real_time_factor", "base_height_mean"):
        assert key in metrics
    assert metrics["fell"] is False
    assert metrics["sim_time_s"] == pytest.approx(0.5)
    written = yaml.safe_load((out / "config.yaml").read_text())
    assert written["simulation"]["duration"] == 0.5
    printed = capsys.readouterr().out.splitlines()
    assert printed[0].startswith(
        "stand: stayed up for the whole 0.50 s (simulated in "
    )  # the report's summary
    assert any(line.startswith("  Height: base 0.2") for line in printed)
    assert printed[-1] == f"results in {out}"


def test_cli_errors_are_one_line_and_leave_nothing(tmp_path, capsys):
    out = tmp_path / "bad"
    assert main(["run", "stand", "--duration", "-2", "--out", str(out)]) == 2
    error = capsys.readouterr().err.strip().splitlines()
    assert len(error) == 1 and error[0].startswith("cafe-mpc: error:")
    assert not out.exists()
    assert not any(tmp_path.iterdir())
    assert main(["run", "jump", "--out", str(out)]) == 2
    assert main(["robot", "no_such_robot"]) == 2


@pytest.mark.slow
def test_cli_robot_json(capsys):
    assert main(["robot", "mini_cheetah", "--json", "--samples", "2"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["total_mass"] == pytest.approx(8.252)
    assert summary["consistency"]["passed"] is True
    assert summary["foot_frames"] == ["FL_foot", "FR_foot", "HL_foot", "HR_foot"]
    assert summary["srb_mass"] == pytest.approx(8.912)  # 12 rotors of 0.055 kg added to the links
    inertia = summary["srb_inertia"]
    assert len(inertia) == 3 and all(len(row) == 3 for row in inertia) and inertia[1][1] > inertia[0][0] > 0
    assert main(["robot", "go1", "--json", "--samples", "1"]) == 0
    go1 = json.loads(capsys.readouterr().out)
    assert go1["srb_mass"] == pytest.approx(go1["total_mass"]) and go1["srb_inertia"] != inertia


@pytest.mark.slow
def test_an_mpc_run_logs_every_update(tmp_path):
    """log.npz keeps each MPC update's timing and solver record, not only the medians in metrics.json."""
    out = tmp_path / "trot"
    overrides = ["--set", "mpc.latency=fixed", "--set", "output.plots=false"]
    assert main(["run", "trot", "--duration", "0.3", "--out", str(out), *overrides]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    with np.load(out / "log.npz") as log:
        solves = metrics["mpc"]["solves"]
        for name in ("start_time", "update_ms", "problem_ms", "iterations", "line_search_steps", "status"):
            assert log[f"sampled_mpc_{name}"].shape == (solves,), name
        assert np.all(np.diff(log["sampled_mpc_start_time"]) > 0)
        assert np.all(log["sampled_mpc_iterations"] >= 1)
        assert log["sampled_mpc_prepare_ms"].shape == (solves - 1,)  # the first, cold solve has none
        assert np.all(log["sampled_mpc_prepare_ms"] > 0)
        cpu = log["sampled_mpc_prepare_cpu_ms"]  # one thread's CPU time: no more than its wall time
        assert cpu.shape == (solves - 1,) and np.all(cpu > 0)
        assert np.all(cpu <= log["sampled_mpc_prepare_ms"] + 0.05)
        assert np.median(log["sampled_mpc_prepare_ms"]) == pytest.approx(metrics["mpc"]["prepare_ms_median"])
        assert set(log["sampled_mpc_status"]) <= {"converged", "max_iterations", "time_budget"}
