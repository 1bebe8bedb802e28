"""Trajectory files (``reference/trajectory_file.py``): round trip, contact codes, one clear error per bad
file naming the file and the field, and the shipped barrel roll loads."""

from __future__ import annotations

import numpy as np
import pytest

from cafe_mpc.reference.trajectory_file import (
    FIELDS,
    TrajectoryFileError,
    WholeBodyTrajectory,
    contact_code,
    load_packaged_trajectory,
    load_trajectory,
    packaged_trajectory_path,
    parse_contact_code,
    save_trajectory,
)


def small_trajectory(robot) -> WholeBodyTrajectory:
    """Two phases (FS for 3 knots, FT for 2) of standing states: valid, not dynamically meaningful."""
    n = 5
    xs = np.tile(robot.x_standing, (n + 1, 1))
    contacts = np.array([[1, 1, 1, 1]] * 3 + [[0, 0, 0, 0]] * 2, dtype=np.uint8)
    forces = np.zeros((n, 4, 3))
    forces[:3, :, 2] = 20.0
    return WholeBodyTrajectory(
        name="test",
        robot=robot.name,
        dt=0.01,
        times=0.01 * np.arange(n + 1),
        xs=xs,
        us=np.zeros((n, robot.nu)),
        contacts=contacts,
        forces=forces,
        phase_contacts=("FS", "FT"),
        switching_times=np.array([0.0, 0.03, 0.05]),
        phase_names=("stand", "jump"),
    )


def write_raw(path, trajectory: WholeBodyTrajectory, **changes) -> None:
    """Write the fields of ``trajectory`` with some replaced (or removed with ``None``), unvalidated."""
    fields = {
        "format_version": np.array(1),
        "name": np.array(trajectory.name),
        "robot": np.array(trajectory.robot),
        "dt": np.array(trajectory.dt),
        "times": trajectory.times,
        "xs": trajectory.xs,
        "us": trajectory.us,
        "contacts": trajectory.contacts,
        "forces": trajectory.forces,
        "phase_contacts": np.array(trajectory.phase_contacts),
        "switching_times": trajectory.switching_times,
        "phase_names": np.array(trajectory.phase_names),
    }
    for key, value in changes.items():
        if value is None:
            del fields[key]
        else:
            fields[key] = value
    with open(path, "wb") as handle:
        np.savez(handle, **fields)


def test_contact_codes_round_trip():
    assert parse_contact_code("FS") == (True, True, True, True)
    assert parse_contact_code("FT") == (False, False, False, False)
    assert parse_contact_code("FR-HR") == (False, True, False, True)
    assert parse_contact_code("fl-hr") == (True, False, False, True)
    for flags in [(True, False, True, False), (False, True, False, True), (True,) * 4, (False,) * 4]:
        assert parse_contact_code(contact_code(flags)) == flags
    assert contact_code((True, True, True, True)) == "FS"
    for bad in ("XX", "FR-FR", "HR-FR", "", "FL+HR"):
        with pytest.raises(ValueError, match="contact code"):
            parse_contact_code(bad)


def test_round_trip(tmp_path, robot):
    trajectory = small_trajectory(robot)
    path = save_trajectory(tmp_path / "t.npz", trajectory, robot)
    loaded = load_trajectory(path, robot)
    for field in ("times", "xs", "us", "contacts", "forces", "switching_times"):
        np.testing.assert_array_equal(getattr(loaded, field), getattr(trajectory, field))
    assert loaded.phase_contacts == ("FS", "FT")
    assert loaded.phase_names == ("stand", "jump")
    assert loaded.dt == 0.01 and loaded.robot == robot.name and loaded.name == "test"
    assert [list(r) for r in loaded.phase_knots()] == [[0, 1, 2], [3, 4]]


