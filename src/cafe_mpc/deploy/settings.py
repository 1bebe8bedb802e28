"""The settings of a deployment on a robot (``cafe-mpc deploy``): start-up checks, motions, safety limits.

Robot-specific values (the pose the robot lies in, the motor gains of the stance) are the robot file's
``hardware`` section (``robots.hardware``); the controller's are the run config's. These are the rest: how
long each motion takes, what the start-up checks accept and the limits every command is held to.
"""

from __future__ import annotations

from pydantic import Field

from cafe_mpc.config import StrictModel


class DeploySettings(StrictModel):
    """How a deployment starts, runs and stops (``deploy.runner.Deployment``; docs/deploy.md)."""

    duration: float | None = Field(
        None,
        ge=0.0,
        description="s of MPC control; null: the run config's simulation.duration; 0: until Ctrl-C",
    )
    state_timeout: float = Field(5.0, gt=0.0, description="s to wait for the robot's first state")
    min_link_rate_hz: float = Field(
        400.0, ge=0.0, description="Hz; the state rate measured over link_window before starting"
    )
    link_window: float = Field(0.5, gt=0.0, description="s over which the start-up check measures the link")
    max_start_tilt: float = Field(
        0.5, gt=0.0, le=3.2, description="rad; the trunk's tilt from upright (IMU) the start accepts"
    )
    joint_range_tolerance: float = Field(
        0.05, ge=0.0, description="rad a joint may read beyond its position limits at the start"
    )
    stand_duration: float = Field(3.0, gt=0.0, description="s to stand up from where the robot lies")
    hold_duration: float = Field(
        1.0,
        ge=0.0,
        description="s to hold the stance before starting the MPC (at least; its start takes longer)",
    )
    blend_duration: float = Field(
        0.1, ge=0.0, description="s over which the stance's motor PD hands over to the MPC's torques"
    )
    lie_duration: float = Field(3.0, gt=0.0, description="s to lie down at the end")
    damp_duration: float = Field(1.0, ge=0.0, description="s of motor damping after lying down")
    stale_after: float = Field(
        0.04, gt=0.0, description="s without a new state after which the link counts as lost (damped stance)"
    )
    resume_after: float = Field(
        1.0, ge=0.0, description="s of states flowing again after a link loss before the MPC restarts"
    )
    max_link_loss: float = Field(
        10.0, gt=0.0, description="s without a state after which the deployment gives up and lies down"
    )
    fall_tilt: float = Field(
        1.0, gt=0.0, description="rad of trunk tilt (IMU) that counts as a fall (motor damping, then stop)"
    )
    mpc_kd: float = Field(
        0.0,
        ge=0.0,
        description="Nm s/rad; damping the motors add around the measured joint rate during the MPC",
    )
    max_torque_rate: float = Field(
        5000.0, gt=0.0, description="Nm/s; the feed-forward torque's largest change (per tick: x the period)"
    )
    position_margin: float = Field(
        0.02, ge=0.0, description="rad; commanded joint angles stay this far inside the position limits"
    )
    max_kp: float = Field(150.0, ge=0.0, description="Nm/rad; the largest motor stiffness commanded")
    max_kd: float = Field(10.0, ge=0.0, description="Nm s/rad; the largest motor damping commanded")
    spin: float = Field(
        0.0005, ge=0.0, description="s; the loop sleeps until this long before a tick, then spins (lateness)"
    )
    sync_to_state: bool = Field(
        True,
        description="against a wall clock, start each tick when the robot's next state arrives (waiting "
        "up to half a period past the tick's time), so that the command answers the newest state at once: on "
        "`sim-robot`'s loopback the round trip is one period instead of up to two (docs/deploy.md)",
    )
    realtime_priority: int = Field(
        0,
        ge=0,
        le=99,
        description="the 500 Hz loop's thread in SCHED_FIFO at this priority once the checks pass, where the "
        "OS allows it (root or CAP_SYS_NICE; the report says what it got); 0: the normal class (the default: "
        "with `sim-robot` on the same 2-core machine it starved the simulator, docs/deploy.md)",
    )
    lock_memory: bool = Field(
        True,
        description="lock the deployment's memory (mlockall) once the checks pass: no page faults mid-run",
    )
