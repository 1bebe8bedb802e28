"""Settings of the kinematic Kalman filter (``estimation.estimator``; the run config's ``kinematic_kf``).

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
0.014 m/s.
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from cafe_mpc.config.loading import StrictModel


class KinematicKFSettings(StrictModel):
    """Tuning of the kinematic Kalman filter (variances as MIT scales them; see ``estimation.estimator``).

    Process noise per step of ``dt`` seconds: base position ``dt / 20 * imu_process_noise_position``, base
    velocity ``dt * 9.8 / 20 * imu_process_noise_velocity``, each foot ``dt * foot_process_noise_position``,
    the accelerometer bias (if estimated) ``dt * bias_process_noise``. Measurement noise per foot in stance:
    relative position ``foot_sensor_noise_position``, base velocity from the leg
    ``foot_sensor_noise_velocity`` (times ``vertical_velocity_factor`` on the vertical axis), foot height
    ``foot_height_sensor_noise``; the last two (and the foot's process noise) are multiplied by ``1 + (1 -
    trust) * suspect_factor`` while a foot's trust ramps from 0 to 1 over the first ``trust_window`` of its
    planned stance and back to 0 over the last.
    """

    imu_process_noise_position: float = Field(
        0.02, gt=0.0, le=100.0, description="base position process noise (x dt / 20; MIT's value)"
    )
    imu_process_noise_velocity: float = Field(
        0.02, gt=0.0, le=100.0, description="base velocity process noise (x dt 9.8 / 20; MIT's value)"
    )
    foot_process_noise_position: float = Field(
        0.002, gt=0.0, le=100.0, description="foot position process noise (x dt; MIT's value)"
    )
    foot_sensor_noise_position: float = Field(
        0.001, gt=0.0, le=100.0, description="stance foot position relative to the base (MIT's value)"
    )
    foot_sensor_noise_velocity: float = Field(0.3, gt=0.0, le=100.0, description="MIT: 0.1")
    vertical_velocity_factor: float = Field(
        10.0,
        gt=0.0,
        le=1e6,
        description="x foot_sensor_noise_velocity, vertical axis (MIT: 1, the same on all axes)",
    )
    """A compliant foot or floor moves a loaded foot vertically (it sinks at touchdown and rises back), so the
    leg's vertical velocity is its least reliable; the foot height still measures the base height."""
    foot_height_sensor_noise: float = Field(
        0.001, gt=0.0, le=100.0, description="stance foot height on flat ground (MIT's value)"
    )
    trust_window: float = Field(
        0.4,
        gt=0.0,
        le=0.5,
        description="fraction of a planned stance at its start and its end over which the foot's trust ramps "
        "(MIT: 0.2)",
    )
    suspect_factor: float = Field(
        100.0, ge=0.0, le=1e6, description="MIT's high suspect number: noise x (1 + (1 - trust) x this)"
    )
    accelerometer_bias: bool | Literal["flat"] = Field(
        True,
        description="estimate a world-frame accelerometer bias: true | false | flat (on flat ground only, "
        "terrain: flat; off it the blind bound went down a 15 deg slope without the state: docs/terrain.md)",
    )
    """3 more states, a random walk (MIT's filter has none): it absorbs the IMU's bias and the acceleration
    error of a tilted attitude estimate (g x tilt), so the legs' velocity can be trusted less without the
    estimate drifting."""
    bias_process_noise: float = Field(
        0.01, gt=0.0, le=100.0, description="(m/s^2)^2 / s: random-walk intensity of the estimated bias"
    )
    initial_bias_variance: float = Field(
        0.04, gt=0.0, le=100.0, description="(m/s^2)^2 when the filter starts (0.2 m/s^2 standard deviation)"
    )
    rolling_foot: bool = Field(True, description="correct the leg velocity for a rolling sphere foot")
    """The contact point, not the sphere's centre, is at rest (MIT's feet are points; the plant's are
    spheres)."""
    foot_height: bool = Field(True, description="stance feet on flat ground measure the height")
    """Flat ground assumed, as MIT's filter does. Off: the base height is not observable (it drifts)."""
    stance_height: Literal["ground", "touchdown", "plan"] = Field(
        "ground",
        description="ground: a stance foot's height is measured at the ground's, z = 0 (MIT's; off "
        "flat ground the frame follows the level the feet stand on); touchdown (terrain: blind or "
        "height_map): at the height its foot state settled at after touching down (the base height is "
        "odometry); plan: at the height the plan in effect puts it (its configuration at the current "
        "knot: a box top in a stored trajectory)",
    )
    """With ``ground`` the estimated base height jumps by a step's rise within a few ticks of a stance on a
    new level, and feet standing on two levels are all measured at z = 0 (inconsistent). With ``touchdown``
    a foot at rest stays where it landed: feet on two levels keep their heights, and the base height is
    dead reckoning between the feet's levels: it drifted down by 1.5-5 cm/s on flat ground in the bound
    and the trot (docs/terrain-notes.md). With ``plan`` the feet stand where the plan says (within
    ``PLANNED_LEVEL_DEADBAND`` of z = 0: on it): a robot that jumped onto a box keeps its legs in the filter
    (with ``ground`` on flat terrain, feet planned on a 0.30 m top count as not in contact and the filter
    drifts on the IMU)."""
    foot_compliance: float = Field(
        9.3e-5, ge=0.0, le=0.01, description="m/N, a loaded foot at rest sinks this much per N (0: off)"
    )
    """How far a loaded foot's frame sinks below its unloaded height, per newton of the ground force its
    joint torques imply (``-J^-T tau``), once settled; the foot-height measurement subtracts the sink
    (``foot_contact_frequency``: how it gets there). Calibrated on this simulator's plant: MuJoCo's soft
    contact (``solref`` 0.02 s / 1, ``solimp`` 0.9-0.95) holds a foot at ``(1 - d) / d^2 x invweight / k`` =
    0.05 / 0.95^2 x 4.67 kg^-1 / 2770 s^-2 = 9.3e-5 m/N (``d`` = 0.95 its impedance, ``k`` = 1 / (0.95 x
    0.02)^2 its stiffness, ``invweight`` the foot body's ``body_invweight0``); a rubber foot compresses too.
    MIT's filter: 0. Needs joint torques."""
    foot_contact_frequency: float | None = Field(
        51.3,
        gt=0.0,
        le=1e4,
        description="rad/s; null: a foot's sink follows its load at once; else a spring-damper of "
        "this natural frequency driven by the load, starting at touchdown with the speed the foot hits the "
        "floor with",
    )
    """A foot that lands at 2.5 m/s (the bound's hind feet) sinks 20 mm under a 100 N load before it settles
    at 8 mm while still loaded: a static compliance read that stance's height 6 mm high and the front feet's
    (landing at 0.7 m/s, loaded as they push off) 3 mm low, and the bound rode 1 cm higher than with the
    true state. MuJoCo's contact is this spring exactly: ``r'' = -b r' - k d r - R f`` with ``k d`` = 1 /
    (0.95 x 0.02^2) = 2632 s^-2 (51.3 rad/s) and ``b`` = 2 / (0.95 x 0.02) = 105 s^-1
    (``foot_contact_damping`` 1.03). The foot's sink speed also corrects the legs' vertical velocity
    measurement (the foot is not at rest while it sinks or rises back)."""
    foot_contact_damping: float = Field(
        1.03, gt=0.0, le=100.0, description="damping ratio of the foot's sink (foot_contact_frequency)"
    )
    contact_force_threshold: float | None = Field(
        None,
        ge=0.0,
        le=1000.0,
        description="N; null: planned contact only (MIT's choice); else planned and the ground force its "
        "joint torques imply (-J^-T tau, legs massless) pushing up harder than this",
    )
    slip_threshold: float | None = Field(
        0.2,
        gt=0.0,
        le=100.0,
        description="m/s; null: off (MIT's filter has no slip test); else a trusted foot whose leg velocity "
        "differs horizontally from the IMU-propagated estimate by more than this is left out for the tick "
        "(a slipping foot, a foot leaving the ground early)",
    )
    slip_patience: float = Field(
        0.2,
        gt=0.0,
        le=10.0,
        description="s; all trusted feet failing the slip test this long: used again (the estimate may be "
        "the one that is off)",
    )
    contact_height_threshold: float | None = Field(
        0.03,
        gt=0.0,
        le=1.0,
        description="m; null: off (MIT's choice); else a foot planned in stance higher than this above the "
        "(flat) ground counts as not in contact (a late or missed touchdown); only with terrain: flat",
    )
    imu_outage: Literal["dynamics", "hold"] = Field(
        "dynamics",
        description="while the IMU is out: dynamics, the base's attitude and rates from the robot's model, "
        "joint torques and the feet on the ground (estimation.imu_outage); hold, its last sample",
    )
    """A held gyro is the worst guess for a robot in motion: a bound reverses its pitch rate at every stance,
    and 0.1 s after its IMU went out the held rate was 8 rad/s off (docs/estimation.md)."""
    initial_position_variance: float = Field(
        1e-4, gt=0.0, le=100.0, description="m^2, base and foot positions when the filter starts"
    )
    initial_velocity_variance: float = Field(
        1e-2, gt=0.0, le=100.0, description="(m/s)^2, base velocity when the filter starts (from rest)"
    )
    swing_foot_variance: float = Field(
        1.0,
        gt=0.0,
        le=1e6,
        description="m^2 of a foot not used (swing, flight): re-anchored at its kinematic position with this "
        "variance and no correlation, so it carries no information into the base state",
    )

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
            foot_contact_frequency=None,
        )
