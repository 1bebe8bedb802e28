"""Dynamics models of the CAFE-MPC plans (paper Sec. IV-A..C).

* ``MultibodyState`` / ``WholeBodyDynamics``: whole-body state manifold and KKT contact dynamics with an
  Euler step (Eqs. (19)-(23));
* ``ImpactReset``: touchdown impact map (22), (24);
* ``SRBState`` / ``SRBDynamics``: single-rigid-body tail (29), (30); ``srb_parameters(robot)``: its mass and
  inertia from the robot's model;
* ``WholeBodyToSRB`` / ``ComposedReset``: the model transition (31), (32);
* ``FootKinematics``: foot positions/velocities and their Jacobians for costs and constraints;
* ``static_stance_torques``: joint torques of a static stance (torque targets, PD feed-forward).
"""

from cafe_mpc.dynamics.impact import ImpactReset
from cafe_mpc.dynamics.kinematics import FootKinematics
from cafe_mpc.dynamics.multibody_state import MultibodyState
from cafe_mpc.dynamics.srb import SRBDynamics, SRBParameters, SRBState, srb_parameters
from cafe_mpc.dynamics.statics import static_stance_torques
from cafe_mpc.dynamics.transition import ComposedReset, WholeBodyToSRB, whole_body_to_srb_state
from cafe_mpc.dynamics.whole_body import ContactDynamicsError, WholeBodyDynamics

__all__ = [
    "ComposedReset",
    "ContactDynamicsError",
    "FootKinematics",
    "ImpactReset",
    "MultibodyState",
    "SRBDynamics",
    "SRBParameters",
    "SRBState",
    "WholeBodyDynamics",
    "WholeBodyToSRB",
    "srb_parameters",
    "static_stance_torques",
    "whole_body_to_srb_state",
]
