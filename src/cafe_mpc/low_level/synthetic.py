"""Synthetic whole-body ``Plan``s around a static pose, for testing and benchmarking low-level controllers.

The real plans come from the MS-iLQR MPC; these stand-ins have the same shapes and plausible numbers so
that the Riccati controller (33) and the VWBC (34) can be exercised without running the MPC: a constant
state ``x*`` (standing pose, zero velocity), the static stance torques (weight split equally over the
stance feet) as ``tau*``, a random symmetric positive definite ``Quu``, and ``Qux = -Quu K`` for a gain ``K``
that is a joint PD plus random base-error feedback (so ``K = -Quu^{-1} Qux`` as in Eq. (7)).
"""

from __future__ import annotations

import numpy as np

from cafe_mpc.core.physics import GRAVITY
from cafe_mpc.dynamics.statics import static_stance_torques
from cafe_mpc.planners.cafe.plan import Plan
from cafe_mpc.robots.robot import Robot


def synthetic_plan(
    robot: Robot,
    stance: np.ndarray | tuple[bool, ...] | None = None,
    knots: int = 8,
    dt: float = 0.02,
    seed: int = 0,
    kp: float = 40.0,
    kd: float = 1.0,
    base_gain_scale: float = 5.0,
    qu_scale: float = 0.0,
    q: np.ndarray | None = None,
    t0: float = 0.0,
) -> Plan:
    """A ``Plan`` of ``knots`` identical knots holding ``q`` (default: standing), feet in ``stance`` (default:
    all)."""
    rng = np.random.default_rng(seed)
    stance = np.ones(robot.n_feet, dtype=bool) if stance is None else np.asarray(stance, dtype=bool)
    nu, nv = robot.nu, robot.nv
    q = robot.q_standing if q is None else np.asarray(q, dtype=float)
    x = np.concatenate([q, np.zeros(nv)])
    tau = static_stance_torques(robot, q, stance) if stance.any() else np.zeros(nu)  # flight: no support
    Quu = np.empty((knots, nu, nu))
    Qux = np.empty((knots, nu, 2 * nv))
    K = np.empty((knots, nu, 2 * nv))
    for k in range(knots):
        L = rng.normal(size=(nu, nu)) / np.sqrt(nu)
        Quu[k] = L @ L.T + 0.5 * np.eye(nu)
        gain = np.zeros((nu, 2 * nv))
        gain[:, nv - nu : nv] = -kp * np.eye(nu)
        gain[:, 2 * nv - nu :] = -kd * np.eye(nu)
        gain[:, : nv - nu] = base_gain_scale * rng.normal(size=(nu, nv - nu))
        gain[:, nv : 2 * nv - nu] = 0.1 * base_gain_scale * rng.normal(size=(nu, nv - nu))
        K[k] = gain
        Qux[k] = -Quu[k] @ gain
    forces = np.zeros((knots, robot.n_feet, 3))
    forces[:, stance, 2] = robot.total_mass * GRAVITY / max(int(stance.sum()), 1)
    return Plan(
        times=t0 + dt * np.arange(knots),
        xs=np.tile(x, (knots + 1, 1)),
        us=np.tile(tau, (knots, 1)),
        K=K,
        Qu=qu_scale * rng.normal(size=(knots, nu)),
        Quu=Quu,
        Qux=Qux,
        contacts=np.tile(stance, (knots, 1)),
        forces=forces,
        dt=np.full(knots, dt),
    )