def bad_cases(trajectory, robot):
    xs_nan = trajectory.xs.copy()
    xs_nan[2, 9] = np.nan
    times_back = trajectory.times.copy()
    times_back[3] = times_back[1]
    contacts_bad = trajectory.contacts.copy()
    contacts_bad[0, 0] = 2
    quaternion = trajectory.xs.copy()
    quaternion[1, 3:7] = [0.0, 0.0, 0.0, 2.0]
    forces_swing = trajectory.forces.copy()
    forces_swing[4, 0, 2] = 5.0
    return {
        "wrong xs dimensions": ("xs", {"xs": trajectory.xs[:, :-1]}),
        "wrong us dimensions": ("us", {"us": np.zeros((trajectory.n_knots, robot.nu + 1))}),
        "too few states": ("xs", {"xs": trajectory.xs[:-1]}),
        "non-monotone times": ("times", {"times": times_back}),
        "unknown contact code": ("phase_contacts", {"phase_contacts": np.array(["FS", "XY"])}),
        "NaN": ("xs", {"xs": xs_nan}),
        "NaN torque": ("us", {"us": np.full((trajectory.n_knots, robot.nu), np.nan)}),
        "contact flag not 0/1": ("contacts", {"contacts": contacts_bad}),
        "flags differ from phase": (
            "contacts",
            {"contacts": np.ones((trajectory.n_knots, 4), dtype=np.uint8)},
        ),
        "missing field": ("forces", {"forces": None}),
        "force on a swing foot": ("forces", {"forces": forces_swing}),
        "not a unit quaternion": ("xs", {"xs": quaternion}),
        "switching times off the grid": (
            "switching_times",
            {"switching_times": np.array([0.0, 0.025, 0.05])},
        ),
        "switching times do not cover": ("switching_times", {"switching_times": np.array([0.0, 0.03, 0.04])}),
        "negative dt": ("dt", {"dt": np.array(-0.01)}),
        "times off the dt grid": ("times", {"dt": np.array(0.02)}),
        "unknown robot": ("robot", {"robot": np.array("no_such_robot")}),
        "future version": ("format_version", {"format_version": np.array(7)}),
        "phase names": ("phase_names", {"phase_names": np.array(["only-one"])}),
        "strings where numbers belong": ("xs", {"xs": np.array(["a", "b"])}),
    }


@pytest.mark.parametrize(
    "case",
    [
        "wrong xs dimensions",
        "wrong us dimensions",
        "too few states",
        "non-monotone times",
        "unknown contact code",
        "NaN",
        "NaN torque",
        "contact flag not 0/1",
        "flags differ from phase",
        "missing field",
        "force on a swing foot",
        "not a unit quaternion",
        "switching times off the grid",
        "switching times do not cover",
        "negative dt",
        "times off the dt grid",
        "unknown robot",
        "future version",
        "phase names",
        "strings where numbers belong",
    ],
)
def test_bad_file_names_file_and_field(tmp_path, robot, case):
    trajectory = small_trajectory(robot)
    field, changes = bad_cases(trajectory, robot)[case]
    path = tmp_path / "bad.npz"
    write_raw(path, trajectory, **changes)
    with pytest.raises(TrajectoryFileError) as info:
        load_trajectory(path, None if field == "robot" else robot)
    error = info.value
    assert isinstance(error, ValueError)
    assert error.field == field
    assert str(path) in str(error) and repr(field) in str(error)


def test_unreadable_files(tmp_path, robot):
    with pytest.raises(TrajectoryFileError, match="does not exist"):
        load_trajectory(tmp_path / "missing.npz", robot)
    garbage = tmp_path / "garbage.npz"
    garbage.write_text("not a zip file")
    with pytest.raises(TrajectoryFileError, match=r"garbage\.npz"):
        load_trajectory(garbage, robot)


def test_robot_mismatch(tmp_path, robot):
    path = tmp_path / "t.npz"
    write_raw(path, small_trajectory(robot), robot=np.array("go1"))
    with pytest.raises(TrajectoryFileError, match=r"'robot'.*go1"):
        load_trajectory(path, robot)


def test_save_validates(tmp_path, robot):
    trajectory = small_trajectory(robot)
    trajectory.us = trajectory.us[:, :3]
    with pytest.raises(TrajectoryFileError, match="'us'"):
        save_trajectory(tmp_path / "t.npz", trajectory, robot)
    assert not (tmp_path / "t.npz").exists()


def test_packaged_barrel_roll_loads(robot):
    path = packaged_trajectory_path("barrel-roll")
    assert path.is_file() and path.with_suffix(".yaml").is_file()
    trajectory = load_packaged_trajectory("barrel-roll", robot)
    assert trajectory.phase_contacts == ("FS", "FR-HR", "FT", "FS", "FT", "FS")
    np.testing.assert_allclose(trajectory.switching_times, [0.0, 0.12, 0.33, 0.75, 0.90, 1.10, 1.25])
    assert trajectory.n_knots == 125 and trajectory.dt == 0.01
    assert set(FIELDS) <= set(np.load(path).files)
    with pytest.raises(ValueError, match="no packaged trajectory"):
        packaged_trajectory_path("no-such-task")
