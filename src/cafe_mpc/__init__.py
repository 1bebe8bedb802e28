"""CAFE-MPC: cascaded-fidelity whole-body MPC with MS-iLQR and value-function whole-body control.

``cafe_mpc.Controller`` (``cafe_mpc.api``) is the controller as a library, for your own simulator or robot
loop; it is imported on first use (the command line does not need it).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"
__all__ = ["Controller", "__version__"]

if TYPE_CHECKING:
    from cafe_mpc.api import Controller


def __getattr__(name: str) -> Any:
    if name == "Controller":
        from cafe_mpc.api import Controller

        return Controller
    raise AttributeError(f"module 'cafe_mpc' has no attribute {name!r}")
