"""Torque commands for motors of a calibrated strength: the joint torque a low level wants, divided by what
each motor delivers per commanded torque.

A motor of strength ``s`` (``calibration.motor_strength_scales``) delivers ``s x`` its command, up to ``s x``
its limit. The controller's robot (``robots.calibration``) already limits every planned and commanded joint
torque to ``s x`` the limit; ``MotorStrengthCompensation`` wraps a low level so that it sends ``tau / s``,
which the motor turns back into ``tau``. ``last_request`` stays the joint torque the inner low level asked
for (before its clamping), in the units of the run's torque limits.

``OnlineSupportCompensation`` does the same with the strength times the support ratio the controller
estimates while it runs (``estimation.support_ratio``: motor strength over mass factor beyond the
calibration, ``calibration.online``): it sends ``tau / (strength r)``, within the motors' command limits,
and tells the estimator what it sent.
"""

from __future__ import annotations

from typing import Generic

import numpy as np

from cafe_mpc.core.controller import LowLevelController
from cafe_mpc.core.measurement import Measurement
from cafe_mpc.core.plan import PlanT
from cafe_mpc.estimation.support_ratio import SupportRatioEstimator


class MotorStrengthCompensation(LowLevelController[PlanT], Generic[PlanT]):
    """``inner``'s torques divided by each motor's ``strength`` (positive, one per joint) (module
    docstring); ``reset`` and ``statistics`` are the inner controller's. Without a plan it is a closed-loop
    controller by itself, as a PD or balance stance that runs alone is."""

    def __init__(self, inner: LowLevelController[PlanT], strength: np.ndarray) -> None:
        strength = np.array(strength, dtype=float)
        if strength.ndim != 1 or not np.all(np.isfinite(strength)) or np.any(strength <= 0.0):
            raise ValueError(f"motor strengths must be positive numbers, one per joint, got {strength}")
        self.inner = inner
        self.strength = strength
        self._commands = np.zeros_like(strength)

    @property
    def last_request(self) -> np.ndarray:  # type: ignore[override]
        return self.inner.last_request

    def reset(self) -> None:
        self.inner.reset()
        self._commands[:] = 0.0

    def compute(self, t: float, measurement: Measurement, plan: PlanT | None = None) -> np.ndarray:
        torques = self.inner.compute(t, measurement, plan)
        np.divide(torques, self.strength, out=self._commands)
        return self._commands

    def statistics(self) -> dict:
        return self.inner.statistics()


class OnlineSupportCompensation(LowLevelController[PlanT], Generic[PlanT]):
    """``inner``'s torques divided by ``strength`` (the calibrated motor strengths) times ``estimator.ratio``
    (the support ratio estimated online) and clipped to ``command_limits`` (the motors' own: what a command
    can ask of them); the estimator observes every tick's measurement and the torques sent. ``reset``
    resets both; ``statistics`` are the inner controller's with the estimator's as ``support_ratio``."""

    def __init__(
        self,
        inner: LowLevelController[PlanT],
        strength: np.ndarray,
        estimator: SupportRatioEstimator,
        command_limits: np.ndarray,
    ) -> None:
        strength = np.array(strength, dtype=float)
        limits = np.array(command_limits, dtype=float)
        if strength.ndim != 1 or not np.all(np.isfinite(strength)) or np.any(strength <= 0.0):
            raise ValueError(f"motor strengths must be positive numbers, one per joint, got {strength}")
        if limits.shape != strength.shape or not np.all(np.isfinite(limits)) or np.any(limits <= 0.0):
            raise ValueError(f"command limits must be positive numbers, one per joint, got {limits}")
        self.inner = inner
        self.strength = strength
        self.estimator = estimator
        self.command_limits = limits
        self._commands = np.zeros_like(strength)
        self._delivered = np.zeros_like(strength)
        self._gain = np.zeros_like(strength)

    @property
    def last_request(self) -> np.ndarray:  # type: ignore[override]
        return self.inner.last_request

    def reset(self) -> None:
        self.inner.reset()
        self.estimator.reset()
        self._commands[:] = 0.0

    def compute(self, t: float, measurement: Measurement, plan: PlanT | None = None) -> np.ndarray:
        self.estimator.observe(t, measurement)
        torques = self.inner.compute(t, measurement, plan)
        np.multiply(self.strength, self.estimator.ratio, out=self._gain)
        np.divide(torques, self._gain, out=self._commands)
        np.clip(self._commands, -self.command_limits, self.command_limits, out=self._commands)
        np.multiply(self._commands, self.strength, out=self._delivered)  # what the model's motors deliver
        self.estimator.command(self._delivered)
        return self._commands

    def statistics(self) -> dict:
        return {**self.inner.statistics(), "support_ratio": self.estimator.statistics()}


def with_motor_strength(
    low_level: LowLevelController[PlanT], strength: np.ndarray
) -> LowLevelController[PlanT]:
    """``low_level`` sending commands for motors of ``strength`` (``MotorStrengthCompensation``), or
    ``low_level`` itself when every strength is 1."""
    if np.all(np.asarray(strength) == 1.0):
        return low_level
    return MotorStrengthCompensation(low_level, strength)
