"""Config files a user writes: ``base:`` inheritance, names from the file, the resolved config printed by
``cafe-mpc config``, one-line YAML errors in ``--set`` and ``--version``."""

import pytest
import yaml

from cafe_mpc.config import ConfigError, load_config
from cafe_mpc_lab.cli import main


def test_base_inherits_a_preset_and_overrides_only_what_it_lists(tmp_path):
    path = tmp_path / "fast_trot.yaml"
    path.write_text("base: trot\ngait:\n  commands: [{vx: 0.8}]\nsimulation:\n  duration: 3\n")
    config = load_config(str(path))
    trot = load_config("trot")
    assert config.name == "fast_trot"  # named after its file, not labelled as the preset or the default
    assert config.wbc == trot.wbc == "vwbc"
    assert config.gait.start_stance == trot.gait.start_stance > 0.0  # the preset's clean start is kept
    assert [command.vx for command in config.gait.commands] == [0.8]  # lists are replaced whole
    assert config.simulation.duration == 3.0
    assert config.simulation.control_rate_hz == trot.simulation.control_rate_hz  # sections merge per key


def test_base_chains_through_files_and_rejects_cycles(tmp_path):
    (tmp_path / "a.yaml").write_text("base: trot\nname: my-a\nmpc: {period: 0.03}\n")
    (tmp_path / "b.yaml").write_text("base: a.yaml\ngait: {swing_height: 0.08}\n")
    config = load_config(str(tmp_path / "b.yaml"))
    assert (config.name, config.mpc.period, config.gait.swing_height) == ("b", 0.03, 0.08)
    (tmp_path / "c.yaml").write_text("base: d.yaml\n")
    (tmp_path / "d.yaml").write_text("base: c.yaml\n")
    with pytest.raises(ConfigError, match="cycle"):
        load_config(str(tmp_path / "c.yaml"))
    (tmp_path / "e.yaml").write_text("base: trott\n")
    with pytest.raises(ConfigError, match="unknown preset 'trott'"):
        load_config(str(tmp_path / "e.yaml"))


def test_a_file_without_name_is_named_after_the_file(tmp_path):
    path = tmp_path / "my_gait.yaml"
    path.write_text("wbc: vwbc\ngait: {name: trot}\n")
    assert load_config(str(path)).name == "my_gait"


def test_config_command_prints_the_resolved_yaml(capsys):
    assert main(["config", "trot", "--set", "gait.commands.0.vx=0.7"]) == 0
    printed = yaml.safe_load(capsys.readouterr().out)
    assert printed["name"] == "trot"
    assert printed["gait"]["commands"][0]["vx"] == 0.7
    assert printed["mpc"]["schedule"] == load_config("trot").mpc.schedule


def test_set_yaml_error_is_one_line(capsys):
    assert main(["config", "trot", "--set", "gait.commands=[{vx: 0.3"]) == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and error.startswith("cafe-mpc: error: --set gait.commands: cannot parse")


def test_version(capsys):
    with pytest.raises(SystemExit) as stop:
        main(["--version"])
    assert stop.value.code == 0
    assert capsys.readouterr().out.startswith("cafe-mpc ")


def test_a_weight_set_given_in_part_keeps_its_own_defaults(tmp_path):
    """A file that changes one weight of a set keeps the set's other weights, as ``--set`` does: the
    barrel-roll set's joint weight (2.5), not the regular set's (1.0) that ``WholeBodyWeights`` defaults to;
    the regular terminal set's, not the running set's."""
    path = tmp_path / "roll.yaml"
    path.write_text(
        yaml.safe_dump(
            {
                "base": "running-barrel-roll",
                "reference": {"costs": {"running": {"base_position": [0, 5, 15, 5, 5, 5]}}},
                "costs": {"terminal": {"torque": 0.5}},
            }
        )
    )
    config = load_config(str(path))
    from_set = load_config("running-barrel-roll", ["reference.costs.running.base_position=[0,5,15,5,5,5]"])
    assert config.reference.costs.running == from_set.reference.costs.running
    assert config.reference.costs.running.joint_position == 2.5
    assert config.reference.costs.terminal == load_config("running-barrel-roll").reference.costs.terminal
    assert config.costs.terminal.torque == 0.5 and config.costs.terminal.joint_position == 0.5
    with pytest.raises(ConfigError, match="joint_posture"):
        path.write_text(yaml.safe_dump({"base": "trot", "costs": {"running": {"joint_posture": 1.0}}}))
        load_config(str(path))


def test_a_slower_computer_gets_the_period_on_its_own_clock():
    """``mpc.compute_scale`` s emulates a computer s times slower: its update's cap (0.9 x period, or
    ``time_budget``) is simulated time, so this computer's solver gets cap / s of its wall time; a real-time
    run has no emulated computer and refuses the scale."""
    config = load_config("spin", ["mpc.compute_scale=1.5"])
    assert config.mpc.budget == pytest.approx(0.9 * config.mpc.period / 1.5)
    config = load_config("spin", ["mpc.compute_scale=2", "mpc.time_budget=0.016"])
    assert config.mpc.budget == pytest.approx(0.008)
    assert load_config("spin", ["mpc.latency=fixed", "mpc.compute_scale=2"]).mpc.budget is None
    with pytest.raises(ConfigError, match="compute_scale"):
        load_config("trot", ["simulation.realtime=true", "mpc.compute_scale=2"])
