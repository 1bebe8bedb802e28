"""What the MPC process and the control loop exchange, without locks: shared memory and seqlocks.

* ``seqlock``: the seqlock protocol over a float64 array (a counter that is odd while the writer writes;
  readers copy and retry or skip when it moved), used by every channel here and by the runtime command
  channel (``control.commands``);
* ``shared``: named shared-memory blocks of float64 (``SharedArray``), named after the creating process;
* ``channels``: the measurement ring (main -> MPC process), the plan channel (MPC process -> main; generic
  over the plan type's array fields, ``core.plan.PlanFormat``) and the control block (stop, ready, scheme,
  runtime commands).
"""
