"""Settings of the kinematic Kalman filter (``estimation.estimator``); the one source of their defaults.

The filter is MIT's (Mini Cheetah, ``Cheetah-Software``); ``KinematicKFSettings.mit()`` is MIT's published
tuning exactly: the six noise values of ``config/mini-cheetah-defaults.yaml``, their scaling, the trust
window 0.2 and the "high suspect number" 100 of ``common/src/Controllers/PositionVelocityEstimator.cpp``.

The defaults differ from it in four values, each measured on this simulator (docs/estimation.md,
BENCHMARKS.md "State estimation"): the plant's feet sink into the (soft) floor at touchdown and rise back
while loaded, so a loaded foot is not at rest vertically and not at all during impacts and lift-off. With
MIT's tuning the base velocity error was 0.11 m/s RMS while bounding (fixed latency, 3 s); with the legs'
velocity trusted less (``foot_sensor_noise_velocity`` 0.3, ``vertical_velocity_factor`` 10), a wider trust
ramp (``trust_window`` 0.4) and a world-frame accelerometer bias in the state (``accelerometer_bias``: so that
relying more on the IMU does not let its bias or the tilt error of its attitude drift the velocity) it was
0.014 m/s. The config's ``kinematic_kf`` section takes its defaults from here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields


@dataclass(frozen=True)
class KinematicKFSettings:
    """Tuning of the kinematic Kalman filter (variances as MIT scales them; see ``estimator``).

    Process noise per step of ``dt`` seconds: base position ``dt / 20 * imu_process_noise_position``, base
    velocity ``dt * 9.8 / 20 * imu_process_noise_velocity``, each foot ``dt * foot_process_noise_position``,
    the accelerometer bias (if estimated) ``dt * bias_process_noise``. Measurement noise per foot in stance:
    relative position ``foot_sensor_noise_position``, base velocity from the leg
    ``foot_sensor_noise_velocity`` (times ``vertical_velocity_factor`` on the vertical axis), foot height
    ``foot_height_sensor_noise``; the last two (and the foot's process noise) are multiplied by ``1 + (1 -
    trust) * suspect_factor`` while a foot's trust ramps from 0 to 1 over the first ``trust_window`` of its
    planned stance and back to 0 over
    the last.
    """

    imu_process_noise_position: float = 0.02
    imu_process_noise_velocity: float = 0.02
    foot_process_noise_position: float = 0.002
    foot_sensor_noise_position: float = 0.001
    foot_sensor_noise_velocity: float = 0.3
    """MIT: 0.1."""
    vertical_velocity_factor: float = 10.0
    """Factor on ``foot_sensor_noise_velocity`` for the vertical component (MIT: 1, the same on all axes).
    A compliant foot or floor moves a loaded foot vertically (it sinks at touchdown and rises back), so the
    leg's vertical velocity is its least reliable; the foot height still measures the base height."""
    foot_height_sensor_noise: float = 0.001
    trust_window: float = 0.4
    """Fraction of a planned stance at its start and its end over which the foot's trust ramps (MIT: 0.2)."""
    suspect_factor: float = 100.0
    """MIT's "high suspect number": noise factor ``1 + (1 - trust) * suspect_factor``."""
    accelerometer_bias: bool = True
    """Estimate a world-frame accelerometer bias (3 more states, a random walk; MIT's filter has none): it
    absorbs the IMU's bias and the acceleration error of a tilted attitude estimate (g x tilt), so the legs'
    velocity can be trusted less without the estimate drifting."""
    bias_process_noise: float = 0.01
    """(m/s^2)^2 per s: random-walk intensity of the estimated bias (per step: ``dt`` times this)."""
    initial_bias_variance: float = 0.04
    """(m/s^2)^2: of the estimated bias when the filter starts (0.2 m/s^2 standard deviation)."""
    rolling_foot: bool = True
    """Correct the leg's velocity for a spherical foot rolling on the ground (the contact point, not the
    sphere's centre, is at rest; MIT's feet are points). The plant's feet are spheres."""
    foot_height: bool = True
    """Use the stance feet's height (on the ground, z = foot radius) as a measurement: flat ground assumed,
    as MIT's filter does. Off: the base height is not observable (it drifts)."""
    foot_compliance: float = 1.2e-4
    """m/N: how far a loaded foot's frame sinks below its unloaded height, per newton of the ground force
    its joint torques imply (``-J^-T tau``); the foot-height measurement subtracts it. Calibrated on this
    simulator's plant (MuJoCo's soft contact: 0.12-0.15 mm/N over trot and bound, median 4-7 mm; a rubber
    foot compresses too); MIT's filter: 0. Without it the base height read 5-8 mm high while bounding,
    enough to make the push test fall (docs/estimation.md). 0: off; needs joint torques."""
    contact_force_threshold: float | None = None
    """N; when set, a foot planned in stance counts as in contact only while the ground force estimated from
    its joint torques (``-J^-T tau``, legs massless) pushes up harder than this. None: planned contact only
    (MIT's choice)."""
    slip_threshold: float | None = 0.2
    """m/s; when set, a trusted foot whose leg velocity differs horizontally from the IMU-propagated estimate
    by more than this gives nothing for that tick (a slipping foot, a foot leaving the ground early). None:
    off (MIT's filter has no slip test)."""
    slip_patience: float = 0.2
    """s; when every trusted foot has failed the slip test this long, the estimate may be the one that is
    off: they are used again (the filter never runs on the IMU alone for long while feet are down)."""
    contact_height_threshold: float | None = 0.03
    """m; when set, a foot planned in stance whose height above the ground (the filter's base height plus the
    leg kinematics, flat ground) is above this counts as not in contact (a late or missed touchdown: its leg
    would drag the estimate along with the swinging foot). None: planned contact only (MIT's choice)."""
    initial_position_variance: float = 1e-4
    """m^2: of the base and foot positions when the filter starts (leg kinematics, robot standing)."""
    initial_velocity_variance: float = 1e-2
    """(m/s)^2: of the base velocity when the filter starts (from rest)."""
    swing_foot_variance: float = 1.0
    """m^2: of a foot's position while it is not used (swing, flight): it is re-anchored at its kinematic
    position with this variance and no correlation, so it carries no information into the base state."""

    @classmethod
    def mit(cls) -> KinematicKFSettings:
        """MIT's published tuning of the Mini Cheetah's filter (see the module docstring), everything else
        (rolling foot, foot height, no force gating) as the defaults."""
        return cls(
            foot_sensor_noise_velocity=0.1,
            vertical_velocity_factor=1.0,
            trust_window=0.2,
            accelerometer_bias=False,
            slip_threshold=None,
            contact_height_threshold=None,
            foot_compliance=0.0,
        )

    def check(self) -> None:
        """Raise ``ValueError`` naming the field when a value cannot be used."""
        for field in fields(self):
            value = getattr(self, field.name)
            if isinstance(value, bool) or value is None:
                continue
            if not math.isfinite(value):
                raise ValueError(f"kinematic_kf.{field.name} must be finite, got {value}")
            positive = field.name not in (
                "suspect_factor",
                "contact_force_threshold",
                "slip_threshold",
                "contact_height_threshold",
                "foot_compliance",
            )
            if (positive and value <= 0.0) or value < 0.0:
                raise ValueError(
                    f"kinematic_kf.{field.name} must be {'> 0' if positive else '>= 0'}, got {value}"
                )
        if not self.trust_window <= 0.5:
            raise ValueError(f"kinematic_kf.trust_window must be in (0, 0.5], got {self.trust_window}")
