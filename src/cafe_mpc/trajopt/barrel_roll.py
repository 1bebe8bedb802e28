"""The in-place barrel roll of the paper's Appendix (Sec. VI-B) as a ``TrajOptTask``.

Contact sequence ``{FS, FR-HR, FT, FS}`` plus a recovery hop ``{FT, FS}`` (paper Appendix), i.e.
all-stance -> right stance (FR, HR) -> flight -> all-stance -> flight (hop) -> all-stance, with the authors'
switching times {0, 0.12, 0.33, 0.75, 0.90, 1.10, 1.25} s, dt = 0.01 s (125 knots). Each phase tracks the
keyframe it ends on (paper Fig. 18), with the authors' per-phase weights; touchdowns at the ends of the
flight phases are augmented-Lagrangian constraints (Eq. (25)); |tau| <= 17 Nm, joint speed <= 20 rad/s,
friction mu = 0.6, joint limits and a minimum base height are relaxed-barrier constraints.

Sources (authors' public code ROAM-Lab-ND/CAFE-MPC, ``MHPC/MHPC-Trajopt/BarrelRoll``):

* switching times, contact sequence, initial state (z 0.2183 m, joints (0, -1, 2)) and the six keyframes:
  ``BarrelRollTO.cpp`` (``load_desired_final_states``); keyframes 4-6 keep the x, y of keyframe 3;
* weights per phase: ``setting/br_cost_weights.JSON`` (``qw_*`` running, ``qfw_*`` terminal, ``rw`` torque;
  joint weights per joint kind abad, hip, knee);
* barriers: ``setting/br_constraint_params.info``; joint speed limit +-20 rad/s and minimum height 0.13 m on
  every phase: ``BarrelRollConstraints.h``; solver: up to 10 inner x 30 AL iterations, thresholds 1e-2 (cost),
  1e-3 (dynamics, constraints).

Deviations (this project; each measured with ``cafe-mpc optimize barrel-roll``):

* **Heights + 0.02 m.** The authors' foot point is the contact point; ours is the centre of the 0.02 m foot
  sphere (``Robot.foot_radius``), so the same leg touches the floor with the base 0.02 m higher. Every base
  height (start, keyframes, minimum height) is the authors' + 0.02 m, which reproduces their motion relative
  to the floor (the start pose then has its feet on the floor).
* **Landing roll weight 100 instead of 5** (terminal weight of the flight phase). The authors track the
  keyframe roll in Euler angles, where a running cost toward roll 2 pi keeps pulling the body forward during
  the whole flight. Our orientation error is ``log3(R_ref' R)``, for which 2 pi is the identity, so the
  running references interpolate the roll between keyframes (``multiphase``) and exert no such pull. With the
  authors' 5 the optimum landed 0.22 rad short of 2 pi; 20: 0.12, 50: 0.04-0.06, 100: 0.025 rad short
  (torques within 17 Nm in every case).
* **Barrier continuation**: the first solve uses this package's softer MPC barriers, the second the authors'
  (see ``ConstraintSpec``); from the keyframe guess the authors' barriers alone stall the line search.

``running_barrel_roll_task``: the same roll with the phase durations of the authors' running barrel roll
(Fosbury flop, paper Sec. VII-C): 0.24 s right stance, 0.47 s flight, 0.15 s stance, 0.20 s hop, 0.21 s stance
(switching times {0, 0.12, 0.36, 0.83, 0.98, 1.18, 1.39} s; authors' running-roll reference). The longer
flight makes a higher jump (planned apex 0.60 m instead of 0.55 m), which the 0.4 m bar needs; the running
preset plays it from its right-stance phase (docs/settings.md, "Running barrel roll").
"""

from __future__ import annotations

import math

from cafe_mpc.config import DEFAULT_FRICTION
from cafe_mpc.trajopt.task import (
    ConstraintSpec,
    KeyframeSpec,
    PhaseSpec,
    SolverSpec,
    TrajOptTask,
    WeightsSpec,
)

PI = math.pi
FOOT_SPHERE_OFFSET = 0.02
"""Added to the authors' base heights (see the module docstring)."""

SWITCHING_TIMES = [0.0, 0.12, 0.33, 0.75, 0.90, 1.10, 1.25]
RUNNING_SWITCHING_TIMES = [0.0, 0.12, 0.36, 0.83, 0.98, 1.18, 1.39]
"""The authors' running barrel roll: right stance 0.24 s, flight 0.47, stance 0.15, hop 0.20, stance 0.21."""
LANDING_ROLL_WEIGHT = 100.0
"""Terminal roll weight of the flight phase (authors: 5; see the module docstring)."""


def _z(authors_height: float) -> float:
    return round(authors_height + FOOT_SPHERE_OFFSET, 6)


def _weights(
    base_position: list[float],
    base_velocity: list[float],
    joint_position: list[float],
    joint_velocity: list[float],
    torque: float = 0.0,
) -> WeightsSpec:
    return WeightsSpec(
        base_position=tuple(base_position),
        base_velocity=tuple(base_velocity),
        joint_position=joint_position,
        joint_velocity=joint_velocity,
        torque=torque,
    )


