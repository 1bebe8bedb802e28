"""Random points on the state manifolds, random controls, references and weights with every term on."""

from __future__ import annotations

import itertools

import numpy as np
import pinocchio as pin

from cafe_mpc.config.weights import SRBWeights, WholeBodyWeights
from cafe_mpc.dynamics.srb import SRBState
from cafe_mpc.ocp.knots import SRBReference, WholeBodyReference
from cafe_mpc.robots.robot import Robot

N_FEET = 4


def stance_modes() -> list[tuple[bool, ...]]:
    """Every contact mode of four feet (flight first, all four in stance last)."""
    return [tuple(bool(flag) for flag in flags) for flags in itertools.product((0, 1), repeat=N_FEET)]


def mode_name(flags: tuple[bool, ...]) -> str:
    """``(1, 0, 0, 1)`` -> ``"1001"`` (leg order FL, FR, HL, HR)."""
    return "".join(str(int(flag)) for flag in flags)


def whole_body_state(
    robot: Robot, rng: np.random.Generator, spread: float = 0.3, speed: float = 1.0, around=None
) -> np.ndarray:
    """``[q, v]``: ``q = q0 ⊕ spread * n`` (base pose and joints, ``q0`` the standing pose or ``around``'s
    configuration) and ``v = v0 + speed * n`` (``n`` standard normal)."""
    q0 = robot.q_standing if around is None else around[: robot.nq]
    v0 = np.zeros(robot.nv) if around is None else around[robot.nq :]
    q = pin.integrate(robot.model, q0, spread * rng.standard_normal(robot.nv))
    return np.concatenate([q, v0 + speed * rng.standard_normal(robot.nv)])


def srb_state(rng: np.random.Generator, height: float = 0.3) -> np.ndarray:
    """``[c, quaternion, c_dot, omega]`` at a random orientation and velocity, the body ``height`` up."""
    state = SRBState()
    x = state.integrate(state.zero(), rng.standard_normal(state.ndx))
    x[2] = height
    return x


def whole_body_reference(robot: Robot, rng: np.random.Generator) -> WholeBodyReference:
    """A reference away from the state: a state drawn far from standing, random feet and torques."""
    return WholeBodyReference(
        whole_body_state(robot, rng, spread=1.0),
        foot_positions=rng.standard_normal((N_FEET, 3)),
        foot_velocities=rng.standard_normal((N_FEET, 3)),
        torque=rng.standard_normal(robot.nu),
    )


def srb_reference(
    rng: np.random.Generator, contacts: tuple[bool, ...], weight: float, forces: bool = True
) -> SRBReference:
    """A reference state, footholds about 0.2 m around it, and (``forces``) a random GRF target."""
    x_ref = srb_state(rng)
    feet = x_ref[:3] + 0.2 * rng.standard_normal((N_FEET, 3))
    target = 10.0 * rng.standard_normal(3 * N_FEET) if forces else None
    return SRBReference(x_ref, feet, contacts, weight, target)


def srb_forces(rng: np.random.Generator, weight: float, spread: float = 20.0) -> np.ndarray:
    """Foot forces about the weight split over four feet (some outside the friction cone)."""
    forces = np.zeros((N_FEET, 3))
    forces[:, 2] = weight / N_FEET
    return (forces + spread * rng.standard_normal((N_FEET, 3))).reshape(-1)


def whole_body_weights(rng: np.random.Generator) -> WholeBodyWeights:
    """Every term of the whole-body cost (18) weighted, each weight its own (0.5 to 2): no Jacobian block of
    the residual is multiplied by zero."""

    def draw(size: int) -> tuple[float, ...]:
        return tuple(float(w) for w in rng.uniform(0.5, 2.0, size))

    return WholeBodyWeights(
        base_position=draw(6),
        base_velocity=draw(6),
        joint_position=draw(12),
        joint_velocity=draw(12),
        torque=draw(12),
        swing_foot_position=draw(12),
        swing_foot_velocity=draw(12),
    )


def srb_weights(rng: np.random.Generator) -> SRBWeights:
    """Every term of the SRB cost (28) weighted, each weight its own (0.5 to 2)."""

    def draw(size: int) -> tuple[float, ...]:
        return tuple(float(w) for w in rng.uniform(0.5, 2.0, size))

    return SRBWeights(base_position=draw(6), base_velocity=draw(6), force=draw(12))
