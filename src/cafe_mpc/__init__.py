"""CAFE-MPC: cascaded-fidelity whole-body MPC with MS-iLQR and value-function whole-body control."""

__version__ = "0.1.0"
