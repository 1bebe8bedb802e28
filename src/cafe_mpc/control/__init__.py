"""The MPC loop: a planner and a low level closed around the robot at the control rate.

* ``loop``: the interface (``MpcLoop``) both transports implement;
* ``inline``: the planner in the calling thread, in simulated (or the caller's) time;
* ``process``: the planner in its own process against the wall clock;
* ``ipc``: the shared-memory channels between them (one seqlock), generic over the plan type;
* ``commands``: runtime commands (velocity, gait) and their one check;
* ``plan_follower``: the low level on the newest plan with the safe ladder (last plan, balance, damped
  stance) when plans stop coming, or on one fixed plan;
* ``update_clock``: when the next real-time-iteration update happens.
"""
