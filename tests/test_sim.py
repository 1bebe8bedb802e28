"""The MuJoCo plant and the closed loop under the PD standing controller."""

import numpy as np
import pytest

from cafe_mpc.config import PDSettings
from cafe_mpc.low_level.pd import PDController
from cafe_mpc.robots.robot import load_robot
from cafe_mpc_lab.sim.loop import ControllerError, Push, SimulationOptions, simulate
from cafe_mpc_lab.sim.mujoco_plant import MujocoPlant
from cafe_mpc_lab.sim.plant import SimulationDiverged


def test_state_round_trip_in_planning_coordinates(robot):
    plant = MujocoPlant(robot)
    rng = np.random.default_rng(0)
    q = robot.q_standing.copy()
    quaternion = rng.normal(size=4)
    q[3:7] = quaternion / np.linalg.norm(quaternion)
    v = rng.normal(size=robot.nv)
    plant.reset(q, v)
    state = plant.read_state()
    sign = np.sign(state.q[6]) * np.sign(q[6])
    assert state.q[:3] == pytest.approx(q[:3])
    assert sign * state.q[3:7] == pytest.approx(q[3:7])
    assert state.v == pytest.approx(v)


def test_plant_stands_under_pd_for_three_seconds(robot):
    log = simulate(MujocoPlant(robot), PDController(robot), SimulationOptions(3.0))
    assert not log.fell
    assert log.ticks == 1500
    assert np.all(log.q[:, 2] > 0.22)
    assert abs(log.q[-1, 2] - robot.standing_height) < 0.02
    assert np.all(log.contacts[-10:])
    # the feet carry the weight
    assert log.foot_forces[-1, :, 2].sum() == pytest.approx(robot.total_mass * 9.81, rel=0.02)


def test_push_moves_the_base(robot):
    quiet = simulate(MujocoPlant(robot), PDController(robot), SimulationOptions(1.0))
    pushes = (Push(0.2, 0.1, (0.0, 40.0, 0.0)),)
    pushed = simulate(MujocoPlant(robot), PDController(robot), SimulationOptions(1.0, pushes=pushes))
    assert np.abs(quiet.v[:, 1]).max() < 0.05
    assert pushed.v[:, 1].max() > 0.2  # base frame y velocity during the push
    assert np.any(np.abs(pushed.external_force[:, 1] - 40.0) < 1e-12)
    assert not pushed.fell


def test_fall_is_detected(robot):
    weak = PDController(robot, PDSettings(kp=0.0, kd=0.0, gravity_feedforward=False))
    log = simulate(MujocoPlant(robot), weak, SimulationOptions(2.0))
    assert log.fell and log.fall_time is not None and log.fall_time < 2.0


def test_controller_nan_is_a_clear_error(robot):
    class Broken:
        def reset(self):
            pass

        def compute(self, t, state):
            return np.full(12, np.nan)

    with pytest.raises(ControllerError, match="invalid torques"):
        simulate(MujocoPlant(robot), Broken(), SimulationOptions(0.1))


def test_simulator_nan_is_detected(robot):
    plant = MujocoPlant(robot)
    plant.reset(robot.q_standing)
    plant.data.qvel[0] = np.nan
    with pytest.raises(SimulationDiverged, match="non-finite"):
        plant.step(np.zeros(12))


def test_bad_rates_are_rejected(robot):
    with pytest.raises(ValueError, match="duration"):
        SimulationOptions(0.0)
    with pytest.raises(ValueError, match="control rate"):
        SimulationOptions(0.1, control_rate_hz=0.0)
    with pytest.raises(ValueError, match="invalid push"):
        SimulationOptions(0.1, pushes=(Push(-0.1, 0.1, (1.0, 0.0, 0.0)),))
    with pytest.raises(ValueError, match="whole multiple"):
        simulate(MujocoPlant(robot), PDController(robot), SimulationOptions(0.1, control_rate_hz=300.0))


@pytest.mark.slow
def test_second_quadruped_from_config_stands():
    go1 = load_robot("go1")
    log = simulate(MujocoPlant(go1), PDController(go1), SimulationOptions(1.5))
    assert not log.fell
    assert abs(log.q[-1, 2] - go1.standing_height) < 0.03
