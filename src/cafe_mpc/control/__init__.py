"""Closed-loop compositions: the CAFE-MPC loop over a low-level controller (``mpc_loop``) and a low-level
controller on a fixed plan (``plan_follower``)."""