def barrel_roll_task() -> TrajOptTask:
    """The in-place barrel-roll TO task (values and sources in the module docstring)."""
    crouch = [0.0, -1.2, 2.4]
    landing = [0.3, -1.1, 2.2, -0.3, -1.1, 2.2, 0.3, -1.1, 2.2, -0.3, -1.1, 2.2]
    # Left legs (swinging up) and right legs (pushing): FL, FR, HL, HR.
    take_off = [PI / 6, -1.0, 2.0, -PI / 5, -0.5, 1.0, PI / 6, -1.0, 2.0, -PI / 5, -0.5, 1.0]
    stand = [0.0, -1.0, 2.0]
    landed = (0.0, -0.55, _z(0.25))
    minimum_height = _z(0.13)
    phases = [
        PhaseSpec(
            name="stance",
            contacts="FS",
            keyframe=KeyframeSpec(
                position=(0.0, -0.15, _z(0.26)),
                rpy=(PI / 6, 0.0, 0.0),
                linear_velocity=(0.0, -1.0, 2.0),
                rpy_rates=(3 * PI, 0.0, 0.0),
                joint_positions=crouch,
            ),
            running=_weights([0, 5, 10, 2, 2, 2], [1, 0.1, 1, 1, 1, 1], [0.01] * 3, [0.01] * 3, 0.2),
            terminal=_weights([0, 1, 10, 2, 2, 10], [1, 0.5, 5, 2, 2, 5], [0.05] * 3, [0.1] * 3),
            minimum_height=minimum_height,
        ),
        PhaseSpec(
            name="right-stance",
            contacts="FR-HR",
            keyframe=KeyframeSpec(
                position=(0.0, -0.25, _z(0.33)),
                rpy=(PI / 2, 0.0, 0.0),
                linear_velocity=(0.0, -1.2, 2.0),
                rpy_rates=(3 * PI, 0.0, 0.0),
                joint_positions=take_off,
            ),
            running=_weights([0, 1, 10, 2, 2, 10], [1] * 6, [0.1] * 3, [0.1] * 3, 0.05),
            terminal=_weights([0, 1, 10, 5, 5, 10], [1, 1, 5, 1, 1, 5], [0.1] * 3, [0.01] * 3),
            minimum_height=minimum_height,
        ),
        PhaseSpec(
            name="flight",
            contacts="FT",
            keyframe=KeyframeSpec(
                position=(0.0, -0.55, _z(0.22)),
                rpy=(2 * PI, 0.0, 0.0),
                linear_velocity=(0.0, -1.5, -2.5),
                rpy_rates=(3 * PI, 0.0, 0.0),
                joint_positions=landing,
            ),
            running=_weights([0, 1, 5, 2, 2, 2], [1] * 6, [1, 0.1, 0.1], [0.1] * 3, 0.5),
            terminal=_weights(
                [0, 1, 5, 5, 5, LANDING_ROLL_WEIGHT], [1, 1, 2, 1, 1, 1], [0.5, 0.1, 0.1], [0.01] * 3
            ),
            minimum_height=minimum_height,
        ),
        PhaseSpec(
            name="landing",
            contacts="FS",
            keyframe=KeyframeSpec(position=landed, rpy=(2 * PI, 0.0, 0.0), joint_positions=landing),
            running=_weights([0, 1, 5, 2, 2, 2], [1] * 6, [0.1] * 3, [0.1] * 3, 0.1),
            terminal=_weights([0, 1, 5, 5, 5, 10], [2, 2, 0.5, 1, 1, 1], [0.1] * 3, [0.01] * 3),
            minimum_height=minimum_height,
        ),
        PhaseSpec(
            name="hop",
            contacts="FT",
            keyframe=KeyframeSpec(position=landed, rpy=(2 * PI, 0.0, 0.0), joint_positions=stand),
            running=_weights([0, 1, 5, 2, 2, 2], [1, 1, 0.5, 1, 1, 1], [1] * 3, [0.1] * 3, 0.1),
            terminal=_weights([0, 0, 1, 5, 5, 10], [2, 2, 0.2, 1, 1, 1], [1] * 3, [0.01] * 3),
            minimum_height=minimum_height,
        ),
        PhaseSpec(
            name="stand",
            contacts="FS",
            keyframe=KeyframeSpec(position=landed, rpy=(2 * PI, 0.0, 0.0), joint_positions=stand),
            running=_weights([0, 1, 5, 2, 2, 2], [1] * 6, [0.1] * 3, [0.1] * 3, 0.1),
            terminal=_weights([0, 1, 5, 5, 5, 10], [2, 2, 0.5, 1, 1, 1], [0.1] * 3, [0.01] * 3),
            minimum_height=minimum_height,
        ),
    ]
    return TrajOptTask(
        name="barrel-roll",
        robot="mini_cheetah",
        keyframes_robot="mini_cheetah",
        dt=0.01,
        switching_times=SWITCHING_TIMES,
        initial=KeyframeSpec(position=(0.0, 0.0, _z(0.2183)), joint_positions=stand),
        phases=phases,
        constraints=ConstraintSpec(joint_speed_limit=20.0, friction_coefficient=DEFAULT_FRICTION),
        solver=SolverSpec(max_iterations=10, max_al_iterations=30),
        initial_controls="static",
    )


def running_barrel_roll_task() -> TrajOptTask:
    """The barrel roll with the authors' running-roll phase durations (see the module docstring)."""
    task = barrel_roll_task()
    return task.model_copy(update={"name": "running-barrel-roll", "switching_times": RUNNING_SWITCHING_TIMES})
