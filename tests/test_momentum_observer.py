"""The contact detector's generalized-momentum observer (``force_estimate: momentum``) runs at the low level's
rate in preallocated buffers: its estimates are the textbook formulas' to the bit, and a tick creates no
array of its own beyond the copies Pinocchio's bindings return."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pinocchio as pin

from cafe_mpc.config import ContactDetectionSettings
from cafe_mpc.core.measurement import Measurement
from cafe_mpc.low_level.contact_detection import ContactDetector

TICK = 0.002


class TextbookObserver:
    """De Luca and Mattone's observer written the plain way, with new arrays at every step:
    ``r = K_O (M v - p(0) - integral(S' tau + C' v - g + r))``, each foot's force ``J_f,leg'^-1 r_leg``."""

    def __init__(self, robot, gain: float) -> None:
        self.robot, self.gain = robot, gain
        self.data = robot.model.createData()
        self.time = None

    def forces(self, t: float, q: np.ndarray, v: np.ndarray, torques: np.ndarray) -> np.ndarray:
        model, data, robot = self.robot.model, self.data, self.robot
        mass = pin.crba(model, data, q)
        mass = np.triu(mass) + np.triu(mass, 1).T
        momentum = mass @ v
        coriolis = pin.computeCoriolisMatrix(model, data, q, v)
        gravity = pin.computeGeneralizedGravity(model, data, q)
        generalized_torque = np.concatenate([np.zeros(model.nv - robot.nu), torques])
        if self.time is None:
            self.start, self.integral, self.residual = momentum, np.zeros(model.nv), np.zeros(model.nv)
        else:
            rate = generalized_torque + coriolis.T @ v - gravity + self.residual
            self.integral = self.integral + (t - self.time) * rate
            self.residual = self.gain * (momentum - self.start - self.integral)
        self.time = t
        pin.computeJointJacobians(model, data, q)
        pin.updateFramePlacements(model, data)
        forces = np.zeros((robot.n_feet, 3))
        for foot, frame_id in enumerate(robot.foot_frame_ids):
            columns = slice(model.nv - robot.nu + 3 * foot, model.nv - robot.nu + 3 * foot + 3)
            leg = pin.getFrameJacobian(model, data, frame_id, pin.LOCAL_WORLD_ALIGNED)[:3, columns]
            forces[foot] = np.linalg.solve(leg.T, self.residual[columns])
        return forces


def _states(robot, n: int, seed: int = 0):
    """``n`` ticks of a robot moving about its standing pose: states and applied torques, random but smooth
    enough that the legs stay bent (no singular Jacobian)."""
    rng = np.random.default_rng(seed)
    for tick in range(n):
        q = robot.q_standing.copy()
        q[:3] += 0.01 * rng.standard_normal(3)
        q[7:] += 0.1 * rng.standard_normal(robot.nu)
        v = rng.standard_normal(robot.nv)
        yield tick * TICK, q, v, 5.0 * rng.standard_normal(robot.nu)


def _detector(robot) -> ContactDetector:
    return ContactDetector(robot, ContactDetectionSettings(force_estimate="momentum"), ground_plane=True)


def test_the_observer_gives_the_textbook_estimates_to_the_bit(robot):
    detector, textbook = _detector(robot), TextbookObserver(robot, ContactDetectionSettings().momentum_gain)
    contacts = np.ones(robot.n_feet, dtype=bool)
    for t, q, v, torques in _states(robot, 400):
        measurement = Measurement(t, q, v, contacts, np.zeros((robot.n_feet, 3)))
        estimated = detector._observe_momentum(t, measurement, torques)
        np.testing.assert_array_equal(estimated, textbook.forces(t, q, v, torques))
    assert np.abs(estimated).max() > 1.0  # the sequence is no trivial one


def _peak_bytes(step, inputs) -> int:
    """The most memory one call of ``step`` held above what it started with (tracemalloc sees numpy's and
    Pinocchio's arrays), over ``inputs``."""
    peak = 0
    tracemalloc.start()
    try:
        for arguments in inputs:
            tracemalloc.reset_peak()
            before, _ = tracemalloc.get_traced_memory()
            step(*arguments)
            peak = max(peak, tracemalloc.get_traced_memory()[1] - before)
    finally:
        tracemalloc.stop()
    return peak


def test_a_tick_of_the_observer_holds_no_more_than_one_of_the_bindings_copies(robot):
    """Pinocchio's Python bindings return copies of ``data.M`` and ``data.C`` (``nv x nv``); the observer
    drops each at once and works in its own buffers, so a tick never holds more than one such copy and a few
    small arrays. The textbook observer holds several ``nv x nv`` arrays at once."""
    contacts = np.ones(robot.n_feet, dtype=bool)
    states = list(_states(robot, 20))
    detector = _detector(robot)

    def tick(t, q, v, torques):
        detector._observe_momentum(t, Measurement(t, q, v, contacts, None), torques)

    inputs = [(t, q, v, torques) for t, q, v, torques in states]
    tick(*inputs[0])  # the first update starts the integral
    one_copy = robot.nv * robot.nv * 8
    assert _peak_bytes(tick, inputs[1:]) < one_copy + 2048
    textbook = TextbookObserver(robot, ContactDetectionSettings().momentum_gain)
    textbook.forces(*inputs[0])
    assert _peak_bytes(textbook.forces, inputs[1:]) > 2 * one_copy
